//! The progressive viewport: shows the newest finished frame, turns mouse input into
//! camera edits (orbit with the left button, pan with the right or middle button or
//! shift-drag, zoom with the wheel) and a click into a pick position; in paint mode a
//! left-drag (or click) is a brush stroke instead of an orbit. While the
//! camera moves the render runs at a quarter of the resolution with the residual
//! skipped; the studio sends those edits, this module only reports what happened.
//! In the compare view a draggable vertical divider splits the image: the live frame
//! on its left, the reference on its right, each half labelled.
//! A frame left on the device the window draws with (a GPU mode sharing it) is
//! encoded there into a texture the window samples: no copy through the host.

use std::sync::Arc;

#[cfg(feature = "gpu")]
use eframe::egui_wgpu::RenderState;
#[cfg(feature = "gpu")]
use eframe::wgpu;
use egui::{ColorImage, Sense, TextureHandle, TextureId, TextureOptions, Ui, Vec2};
use glam::DVec3;
#[cfg(feature = "gpu")]
use meso_gpu::{DisplayTexture, GpuContext};
use meso_materials::image::{Image, to_srgb8};
use meso_render::scene::Camera;

use meso_viewport::worker::{Frame, Picture};

/// Radians of orbit per point of drag.
const ORBIT_PER_POINT: f64 = 0.008;
/// Closest the camera may come to its target, and the farthest, in metres.
const MIN_DISTANCE: f64 = 0.05;
const MAX_DISTANCE: f64 = 500.0;

/// Orbits the camera about its look-at point: `yaw` about the world up axis, `pitch`
/// about the camera's right axis, stopping short of the poles.
pub fn orbit(camera: &Camera, yaw: f64, pitch: f64) -> Camera {
    let up = camera.up.normalize_or(DVec3::Y);
    let offset = camera.position - camera.look_at;
    let distance = offset.length();
    let dir = offset / distance;
    let elevation = dir.dot(up).clamp(-1.0, 1.0).asin();
    let limit = 89f64.to_radians();
    let new_elevation = (elevation + pitch).clamp(-limit, limit);
    let horizontal = (dir - up * dir.dot(up)).normalize_or(up.any_orthonormal_vector());
    let side = up.cross(horizontal);
    let (s, c) = yaw.sin_cos();
    let h = horizontal * c + side * s;
    let d = h * new_elevation.cos() + up * new_elevation.sin();
    Camera {
        position: camera.look_at + d * distance,
        ..*camera
    }
}

/// Moves the camera and its target across the view so that the point under the
/// cursor follows it: `dx`, `dy` in pixels of an image `height` pixels tall.
pub fn pan(camera: &Camera, dx: f64, dy: f64, height: f64) -> Camera {
    let forward = (camera.look_at - camera.position).normalize();
    let right = forward.cross(camera.up).normalize();
    let up = right.cross(forward);
    let distance = (camera.look_at - camera.position).length();
    let metres_per_pixel = 2.0 * distance * (camera.fov_y_deg.to_radians() * 0.5).tan() / height;
    let shift = (-right * dx + up * dy) * metres_per_pixel;
    Camera {
        position: camera.position + shift,
        look_at: camera.look_at + shift,
        ..*camera
    }
}

/// Moves the camera towards (factor < 1) or away from its target.
pub fn zoom(camera: &Camera, factor: f64) -> Camera {
    let offset = camera.position - camera.look_at;
    let distance = (offset.length() * factor).clamp(MIN_DISTANCE, MAX_DISTANCE);
    Camera {
        position: camera.look_at + offset.normalize() * distance,
        ..*camera
    }
}

/// What the user did in the viewport this UI frame.
#[derive(Default)]
pub struct Input {
    /// The camera after this frame's drag or wheel, if it moved.
    pub camera: Option<Camera>,
    pub drag_started: bool,
    pub drag_stopped: bool,
    /// A click (not a drag) at this position, in [0, 1]^2 of the image.
    pub click: Option<(f64, f64)>,
    /// The image size the panel shows, in physical pixels.
    pub panel_pixels: (u32, u32),
    /// In paint mode: the brush moved from `.0` to `.1` (in [0, 1]^2 of the image).
    pub paint: Option<((f64, f64), (f64, f64))>,
    /// In paint mode: the stroke ended (the button was released).
    pub paint_end: bool,
}

