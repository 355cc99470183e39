//! The material library: the shipped packs (`materials/*.spmm`) and the files in the
//! designer's own folders (SPMM packs, MERL `.binary` tables, BTFs), each with a
//! thumbnail: a lit sphere in that material rendered by core's spmm mode on a
//! background thread. Thumbnails are cached on disk under the hash of the file's bytes
//! (and of the thumbnail recipe), so a library opened again shows them without
//! rendering. A click asks the studio to assign the material to the selected object
//! (an ordinary, undoable `SceneEdit`); BTFs are listed but cannot be assigned until a
//! BTF material kind exists (the click says what to do instead).

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::mpsc::{self, Receiver, Sender};
use std::thread::JoinHandle;

use egui::{ColorImage, TextureHandle, TextureOptions, Ui};
use glam::{DVec2, DVec3};
use meso_materials::hash::fnv1a128;
use meso_materials::image::{Image, to_srgb8};
use meso_materials::merl::MerlBrdf;
use meso_materials::rng::Sampler;
use meso_materials::spmm::pack;
use meso_render::RenderModeExt;
use meso_render::scene::mesh::TriangleMesh;
use meso_render::scene::{Ambient, Background, Camera, Light, Material, RenderSettings, Scene};
use meso_render::{Device, ModeKind, Prepare};

/// Thumbnail side in pixels and samples per pixel.
pub const THUMB_SIZE: u32 = 96;
pub const THUMB_SPP: u32 = 16;
/// Names the thumbnail scene and settings: part of the cache key, so a change of the
/// recipe (bump it) never shows stale thumbnails.
const THUMB_RECIPE: &str = "meso-thumbnail 1: uv sphere 48x24, uv_scale 4x2, area light + ambient, 96 px, 16 spp, spmm cpu";

/// What a library file is.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum EntryKind {
    /// An SPMM pack (`.spmm`).
    Pack,
    /// A measured isotropic BRDF in the MERL binary format (`.binary`).
    Merl,
    /// A bidirectional texture function (`.btf`): listed, not yet a material kind.
    Btf,
}

impl EntryKind {
    /// The kind of the file at `path`, by its extension (case-insensitive).
    pub fn of(path: &Path) -> Option<Self> {
        let ext = path.extension()?.to_string_lossy().to_ascii_lowercase();
        match ext.as_str() {
            "spmm" => Some(Self::Pack),
            "binary" => Some(Self::Merl),
            "btf" => Some(Self::Btf),
            _ => None,
        }
    }
}

/// One file of the library.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Entry {
    pub path: PathBuf,
    /// The file name without its extension.
    pub name: String,
    pub kind: EntryKind,
}

/// Where the project's packs are.
pub fn shipped_dir() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../materials")
}

/// The library files directly in `dir` (not its subfolders), by name; an unreadable
/// folder has none.
pub fn scan(dir: &Path) -> Vec<Entry> {
    let mut entries: Vec<Entry> = std::fs::read_dir(dir)
        .into_iter()
        .flatten()
        .flatten()
        .map(|e| e.path())
        .filter(|p| p.is_file())
        .filter_map(|path| {
            let kind = EntryKind::of(&path)?;
            let name = path.file_stem()?.to_string_lossy().into_owned();
            Some(Entry { path, name, kind })
        })
        .collect();
    entries.sort_by(|a, b| a.name.cmp(&b.name).then(a.path.cmp(&b.path)));
    entries
}

/// The default thumbnail cache folder: `$XDG_CACHE_HOME/meso/thumbnails`, else
/// `~/.cache/meso/thumbnails`, else one in the temporary folder.
pub fn default_cache_dir() -> PathBuf {
    let base = std::env::var_os("XDG_CACHE_HOME")
        .map(PathBuf::from)
        .filter(|p| p.is_absolute())
        .or_else(|| std::env::var_os("HOME").map(|h| PathBuf::from(h).join(".cache")))
        .unwrap_or_else(std::env::temp_dir);
    base.join("meso").join("thumbnails")
}

/// 128-bit FNV-1a of the thumbnail recipe and then `bytes`: the cache key of a file's
/// thumbnail (a different file content or recipe gives a different key).
pub fn content_key(bytes: &[u8]) -> u128 {
    fnv1a128([THUMB_RECIPE.as_bytes(), bytes])
}

