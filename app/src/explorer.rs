//! The BRDF explorer: pick one of the seven analytic models, move its parameters,
//! and see its lobe in the plane of incidence (painted at once on the UI thread) and
//! a lit sphere (rendered by a worker thread; the newest finished image is shown).
//! Every edit bumps a version, the pattern the progressive viewport will use too.

use egui::{ColorImage, TextureHandle, TextureOptions, Ui};
use glam::DVec3;
use meso_materials::brdf::{AnalyticBrdf, BrdfModel, LobePoint, incidence_plane_lobe};
use meso_materials::image::{Image, to_srgb8};

use crate::brdf_editor::{slider_is_logarithmic, smallest_positive};
use crate::lobe_plot::{self, Scale};
use crate::sphere_preview::{PreviewWorker, Request};

/// The sphere is rendered at the size it is shown, in steps of this many pixels so
/// that resizing the window does not re-render on every pixel of the drag.
const SPHERE_PX_STEP: u32 = 64;
const SPHERE_PX_MAX: u32 = 768;
const LOBE_STEPS: usize = 361;

/// What survives a restart: the chosen model and parameters and the view settings.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default)]
pub struct Settings {
    pub model: String,
    pub params: Vec<(String, f64)>,
    pub theta_i_deg: f64,
    pub plane_azimuth_deg: f64,
    pub light_elevation_deg: f64,
    pub light_azimuth_deg: f64,
    pub exposure_stops: f64,
    pub scale: Scale,
}

impl Default for Settings {
    fn default() -> Self {
        let brdf = AnalyticBrdf::with_defaults(BrdfModel::Ward);
        Self {
            model: brdf.model().name().to_string(),
            params: named_params(&brdf),
            theta_i_deg: 45.0,
            plane_azimuth_deg: 0.0,
            light_elevation_deg: 35.0,
            light_azimuth_deg: 135.0,
            // Specular highlights of the defaults reach a few times the white level.
            exposure_stops: -2.0,
            scale: Scale::Linear,
        }
    }
}

fn named_params(brdf: &AnalyticBrdf) -> Vec<(String, f64)> {
    brdf.model()
        .param_specs()
        .iter()
        .map(|s| s.name.to_string())
        .zip(brdf.param_values())
        .collect()
}

struct ShownSphere {
    version: u64,
    image: Image,
    texture: Option<TextureHandle>,
    texture_exposure: f64,
    render_ms: f64,
}

pub struct Explorer {
    settings: Settings,
    brdf: AnalyticBrdf,
    /// Bumped by every edit that changes what the sphere shows.
    version: u64,
    requested: u64,
    /// Side of the sphere image in physical pixels, following the space it has.
    sphere_px: u32,
    lobe: Vec<LobePoint>,
    worker: PreviewWorker,
    sphere: Option<ShownSphere>,
}

impl Default for Explorer {
    fn default() -> Self {
        Self::from_settings(Settings::default())
    }
}

impl Explorer {
    /// Restores settings; a stored model or parameter that no longer validates falls
    /// back to that model's defaults (or to Ward) rather than failing to start.
    pub fn from_settings(settings: Settings) -> Self {
        let brdf = BrdfModel::from_name(&settings.model)
            .ok()
            .map(|m| {
                let named: Vec<(&str, f64)> = settings
                    .params
                    .iter()
                    .map(|(k, v)| (k.as_str(), *v))
                    .collect();
                AnalyticBrdf::new(m, &named).unwrap_or_else(|_| AnalyticBrdf::with_defaults(m))
            })
            .unwrap_or_else(|| AnalyticBrdf::with_defaults(BrdfModel::Ward));
        let mut explorer = Self {
            settings,
            brdf,
            version: 1,
            requested: 0,
            sphere_px: 0,
            lobe: Vec::new(),
            worker: PreviewWorker::spawn(),
            sphere: None,
        };
        explorer.sync_settings();
        explorer.update_lobe();
        explorer
    }

    #[cfg(test)]
    pub fn settings(&self) -> Settings {
        self.settings.clone()
    }

