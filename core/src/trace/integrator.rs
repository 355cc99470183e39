//! The `spmm` render mode: progressive ray tracing (Silva & Santos 2013, section 4).
//! Per pixel and frame one jittered primary ray; each point light with one shadow ray;
//! each area light with one shadow ray to a point drawn uniformly on its area (eq. 4-5
//! in the area measure: L_e f cos_i cos_l / r^2 * A); ambient occlusion with one
//! cosine-distributed ray limited to the ambient radius (eq. 6-7: pi L_a V f per
//! sample); perfect mirror reflection up to the scene's depth. SPMM materials return the
//! BTF, cosine included. Every light, the ambient term and the background accumulate
//! for unit emission in their own film layer (`render::film`), so edits keep samples.

use std::time::Instant;

use glam::{DVec2, DVec3};

use super::bvh::{Hit, SceneBvh};
use super::camera::PinholeCamera;
use crate::brdf::warp;
use crate::image::Image;
use crate::render::film::material_bit;
use crate::render::{
    EditError, Film, FrameStats, GeometryUpdate, Invalidation, ModeKind, Progress, RenderMode,
    SceneEdit,
};
use crate::rng::SampleStream;
use crate::scene::{Background, Light, Material, Scene};
use crate::spmm::{EvalSettings, PrepareRequest, PreparedSpmm, TexelFilter};

/// Offset of secondary ray origins along the normal, relative to the hit point's
/// magnitude: well above the f32 rounding of the BVH's triangles (6e-8 relative).
const EPSILON_REL: f64 = 1e-5;

/// Film layers: the background, the ambient term, then one per light.
const BACKGROUND: usize = 0;
const AMBIENT: usize = 1;
const FIRST_LIGHT: usize = 2;

/// Rays traced, by kind.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
pub struct RayCounts {
    pub primary: u64,
    pub shadow: u64,
    pub ambient: u64,
    pub specular: u64,
}

impl std::ops::Add for RayCounts {
    type Output = Self;
    fn add(self, o: Self) -> Self {
        Self {
            primary: self.primary + o.primary,
            shadow: self.shadow + o.shadow,
            ambient: self.ambient + o.ambient,
            specular: self.specular + o.specular,
        }
    }
}

impl RayCounts {
    pub fn total(&self) -> u64 {
        self.primary + self.shadow + self.ambient + self.specular
    }
}

/// What shading a material needs at render time.
enum Shader {
    /// Analytic BRDFs and mirrors read the scene's material directly.
    Scene,
    /// An SPMM pack prepared for this render, with its settings when still and moving.
    Spmm {
        prepared: Box<PreparedSpmm>,
        still: EvalSettings,
        moving: EvalSettings,
    },
}

impl Shader {
    fn new(material: &Material) -> Self {
        match material {
            Material::Spmm {
                material,
                uv_scale,
                residual,
                npca,
            } => {
                let still = EvalSettings {
                    residual: *residual,
                    max_npca: *npca,
                    filter: TexelFilter::Nearest,
                    uv_scale: *uv_scale,
                };
                Shader::Spmm {
                    prepared: Box::new(material.prepare(&PrepareRequest {
                        used_clusters: None,
                        residual: *residual,
                        max_npca: *npca,
                    })),
                    still,
                    moving: EvalSettings {
                        residual: false,
                        ..still
                    },
                }
            }
            _ => Shader::Scene,
        }
    }

    /// True if moving changes this material's evaluation (it has a residual in use).
    fn skips_residual_when_moving(&self) -> bool {
        matches!(self, Shader::Spmm { prepared, still, .. } if still.residual && prepared.has_residual())
    }
}

/// The `spmm` mode: owns its scene, BVH, prepared materials and film.
pub struct SpmmMode {
    scene: Scene,
    bvh: SceneBvh,
    camera: PinholeCamera,
    shaders: Vec<Shader>,
    film: Film,
    samples_per_frame: u32,
    /// Index of the next sample (frame-major); random numbers derive from it.
    next_sample: u64,
    frames: u32,
    moving: bool,
    /// The radius the ambient layer's samples were traced with.
    ambient_radius: Option<f64>,
}

struct Shading {
    p: DVec3,
    /// Shading frame: tangent, bitangent, normal (facing the incoming ray).
    t: DVec3,
    b: DVec3,
    n: DVec3,
    uv: DVec2,
    material: usize,
}

fn check_size(width: u32, height: u32) -> Result<(), EditError> {
    if (1..=16384).contains(&width) && (1..=16384).contains(&height) {
        Ok(())
    } else {
        Err(EditError::Size { width, height })
    }
}

impl SpmmMode {
    pub fn new(scene: Scene, width: u32, height: u32) -> Result<Self, EditError> {
        check_size(width, height)?;
        let bvh = SceneBvh::build(&scene.meshes);
        let shaders = scene.materials.iter().map(Shader::new).collect();
        Ok(Self {
            bvh,
            camera: PinholeCamera::new(&scene.camera, width, height),
            shaders,
            film: Film::new(width, height, FIRST_LIGHT + scene.lights.len()),
            samples_per_frame: 1,
            next_sample: 0,
            frames: 0,
            moving: false,
            ambient_radius: scene.ambient.map(|a| a.radius),
            scene,
        })
    }