/// A thumbnail as shown: sRGB, 8 bits per channel, row-major RGB.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Thumbnail {
    pub width: u32,
    pub height: u32,
    pub rgb: Vec<u8>,
}

const CACHE_MAGIC: &[u8] = b"meso-thumb 1\n";

impl Thumbnail {
    pub fn from_image(img: &Image) -> Self {
        Self {
            width: img.width(),
            height: img.height(),
            rgb: to_srgb8(img, 0.0).into_iter().flatten().collect(),
        }
    }

    /// The cache file's bytes: a magic line, width and height (u32 little-endian),
    /// then the pixels.
    fn encode(&self) -> Vec<u8> {
        let mut out = CACHE_MAGIC.to_vec();
        out.extend(self.width.to_le_bytes());
        out.extend(self.height.to_le_bytes());
        out.extend(&self.rgb);
        out
    }

    /// A cache file's thumbnail, or `None` if the bytes are not one (a damaged file is
    /// rendered again, never trusted).
    fn decode(bytes: &[u8]) -> Option<Self> {
        let rest = bytes.strip_prefix(CACHE_MAGIC)?;
        let width = u32::from_le_bytes(rest.get(0..4)?.try_into().ok()?);
        let height = u32::from_le_bytes(rest.get(4..8)?.try_into().ok()?);
        let rgb = rest.get(8..)?;
        let expected = (width as usize)
            .checked_mul(height as usize)?
            .checked_mul(3)?;
        (width > 0 && height > 0 && rgb.len() == expected).then(|| Self {
            width,
            height,
            rgb: rgb.to_vec(),
        })
    }
}

/// Thumbnails on disk, one file per content key.
#[derive(Clone, Debug)]
pub struct ThumbnailCache {
    dir: PathBuf,
}

impl ThumbnailCache {
    pub fn new(dir: PathBuf) -> Self {
        Self { dir }
    }

    pub fn path_of(&self, key: u128) -> PathBuf {
        self.dir.join(format!("{key:032x}.thumb"))
    }

    pub fn load(&self, key: u128) -> Option<Thumbnail> {
        Thumbnail::decode(&std::fs::read(self.path_of(key)).ok()?)
    }

    /// Writes atomically (a reader never sees half a thumbnail).
    pub fn store(&self, key: u128, thumb: &Thumbnail) -> Result<(), String> {
        std::fs::create_dir_all(&self.dir).map_err(|e| format!("`{}`: {e}", self.dir.display()))?;
        meso_materials::atomic::write_bytes_atomic(&self.path_of(key), &thumb.encode())
            .map_err(|e| e.to_string())
    }
}

/// A lat-long unit sphere at the origin: `rings` x `segments` quads, outward normals,
/// uv = (longitude, latitude) in [0, 1]^2.
fn sphere(rings: u32, segments: u32, material: usize) -> TriangleMesh {
    let mut mesh = TriangleMesh {
        positions: Vec::new(),
        normals: Vec::new(),
        uvs: Vec::new(),
        indices: Vec::new(),
        material,
    };
    for i in 0..=rings {
        let v = f64::from(i) / f64::from(rings);
        let theta = std::f64::consts::PI * v;
        for j in 0..=segments {
            let u = f64::from(j) / f64::from(segments);
            let phi = std::f64::consts::TAU * u;
            let p = DVec3::new(
                theta.sin() * phi.cos(),
                theta.cos(),
                -theta.sin() * phi.sin(),
            );
            mesh.positions.push(p);
            mesh.normals.push(p);
            mesh.uvs.push(DVec2::new(u, 1.0 - v));
        }
    }
    let row = segments + 1;
    for i in 0..rings {
        for j in 0..segments {
            let a = i * row + j;
            let (b, c, d) = (a + row, a + row + 1, a + 1);
            if i > 0 {
                mesh.indices.push([a, b, d]);
            }
            if i + 1 < rings {
                mesh.indices.push([d, b, c]);
            }
        }
    }
    mesh
}

