//! One progressive frame of the `spmm` mode (Silva & Santos 2013, section 4): per
//! pixel one jittered primary ray; each point light with one shadow ray; each area
//! light with one shadow ray to a point drawn uniformly on its area (eq. 4-5, the area
//! measure: L_e f cos_i cos_l / r^2 * A); ambient occlusion with one cosine-distributed
//! ray limited to the ambient radius (eq. 6-7: pi L_a V f per sample); perfect mirror
//! reflection up to the scene's depth. SPMM materials return the BTF, cosine included.

use glam::{DVec2, DVec3};
use rayon::prelude::*;

use super::bvh::{Hit, SceneBvh};
use super::camera::PinholeCamera;
use crate::brdf::warp;
use crate::rng::SampleStream;
use crate::scene::{Background, Light, Material, Scene};
use crate::spmm::{EvalSettings, PrepareRequest, PreparedSpmm, TexelFilter};

/// Offset of secondary ray origins along the normal, relative to the hit point's
/// magnitude: well above the f32 rounding of the BVH's triangles (6e-8 relative).
const EPSILON_REL: f64 = 1e-5;

/// Rays traced in one frame, by kind.
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

/// Everything one render of a scene needs, built once.
pub struct Renderer<'s> {
    scene: &'s Scene,
    bvh: SceneBvh,
    camera: PinholeCamera,
    prepared: Vec<Option<(PreparedSpmm, EvalSettings)>>,
    width: u32,
    height: u32,
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

impl<'s> Renderer<'s> {
    pub fn new(scene: &'s Scene, width: u32, height: u32) -> Self {
        let bvh = SceneBvh::build(&scene.meshes);
        let prepared = scene
            .materials
            .iter()
            .map(|m| match m {
                Material::Spmm {
                    material,
                    uv_scale,
                    residual,
                    npca,
                } => Some((
                    material.prepare(&PrepareRequest {
                        used_clusters: None,
                        residual: *residual,
                        max_npca: *npca,
                    }),
                    EvalSettings {
                        residual: *residual,
                        max_npca: *npca,
                        filter: TexelFilter::Nearest,
                        uv_scale: *uv_scale,
                    },
                )),
                _ => None,
            })
            .collect();
        Self {
            scene,
            bvh,
            camera: PinholeCamera::new(&scene.camera, width, height),
            prepared,
            width,
            height,
        }
    }

    pub fn bvh(&self) -> &SceneBvh {
        &self.bvh
    }

    /// One sample per pixel for frame `frame` (row-major), and the rays it traced.
    pub fn render_frame(&self, frame: u32) -> (Vec<[f64; 3]>, RayCounts) {
        let seed = self.scene.render.seed;
        let rows: Vec<(Vec<[f64; 3]>, RayCounts)> = (0..self.height)
            .into_par_iter()
            .map(|y| {
                let mut counts = RayCounts::default();
                let row = (0..self.width)
                    .map(|x| {
                        let pixel = u64::from(y) * u64::from(self.width) + u64::from(x);
                        let mut rng = SampleStream::new(&[seed, u64::from(frame), pixel]);
                        let ray = self.camera.ray(x, y, rng.next_2d());
                        counts.primary += 1;
                        self.radiance(ray.origin, ray.dir, 0, &mut rng, &mut counts)
                            .to_array()
                    })
                    .collect();
                (row, counts)
            })
            .collect();
        let counts = rows.iter().fold(RayCounts::default(), |a, (_, c)| a + *c);
        (rows.into_iter().flat_map(|(r, _)| r).collect(), counts)
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
        match &self.scene.materials[s.material] {
            Material::Brdf { brdf, albedo } => *albedo * (brdf.eval(li, lo) * li.z.max(0.0)),
            Material::Spmm { .. } => match &self.prepared[s.material] {
                Some((p, settings)) => p.eval_uv(s.uv, li, lo, settings),
                None => DVec3::ZERO,
            },
            Material::Mirror { .. } => DVec3::ZERO,
        }
    }

