//! The lit-sphere preview of a BRDF: an orthographic unit sphere under one
//! directional light, shaded on the CPU, on a worker thread so the UI never waits.
//! Requests carry a version; the worker renders only the newest pending request and
//! the UI keeps only the newest finished image (latest wins).

use std::sync::mpsc::{self, Receiver, Sender};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use glam::DVec3;
use meso_materials::brdf::AnalyticBrdf;
use meso_materials::image::Image;
use rayon::prelude::*;

/// Irradiance of the light on a surface facing it, W/m^2. Chosen as pi so that a white
/// Lambertian facing the light has radiance exactly 1 (exposure 0 shows it as white).
pub const LIGHT_IRRADIANCE: f64 = std::f64::consts::PI;
/// Radiance of the pixels outside the sphere.
pub const BACKGROUND: [f32; 3] = [0.02, 0.02, 0.025];

/// Renders the sphere: pixel radiance = E f(wi, wo) max(0, n . l) with the view along
/// -z (wo = +z), a tangent running around the vertical axis (so anisotropic models
/// show their direction), `light_dir` pointing towards the light.
pub fn render_sphere(brdf: &AnalyticBrdf, light_dir: DVec3, size: u32) -> Image {
    let l = light_dir.normalize_or(DVec3::Z);
    let rows: Vec<Vec<[f32; 3]>> = (0..size)
        .into_par_iter()
        .map(|y| {
            (0..size)
                .map(|x| {
                    let u = 2.0 * (x as f64 + 0.5) / size as f64 - 1.0;
                    let v = 1.0 - 2.0 * (y as f64 + 0.5) / size as f64;
                    let r2 = u * u + v * v;
                    if r2 >= 1.0 {
                        return BACKGROUND;
                    }
                    let n = DVec3::new(u, v, (1.0 - r2).sqrt());
                    let t = DVec3::new(n.z, 0.0, -n.x)
                        .try_normalize()
                        .unwrap_or(DVec3::X);
                    let b = n.cross(t);
                    let local = |w: DVec3| DVec3::new(w.dot(t), w.dot(b), w.dot(n));
                    let radiance =
                        LIGHT_IRRADIANCE * brdf.eval(local(l), local(DVec3::Z)) * n.dot(l).max(0.0);
                    [radiance as f32; 3]
                })
                .collect()
        })
        .collect();
    let pixels = rows.into_iter().flatten().collect();
    Image::from_pixels(size, size, pixels).expect("size * size pixels were rendered")
}

pub struct Request {
    pub version: u64,
    pub brdf: AnalyticBrdf,
    pub light_dir: DVec3,
    pub size: u32,
    /// Woken when the image is ready, so the UI repaints without polling.
    pub repaint: Option<egui::Context>,
}

pub struct Rendered {
    pub version: u64,
    pub image: Image,
    pub elapsed: Duration,
}

/// A background thread that renders sphere previews.
pub struct PreviewWorker {
    requests: Option<Sender<Request>>,
    results: Receiver<Rendered>,
    thread: Option<JoinHandle<()>>,
    /// Why the thread could not be started, for the status line.
    spawn_error: Option<String>,
}

impl PreviewWorker {
    pub fn spawn() -> Self {
        let (request_tx, request_rx) = mpsc::channel::<Request>();
        let (result_tx, result_rx) = mpsc::channel::<Rendered>();
        let thread = std::thread::Builder::new()
            .name("sphere-preview".into())
            .spawn(move || {
                // Ends when the UI drops its sender.
                while let Ok(mut request) = request_rx.recv() {
                    // Latest wins: skip requests that a newer one already replaced.
                    while let Ok(newer) = request_rx.try_recv() {
                        request = newer;
                    }
                    let start = Instant::now();
                    let image = render_sphere(&request.brdf, request.light_dir, request.size);
                    let done = Rendered {
                        version: request.version,
                        image,
                        elapsed: start.elapsed(),
                    };
                    if result_tx.send(done).is_err() {
                        return;
                    }
                    if let Some(ctx) = &request.repaint {
                        ctx.request_repaint();
                    }
                }
            });
        let (thread, spawn_error) = match thread {
            Ok(t) => (Some(t), None),
            Err(e) => (None, Some(e.to_string())),
        };
        Self {
            requests: Some(request_tx),
            results: result_rx,
            thread,
            spawn_error,
        }
    }

