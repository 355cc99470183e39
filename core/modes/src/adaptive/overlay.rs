//! The adaptive mode's debug overlays, as the paper's Fig. 7 and 9 show them: the
//! bandwidth buffer's level per pixel at the last frame (blue = shaded at every pixel,
//! red = the coarsest level) and the samples each pixel took itself so far (black =
//! none, up-sampled; then a ramp on a log scale up to white). Both are colour maps in
//! linear RGB, ready to show instead of the image.

use super::AdaptiveMode;
use meso_materials::image::Image;

/// A blue - cyan - green - yellow - red ramp over t in [0, 1].
pub fn ramp(t: f64) -> [f32; 3] {
    let t = t.clamp(0.0, 1.0) * 4.0;
    let (r, g, b) = match t {
        t if t < 1.0 => (0.0, t, 1.0),
        t if t < 2.0 => (0.0, 1.0, 2.0 - t),
        t if t < 3.0 => (t - 2.0, 1.0, 0.0),
        t => (1.0, 4.0 - t, 0.0),
    };
    [r as f32, g as f32, b as f32]
}

/// The level of the leaf each pixel belonged to in the last frame's plan, and for
/// up-sampled pixels their own level (eq. 11, after the refinements so far).
pub fn level_map(mode: &AdaptiveMode) -> Option<Image> {
    let b = mode.buffers()?;
    let top = mode.top_level().max(1);
    let mut img = Image::new(mode.width(), mode.height());
    for (i, p) in img.pixels_mut().iter_mut().enumerate() {
        let level = mode
            .plan()
            .and_then(|plan| plan.site_level[i])
            .unwrap_or(b.level[i]);
        *p = ramp(f64::from(level) / f64::from(top));
    }
    Some(img)
}

/// Samples per pixel taken by the pixel itself, log scale up to the largest count.
pub fn samples_map(mode: &AdaptiveMode) -> Image {
    let own = mode.own_samples();
    let max = own.iter().copied().max().unwrap_or(0).max(1);
    let mut img = Image::new(mode.width(), mode.height());
    for (p, &n) in img.pixels_mut().iter_mut().zip(own) {
        *p = if n == 0 {
            [0.0; 3]
        } else {
            ramp((f64::from(n)).ln_1p() / f64::from(max).ln_1p())
        };
    }
    img
}

pub fn overlays(mode: &AdaptiveMode) -> Vec<(&'static str, Image)> {
    let mut out = Vec::new();
    if let Some(l) = level_map(mode) {
        out.push(("bandwidth level", l));
    }
    out.push(("samples per pixel", samples_map(mode)));
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use meso_render::RenderModeExt;
    use meso_render::{Prepare, RenderMode};

    #[test]
    fn the_overlays_show_levels_and_counts_as_the_mode_decided_them() {
        let scene = super::super::tests::merl_test_scene();
        let mut mode = AdaptiveMode::prepare(scene, 32, 32, Prepare::quietly()).expect("adaptive");
        assert_eq!(
            mode.diagnostics().overlays().len(),
            1,
            "no level before the first frame"
        );
        mode.render_frame();
        let o = mode.diagnostics().overlays();
        assert_eq!(
            o.iter().map(|x| x.0).collect::<Vec<_>>(),
            ["bandwidth level", "samples per pixel"]
        );
        let samples = &o[1].1;
        for (i, &n) in mode.own_samples().iter().enumerate() {
            let black = samples.pixels()[i] == [0.0; 3];
            assert_eq!(black, n == 0, "pixel {i}");
        }
        // A site at level 0 is blue, the top level red.
        assert_eq!(ramp(0.0), [0.0, 0.0, 1.0]);
        assert_eq!(ramp(1.0), [1.0, 0.0, 0.0]);
    }
}