/// The compare view's labels: (left, live; right, reference).
pub struct CompareLabels {
    pub live: String,
    pub reference: String,
}

/// Without the `gpu` feature no frame is on a device: none is ever made.
#[cfg(not(feature = "gpu"))]
enum WindowTexture {}

/// The window's wgpu renderer and the texture frames on its device are shown in.
#[cfg(feature = "gpu")]
struct WindowTexture {
    render_state: RenderState,
    texture: DisplayTexture,
    /// The id egui knows the texture by, and the texture's generation it shows.
    id: Option<(TextureId, u64)>,
}

#[cfg(feature = "gpu")]
impl WindowTexture {
    /// The texture's id in the window's renderer, registered again when the texture
    /// was made anew (a new size).
    fn id(&mut self) -> TextureId {
        let generation = self.texture.generation();
        let rs = &self.render_state;
        let mut renderer = rs.renderer.write();
        let filter = wgpu::FilterMode::Linear;
        match self.id {
            Some((id, g)) if g == generation => id,
            Some((id, _)) => {
                renderer.update_egui_texture_from_wgpu_texture(
                    &rs.device,
                    self.texture.view(),
                    filter,
                    id,
                );
                self.id = Some((id, generation));
                id
            }
            None => {
                let id = renderer.register_native_texture(&rs.device, self.texture.view(), filter);
                self.id = Some((id, generation));
                id
            }
        }
    }
}

pub struct Viewport {
    texture: Option<TextureHandle>,
    /// Set when the window draws with wgpu: frames on its device are shown from there.
    window: Option<WindowTexture>,
    /// The texture the image is painted from, and whether it is the window's (a frame
    /// shown without leaving the device).
    painted: Option<(TextureId, bool)>,
    /// The debug overlay shown instead of the image, by name, and the one uploaded.
    overlay: Option<&'static str>,
    uploaded_overlay: Option<&'static str>,
    /// The newest frame and what its texture was made with (exposure, estimate only).
    shown: Option<(Frame, Option<(f64, bool)>)>,
    reference_texture: Option<TextureHandle>,
    /// The reference image on screen and the exposure its texture was made with.
    reference: Option<(Arc<Image>, f64)>,
    /// Where the compare view's divider is, as a fraction of the width.
    pub split: f32,
    /// Where the image was last shown, in points (tests click into it).
    pub rect: Option<egui::Rect>,
}

impl Default for Viewport {
    fn default() -> Self {
        Self {
            texture: None,
            window: None,
            painted: None,
            overlay: None,
            uploaded_overlay: None,
            shown: None,
            reference_texture: None,
            reference: None,
            split: 0.5,
            rect: None,
        }
    }
}

/// The window's texture showing `picture` (a frame's estimate or its denoised
/// picture) after `exposure`, encoded on the device, if it is on the window's device.
#[cfg(feature = "gpu")]
fn device_texture(
    window: Option<&mut WindowTexture>,
    picture: &Picture,
    exposure: f64,
) -> Option<TextureId> {
    let (d, w) = picture.on_device().zip(window)?;
    w.texture.show(d, exposure).then(|| w.id())
}

/// Without the `gpu` feature every frame is on the host.
#[cfg(not(feature = "gpu"))]
fn device_texture(
    window: Option<&mut WindowTexture>,
    _picture: &Picture,
    _exposure: f64,
) -> Option<TextureId> {
    window.map(|w| match *w {})
}

/// Makes or refreshes `texture` from `img` after `exposure`.
fn upload(ui: &Ui, texture: &mut Option<TextureHandle>, name: &str, img: &Image, exposure: f64) {
    let rgb: Vec<u8> = to_srgb8(img, exposure).into_iter().flatten().collect();
    let color = ColorImage::from_rgb([img.width() as usize, img.height() as usize], &rgb);
    match texture {
        Some(t) => t.set(color, TextureOptions::LINEAR),
        None => *texture = Some(ui.ctx().load_texture(name, color, TextureOptions::LINEAR)),
    }
}

