//! `meso brdf plot`: a polar plot of a BRDF lobe in the plane of incidence, drawn
//! with anti-aliased lines into an image and written as PNG. Used for docs/brdf.md;
//! it has no text rendering: the figure's caption gives the scale.

use std::path::Path;

use anyhow::anyhow;
use glam::DVec2;
use meso_materials::brdf::{AnalyticBrdf, incidence_plane_lobe};
use meso_materials::image::{self, Image};

use crate::failure::{CliError, ResultExt};

const BACKGROUND: [f32; 3] = [1.0, 1.0, 1.0];
const GRID: [f32; 3] = [0.78, 0.78, 0.78];
const SURFACE: [f32; 3] = [0.2, 0.2, 0.2];
const INCIDENT: [f32; 3] = [0.85, 0.33, 0.05];
const MIRROR: [f32; 3] = [0.55, 0.55, 0.55];
const LOBE: [f32; 3] = [0.05, 0.25, 0.75];

/// Polar plot: the surface point at the bottom centre, the normal up, the incident
/// direction on the left (orange), the mirror direction (grey), rings at quarters of
/// the largest value, and the lobe r(theta_o) = f(wi, wo) (blue).
pub fn write_lobe_plot(
    brdf: &AnalyticBrdf,
    theta_i_deg: f64,
    phi_deg: f64,
    size: u32,
    output: &Path,
) -> Result<(), CliError> {
    if !(0.0..90.0).contains(&theta_i_deg) {
        return Err(CliError::bad_input(anyhow!(
            "--theta-i-deg {theta_i_deg}: must lie in [0, 90) degrees"
        )));
    }
    if !phi_deg.is_finite() {
        return Err(CliError::bad_input(anyhow!(
            "--phi-deg {phi_deg} is not finite"
        )));
    }
    if !(64..=4096).contains(&size) {
        return Err(CliError::bad_input(anyhow!(
            "--size {size}: must lie in [64, 4096] pixels"
        )));
    }
    let lobe = incidence_plane_lobe(brdf, theta_i_deg.to_radians(), phi_deg.to_radians(), 721);
    let peak = lobe.iter().map(|p| p.value).fold(0.0f64, f64::max);

    let s = size as f64;
    let mut canvas = Canvas::new(size, (size as f64 * 0.56).round() as u32);
    let origin = DVec2::new(s * 0.5, canvas.height() - s * 0.04);
    let radius = s * 0.46;
    // Direction at signed angle theta from the normal, +theta to the right (mirror side).
    let dir = |theta: f64| DVec2::new(theta.sin(), -theta.cos());
    let width = (s / 320.0).max(1.0);

    for quarter in 1..=4 {
        let r = radius * quarter as f64 / 4.0;
        let arc: Vec<DVec2> = (0..=180)
            .map(|k| origin + dir((k as f64 - 90.0).to_radians()) * r)
            .collect();
        canvas.polyline(&arc, width * 0.75, GRID);
    }
    for k in (-90..=90).step_by(15) {
        canvas.line(
            origin,
            origin + dir((k as f64).to_radians()) * radius,
            width * 0.5,
            GRID,
        );
    }
    canvas.line(
        origin - DVec2::new(radius * 1.05, 0.0),
        origin + DVec2::new(radius * 1.05, 0.0),
        width * 1.5,
        SURFACE,
    );
    let theta_i = theta_i_deg.to_radians();
    canvas.line(
        origin,
        origin + dir(-theta_i) * radius,
        width * 1.5,
        INCIDENT,
    );
    canvas.dashed(
        origin,
        origin + dir(theta_i) * radius,
        width,
        MIRROR,
        s / 40.0,
    );
    if peak > 0.0 && peak.is_finite() {
        let curve: Vec<DVec2> = lobe
            .iter()
            .map(|p| origin + dir(p.theta_o_rad) * (radius * p.value / peak))
            .collect();
        canvas.polyline(&curve, width * 2.0, LOBE);
    }
    image::write_png(output, &canvas.image, 0.0)
        .failure_ctx(|| format!("writing the plot `{}`", output.display()))?;
    println!(
        "wrote {} (largest value {peak:.6e} 1/sr = outer ring)",
        output.display()
    );
    Ok(())
}

/// A white image with anti-aliased line drawing: each line covers the pixels within
/// half its width of the segment, with a one-pixel linear fall-off at the edge.
struct Canvas {
    image: Image,
}

impl Canvas {
    fn new(width: u32, height: u32) -> Self {
        let mut image = Image::new(width, height);
        let background = BACKGROUND.map(image::srgb_decode);
        for p in image.pixels_mut() {
            *p = background;
        }
        Self { image }
    }

    fn height(&self) -> f64 {
        self.image.height() as f64
    }

    /// `color` is sRGB-encoded, as a designer picks it; blending happens in linear light.
    fn line(&mut self, a: DVec2, b: DVec2, width: f64, color: [f32; 3]) {
        let color = color.map(image::srgb_decode);
        let half = width * 0.5 + 1.0;
        let lo = a.min(b) - DVec2::splat(half);
        let hi = a.max(b) + DVec2::splat(half);
        let (w, h) = (self.image.width() as f64, self.image.height() as f64);
        let (x0, y0) = (lo.x.max(0.0).floor() as u32, lo.y.max(0.0).floor() as u32);
        let (x1, y1) = (hi.x.min(w - 1.0).ceil(), hi.y.min(h - 1.0).ceil());
        if x1 < 0.0 || y1 < 0.0 {
            return;
        }
        for y in y0..=(y1 as u32) {
            for x in x0..=(x1 as u32) {
                let p = DVec2::new(x as f64 + 0.5, y as f64 + 0.5);
                let coverage =
                    (width * 0.5 + 0.5 - distance_to_segment(p, a, b)).clamp(0.0, 1.0) as f32;
                if coverage > 0.0 {
                    let old = self.image.get(x, y);
                    let mixed = std::array::from_fn(|c| old[c] + (color[c] - old[c]) * coverage);
                    self.image.set(x, y, mixed);
                }
            }
        }
    }

    fn polyline(&mut self, points: &[DVec2], width: f64, color: [f32; 3]) {
        for pair in points.windows(2) {
            self.line(pair[0], pair[1], width, color);
        }
    }

    fn dashed(&mut self, a: DVec2, b: DVec2, width: f64, color: [f32; 3], dash: f64) {
        let length = a.distance(b);
        let count = (length / dash).ceil().max(1.0) as usize;
        for k in (0..count).step_by(2) {
            let t0 = k as f64 / count as f64;
            let t1 = ((k + 1) as f64 / count as f64).min(1.0);
            self.line(a.lerp(b, t0), a.lerp(b, t1), width, color);
        }
    }
}

fn distance_to_segment(p: DVec2, a: DVec2, b: DVec2) -> f64 {
    let ab = b - a;
    let len2 = ab.length_squared();
    let t = if len2 > 0.0 {
        ((p - a).dot(ab) / len2).clamp(0.0, 1.0)
    } else {
        0.0
    };
    p.distance(a + ab * t)
}
