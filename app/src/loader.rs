//! File loading off the UI thread: scenes (with their BVH), SPMM packs, library files
//! for a material slot and environment maps are read as background jobs, and what
//! finished is handed to the studio (`poll`) to install. It also keeps the environment
//! maps (the shipped ones, the map read last, the last environment used) and sorts
//! dropped files. Its own type so the window holds no job of its own and one place
//! says what a load does.

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Instant;

use meso_materials::image::Image;
use meso_materials::spmm::SpmmMaterial;
use meso_materials::spmm::pack::ResidualPrecision;
use meso_render::geometry::SceneBvh;
use meso_render::scene::{Environment, Material, Scene, load_scene};

use crate::document::{Document, read_pack_file};
use crate::jobs::Job;
use crate::library::{self, EntryKind};
use crate::scene_panel;

/// A library file read for a material slot: its path, the material, and (for a
/// pack) its residual precision.
pub type Assigned = (PathBuf, Material, ResidualPrecision);

/// A load that finished, to install.
pub enum Loaded {
    /// An environment map was read: the scene's environment lit by it.
    /// A map read from this file, lighting the scene as its environment does now.
    Environment(Environment, PathBuf),
    Scene(PathBuf, Box<(Scene, SceneBvh)>),
    /// A library file for material slot `.0`.
    Assigned(usize, Assigned),
    Pack(PathBuf, Arc<SpmmMaterial>, ResidualPrecision),
}

/// What a dropped file is.
pub enum Dropped {
    Scene,
    Material(EntryKind),
}

/// "loading default.toml": what a background job does, for the status bar.
fn job_name(verb: &str, path: &Path) -> String {
    let file = path.file_name().unwrap_or(path.as_os_str());
    format!("{verb} {}", file.to_string_lossy())
}

/// The loads in progress and the environment maps.
pub struct Loader {
    repaint: Option<egui::Context>,
    scene_job: Option<Job<(PathBuf, Scene, SceneBvh)>>,
    pack_job: Option<Job<(PathBuf, Arc<SpmmMaterial>, ResidualPrecision)>>,
    /// A library file being read to go on material slot `.0`.
    assign_job: Option<(usize, Job<Assigned>)>,
    env_job: Option<Job<(PathBuf, Arc<Image>)>>,
    /// Shipped environment maps, the map read last (file, image), and the last
    /// environment used (turning it on again brings it back).
    environments: Vec<(String, PathBuf)>,
    env_source: Option<(PathBuf, Arc<Image>)>,
    last_environment: Option<Environment>,
}

impl Loader {
    pub fn new(repaint: Option<egui::Context>) -> Self {
        Self {
            repaint,
            scene_job: None,
            pack_job: None,
            assign_job: None,
            env_job: None,
            environments: scene_panel::shipped_environments(),
            env_source: None,
            last_environment: None,
        }
    }

    /// Whether a load is in progress.
    pub fn busy(&self) -> bool {
        self.scene_job.is_some()
            || self.pack_job.is_some()
            || self.env_job.is_some()
            || self.assign_job.is_some()
    }

    /// The loads in progress, for the status bar: name and start.
    pub fn jobs(&self) -> impl Iterator<Item = (&String, Instant)> {
        [
            self.scene_job.as_ref().map(|j| (&j.name, j.started)),
            self.pack_job.as_ref().map(|j| (&j.name, j.started)),
            self.assign_job.as_ref().map(|(_, j)| (&j.name, j.started)),
            self.env_job.as_ref().map(|j| (&j.name, j.started)),
        ]
        .into_iter()
        .flatten()
    }

    /// Starts loading a scene.
    pub fn open_scene(&mut self, path: &Path) {
        let path = path.to_path_buf();
        let name = job_name("loading", &path);
        self.scene_job = Some(Job::spawn(name, self.repaint.clone(), move || {
            let scene = load_scene(&path).map_err(|e| e.to_string())?;
            let bvh = SceneBvh::build(&scene.meshes);
            Ok((path, scene, bvh))
        }));
    }

    /// Starts reading a pack.
    pub fn open_pack(&mut self, path: &Path) {
        let path = path.to_path_buf();
        let name = job_name("reading", &path);
        self.pack_job = Some(Job::spawn(name, self.repaint.clone(), move || {
            let (material, precision) = read_pack_file(&path)?;
            Ok((path, material, precision))
        }));
    }

