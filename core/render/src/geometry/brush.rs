//! The viewport's weight brush: which texels of an SPMM material a dab at an image
//! point covers, found through picking (image point -> surface -> UV -> texel, with
//! the material's tiling). A radius in texels stamps a disc on the texel grid around
//! the texel under the cursor (the same size on the material wherever it is seen); a
//! radius in screen pixels picks every pixel of a disc on the image (the same size on
//! screen, foreshortened on the material, never crossing onto other objects).

use glam::DVec2;

use super::bvh::SceneBvh;
use super::pick::pick;
use crate::scene::{Material, Scene};
use meso_materials::spmm::{Falloff, TexelMask};

/// What the radius is measured in.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum BrushUnits {
    #[default]
    Texels,
    ScreenPixels,
}

#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Brush {
    pub radius: f64,
    pub units: BrushUnits,
    /// Strength at the centre, in [0, 1].
    pub strength: f32,
    pub falloff: Falloff,
}

impl Default for Brush {
    fn default() -> Self {
        Self {
            radius: 2.0,
            units: BrushUnits::Texels,
            strength: 1.0,
            falloff: Falloff::Linear,
        }
    }
}

/// Adds one dab at image point `at` (pixels, x right, y down) of a `width` x `height`
/// image of `scene` to `mask`, for SPMM material `material`; returns whether it landed
/// on that material. The mask must have the material's texel grid.
pub fn dab(
    scene: &Scene,
    bvh: &SceneBvh,
    (width, height): (u32, u32),
    at: DVec2,
    brush: &Brush,
    material: usize,
    mask: &mut TexelMask,
) -> bool {
    let Some(Material::Spmm {
        material: pack,
        uv_scale,
        ..
    }) = scene.materials.get(material)
    else {
        return false;
    };
    if (pack.width(), pack.height()) != (mask.width(), mask.height())
        || brush.radius.is_nan()
        || brush.radius <= 0.0
    {
        return false;
    }
    match brush.units {
        BrushUnits::Texels => match pick(scene, bvh, width, height, at.x, at.y) {
            Some(p) if p.material == material => {
                let centre = pack.texel_position(p.uv, *uv_scale);
                mask.stamp(centre, brush.radius, brush.strength, brush.falloff);
                true
            }
            _ => false,
        },
        BrushUnits::ScreenPixels => {
            let r = brush.radius;
            let mut landed = false;
            let (x0, x1) = ((at.x - r).floor() as i64, (at.x + r).ceil() as i64);
            let (y0, y1) = ((at.y - r).floor() as i64, (at.y + r).ceil() as i64);
            for y in y0.max(0)..y1.min(i64::from(height)) {
                for x in x0.max(0)..x1.min(i64::from(width)) {
                    let p = DVec2::new(x as f64 + 0.5, y as f64 + 0.5);
                    let s = f64::from(brush.strength) * brush.falloff.at(p.distance(at) / r);
                    if s <= 0.0 {
                        continue;
                    }
                    if let Some(hit) = pick(scene, bvh, width, height, p.x, p.y)
                        && hit.material == material
                    {
                        mask.raise(pack.texel_at(hit.uv, *uv_scale), s as f32);
                        landed = true;
                    }
                }
            }
            landed
        }
    }
}

/// Dabs along the segment `from` -> `to` (a drag between two frames), spaced so that
/// consecutive dabs overlap; returns whether any landed on the material.
#[allow(clippy::too_many_arguments)]
pub fn stroke(
    scene: &Scene,
    bvh: &SceneBvh,
    size: (u32, u32),
    from: DVec2,
    to: DVec2,
    brush: &Brush,
    material: usize,
    mask: &mut TexelMask,
) -> bool {
    let spacing = match brush.units {
        BrushUnits::ScreenPixels => (brush.radius / 3.0).max(1.0),
        BrushUnits::Texels => 2.0,
    };
    let steps = ((to.distance(from) / spacing).ceil() as usize).clamp(1, 10_000);
    let mut landed = false;
    for i in 0..=steps {
        let p = from.lerp(to, i as f64 / steps as f64);
        landed |= dab(scene, bvh, size, p, brush, material, mask);
    }
    landed
}