    pub fn bvh(&self) -> &SceneBvh {
        &self.bvh
    }

    /// The weight of each film layer: the current emissions.
    fn layer_weights(&self) -> Vec<DVec3> {
        let mut w = vec![DVec3::ZERO; self.film.layers()];
        w[BACKGROUND] = match &self.scene.background {
            Background::Color(c) => *c,
            Background::Environment(_) => DVec3::ONE,
        };
        w[AMBIENT] = self.scene.ambient.map_or(DVec3::ZERO, |a| a.radiance);
        for (k, light) in self.scene.lights.iter().enumerate() {
            w[FIRST_LIGHT + k] = light.emission();
        }
        w
    }

    /// The layers sampled every frame (the ambient layer only while AO is on).
    fn active_layers(&self) -> Vec<usize> {
        (0..self.film.layers())
            .filter(|&l| l != AMBIENT || self.scene.ambient.is_some())
            .collect()
    }

    /// One sample of pixel (x, y) with sample index `index`, per layer for unit
    /// emission, the materials it shaded and the rays it traced. Replayable: a bad
    /// pixel can be re-rendered alone.
    pub fn sample(&self, x: u32, y: u32, index: u64) -> (Vec<DVec3>, u64, RayCounts) {
        let mut out = vec![DVec3::ZERO; self.film.layers()];
        let mut mask = 0;
        let mut counts = RayCounts::default();
        self.sample_into(
            x,
            y,
            self.film.width(),
            index,
            &mut out,
            &mut mask,
            &mut counts,
        );
        (out, mask, counts)
    }

    /// `width` is the image's (the film may be borrowed out while a frame renders).
    #[allow(clippy::too_many_arguments)]
    fn sample_into(
        &self,
        x: u32,
        y: u32,
        width: u32,
        index: u64,
        out: &mut [DVec3],
        mask: &mut u64,
        counts: &mut RayCounts,
    ) {
        let pixel = u64::from(y) * u64::from(width) + u64::from(x);
        let mut rng = SampleStream::new(&[self.scene.render.seed, index, pixel]);
        let ray = self.camera.ray(x, y, rng.next_2d());
        counts.primary += 1;
        let mut path = Path {
            out,
            mask,
            counts,
            rng: &mut rng,
        };
        self.trace(ray.origin, ray.dir, 0, DVec3::ONE, &mut path);
    }

    fn shading(&self, hit: &Hit, dir: DVec3) -> Shading {
        let mesh = &self.scene.meshes[hit.mesh];
        let [i0, i1, i2] = mesh.indices[hit.triangle].map(|i| i as usize);
        let w0 = 1.0 - hit.b1 - hit.b2;
        let (p0, p1, p2) = (mesh.positions[i0], mesh.positions[i1], mesh.positions[i2]);
        let p = p0 * w0 + p1 * hit.b1 + p2 * hit.b2;
        let mut ng = (p1 - p0).cross(p2 - p0).normalize_or(DVec3::Y);
        if ng.dot(dir) > 0.0 {
            ng = -ng;
        }
        let mut n = (mesh.normals[i0] * w0 + mesh.normals[i1] * hit.b1 + mesh.normals[i2] * hit.b2)
            .normalize_or(ng);
        // Normals facing away from the viewer are flipped to the side the ray came from.
        if n.dot(ng) < 0.0 {
            n = -n;
        }
        let (uv0, uv1, uv2) = (mesh.uvs[i0], mesh.uvs[i1], mesh.uvs[i2]);
        let uv = uv0 * w0 + uv1 * hit.b1 + uv2 * hit.b2;
        // Tangent along increasing u (dp/du), made orthogonal to n.
        let (e1, e2, d1, d2) = (p1 - p0, p2 - p0, uv1 - uv0, uv2 - uv0);
        let det = d1.x * d2.y - d2.x * d1.y;
        let dpdu = if det.abs() > 1e-20 {
            (e1 * d2.y - e2 * d1.y) / det
        } else {
            DVec3::ZERO
        };
        let t = (dpdu - n * n.dot(dpdu))
            .try_normalize()
            .unwrap_or_else(|| warp::orthonormal_basis(n).0);
        let b = n.cross(t);
        Shading {
            p,
            t,
            b,
            n,
            uv,
            material: mesh.material,
        }
    }

    /// The material's response to light from `wi` seen from `wo`, cosine included:
    /// albedo f cos_i for BRDFs, the BTF for SPMM packs (world-space unit vectors).
    fn response(&self, s: &Shading, wi: DVec3, wo: DVec3) -> DVec3 {
        let local = |w: DVec3| DVec3::new(w.dot(s.t), w.dot(s.b), w.dot(s.n));
        let (li, lo) = (local(wi), local(wo));
        match (&self.scene.materials[s.material], &self.shaders[s.material]) {
            (Material::Brdf { brdf, albedo }, _) => *albedo * (brdf.eval(li, lo) * li.z.max(0.0)),
            (
                Material::Spmm { .. },
                Shader::Spmm {
                    prepared,
                    still,
                    moving,
                },
            ) => prepared.eval_uv(s.uv, li, lo, if self.moving { moving } else { still }),
            _ => DVec3::ZERO,
        }
    }