    #[cfg(test)]
    pub fn brdf(&self) -> &AnalyticBrdf {
        &self.brdf
    }

    #[cfg(test)]
    pub fn version(&self) -> u64 {
        self.version
    }

    #[cfg(test)]
    pub fn lobe(&self) -> &[LobePoint] {
        &self.lobe
    }

    #[cfg(test)]
    /// The version and pixels of the sphere image on screen, if one arrived yet.
    pub fn shown_sphere(&self) -> Option<(u64, &Image)> {
        self.sphere.as_ref().map(|s| (s.version, &s.image))
    }

    fn sync_settings(&mut self) {
        self.settings.model = self.brdf.model().name().to_string();
        self.settings.params = named_params(&self.brdf);
    }

    fn update_lobe(&mut self) {
        self.lobe = incidence_plane_lobe(
            &self.brdf,
            self.settings.theta_i_deg.to_radians(),
            self.settings.plane_azimuth_deg.to_radians(),
            LOBE_STEPS,
        );
    }

    fn light_dir(&self) -> DVec3 {
        let (e, a) = (
            self.settings.light_elevation_deg.to_radians(),
            self.settings.light_azimuth_deg.to_radians(),
        );
        // Azimuth 90 deg is straight up on screen, 0 deg to the right; elevation is
        // measured from the screen plane towards the viewer.
        DVec3::new(e.cos() * a.cos(), e.cos() * a.sin(), e.sin())
    }

    fn edited(&mut self) {
        self.version += 1;
        self.sync_settings();
        self.update_lobe();
    }

    /// One frame of the explorer's UI.
    pub fn show(&mut self, ui: &mut Ui) {
        self.receive_sphere(ui.ctx());
        egui::Panel::left("controls")
            .resizable(true)
            .default_size(300.0)
            .show(ui, |ui| {
                egui::ScrollArea::vertical().show(ui, |ui| self.controls(ui));
            });
        egui::Panel::bottom("status").show(ui, |ui| self.status(ui));
        egui::CentralPanel::default().show(ui, |ui| self.views(ui));
        if self.requested != self.version && self.sphere_px > 0 {
            let request = Request {
                version: self.version,
                brdf: self.brdf,
                light_dir: self.light_dir(),
                size: self.sphere_px,
                repaint: Some(ui.ctx().clone()),
            };
            if self.worker.request(request) {
                self.requested = self.version;
            }
        }
    }

    fn receive_sphere(&mut self, ctx: &egui::Context) {
        if let Some(done) = self.worker.newest() {
            let newer = self
                .sphere
                .as_ref()
                .is_none_or(|s| done.version > s.version);
            if newer {
                let texture = self.sphere.take().and_then(|s| s.texture);
                self.sphere = Some(ShownSphere {
                    version: done.version,
                    image: done.image,
                    texture,
                    texture_exposure: f64::NAN,
                    render_ms: done.elapsed.as_secs_f64() * 1e3,
                });
            }
        }
        // (Re)upload when the image or the exposure changed.
        if let Some(s) = &mut self.sphere
            && (s.texture.is_none() || s.texture_exposure != self.settings.exposure_stops)
        {
            let rgb: Vec<u8> = to_srgb8(&s.image, self.settings.exposure_stops)
                .into_iter()
                .flatten()
                .collect();
            let size = [s.image.width() as usize, s.image.height() as usize];
            let image = ColorImage::from_rgb(size, &rgb);
            match &mut s.texture {
                Some(t) => t.set(image, TextureOptions::LINEAR),
                None => {
                    s.texture =
                        Some(ctx.load_texture("sphere-preview", image, TextureOptions::LINEAR))
                }
            }
            s.texture_exposure = self.settings.exposure_stops;
        }
    }