    fn background(&self, dir: DVec3) -> DVec3 {
        match &self.scene.background {
            Background::Color(c) => *c,
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

    fn radiance(
        &self,
        origin: DVec3,
        dir: DVec3,
        depth: u32,
        rng: &mut SampleStream,
        counts: &mut RayCounts,
    ) -> DVec3 {
        let Some(hit) = self
            .bvh
            .closest_hit(&self.scene.meshes, origin, dir, 0.0, f64::INFINITY)
        else {
            return self.background(dir);
        };
        let s = self.shading(&hit, dir);
        let wo = -dir;
        // Secondary rays start just off the surface; light geometry uses the true point.
        let lift = s.p + s.n * (EPSILON_REL * s.p.abs().max_element().max(1.0));
        if let Material::Mirror { reflectance } = &self.scene.materials[s.material] {
            if depth >= self.scene.render.max_specular_depth {
                return DVec3::ZERO;
            }
            counts.specular += 1;
            let r = dir - 2.0 * dir.dot(s.n) * s.n;
            return *reflectance * self.radiance(lift, r, depth + 1, rng, counts);
        }
        let mut l = DVec3::ZERO;
        for light in &self.scene.lights {
            match *light {
                Light::Point {
                    position,
                    intensity,
                } => {
                    let _ = rng.next_2d(); // keep the dimension layout of the area case
                    let to = position - s.p;
                    let d2 = to.length_squared();
                    let wi = to / d2.sqrt();
                    if wi.dot(s.n) <= 0.0 {
                        continue;
                    }
                    counts.shadow += 1;
                    if !self
                        .bvh
                        .occluded(lift, wi, 0.0, (position - lift).length() * (1.0 - 1e-6))
                    {
                        l += intensity / d2 * self.response(&s, wi, wo);
                    }
                }
                Light::Area {
                    corner,
                    edge_u,
                    edge_v,
                    radiance,
                } => {
                    let u = rng.next_2d();
                    let q = corner + edge_u * u.x + edge_v * u.y;
                    let cross = edge_u.cross(edge_v);
                    let area = cross.length();
                    let to = q - s.p;
                    let d2 = to.length_squared();
                    let wi = to / d2.sqrt();
                    // One-sided: the light emits towards edge_u x edge_v.
                    let cos_l = -(wi.dot(cross / area));
                    if cos_l <= 0.0 || wi.dot(s.n) <= 0.0 {
                        continue;
                    }
                    counts.shadow += 1;
                    if !self
                        .bvh
                        .occluded(lift, wi, 0.0, (q - lift).length() * (1.0 - 1e-6))
                    {
                        l += radiance * self.response(&s, wi, wo) * (cos_l * area / d2);
                    }
                }
            }
        }
        if let Some(ambient) = &self.scene.ambient {
            let local = warp::cosine_hemisphere(rng.next_2d());
            let wi = s.t * local.x + s.b * local.y + s.n * local.z;
            if local.z > 0.0 {
                counts.ambient += 1;
                if !self.bvh.occluded(lift, wi, 0.0, ambient.radius) {
                    // Cosine sampling: pdf = cos_i / pi, and the response carries cos_i.
                    l += ambient.radiance
                        * self.response(&s, wi, wo)
                        * (std::f64::consts::PI / local.z);
                }
            }
        }
        l
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::brdf::{AnalyticBrdf, BrdfModel};
    use crate::scene::mesh::quad;
    use crate::scene::{Ambient, Camera, RenderSettings};
    use crate::trace::Film;

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

    fn converge(scene: &Scene, frames: u32) -> DVec3 {
        let r = Renderer::new(scene, scene.render.width, scene.render.height);
        let mut film = Film::new(scene.render.width, scene.render.height);
        for f in 0..frames {
            film.add_frame(&r.render_frame(f).0);
        }
        assert_eq!(film.dropped(), 0);
        let p = film.mean().get(1, 1);
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
        let r = Renderer::new(&scene, 16, 12);
        let (a, ca) = r.render_frame(3);
        let one = rayon::ThreadPoolBuilder::new()
            .num_threads(1)
            .build()
            .expect("pool");
        let (b, cb) = one.install(|| r.render_frame(3));
        assert_eq!(a, b);
        assert_eq!(ca, cb);
        assert_eq!(ca.primary, 16 * 12);
        assert_ne!(r.render_frame(4).0, a, "another frame draws other samples");
    }
}

#[cfg(test)]
mod hard_cases {
    use super::*;
    use crate::brdf::{AnalyticBrdf, BrdfModel};
    use crate::scene::mesh::quad;
    use crate::scene::{Ambient, Camera, RenderSettings, TriangleMesh};
    use crate::trace::Film;

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
        let r = Renderer::new(&scene, 24, 24);
        let mut film = Film::new(24, 24);
        for f in 0..8 {
            let (samples, _) = r.render_frame(f);
            assert!(
                samples.iter().flatten().all(|c| c.is_finite() && *c >= 0.0),
                "frame {f}"
            );
            film.add_frame(&samples);
        }
        assert_eq!(film.dropped(), 0);
        assert!(
            film.mean().pixels().iter().any(|p| p[0] > 0.0),
            "some light arrives"
        );
    }
}