    /// The background's radiance along `dir` per unit of its layer's weight.
    fn background(&self, dir: DVec3) -> DVec3 {
        match &self.scene.background {
            Background::Color(_) => DVec3::ONE,
            Background::Environment(img) => {
                // Lat-long, +y up, u = 0.5 + atan2(z, x) / 2 pi (docs/scenes.md).
                let u = 0.5 + dir.z.atan2(dir.x) / std::f64::consts::TAU;
                let v = dir.y.clamp(-1.0, 1.0).acos() / std::f64::consts::PI;
                let x = ((u * img.width() as f64) as u32).min(img.width() - 1);
                let y = ((v * img.height() as f64) as u32).min(img.height() - 1);
                let p = img.get(x, y);
                DVec3::new(p[0] as f64, p[1] as f64, p[2] as f64)
            }
        }
    }

    /// Follows the ray and adds `throughput` times what it finds to the layers.
    fn trace(&self, origin: DVec3, dir: DVec3, depth: u32, throughput: DVec3, path: &mut Path) {
        let Some(hit) = self
            .bvh
            .closest_hit(&self.scene.meshes, origin, dir, 0.0, f64::INFINITY)
        else {
            path.out[BACKGROUND] += throughput * self.background(dir);
            return;
        };
        let s = self.shading(&hit, dir);
        *path.mask |= material_bit(s.material);
        let wo = -dir;
        // Secondary rays start just off the surface; light geometry uses the true point.
        let lift = s.p + s.n * (EPSILON_REL * s.p.abs().max_element().max(1.0));
        if let Material::Mirror { reflectance } = &self.scene.materials[s.material] {
            if depth >= self.scene.render.max_specular_depth {
                return;
            }
            path.counts.specular += 1;
            let r = dir - 2.0 * dir.dot(s.n) * s.n;
            self.trace(lift, r, depth + 1, throughput * *reflectance, path);
            return;
        }
        for (k, light) in self.scene.lights.iter().enumerate() {
            // Both kinds draw two numbers, so the dimension layout does not depend on
            // which kinds the scene has.
            let u = path.rng.next_2d();
            let (q, geometry) = match *light {
                Light::Point { position, .. } => (position, None),
                Light::Area {
                    corner,
                    edge_u,
                    edge_v,
                    ..
                } => (
                    corner + edge_u * u.x + edge_v * u.y,
                    Some(edge_u.cross(edge_v)),
                ),
            };
            let to = q - s.p;
            let d2 = to.length_squared();
            let wi = to / d2.sqrt();
            let falloff = match geometry {
                None => 1.0 / d2,
                Some(cross) => {
                    // One-sided: the light emits towards edge_u x edge_v.
                    let area = cross.length();
                    let cos_l = -wi.dot(cross / area);
                    if cos_l <= 0.0 {
                        continue;
                    }
                    cos_l * area / d2
                }
            };
            let cos_i = wi.dot(s.n);
            if cos_i.is_nan() || cos_i <= 0.0 {
                continue;
            }
            path.counts.shadow += 1;
            if !self
                .bvh
                .occluded(lift, wi, 0.0, (q - lift).length() * (1.0 - 1e-6))
            {
                path.out[FIRST_LIGHT + k] += throughput * self.response(&s, wi, wo) * falloff;
            }
        }
        let u = path.rng.next_2d();
        if let Some(ambient) = &self.scene.ambient {
            let (local, weight) = self.ambient_direction(&s, u);
            let wi = s.t * local.x + s.b * local.y + s.n * local.z;
            if local.z > 0.0 {
                path.counts.ambient += 1;
                if !self.bvh.occluded(lift, wi, 0.0, ambient.radius) {
                    path.out[AMBIENT] += throughput * self.response(&s, wi, wo) * weight;
                }
            }
        }
    }

    /// The ambient ray's direction in the shading frame and 1 / its pdf (eq. 7).
    /// Analytic BRDFs use cosine-distributed directions: their response carries
    /// cos_i, so a sample is pi L_a V f. An SPMM's BTF does not vanish with the shading
    /// cosine (each basis has its own normal), and dividing it by a cosine pdf has
    /// infinite variance; it gets a defensive half-cosine, half-uniform mixture whose
    /// pdf is at least 1 / 4 pi (docs/rendering.md has the measured difference).
    fn ambient_direction(&self, s: &Shading, u: DVec2) -> (DVec3, f64) {
        use std::f64::consts::PI;
        match self.shaders[s.material] {
            Shader::Spmm { .. } => {
                let local = if u.x < 0.5 {
                    warp::cosine_hemisphere(DVec2::new(2.0 * u.x, u.y))
                } else {
                    // Uniform: cos theta = uniform in [0, 1).
                    let z = 1.0 - u.y;
                    let r = (1.0 - z * z).max(0.0).sqrt();
                    let phi = std::f64::consts::TAU * (2.0 * u.x - 1.0);
                    DVec3::new(r * phi.cos(), r * phi.sin(), z)
                };
                let pdf = 0.5 * local.z / PI + 0.25 / PI;
                (local, 1.0 / pdf)
            }
            Shader::Scene => {
                let local = warp::cosine_hemisphere(u);
                (local, PI / local.z)
            }
        }
    }