    fn controls(&mut self, ui: &mut Ui) {
        ui.heading("BRDF");
        let mut model = self.brdf.model();
        egui::ComboBox::from_label("Model")
            .selected_text(model.name())
            .show_ui(ui, |ui| {
                for m in BrdfModel::ALL {
                    ui.selectable_value(&mut model, m, m.name());
                }
            });
        if model != self.brdf.model() {
            self.brdf = AnalyticBrdf::with_defaults(model);
            self.edited();
        }

        let specs = self.brdf.model().param_specs();
        if specs.is_empty() {
            ui.label("no parameters: f = 1/pi");
        }
        for (spec, mut value) in specs.iter().zip(self.brdf.param_values()) {
            let slider = egui::Slider::new(&mut value, spec.min..=spec.max)
                .text(spec.name)
                .logarithmic(slider_is_logarithmic(spec))
                .smallest_positive(smallest_positive(spec))
                .max_decimals(6);
            let changed = ui.add(slider).on_hover_text(spec.doc).changed();
            if changed {
                // The slider range is the spec range, so this only fails on NaN input.
                if let Ok(b) = self.brdf.with_param(spec.name, value) {
                    self.brdf = b;
                    self.edited();
                }
            }
        }
        if ui.button("Reset to defaults").clicked() {
            self.brdf = AnalyticBrdf::with_defaults(self.brdf.model());
            self.edited();
        }

        ui.separator();
        ui.heading("Lobe plot");
        let mut lobe_changed = false;
        lobe_changed |= ui
            .add(
                egui::Slider::new(&mut self.settings.theta_i_deg, 0.0..=89.9)
                    .text("incidence (deg)"),
            )
            .changed();
        lobe_changed |= ui
            .add(egui::Slider::new(&mut self.settings.plane_azimuth_deg, 0.0..=180.0).text("plane azimuth (deg)"))
            .on_hover_text("azimuth of the plane of incidence in the tangent frame: matters for anisotropic models")
            .changed();
        ui.horizontal(|ui| {
            ui.radio_value(&mut self.settings.scale, Scale::Linear, "f");
            ui.radio_value(&mut self.settings.scale, Scale::Foreshortened, "f cos");
            ui.radio_value(&mut self.settings.scale, Scale::Log, "log f");
        });
        if lobe_changed {
            self.update_lobe();
        }

        ui.separator();
        ui.heading("Sphere");
        ui.label("one directional light, irradiance pi W/m^2, white albedo");
        let mut light_changed = false;
        light_changed |= ui
            .add(
                egui::Slider::new(&mut self.settings.light_elevation_deg, 0.0..=90.0)
                    .text("light elevation (deg)"),
            )
            .changed();
        light_changed |= ui
            .add(
                egui::Slider::new(&mut self.settings.light_azimuth_deg, 0.0..=360.0)
                    .text("light azimuth (deg)"),
            )
            .changed();
        if light_changed {
            self.version += 1;
        }
        ui.add(
            egui::Slider::new(&mut self.settings.exposure_stops, -8.0..=8.0)
                .text("exposure (stops)"),
        );
    }

    fn views(&mut self, ui: &mut Ui) {
        let light = self.light_dir();
        ui.columns(2, |cols| {
            let plot = &mut cols[0];
            plot.heading("Lobe in the plane of incidence");
            let max_height = plot.available_height() - 60.0;
            let theta_i = self.settings.theta_i_deg.to_radians();
            lobe_plot::show(plot, &self.lobe, &[], theta_i, self.settings.scale, max_height);
            if let Some(r) = lobe_plot::readout(&self.lobe, theta_i) {
                plot.label(format!(
                    "peak f = {} 1/sr at θo = {:.1}°;  at the mirror direction ({:.1}°) f = {} 1/sr",
                    lobe_plot::format_value(r.peak_value),
                    r.peak_theta_o_rad.to_degrees(),
                    self.settings.theta_i_deg,
                    lobe_plot::format_value(r.mirror_value),
                ));
            }
            plot.weak("θo is negative on the light's side; hover the plot for values");

            let sphere = &mut cols[1];
            sphere.heading("Lit sphere");
            let side = sphere
                .available_width()
                .min(sphere.available_height() - 40.0)
                .max(64.0);
            let physical = side * sphere.ctx().pixels_per_point() / SPHERE_PX_STEP as f32;
            let px = (physical.round() as u32 * SPHERE_PX_STEP).clamp(SPHERE_PX_STEP, SPHERE_PX_MAX);
            if px != self.sphere_px {
                self.sphere_px = px;
                self.version += 1;
            }
            match self.sphere.as_ref().and_then(|s| s.texture.as_ref()) {
                Some(t) => {
                    let rect = sphere.image((t.id(), egui::vec2(side, side))).rect;
                    overlay_sphere(sphere, rect, light);
                }
                None => {
                    sphere.spinner();
                }
            }
            sphere.weak(
                "orthographic view, one directional light (ring: where it meets the \
                 surface head-on); the tangent runs around the vertical axis",
            );
        });
    }