impl Viewport {
    /// The window is drawn by `render_state`'s renderer on the device of `shared`,
    /// which GPU modes share: their frames are shown from there.
    #[cfg(feature = "gpu")]
    pub fn set_window(&mut self, render_state: RenderState, shared: &GpuContext) {
        self.window = Some(WindowTexture {
            texture: DisplayTexture::new(shared),
            render_state,
            id: None,
        });
    }

    /// Whether the image on screen was shown without leaving the device.
    pub fn shows_from_device(&self) -> bool {
        self.painted.is_some_and(|(_, on_device)| on_device)
    }

    /// Takes a newer reference image for the compare view.
    pub fn set_reference(&mut self, image: Arc<Image>) {
        self.reference = Some((image, f64::NAN));
    }

    pub fn clear_reference(&mut self) {
        self.reference = None;
        self.reference_texture = None;
    }

    pub fn frame(&self) -> Option<&Frame> {
        self.shown.as_ref().map(|(f, _)| f)
    }

    /// Shows the frame's debug overlay of this name instead of the image (where the
    /// frame has one), or the image with `None`.
    pub fn set_overlay(&mut self, overlay: Option<&'static str>) {
        self.overlay = overlay;
    }

    pub fn overlay(&self) -> Option<&'static str> {
        self.overlay
    }

    /// Takes a newer frame for display.
    pub fn set_frame(&mut self, frame: Frame) {
        self.shown = Some((frame, None));
    }

    /// Makes the textures the image and the reference are painted from again when
    /// the frame, the exposure, the overlay or the view (`compare`) changed.
    fn refresh_textures(&mut self, ui: &Ui, exposure: f64, compare: bool) {
        // The compare view measures the estimate, so it shows the estimate; otherwise
        // the first frames come through the denoiser (`Frame::shown`).
        let key = Some((exposure, compare));
        if let Some((frame, made_with)) = &mut self.shown
            && (self.texture.is_none()
                || *made_with != key
                || self.uploaded_overlay != self.overlay)
        {
            // A debug overlay is a colour map: shown as it is, without exposure.
            let overlay = self
                .overlay
                .and_then(|name| frame.overlays.iter().find(|o| o.0 == name));
            // The estimate, or its denoised picture, shown on the window's device when
            // it is there.
            let picture = match &frame.shown {
                Some(shown) if !compare => shown,
                _ => &frame.estimate,
            };
            let on_device = overlay
                .is_none()
                .then(|| device_texture(self.window.as_mut(), picture, exposure))
                .flatten();
            self.painted = if let Some(id) = on_device {
                Some((id, true))
            } else {
                match overlay {
                    Some((_, img)) => upload(ui, &mut self.texture, "viewport", img, 0.0),
                    None => {
                        let image = if compare {
                            frame.image()
                        } else {
                            frame.shown_image()
                        };
                        upload(ui, &mut self.texture, "viewport", &image, exposure);
                    }
                }
                self.texture.as_ref().map(|t| (t.id(), false))
            };
            *made_with = key;
            self.uploaded_overlay = self.overlay;
        }
        if compare
            && let Some((img, made_with)) = &mut self.reference
            && (self.reference_texture.is_none() || *made_with != exposure)
        {
            upload(ui, &mut self.reference_texture, "reference", img, exposure);
            *made_with = exposure;
        }
    }

    /// Shows the frame (and, with `compare`, the reference right of the divider).
    pub fn show(
        &mut self,
        ui: &mut Ui,
        camera: &Camera,
        exposure: f64,
        compare: Option<CompareLabels>,
        brush_points: Option<f32>,
    ) -> Input {
        let size = ui.available_size().max(Vec2::splat(16.0));
        let ppp = ui.ctx().pixels_per_point();
        let mut input = Input {
            panel_pixels: (
                (size.x * ppp).round().max(1.0) as u32,
                (size.y * ppp).round().max(1.0) as u32,
            ),
            ..Default::default()
        };
        self.refresh_textures(ui, exposure, compare.is_some());
        let (rect, response) = ui.allocate_exact_size(size, Sense::click_and_drag());
        self.rect = Some(rect);
        ui.painter()
            .rect_filled(rect, 0.0, egui::Color32::from_gray(18));
        if let Some((id, _)) = self.painted {
            ui.painter().image(
                id,
                rect,
                egui::Rect::from_min_max(egui::pos2(0.0, 0.0), egui::pos2(1.0, 1.0)),
                egui::Color32::WHITE,
            );
        } else {
            ui.painter().text(
                rect.center(),
                egui::Align2::CENTER_CENTER,
                "rendering…",
                egui::FontId::proportional(16.0),
                ui.visuals().weak_text_color(),
            );
        }
        if let Some(labels) = compare {
            self.split_ui(ui, rect, &labels);
        }
        ui.painter().text(
            rect.left_top() + Vec2::new(8.0, 6.0),
            egui::Align2::LEFT_TOP,
            if brush_points.is_some() {
                "paint: drag or click paints · right-drag: pan · wheel: zoom"
            } else {
                "drag: orbit · right-drag: pan · wheel: zoom · click: pick a cluster"
            },
            egui::FontId::proportional(11.0),
            egui::Color32::from_gray(150),
        );
        let delta = response.drag_delta();
        let rel = |p: egui::Pos2| {
            let r = (p - rect.min) / rect.size();
            (f64::from(r.x), f64::from(r.y))
        };
        let primary = egui::PointerButton::Primary;
        let painting = brush_points.is_some()
            && !ui.input(|i| i.modifiers.shift)
            && (response.dragged_by(primary)
                || response.drag_started_by(primary)
                || response.drag_stopped_by(primary)
                || response.clicked());
        if painting {
            if let Some(p) = response.interact_pointer_pos() {
                // A drag is recognised only after some movement: its first segment
                // starts where the button went down, so the stroke covers that point.
                let from = if response.drag_started() || response.clicked() {
                    ui.input(|i| i.pointer.press_origin()).unwrap_or(p - delta)
                } else {
                    p - delta
                };
                input.paint = Some((rel(from), rel(p)));
            }
            input.paint_end = response.drag_stopped() || response.clicked();
        }
        if let (Some(r), Some(p)) = (brush_points, response.hover_pos()) {
            ui.painter().circle_stroke(
                p,
                r.max(2.0),
                egui::Stroke::new(1.0, egui::Color32::from_white_alpha(180)),
            );
        }
        input.drag_started = response.drag_started() && !painting;
        input.drag_stopped = response.drag_stopped() && !painting;
        if response.dragged() && delta != Vec2::ZERO && !painting {
            let panning = response.dragged_by(egui::PointerButton::Secondary)
                || response.dragged_by(egui::PointerButton::Middle)
                || ui.input(|i| i.modifiers.shift);
            input.camera = Some(if panning {
                pan(
                    camera,
                    f64::from(delta.x),
                    f64::from(delta.y),
                    f64::from(rect.height()),
                )
            } else {
                orbit(
                    camera,
                    -f64::from(delta.x) * ORBIT_PER_POINT,
                    f64::from(delta.y) * ORBIT_PER_POINT,
                )
            });
        }
        if response.hovered() {
            let scroll = ui.input(|i| i.smooth_scroll_delta.y);
            if scroll != 0.0 {
                let base = input.camera.unwrap_or(*camera);
                input.camera = Some(zoom(&base, (-f64::from(scroll) * 0.002).exp()));
            }
        }
        if response.clicked()
            && !painting
            && let Some(p) = response.interact_pointer_pos()
        {
            input.click = Some(rel(p));
        }
        input
    }
}