    /// The materials whose evaluation changes with the moving flag.
    fn residual_mask(&self) -> u64 {
        self.shaders
            .iter()
            .enumerate()
            .filter(|(_, s)| s.skips_residual_when_moving())
            .fold(0, |m, (i, _)| m | material_bit(i))
    }

    /// Forgets every sample and starts the sample indices again, so the image from
    /// here on equals a fresh render of the edited scene, bit for bit.
    fn restart_all(&mut self) -> Invalidation {
        self.film.reset();
        self.frames = 0;
        self.next_sample = 0;
        Invalidation::All
    }
}

/// The per-sample state threaded through a path.
struct Path<'a> {
    out: &'a mut [DVec3],
    mask: &'a mut u64,
    counts: &'a mut RayCounts,
    rng: &'a mut SampleStream,
}

impl RenderMode for SpmmMode {
    fn kind(&self) -> ModeKind {
        ModeKind::Spmm
    }

    fn scene(&self) -> &Scene {
        &self.scene
    }

    fn render_frame(&mut self) -> FrameStats {
        let start = Instant::now();
        let first = self.next_sample;
        let k = u64::from(self.samples_per_frame);
        let layers = self.film.layers();
        let active = self.active_layers();
        let width = self.film.width();
        let dropped_before = self.film.dropped();
        // The film is moved out while rows borrow it mutably and `self` immutably.
        let mut film = std::mem::replace(&mut self.film, Film::new(0, 0, 0));
        let rows = film.par_rows(|row| {
            let mut counts = RayCounts::default();
            let mut out = vec![DVec3::ZERO; layers];
            for x in 0..width {
                for index in first..first + k {
                    out.iter_mut().for_each(|o| *o = DVec3::ZERO);
                    let mut mask = 0;
                    self.sample_into(x, row.y, width, index, &mut out, &mut mask, &mut counts);
                    for &l in &active {
                        row.add(x, l, out[l]);
                    }
                    row.touch(x, mask);
                }
            }
            counts
        });
        self.film = film;
        self.next_sample += k;
        self.frames += 1;
        FrameStats {
            rays: rows.into_iter().fold(RayCounts::default(), |a, c| a + c),
            seconds: start.elapsed().as_secs_f64(),
            dropped: self.film.dropped() - dropped_before,
        }
    }

    fn image(&self) -> Image {
        self.film.resolve(&self.layer_weights())
    }

    fn progress(&self) -> Progress {
        Progress {
            frames: self.frames,
            min_samples: self.film.min_samples(&self.active_layers()),
            dropped: self.film.dropped(),
            width: self.film.width(),
            height: self.film.height(),
        }
    }

    fn set_samples_per_frame(&mut self, samples: u32) {
        self.samples_per_frame = samples.max(1);
    }

    fn geometry_update(&self) -> GeometryUpdate {
        GeometryUpdate {
            refit: self.bvh.refitted(),
            time: self.bvh.build_time(),
            triangles: self.bvh.triangle_counts().0,
        }
    }