    /// Why no more images will come, if so: the thread failed to start or has ended
    /// (a panic inside a render ends it; the UI keeps the last image and says so).
    pub fn problem(&self) -> Option<String> {
        match (&self.thread, &self.spawn_error) {
            (_, Some(e)) => Some(format!("the sphere worker could not start: {e}")),
            (Some(t), None) if t.is_finished() => Some("the sphere worker stopped".into()),
            _ => None,
        }
    }

    /// Queues a render; returns false if the worker is gone (it never panics the UI).
    pub fn request(&self, request: Request) -> bool {
        match (&self.requests, &self.thread) {
            (Some(tx), Some(_)) => tx.send(request).is_ok(),
            _ => false,
        }
    }

    /// The newest finished image, if any arrived since the last call.
    pub fn newest(&self) -> Option<Rendered> {
        self.results.try_iter().max_by_key(|r| r.version)
    }
}

impl Drop for PreviewWorker {
    fn drop(&mut self) {
        // Closing the channel ends the worker's loop; then wait for it.
        self.requests = None;
        if let Some(thread) = self.thread.take() {
            // A worker that panicked has nothing left to clean up; its panic message
            // was already printed, so the join error carries nothing new.
            let _ = thread.join();
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use meso_materials::brdf::BrdfModel;

    #[test]
    fn lambertian_centre_pixel_matches_closed_form() {
        // Light along the view axis, centre pixel: n = l = wo = z, so the radiance is
        // E * (1/pi) * 1 = E / pi, independently of the tangent frame.
        let brdf = AnalyticBrdf::with_defaults(BrdfModel::Lambertian);
        let img = render_sphere(&brdf, DVec3::Z, 65);
        let centre = img.get(32, 32);
        let expected = (LIGHT_IRRADIANCE / std::f64::consts::PI) as f32;
        for c in centre {
            assert!((c - expected).abs() < 1e-4, "{centre:?}");
        }
        // Corners lie outside the disk.
        assert_eq!(img.get(0, 0), BACKGROUND);
        assert_eq!(img.get(64, 64), BACKGROUND);
        // A pixel at 60 degrees from the light: cosine falloff, E/pi * cos.
        let x = 32 + (0.866 * 32.5f64).round() as u32; // u ~ sin 60
        let u = 2.0 * (x as f64 + 0.5) / 65.0 - 1.0;
        let v = 1.0 - 2.0 * (32.5) / 65.0;
        let nz = (1.0 - u * u - v * v).sqrt();
        let got = img.get(x, 32)[0] as f64;
        assert!((got - nz).abs() < 1e-4, "{got} vs {nz}");
    }

    #[test]
    fn anisotropic_lobe_is_not_rotationally_symmetric() {
        // Ward with ax != ay under a light along the view: the highlight is stretched,
        // so pixels at equal distance right and above the centre differ.
        let brdf = AnalyticBrdf::new(BrdfModel::Ward, &[("ax", 0.05), ("ay", 0.4)]).expect("valid");
        let img = render_sphere(&brdf, DVec3::Z, 129);
        let (right, up) = (img.get(64 + 20, 64)[0], img.get(64, 64 - 20)[0]);
        assert!((right - up).abs() > 0.05 * right.max(up), "{right} vs {up}");
    }

    #[test]
    fn worker_keeps_the_newest_version() {
        let worker = PreviewWorker::spawn();
        let brdf = AnalyticBrdf::with_defaults(BrdfModel::BlinnPhong);
        for version in 1..=5 {
            assert!(worker.request(Request {
                version,
                brdf,
                light_dir: DVec3::Z,
                size: 64,
                repaint: None
            }));
        }
        let deadline = Instant::now() + Duration::from_secs(20);
        let mut newest = 0;
        while newest < 5 && Instant::now() < deadline {
            if let Some(r) = worker.newest() {
                assert!(r.version > newest, "versions only move forward");
                newest = r.version;
            }
            std::thread::sleep(Duration::from_millis(5));
        }
        assert_eq!(newest, 5);
    }
}