/// The thumbnail scene: `material` on a unit sphere under an area light (upper left,
/// in front) and a dim ambient term, on a dark background.
pub fn thumbnail_scene(material: Material) -> Scene {
    Scene {
        render: RenderSettings {
            width: THUMB_SIZE,
            height: THUMB_SIZE,
            frames: THUMB_SPP,
            seed: 1,
            max_specular_depth: 2,
            mode: ModeKind::Spmm,
            device: Device::Cpu,
            sampler: Sampler::Sobol,
            light_samples: 1,
        },
        camera: Camera {
            position: DVec3::new(0.0, 0.9, 3.3),
            look_at: DVec3::ZERO,
            up: DVec3::Y,
            fov_y_deg: 38.0,
        },
        material_names: vec!["thumbnail".into()],
        material_files: Vec::new(),
        materials: vec![material],
        meshes: vec![sphere(24, 48, 0)],
        lights: vec![Light::Area {
            corner: DVec3::new(-2.2, 2.4, 1.2),
            edge_u: DVec3::new(1.2, 0.0, 0.0),
            edge_v: DVec3::new(0.0, 0.0, 1.2),
            radiance: DVec3::splat(4.0),
        }],
        ambient: Some(Ambient {
            radiance: DVec3::splat(0.35),
            radius: f64::INFINITY,
        }),
        environment: None,
        background: Background::Color(DVec3::new(0.03, 0.03, 0.035)),
    }
}

/// The material a library file gives a scene slot (`slot`: what the slot holds now,
/// whose tiling and residual settings a pack keeps), read from `bytes`.
pub fn material_from(
    kind: EntryKind,
    path: &Path,
    bytes: &[u8],
    slot: Option<&Material>,
) -> Result<(Material, pack::ResidualPrecision), String> {
    let named = |e: &dyn std::fmt::Display| format!("`{}`: {e}", path.display());
    match kind {
        EntryKind::Pack => {
            let m = Arc::new(pack::decode_pack(bytes).map_err(|e| named(&e))?);
            let (uv_scale, residual) = match slot {
                Some(Material::Spmm {
                    uv_scale, residual, ..
                }) => (*uv_scale, *residual),
                _ => (DVec2::new(4.0, 4.0), true),
            };
            let npca = m.npca();
            Ok((
                Material::Spmm {
                    material: m,
                    uv_scale,
                    residual,
                    npca,
                },
                pack::residual_precision(bytes),
            ))
        }
        EntryKind::Merl => {
            let brdf = MerlBrdf::from_bytes(bytes).map_err(|e| named(&e))?;
            let tint = match slot {
                Some(Material::Merl { tint, .. }) => *tint,
                _ => DVec3::ONE,
            };
            Ok((
                Material::Merl {
                    brdf: Arc::new(brdf),
                    tint,
                },
                pack::ResidualPrecision::F32,
            ))
        }
        EntryKind::Btf => Err(btf_message(path)),
    }
}

/// Why a BTF cannot be assigned, and what to do instead.
pub fn btf_message(path: &Path) -> String {
    format!(
        "`{}` is a BTF: there is no BTF material kind yet; fit it to a pack \
         (`meso fit {} -o PACK.spmm`) and use the pack",
        path.display(),
        path.display()
    )
}

/// Renders the thumbnail of `material` with core's spmm mode.
pub fn render_thumbnail(material: Material) -> Result<Image, String> {
    let scene = thumbnail_scene(material);
    let mut mode = meso_modes::create(
        ModeKind::Spmm,
        Device::Cpu,
        scene,
        THUMB_SIZE,
        THUMB_SIZE,
        Prepare::quietly(),
    )
    .map_err(|e| e.to_string())?;
    for _ in 0..THUMB_SPP {
        mode.render_frame();
    }
    Ok(mode.image())
}

/// Where a thumbnail came from.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Source {
    Cache,
    Rendered,
}

/// The thumbnail of the file at `path` (of `kind`): from the cache when its bytes
/// were seen before, else rendered and stored.
pub fn thumbnail_of(
    cache: &ThumbnailCache,
    kind: EntryKind,
    path: &Path,
) -> Result<(Thumbnail, Source), String> {
    if kind == EntryKind::Btf {
        return Err("BTFs have no material kind to render yet".into());
    }
    let bytes = std::fs::read(path).map_err(|e| format!("`{}`: {e}", path.display()))?;
    let key = content_key(&bytes);
    if let Some(t) = cache.load(key) {
        return Ok((t, Source::Cache));
    }
    let (material, _) = material_from(kind, path, &bytes, None)?;
    let thumb = Thumbnail::from_image(&render_thumbnail(material)?);
    // A cache that cannot be written only costs a render next time.
    let _ = cache.store(key, &thumb);
    Ok((thumb, Source::Rendered))
}