    fn status(&self, ui: &mut Ui) {
        ui.horizontal(|ui| {
            if let Some(problem) = self.worker.problem() {
                ui.colored_label(ui.visuals().error_fg_color, problem);
            }
            match &self.sphere {
                Some(s) => ui.label(format!(
                    "sphere v{} of v{}: {}x{} rendered in {:.1} ms on the CPU",
                    s.version,
                    self.version,
                    s.image.width(),
                    s.image.height(),
                    s.render_ms
                )),
                None => ui.label("rendering the sphere ..."),
            };
        });
    }
}

/// Over the sphere image: its silhouette, faint (a purely specular sphere is black
/// away from its highlight), and a ring where the surface faces the light (n = l), so
/// the light's direction can be read off the picture.
fn overlay_sphere(ui: &Ui, image_rect: egui::Rect, light: DVec3) {
    let painter = ui.painter_at(image_rect.expand(2.0));
    let half = 0.5 * image_rect.width();
    let outline = egui::Stroke::new(1.0, ui.visuals().weak_text_color().gamma_multiply(0.6));
    painter.circle_stroke(image_rect.center(), half, outline);
    let at = image_rect.center() + egui::vec2(light.x as f32, -(light.y as f32)) * half;
    let ring = egui::Stroke::new(1.5, egui::Color32::from_rgb(255, 210, 80));
    painter.circle_stroke(at, 6.0, ring);
}

#[cfg(test)]
mod tests {
    use std::time::{Duration, Instant};

    use egui::accesskit::Role;
    use egui_kittest::Harness;
    use egui_kittest::kittest::Queryable as _;

    use super::*;

    /// Steps the UI until the sphere of the current version is on screen.
    fn wait_for_sphere(harness: &mut Harness<'_, Explorer>) {
        let deadline = Instant::now() + Duration::from_secs(30);
        loop {
            harness.step();
            let ex = harness.state();
            if ex.shown_sphere().is_some_and(|(v, _)| v == ex.version()) {
                return;
            }
            assert!(
                Instant::now() < deadline,
                "no sphere for version {} within 30 s",
                ex.version()
            );
            std::thread::sleep(Duration::from_millis(10));
        }
    }