impl Viewport {
    /// The reference right of the divider, the divider (dragged on its own: it sits
    /// above the image's response) and the halves' labels.
    fn split_ui(&mut self, ui: &mut Ui, rect: egui::Rect, labels: &CompareLabels) {
        let x = rect.left() + rect.width() * self.split;
        let right = egui::Rect::from_min_max(egui::pos2(x, rect.top()), rect.max);
        match &self.reference_texture {
            Some(t) => {
                ui.painter().image(
                    t.id(),
                    right,
                    egui::Rect::from_min_max(egui::pos2(self.split, 0.0), egui::pos2(1.0, 1.0)),
                    egui::Color32::WHITE,
                );
            }
            None => {
                ui.painter()
                    .rect_filled(right, 0.0, egui::Color32::from_gray(18));
                ui.painter().text(
                    right.center(),
                    egui::Align2::CENTER_CENTER,
                    "rendering the reference…",
                    egui::FontId::proportional(14.0),
                    ui.visuals().weak_text_color(),
                );
            }
        }
        let handle = egui::Rect::from_center_size(
            egui::pos2(x, rect.center().y),
            egui::vec2(8.0, rect.height()),
        );
        let response = ui
            .interact(
                handle,
                egui::Id::unique("meso-compare-divider"),
                Sense::drag(),
            )
            .on_hover_cursor(egui::CursorIcon::ResizeHorizontal);
        if response.dragged() && rect.width() > 0.0 {
            self.split = (self.split + response.drag_delta().x / rect.width()).clamp(0.02, 0.98);
        }
        let stroke_colour = if response.hovered() || response.dragged() {
            egui::Color32::WHITE
        } else {
            egui::Color32::from_gray(200)
        };
        ui.painter().line_segment(
            [egui::pos2(x, rect.top()), egui::pos2(x, rect.bottom())],
            egui::Stroke::new(2.0, stroke_colour),
        );
        let font = egui::FontId::proportional(13.0);
        let bg = egui::Color32::from_black_alpha(160);
        for (text, pos, align) in [
            (
                &labels.live,
                egui::pos2(x - 8.0, rect.bottom() - 8.0),
                egui::Align2::RIGHT_BOTTOM,
            ),
            (
                &labels.reference,
                egui::pos2(x + 8.0, rect.bottom() - 8.0),
                egui::Align2::LEFT_BOTTOM,
            ),
        ] {
            let galley =
                ui.painter()
                    .layout_no_wrap(text.clone(), font.clone(), egui::Color32::WHITE);
            let r = align.anchor_size(pos, galley.size()).expand(3.0);
            ui.painter().rect_filled(r, 3.0, bg);
            ui.painter()
                .galley(r.min + Vec2::splat(3.0), galley, egui::Color32::WHITE);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn camera() -> Camera {
        Camera {
            position: DVec3::new(0.0, 0.7, 2.9),
            look_at: DVec3::new(0.0, 0.33, 0.0),
            up: DVec3::Y,
            fov_y_deg: 35.0,
        }
    }

    #[test]
    fn orbit_keeps_the_distance_and_the_target_and_stops_at_the_pole() {
        let c = camera();
        let d = (c.position - c.look_at).length();
        let o = orbit(&c, 0.7, 0.2);
        assert!(((o.position - o.look_at).length() - d).abs() < 1e-12);
        assert_eq!(o.look_at, c.look_at);
        // A full turn of yaw comes back.
        let back = orbit(&c, std::f64::consts::TAU, 0.0);
        assert!((back.position - c.position).length() < 1e-9);
        // Pitching far past the pole stops at 89 degrees, so `up` stays valid.
        let top = orbit(&c, 0.0, 10.0);
        assert!(top.problem().is_none());
        let elevation = ((top.position - top.look_at) / d).y.asin().to_degrees();
        assert!((elevation - 89.0).abs() < 1e-9, "{elevation}");
    }

    #[test]
    fn pan_moves_position_and_target_together_and_zoom_clamps() {
        let c = camera();
        let p = pan(&c, 100.0, 0.0, 500.0);
        assert!(((p.position - p.look_at) - (c.position - c.look_at)).length() < 1e-12);
        // Dragging right moves the scene right: the camera moves to its left (-x here).
        assert!(p.position.x < c.position.x);
        let z = zoom(&c, 0.5);
        let d = (c.position - c.look_at).length();
        assert!(((z.position - z.look_at).length() - 0.5 * d).abs() < 1e-12);
        assert!(((zoom(&c, 1e-9).position - c.look_at).length() - MIN_DISTANCE).abs() < 1e-12);
    }
}