struct Done {
    path: PathBuf,
    result: Result<(Thumbnail, Source), String>,
}

/// The thumbnail thread: renders the requested files one at a time, in order.
struct Worker {
    requests: Option<Sender<Entry>>,
    results: Receiver<Done>,
    thread: Option<JoinHandle<()>>,
}

impl Worker {
    fn spawn(cache: ThumbnailCache, repaint: Option<egui::Context>) -> Self {
        let (tx, rx) = mpsc::channel::<Entry>();
        let (done_tx, done_rx) = mpsc::channel();
        let thread = std::thread::Builder::new()
            .name("meso-thumbnails".into())
            .spawn(move || {
                while let Ok(entry) = rx.recv() {
                    let result = thumbnail_of(&cache, entry.kind, &entry.path);
                    if done_tx
                        .send(Done {
                            path: entry.path,
                            result,
                        })
                        .is_err()
                    {
                        return;
                    }
                    if let Some(ctx) = &repaint {
                        ctx.request_repaint();
                    }
                }
            })
            .ok();
        Self {
            requests: Some(tx),
            results: done_rx,
            thread,
        }
    }
}

impl Drop for Worker {
    fn drop(&mut self) {
        self.requests.take();
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

enum Thumb {
    Pending,
    Ready(Thumbnail, Option<TextureHandle>),
    Failed(String),
}

/// What the library asks the studio to do.
#[derive(Clone, Debug, PartialEq)]
pub enum LibraryRequest {
    /// Put this file's material on the selected object.
    Assign(Entry),
    AddFolderDialog,
    RemoveFolder(PathBuf),
}

/// The library panel's state: the listed files and their thumbnails.
pub struct Library {
    /// (folder, its files); the shipped folder first.
    groups: Vec<(PathBuf, Vec<Entry>)>,
    thumbs: HashMap<PathBuf, Thumb>,
    worker: Worker,
    /// Thumbnails rendered and thumbnails read from the cache, since it opened.
    pub rendered: usize,
    pub from_cache: usize,
}

impl Library {
    /// Lists the files of `folders` (the studio passes the shipped folder first) and
    /// starts their thumbnails.
    pub fn open(
        folders: &[PathBuf],
        cache: ThumbnailCache,
        repaint: Option<egui::Context>,
    ) -> Self {
        let mut lib = Self {
            groups: Vec::new(),
            thumbs: HashMap::new(),
            worker: Worker::spawn(cache, repaint),
            rendered: 0,
            from_cache: 0,
        };
        lib.rescan(folders);
        lib
    }

    /// Lists the folders again; files not seen before get their thumbnails started.
    pub fn rescan(&mut self, folders: &[PathBuf]) {
        let mut seen = Vec::new();
        self.groups = folders
            .iter()
            .filter(|f| {
                let new = !seen.contains(f);
                seen.push(f);
                new
            })
            .map(|dir| (dir.clone(), scan(dir)))
            .collect();
        for entry in self.groups.iter().flat_map(|(_, e)| e) {
            if self.thumbs.contains_key(&entry.path) {
                continue;
            }
            if entry.kind == EntryKind::Btf {
                self.thumbs.insert(
                    entry.path.clone(),
                    Thumb::Failed("BTF: fit it to a pack to use it".into()),
                );
            } else if let Some(tx) = &self.worker.requests
                && tx.send(entry.clone()).is_ok()
            {
                self.thumbs.insert(entry.path.clone(), Thumb::Pending);
            }
        }
    }

    /// Every listed file, the shipped ones first.
    pub fn entries(&self) -> impl Iterator<Item = &Entry> {
        self.groups.iter().flat_map(|(_, e)| e)
    }

    /// Whether thumbnails are still being made.
    pub fn pending(&self) -> usize {
        self.thumbs
            .values()
            .filter(|t| matches!(t, Thumb::Pending))
            .count()
    }

    /// The thumbnail of the file at `path`, once made.
    pub fn thumbnail(&self, path: &Path) -> Option<&Thumbnail> {
        match self.thumbs.get(path) {
            Some(Thumb::Ready(t, _)) => Some(t),
            _ => None,
        }
    }

    /// Why the file at `path` has no thumbnail, if it failed.
    pub fn failure(&self, path: &Path) -> Option<&str> {
        match self.thumbs.get(path) {
            Some(Thumb::Failed(e)) => Some(e),
            _ => None,
        }
    }

    /// Takes the finished thumbnails.
    pub fn poll(&mut self) {
        while let Ok(done) = self.worker.results.try_recv() {
            let thumb = match done.result {
                Ok((t, source)) => {
                    match source {
                        Source::Cache => self.from_cache += 1,
                        Source::Rendered => self.rendered += 1,
                    }
                    Thumb::Ready(t, None)
                }
                Err(e) => Thumb::Failed(e),
            };
            self.thumbs.insert(done.path, thumb);
        }
    }

    /// The panel: per folder its files as thumbnail buttons (`target` names the
    /// object a click assigns to).
    pub fn show(&mut self, ui: &mut Ui, target: &str) -> Vec<LibraryRequest> {
        self.poll();
        let mut requests = Vec::new();
        ui.horizontal(|ui| {
            ui.label(format!("click assigns to: {target}"));
            if ui.button("Add folder…").clicked() {
                requests.push(LibraryRequest::AddFolderDialog);
            }
        });
        let shipped = shipped_dir();
        let groups = self.groups.clone();
        for (dir, entries) in &groups {
            ui.separator();
            ui.horizontal(|ui| {
                if *dir == shipped {
                    ui.strong("Shipped packs");
                } else {
                    ui.strong(dir.display().to_string());
                    if ui.small_button("Remove").clicked() {
                        requests.push(LibraryRequest::RemoveFolder(dir.clone()));
                    }
                }
            });
            if entries.is_empty() {
                ui.weak("no .spmm, .binary or .btf files here");
            }
            ui.horizontal_wrapped(|ui| {
                for entry in entries {
                    // Each entry in its own id scope and of one size in every state:
                    // its id and place stay put while thumbnails land (a click at that
                    // moment would be lost otherwise).
                    let clicked = ui
                        .push_id(&entry.path, |ui| self.entry_button(ui, entry))
                        .inner;
                    if clicked {
                        requests.push(LibraryRequest::Assign(entry.clone()));
                    }
                }
            });
        }
        requests
    }

    /// One file: its thumbnail beside its name, else an empty square of the same size
    /// with a spinner (being made) or "no preview" (why, on hover). Every state takes the
    /// same room, so a thumbnail landing never moves the entries under the pointer.
    fn entry_button(&mut self, ui: &mut Ui, entry: &Entry) -> bool {
        let side = THUMB_SIZE as f32 * 0.75;
        let kind = match entry.kind {
            EntryKind::Pack => "SPMM pack",
            EntryKind::Merl => "MERL table",
            EntryKind::Btf => "BTF",
        };
        let mut hover = format!("{kind}: {}", entry.path.display());
        let image = match self.thumbs.get_mut(&entry.path) {
            Some(Thumb::Ready(t, texture)) => {
                let tex = texture.get_or_insert_with(|| {
                    let image = ColorImage::from_rgb([t.width as usize, t.height as usize], &t.rgb);
                    ui.ctx().load_texture(
                        format!("library {}", entry.path.display()),
                        image,
                        TextureOptions::LINEAR,
                    )
                });
                egui::Image::new((tex.id(), egui::vec2(side, side)))
            }
            other => {
                if let Some(Thumb::Failed(e)) = other {
                    hover = format!("{hover}\n{e}");
                }
                // Fully transparent: it only holds the thumbnail's place.
                egui::Image::new((egui::TextureId::default(), egui::vec2(side, side)))
                    .tint(egui::Color32::TRANSPARENT)
            }
        };
        let response = ui.add(egui::Button::image_and_text(image, &entry.name));
        let square = egui::Rect::from_min_size(
            response.rect.left_top() + ui.spacing().button_padding,
            egui::vec2(side, side),
        );
        match self.thumbs.get(&entry.path) {
            Some(Thumb::Ready(..)) => {}
            Some(Thumb::Failed(_)) => {
                ui.painter().text(
                    square.center(),
                    egui::Align2::CENTER_CENTER,
                    "no preview",
                    egui::TextStyle::Small.resolve(ui.style()),
                    ui.visuals().weak_text_color(),
                );
            }
            _ => egui::Spinner::new().paint_at(ui, square.shrink(side * 0.3)),
        }
        response.on_hover_text(hover).clicked()
    }
}

#[cfg(test)]
#[path = "library_tests.rs"]
mod tests;