    /// Starts reading a library file of `kind` for material slot `index`, which
    /// holds `slot` now (a MERL file keeps its parameters where they apply).
    pub fn assign(&mut self, kind: EntryKind, path: &Path, index: usize, slot: Material) {
        let path = path.to_path_buf();
        let name = job_name("reading", &path);
        let job = Job::spawn(name, self.repaint.clone(), move || {
            let bytes = std::fs::read(&path).map_err(|e| format!("`{}`: {e}", path.display()))?;
            let (material, precision) = library::material_from(kind, &path, &bytes, Some(&slot))?;
            Ok((path, material, precision))
        });
        self.assign_job = Some((index, job));
    }

    /// Starts reading an environment map.
    pub fn open_environment(&mut self, path: &Path) {
        let path = path.to_path_buf();
        let name = job_name("reading", &path);
        self.env_job = Some(Job::spawn(name, self.repaint.clone(), move || {
            let map = meso_materials::image::read_image(&path)
                .map_err(|e| format!("`{}`: {e}", path.display()))?;
            if let Some(p) = meso_render::environment::check_map(&map) {
                return Err(format!("`{}`: {p}", path.display()));
            }
            Ok((path, Arc::new(map)))
        }));
    }

    /// The environment to turn on: the last one used (`Some`), or the first shipped
    /// map, which starts being read (`None`).
    pub fn environment_on(&mut self) -> Result<Option<Environment>, String> {
        if let Some(e) = self.last_environment.clone() {
            Ok(Some(e))
        } else if let Some((_, path)) = self.environments.first().cloned() {
            self.open_environment(&path);
            Ok(None)
        } else {
            Err("no environment map is shipped: pick a file".into())
        }
    }

    /// Notes the environment the scene uses now (turning it on again brings it back).
    pub fn note_environment(&mut self, doc: &Document) {
        if let Some(e) = &doc.scene.environment {
            self.last_environment = Some(e.clone());
        }
    }

    /// The maps shipped with Meso (name, file).
    pub fn environments(&self) -> &[(String, PathBuf)] {
        &self.environments
    }

    /// The file name of the map `env` is lit by, if it was read here.
    pub fn environment_name(&self, env: &Environment) -> Option<String> {
        self.env_source
            .as_ref()
            .filter(|(_, m)| Arc::ptr_eq(m, &env.map))
            .and_then(|(p, _)| p.file_stem())
            .map(|n| n.to_string_lossy().into_owned())
    }

    /// The loads that finished, in the order they are installed: an environment map
    /// (lighting `doc`'s scene as its environment is now), a scene, a library file,
    /// a pack.
    pub fn poll(&mut self, doc: Option<&Document>) -> Vec<Result<Loaded, String>> {
        let mut done = Vec::new();
        if let Some(r) = self.env_job.as_ref().and_then(|j| j.poll()) {
            self.env_job = None;
            done.push(r.map(|(path, map)| {
                let env = match doc.and_then(|d| d.scene.environment.clone()) {
                    Some(e) => Environment {
                        map: Arc::clone(&map),
                        ..e
                    },
                    None => Environment {
                        map: Arc::clone(&map),
                        strength: 1.0,
                        rotate_y_deg: 0.0,
                        mis: true,
                    },
                };
                self.env_source = Some((path.clone(), map));
                Loaded::Environment(env, path)
            }));
        }
        if let Some(r) = self.scene_job.as_ref().and_then(|j| j.poll()) {
            self.scene_job = None;
            done.push(r.map(|(path, scene, bvh)| Loaded::Scene(path, Box::new((scene, bvh)))));
        }
        if let Some(r) = self.assign_job.as_ref().and_then(|(_, j)| j.poll()) {
            let (index, _) = self.assign_job.take().expect("polled above");
            done.push(r.map(|a| Loaded::Assigned(index, a)));
        }
        if let Some(r) = self.pack_job.as_ref().and_then(|j| j.poll()) {
            self.pack_job = None;
            done.push(r.map(|(path, material, precision)| Loaded::Pack(path, material, precision)));
        }
        done
    }
}

/// A file dropped on the window: a scene `.toml`, a library material (a `.spmm`
/// pack, a MERL `.binary`, a BTF), or what to drop instead.
pub fn dropped(path: &Path) -> Result<Dropped, String> {
    let ext = path
        .extension()
        .map(|e| e.to_string_lossy().to_ascii_lowercase());
    match ext.as_deref() {
        Some("toml") => Ok(Dropped::Scene),
        _ => EntryKind::of(path).map(Dropped::Material).ok_or_else(|| {
            format!(
                "`{}`: drop a .spmm pack, a MERL .binary or a scene .toml",
                path.display()
            )
        }),
    }
}