    fn harness() -> Harness<'static, Explorer> {
        Harness::builder()
            .with_size(egui::vec2(1280.0, 800.0))
            .build_ui_state(|ui, ex: &mut Explorer| ex.show(ui), Explorer::default())
    }

    #[test]
    fn moving_a_parameter_slider_updates_brdf_lobe_and_sphere() {
        let mut harness = harness();
        wait_for_sphere(&mut harness);
        let (v0, before_image) = {
            let (v, img) = harness.state().shown_sphere().expect("a sphere");
            (v, img.clone())
        };
        let before_lobe = harness.state().lobe().to_vec();
        assert_eq!(harness.state().brdf().model(), BrdfModel::Ward);

        harness
            .get_by_role_and_label(Role::Slider, "ax")
            .set_value_accesskit(0.05);
        harness.step();
        let ex = harness.state();
        assert_eq!(
            ex.brdf().param_values()[0],
            0.05,
            "the slider edits the BRDF"
        );
        assert!(ex.version() > v0);
        assert_ne!(
            ex.lobe(),
            &before_lobe[..],
            "the lobe plot follows the edit"
        );

        wait_for_sphere(&mut harness);
        let (v1, after_image) = harness.state().shown_sphere().expect("a sphere");
        assert_eq!(v1, harness.state().version());
        assert_ne!(
            after_image, &before_image,
            "the sphere is re-rendered with the new BRDF"
        );
        // The sphere of the edited BRDF is exactly what core renders for it.
        let expected = crate::sphere_preview::render_sphere(
            harness.state().brdf(),
            harness.state().light_dir(),
            after_image.width(),
        );
        assert_eq!(after_image, &expected);
    }

    #[test]
    fn choosing_a_model_replaces_the_parameter_sliders() {
        let mut harness = harness();
        harness.step();
        assert!(
            harness
                .query_by_role_and_label(Role::Slider, "ay")
                .is_some()
        );
        harness
            .get_by_role_and_label(Role::ComboBox, "Model")
            .click();
        harness.run_steps(3);
        harness.get_by_label("cook_torrance").click();
        harness.run_steps(3);
        let ex = harness.state();
        assert_eq!(ex.brdf().model(), BrdfModel::CookTorrance);
        assert_eq!(ex.settings().model, "cook_torrance");
        assert!(
            harness
                .query_by_role_and_label(Role::Slider, "f0")
                .is_some()
        );
        assert!(
            harness
                .query_by_role_and_label(Role::Slider, "ay")
                .is_none()
        );
        wait_for_sphere(&mut harness);
    }

    #[test]
    fn edits_invalidate_only_the_view_they_change() {
        let mut harness = harness();
        wait_for_sphere(&mut harness);
        let version = harness.state().version();
        let lobe = harness.state().lobe().to_vec();
        let theta_i = harness.state().settings().theta_i_deg;

        // The incidence angle, stepped with the keyboard, moves the lobe only: the
        // sphere is lit by its own light, so no new render is requested.
        harness
            .get_by_role_and_label(Role::Slider, "incidence (deg)")
            .focus();
        harness.step();
        harness.key_press(egui::Key::ArrowRight);
        harness.run_steps(2);
        let ex = harness.state();
        assert!(
            ex.settings().theta_i_deg > theta_i,
            "the arrow key moved it"
        );
        assert_ne!(ex.lobe(), &lobe[..]);
        assert_eq!(ex.version(), version, "the sphere is not re-rendered");

        // The light moves the sphere only.
        let lobe = ex.lobe().to_vec();
        harness
            .get_by_role_and_label(Role::Slider, "light azimuth (deg)")
            .set_value_accesskit(60.0);
        harness.step();
        assert_eq!(harness.state().settings().light_azimuth_deg, 60.0);
        assert_eq!(harness.state().lobe(), &lobe[..]);
        assert!(harness.state().version() > version);
        wait_for_sphere(&mut harness);
    }

    #[test]
    fn reset_restores_the_model_defaults() {
        let mut harness = harness();
        harness.step();
        harness
            .get_by_role_and_label(Role::Slider, "ay")
            .set_value_accesskit(0.7);
        harness.step();
        assert_ne!(
            *harness.state().brdf(),
            AnalyticBrdf::with_defaults(BrdfModel::Ward)
        );
        harness.get_by_label("Reset to defaults").click();
        harness.run_steps(2);
        assert_eq!(
            *harness.state().brdf(),
            AnalyticBrdf::with_defaults(BrdfModel::Ward)
        );
    }

    #[test]
    fn settings_round_trip_and_invalid_ones_fall_back() {
        let mut s = Settings {
            model: "blinn_phong".into(),
            params: vec![("n".into(), 300.0)],
            ..Default::default()
        };
        let ex = Explorer::from_settings(s.clone());
        assert_eq!(ex.brdf().param_values(), vec![300.0]);
        assert_eq!(ex.settings(), s);
        s.params = vec![("n".into(), -5.0)];
        let ex = Explorer::from_settings(s);
        assert_eq!(
            *ex.brdf(),
            AnalyticBrdf::with_defaults(BrdfModel::BlinnPhong)
        );
    }
}