    fn apply(&mut self, edit: SceneEdit) -> Result<Invalidation, EditError> {
        // What the invalidation depends on, read before the scene changes.
        let old_light = match &edit {
            SceneEdit::Light { index, .. } => self.scene.lights.get(*index).copied(),
            _ => None,
        };
        let background_was_colour = matches!(self.scene.background, Background::Color(_));
        edit.apply_to(&mut self.scene)?;
        Ok(match edit {
            SceneEdit::Camera(camera) => {
                self.camera = PinholeCamera::new(&camera, self.film.width(), self.film.height());
                self.restart_all()
            }
            SceneEdit::Resize { width, height } => {
                self.camera = PinholeCamera::new(&self.scene.camera, width, height);
                self.film.resize(width, height);
                self.restart_all()
            }
            SceneEdit::Meshes(_) => {
                self.bvh.update(&self.scene.meshes);
                self.restart_all()
            }
            SceneEdit::Material { index, .. } => {
                self.shaders[index] = Shader::new(&self.scene.materials[index]);
                Invalidation::Pixels(self.film.reset_touching(material_bit(index)))
            }
            SceneEdit::Light { index, light } => {
                let old = old_light.expect("apply_to checked the index");
                if old.with_emission(light.emission()) == light {
                    Invalidation::Nothing
                } else {
                    self.film.reset_layer(FIRST_LIGHT + index);
                    Invalidation::Layer(FIRST_LIGHT + index)
                }
            }
            SceneEdit::AddLight(_) => {
                self.film.push_layer();
                Invalidation::Layer(self.film.layers() - 1)
            }
            SceneEdit::RemoveLight(index) => {
                self.film.remove_layer(FIRST_LIGHT + index);
                Invalidation::Nothing
            }
            // Off: the layer is weighted zero and keeps its samples; on again with the
            // radius its samples were traced with: nothing to redo.
            SceneEdit::Ambient(None) => Invalidation::Nothing,
            SceneEdit::Ambient(Some(a)) if Some(a.radius) == self.ambient_radius => {
                Invalidation::Nothing
            }
            SceneEdit::Ambient(Some(a)) => {
                self.ambient_radius = Some(a.radius);
                self.film.reset_layer(AMBIENT);
                Invalidation::Layer(AMBIENT)
            }
            SceneEdit::Background(Background::Color(_)) if background_was_colour => {
                Invalidation::Nothing
            }
            SceneEdit::Background(_) => {
                self.film.reset_layer(BACKGROUND);
                Invalidation::Layer(BACKGROUND)
            }
            SceneEdit::Moving(moving) if moving == self.moving => Invalidation::Nothing,
            SceneEdit::Moving(moving) => {
                self.moving = moving;
                // Samples taken with and without the residual must not mix.
                Invalidation::Pixels(self.film.reset_touching(self.residual_mask()))
            }
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::brdf::{AnalyticBrdf, BrdfModel};
    use crate::scene::mesh::quad;
    use crate::scene::{Ambient, Camera, RenderSettings};

    const ALBEDO: f64 = 0.6;

    /// A large Lambertian floor seen straight down through a narrow field of view, so
    /// every pixel looks at (almost exactly) the origin.
    fn floor_scene(lights: Vec<Light>, ambient: Option<Ambient>, wall: bool) -> Scene {
        let mut meshes = vec![quad(
            DVec3::new(-50.0, 0.0, 50.0),
            DVec3::new(100.0, 0.0, 0.0),
            DVec3::new(0.0, 0.0, -100.0),
            0,
        )];
        if wall {
            // A wall through x = 0 facing +x; the camera looks at the floor next to it.
            meshes.push(quad(
                DVec3::new(0.0, 0.0, 50.0),
                DVec3::new(0.0, 0.0, -100.0),
                DVec3::new(0.0, 100.0, 0.0),
                0,
            ));
        }
        let look = if wall {
            DVec3::new(1e-3, 0.0, 0.0)
        } else {
            DVec3::ZERO
        };
        Scene {
            render: RenderSettings {
                width: 3,
                height: 3,
                frames: 1,
                seed: 1,
                max_specular_depth: 2,
            },
            camera: Camera {
                position: look + DVec3::new(0.0, 1.0, 0.0),
                look_at: look,
                up: DVec3::NEG_Z,
                fov_y_deg: 0.01,
            },
            material_names: vec!["floor".into()],
            material_files: Vec::new(),
            materials: vec![Material::Brdf {
                brdf: AnalyticBrdf::with_defaults(BrdfModel::Lambertian),
                albedo: DVec3::splat(ALBEDO),
            }],
            meshes,
            lights,
            ambient,
            background: Background::Color(DVec3::ZERO),
        }
    }

    fn mode(scene: &Scene) -> SpmmMode {
        SpmmMode::new(scene.clone(), scene.render.width, scene.render.height).expect("valid size")
    }

    fn converge(scene: &Scene, frames: u32) -> DVec3 {
        let mut r = mode(scene);
        for _ in 0..frames {
            r.render_frame();
        }
        assert_eq!(r.progress().dropped, 0);
        let p = r.image().get(1, 1);
        DVec3::new(p[0] as f64, p[1] as f64, p[2] as f64)
    }

    #[test]
    fn lambertian_plane_under_a_point_light_matches_the_closed_form() {
        // L = albedo / pi * I cos(theta) / r^2 with the light 2 m above the origin.
        let scene = floor_scene(
            vec![Light::Point {
                position: DVec3::new(0.0, 2.0, 0.0),
                intensity: DVec3::splat(4.0),
            }],
            None,
            false,
        );
        let got = converge(&scene, 1);
        let expected = ALBEDO / std::f64::consts::PI * 4.0 / 4.0;
        assert!(
            (got.x - expected).abs() < 1e-5 * expected,
            "{got} vs {expected}"
        );
        // An oblique light at 60 degrees from the normal, 2 m away: cos = 0.5.
        let pos = DVec3::new(
            2.0 * 60f64.to_radians().sin(),
            2.0 * 60f64.to_radians().cos(),
            0.0,
        );
        let scene = floor_scene(
            vec![Light::Point {
                position: pos,
                intensity: DVec3::splat(4.0),
            }],
            None,
            false,
        );
        let got = converge(&scene, 1);
        // The pixel's footprint (1.5e-5 m) moves the oblique distance by ~3e-5 relative.
        assert!((got.x - 0.5 * expected).abs() < 1e-4 * expected, "{got}");
    }

    #[test]
    fn a_small_area_light_approaches_a_point_light_of_intensity_le_times_area() {
        let side = 0.02;
        let light = Light::Area {
            corner: DVec3::new(-side / 2.0, 2.0, -side / 2.0),
            edge_u: DVec3::new(side, 0.0, 0.0),
            edge_v: DVec3::new(0.0, 0.0, side),
            radiance: DVec3::splat(10_000.0),
        };
        let scene = floor_scene(vec![light], None, false);
        let got = converge(&scene, 64);
        let expected = ALBEDO / std::f64::consts::PI * (10_000.0 * side * side) / 4.0;
        // The light subtends 1e-4 sr: cosines and distance vary by < 1e-4 over it.
        assert!(
            (got.x - expected).abs() < 1e-3 * expected,
            "{got} vs {expected}"
        );
        // Facing away (edge_u x edge_v up): no light reaches the floor.
        let up = Light::Area {
            corner: DVec3::new(-side / 2.0, 2.0, -side / 2.0),
            edge_u: DVec3::new(0.0, 0.0, side),
            edge_v: DVec3::new(side, 0.0, 0.0),
            radiance: DVec3::splat(1e4),
        };
        assert_eq!(
            converge(&floor_scene(vec![up], None, false), 4),
            DVec3::ZERO
        );
    }

    /// Cosine-weighted solid-angle fraction (the form factor) from a point to the
    /// rectangle [0, a] x [0, b] at height h directly above one corner, parallel to the
    /// surface: (1 / 2 pi) [A / sqrt(1 + A^2) atan(B / sqrt(1 + A^2)) + (A <-> B)] with
    /// A = a / h, B = b / h (the standard closed form, e.g. Howell's catalogue, C-11).
    fn corner_form_factor(a: f64, b: f64, h: f64) -> f64 {
        let (x, y) = (a / h, b / h);
        let (sx, sy) = ((1.0 + x * x).sqrt(), (1.0 + y * y).sqrt());
        ((x / sx) * (y / sx).atan() + (y / sy) * (x / sy).atan()) / std::f64::consts::TAU
    }

    #[test]
    fn a_light_covering_the_hemisphere_matches_the_closed_form() {
        // A 2s x 2s light at height h = s / 5 centred above the origin, off-centre by
        // (dx, dz) so all four corner rectangles differ: its cosine-weighted fraction
        // is the sum of the four corner form factors (0.97 of the hemisphere).
        let (s, h, dx, dz) = (1.0, 0.2, 0.1, -0.15);
        let light = Light::Area {
            corner: DVec3::new(dx - s, h, dz - s),
            edge_u: DVec3::new(2.0 * s, 0.0, 0.0),
            edge_v: DVec3::new(0.0, 0.0, 2.0 * s),
            radiance: DVec3::splat(2.0),
        };
        let fraction = corner_form_factor(s + dx, s + dz, h)
            + corner_form_factor(s - dx, s + dz, h)
            + corner_form_factor(s + dx, s - dz, h)
            + corner_form_factor(s - dx, s - dz, h);
        assert!(fraction > 0.95 && fraction < 1.0, "{fraction}");
        let mut scene = floor_scene(vec![light], None, false);
        (scene.render.width, scene.render.height) = (64, 64);
        let mut r = mode(&scene);
        let frames = 400;
        for _ in 0..frames {
            r.render_frame();
        }
        let img = r.image();
        let mean = img.pixels().iter().map(|p| p[0] as f64).sum::<f64>() / (64.0 * 64.0);
        let expected = ALBEDO * 2.0 * fraction;
        // Area sampling of this light has a relative standard deviation per sample of
        // about sqrt(4 s^2 / (3 pi h^2)) = 3.3; over 64^2 x 400 samples the mean's is
        // 0.26%: 1.2% is 4.5 standard errors.
        assert!(
            (mean - expected).abs() < 0.012 * expected,
            "{mean} vs {expected}"
        );
    }

    #[test]
    fn ambient_light_on_an_spmm_plane_converges_to_the_integral_of_its_btf() {
        use crate::brdf::BasisFunction;
        use crate::spmm::{Cluster, SparseWeights, SpmmMaterial};
        // One texel, one Ward basis whose normal is tilted 35 degrees: its BTF does not
        // vanish with the shading cosine, the case the defensive mixture exists for.
        let normal = DVec3::new(35f64.to_radians().sin(), 0.0, 35f64.to_radians().cos());
        let basis = BasisFunction::new(
            AnalyticBrdf::new(BrdfModel::Ward, &[("ax", 0.3), ("ay", 0.15)]).expect("valid"),
            normal,
        )
        .expect("unit normal");
        let pack = SpmmMaterial::new(
            "tilted".into(),
            "test".into(),
            1,
            1,
            vec![Cluster { bases: vec![basis] }],
            vec![0],
            SparseWeights {
                offsets: vec![0, 1],
                basis: vec![0],
                rgb: vec![[0.5, 0.5, 0.5]],
            },
            None,
        )
        .expect("valid material");
        let mut scene = floor_scene(
            vec![],
            Some(Ambient {
                radiance: DVec3::splat(0.8),
                radius: f64::INFINITY,
            }),
            false,
        );
        scene.materials[0] = Material::Spmm {
            material: std::sync::Arc::new(pack),
            uv_scale: DVec2::ONE,
            residual: true,
            npca: 0,
        };
        (scene.render.width, scene.render.height) = (32, 32);
        let mut r = mode(&scene);
        for _ in 0..200 {
            r.render_frame();
        }
        let img = r.image();
        let mean = img.pixels().iter().map(|p| p[0] as f64).sum::<f64>() / 1024.0;
        // The camera looks straight down: wo is the shading normal, in the frame the
        // renderer builds for the floor (tangent along +u = +x, normal +y).
        let wo = DVec3::Z;
        let n = 600;
        let mut integral = 0.0;
        for i in 0..n {
            let z = (i as f64 + 0.5) / n as f64;
            for j in 0..n {
                let phi = std::f64::consts::TAU * (j as f64 + 0.5) / n as f64;
                let r = (1.0 - z * z).sqrt();
                let wi = DVec3::new(r * phi.cos(), r * phi.sin(), z);
                integral += basis.eval(wi, wo);
            }
        }
        integral *= std::f64::consts::TAU / (n * n) as f64;
        let expected = 0.8 * 0.5 * integral;
        assert!(
            (mean - expected).abs() < 0.01 * expected,
            "{mean} vs {expected}"
        );
    }

    #[test]
    fn ambient_occlusion_of_an_open_plane_is_one_and_half_in_a_corner() {
        let ambient = Some(Ambient {
            radiance: DVec3::splat(0.5),
            radius: f64::INFINITY,
        });
        // Every cosine-sampled ray escapes: each sample is exactly albedo * L_a.
        let got = converge(&floor_scene(vec![], ambient, false), 8);
        assert!((got.x - ALBEDO * 0.5).abs() < 1e-7, "{got}");
        // Next to an infinite wall the cosine-weighted visible fraction is 1/2
        // (the wall hides the half-space x < 0).
        let frames = 4000;
        let got = converge(&floor_scene(vec![], ambient, true), frames);
        let expected = ALBEDO * 0.5 * 0.5;
        // Binomial standard error of the visible fraction: sqrt(0.25 / 4000) ~ 0.008.
        assert!(
            (got.x - expected).abs() < 4.0 * 0.0079 * ALBEDO * 0.5,
            "{got} vs {expected}"
        );
    }

    #[test]
    fn frames_are_replayable_and_independent_of_thread_count() {
        let light = Light::Area {
            corner: DVec3::new(-0.5, 2.0, -0.5),
            edge_u: DVec3::new(1.0, 0.0, 0.0),
            edge_v: DVec3::new(0.0, 0.0, 1.0),
            radiance: DVec3::splat(5.0),
        };
        let mut scene = floor_scene(
            vec![light],
            Some(Ambient {
                radiance: DVec3::splat(0.2),
                radius: 0.5,
            }),
            true,
        );
        scene.render.width = 16;
        scene.render.height = 12;
        scene.camera.fov_y_deg = 60.0;
        let render = |threads: usize, frames: u32| {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .expect("pool");
            let mut r = mode(&scene);
            let stats: Vec<_> = (0..frames)
                .map(|_| pool.install(|| r.render_frame()).rays)
                .collect();
            (r.image(), stats)
        };
        let (a, ca) = render(2, 3);
        let (b, cb) = render(1, 3);
        assert_eq!(a, b);
        assert_eq!(ca, cb);
        assert_eq!(ca[0].primary, 16 * 12);
        assert_ne!(render(2, 4).0, a, "another frame adds other samples");
        // Every pixel replays alone: the film after two frames holds samples 0 and 1.
        let mut r = mode(&scene);
        r.render_frame();
        r.render_frame();
        let w = r.layer_weights();
        let img = r.image();
        let mut lit = 0;
        for (x, y) in (0..12).flat_map(|y| (0..16).map(move |x| (x, y))) {
            let v: DVec3 = (0..2)
                .flat_map(|i| r.sample(x, y, i).0.into_iter().zip(&w).map(|(l, w)| l * *w))
                .sum::<DVec3>()
                / 2.0;
            let got = img.get(x, y);
            assert!(
                (v.x as f32 - got[0]).abs() <= 1e-6 * got[0].abs().max(1e-6),
                "pixel {x},{y}: {v} vs {got:?}"
            );
            lit += usize::from(got[0] > 0.0);
        }
        assert!(lit > 100, "most pixels see lit surfaces");
    }
}

#[cfg(test)]
mod hard_cases {
    use super::*;
    use crate::brdf::{AnalyticBrdf, BrdfModel};
    use crate::scene::mesh::quad;
    use crate::scene::{Ambient, Camera, RenderSettings, TriangleMesh};

    /// Degenerate triangles, normals facing away from the geometry, UVs far outside
    /// [0, 1], a grazing light, a mirror pair, and a camera inside a closed box: the
    /// film must receive only finite samples and nothing may panic.
    #[test]
    fn no_nan_and_no_panic_on_hard_geometry() {
        let pack = crate::spmm::pack::read_pack(std::path::Path::new(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/../materials/woven_wool.spmm"
        )))
        .expect("shipped pack");
        let mut odd = quad(
            DVec3::new(-1.0, 0.0, 1.0),
            DVec3::new(2.0, 0.0, 0.0),
            DVec3::new(0.0, 0.0, -2.0),
            1,
        );
        odd.normals = vec![DVec3::NEG_Y; 4]; // facing away from the geometric normal
        odd.uvs = odd
            .uvs
            .iter()
            .map(|uv| *uv * 1e6 - DVec2::splat(3e5))
            .collect();
        odd.positions.push(DVec3::new(0.3, 0.2, 0.1));
        odd.indices.push([4, 4, 4]); // zero-area triangle
        odd.indices.push([0, 1, 4]);
        odd.normals.push(DVec3::ZERO); // a zero normal at that vertex
        odd.uvs.push(DVec2::new(f64::MAX / 4.0, 0.5));
        // A closed box around the camera: every primary ray hits the inside of a wall.
        let s = 3.0;
        let walls: Vec<TriangleMesh> = [
            (
                DVec3::new(-s, -s, -s),
                DVec3::new(2.0 * s, 0.0, 0.0),
                DVec3::new(0.0, 2.0 * s, 0.0),
            ),
            (
                DVec3::new(-s, -s, s),
                DVec3::new(0.0, 2.0 * s, 0.0),
                DVec3::new(2.0 * s, 0.0, 0.0),
            ),
            (
                DVec3::new(-s, -s, -s),
                DVec3::new(0.0, 2.0 * s, 0.0),
                DVec3::new(0.0, 0.0, 2.0 * s),
            ),
            (
                DVec3::new(s, -s, -s),
                DVec3::new(0.0, 0.0, 2.0 * s),
                DVec3::new(0.0, 2.0 * s, 0.0),
            ),
            (
                DVec3::new(-s, s, -s),
                DVec3::new(2.0 * s, 0.0, 0.0),
                DVec3::new(0.0, 0.0, 2.0 * s),
            ),
        ]
        .into_iter()
        .map(|(c, u, v)| quad(c, u, v, 2))
        .collect();
        let mut meshes = vec![odd];
        meshes.extend(walls);
        meshes.push(quad(
            DVec3::new(-0.5, 0.5, -0.5),
            DVec3::new(0.0, 0.0, 1.0),
            DVec3::new(0.0, 1.0, 0.0),
            0,
        ));
        let scene = Scene {
            render: RenderSettings {
                width: 24,
                height: 24,
                frames: 1,
                seed: 5,
                max_specular_depth: 3,
            },
            camera: Camera {
                position: DVec3::new(0.0, 0.5, 2.0),
                look_at: DVec3::ZERO,
                up: DVec3::Y,
                fov_y_deg: 150.0,
            },
            material_names: vec!["mirror".into(), "cloth".into(), "wall".into()],
            material_files: Vec::new(),
            materials: vec![
                Material::Mirror {
                    reflectance: DVec3::splat(0.9),
                },
                Material::Spmm {
                    material: std::sync::Arc::new(pack),
                    uv_scale: DVec2::splat(3.0),
                    residual: true,
                    npca: 0,
                },
                Material::Brdf {
                    brdf: AnalyticBrdf::new(BrdfModel::Ward, &[("ax", 1e-4), ("ay", 1e-4)])
                        .expect("valid"),
                    albedo: DVec3::ONE,
                },
            ],
            meshes,
            lights: vec![
                // Grazing: just above the floor's plane.
                Light::Point {
                    position: DVec3::new(2.5, 1e-7, 0.0),
                    intensity: DVec3::splat(10.0),
                },
                Light::Area {
                    corner: DVec3::new(-0.5, 2.9, -0.5),
                    edge_u: DVec3::X,
                    edge_v: DVec3::Z,
                    radiance: DVec3::splat(3.0),
                },
            ],
            ambient: Some(Ambient {
                radiance: DVec3::splat(0.2),
                radius: 0.3,
            }),
            background: Background::Color(DVec3::ZERO),
        };
        let mut r = SpmmMode::new(scene, 24, 24).expect("size");
        for f in 0..8u64 {
            let stats = r.render_frame();
            assert_eq!(stats.dropped, 0, "frame {f}");
            for y in 0..24 {
                for x in 0..24 {
                    let (layers, _, _) = r.sample(x, y, f);
                    assert!(
                        layers
                            .iter()
                            .all(|l| l.is_finite() && l.min_element() >= 0.0),
                        "pixel {x},{y} frame {f}: {layers:?}"
                    );
                }
            }
        }
        // A light shrunk to nothing and a camera inside the floor's plane.
        r.apply(SceneEdit::AddLight(Light::Area {
            corner: DVec3::new(0.0, 1.0, 0.0),
            edge_u: DVec3::new(1e-300, 0.0, 0.0),
            edge_v: DVec3::new(0.0, 0.0, 1e-300),
            radiance: DVec3::ONE,
        }))
        .expect_err("a zero-area light is refused");
        let mut cam = r.scene().camera;
        cam.position = DVec3::new(0.0, 0.0, 0.3);
        r.apply(SceneEdit::Camera(cam)).expect("valid camera");
        for _ in 0..2 {
            assert_eq!(r.render_frame().dropped, 0);
        }
        let img = r.image();
        assert!(img.pixels().iter().flatten().all(|c| c.is_finite()));
        assert!(
            img.pixels().iter().any(|p| p[0] > 0.0),
            "some light arrives"
        );
    }
}
