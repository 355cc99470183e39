//! What the viewport's image is of, in pixels: the full-quality render size (from the
//! panel's size and the resolution setting), the size the renderer has now (a quarter
//! while the camera moves), and the scene's geometry that clicks and brush strokes are
//! traced against. Its own type so sizing, picking and painting share one notion of
//! the image's pixels.

use meso_materials::spmm::TexelMask;
use meso_render::SceneEdit;
use meso_render::geometry::{Brush, Pick, SceneBvh, brush, pick};

use crate::document::Document;
use crate::viewport::Input;

/// The render sizes and the geometry under the image.
#[derive(Default)]
pub struct Canvas {
    /// For clicks: the scene's geometry (rebuilt when meshes change).
    pub bvh: Option<SceneBvh>,
    /// Full-quality render size and the size the renderer has now ((0, 0): the
    /// document is not loaded into the renderer yet).
    pub full_size: (u32, u32),
    pub render_size: (u32, u32),
    /// The camera is being dragged (the render runs at a quarter of the size).
    pub moving: bool,
}

/// What the viewport's input asks of the renderer.
pub struct Resized {
    /// Load the document into the renderer at this size (the first frame after a
    /// scene is opened).
    pub load: Option<(u32, u32)>,
    /// View edits (size, camera, moving), in order.
    pub views: Vec<SceneEdit>,
}

impl Canvas {
    /// The size a mode is prepared at: the renderer's, or the full size before the
    /// document is loaded.
    pub fn prepare_size(&self) -> (u32, u32) {
        if self.render_size == (0, 0) {
            (self.full_size.0.max(16), self.full_size.1.max(16))
        } else {
            self.render_size
        }
    }

    /// Follows the viewport's `input` with the render at `scale` of the panel's
    /// pixels: the size follows the panel (not while moving), a drag renders at a
    /// quarter of the size until it stops, and the camera follows the drag.
    pub fn follow(&mut self, input: &Input, scale: f64) -> Resized {
        let Input {
            panel_pixels,
            camera,
            drag_started,
            drag_stopped,
            ..
        } = *input;
        let full = (
            ((f64::from(panel_pixels.0) * scale) as u32).clamp(16, 4096),
            ((f64::from(panel_pixels.1) * scale) as u32).clamp(16, 4096),
        );
        let resize = |(width, height): (u32, u32)| SceneEdit::Resize { width, height };
        let mut load = None;
        let mut views = Vec::new();
        if self.render_size == (0, 0) {
            self.full_size = full;
            self.render_size = full;
            load = Some(full);
        } else if full != self.full_size && !self.moving {
            self.full_size = full;
            self.render_size = full;
            views.push(resize(full));
        }
        if drag_started {
            self.moving = true;
            let preview = ((full.0 / 4).max(16), (full.1 / 4).max(16));
            self.render_size = preview;
            views.push(SceneEdit::Moving(true));
            views.push(resize(preview));
        }
        if let Some(c) = camera {
            views.push(SceneEdit::Camera(c));
        }
        if drag_stopped {
            self.moving = false;
            self.render_size = self.full_size;
            views.push(resize(self.full_size));
            views.push(SceneEdit::Moving(false));
        }
        Resized { load, views }
    }

    /// What is under (x, y) in [0, 1]^2 of the image of `doc`'s scene.
    pub fn pick(&self, doc: &Document, x: f64, y: f64) -> Option<Pick> {
        let bvh = self.bvh.as_ref()?;
        let (w, h) = self.full_size;
        pick(
            &doc.scene,
            bvh,
            w.max(1),
            h.max(1),
            x * f64::from(w),
            y * f64::from(h),
        )
    }

    /// Paints `brush` from `from` to `to` (in [0, 1]^2 of the image) on material
    /// `index` of `doc`'s scene into `mask`, through the same picking as a click;
    /// whether it landed on the material (`false` without geometry).
    pub fn stroke(
        &self,
        doc: &Document,
        brush: &Brush,
        index: usize,
        (from, to): ((f64, f64), (f64, f64)),
        mask: &mut TexelMask,
    ) -> bool {
        let Some(bvh) = &self.bvh else { return false };
        let (w, h) = (self.full_size.0.max(1), self.full_size.1.max(1));
        let at = |p: (f64, f64)| glam::DVec2::new(p.0 * f64::from(w), p.1 * f64::from(h));
        brush::stroke(
            &doc.scene,
            bvh,
            (w, h),
            at(from),
            at(to),
            brush,
            index,
            mask,
        )
    }
}
