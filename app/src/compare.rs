//! The compare view: a reference renderer kept on the document's version and render
//! size, its newest image beside the live frame in the viewport, and the two compared
//! (RMSE, PSNR, MSSIM) off the UI thread, at most every `MEASURE_EVERY`, when both
//! show the same version at the same size. Its own type so the window only turns it
//! on or off; everything the view holds is dropped when it is turned off.

use std::sync::Arc;
use std::time::{Duration, Instant};

use egui::Ui;
use meso_materials::image::Image;
use meso_materials::metrics::{self, Comparison};
use meso_render::{Device, ModeKind};

use crate::document::Document;
use crate::jobs::Job;
use crate::reference::{Reference, ReferenceRenderer};
use crate::viewport::{CompareLabels, Viewport};
use meso_viewport::maker::mode_name;

/// Least time between two comparisons of the live image with the reference.
const MEASURE_EVERY: Duration = Duration::from_millis(250);

/// The compare view's numbers and the two images they were computed from.
#[derive(Clone)]
pub struct Measured {
    pub reference: Arc<Image>,
    pub live: Arc<Image>,
    pub reference_spp: u32,
    pub comparison: Comparison,
}

/// The reference, its newest image and the comparison with the live frame.
pub struct CompareView {
    repaint: Option<egui::Context>,
    /// The reference renderer (while the view is on) and its newest image.
    reference: Option<ReferenceRenderer>,
    latest: Option<Reference>,
    measure_job: Option<Job<Measured>>,
    measured: Option<Measured>,
    /// When the last comparison started and what it compared (live frame time,
    /// reference image number).
    measure_started: Instant,
    measure_key: Option<(Instant, u64)>,
}

impl CompareView {
    pub fn new(repaint: Option<egui::Context>) -> Self {
        Self {
            repaint,
            reference: None,
            latest: None,
            measure_job: None,
            measured: None,
            measure_started: Instant::now(),
            measure_key: None,
        }
    }

    /// The latest numbers and the two images they come from.
    pub fn measured(&self) -> Option<&Measured> {
        self.measured.as_ref()
    }

    /// The viewport's labels with the live image in `live` mode.
    pub fn labels(&self, live: (ModeKind, Device)) -> CompareLabels {
        CompareLabels {
            live: format!("live: {}", mode_name(live.0, live.1)),
            reference: match &self.latest {
                Some(r) => format!("reference: spmm, {} spp", r.spp),
                None => "reference: spmm, starting".into(),
            },
        }
    }

    /// One UI frame: with the view `on`, keeps the reference renderer on `doc`'s
    /// version and `render_size` (refined to `spp`), shows its newest image in
    /// `viewport` and compares the live frame with it; off, drops it all. A failed
    /// comparison's message is returned.
    pub fn update(
        &mut self,
        on: bool,
        doc: Option<&Document>,
        render_size: (u32, u32),
        spp: u32,
        viewport: &mut Viewport,
    ) -> Option<String> {
        if !on {
            if self.reference.take().is_some() {
                viewport.clear_reference();
                self.latest = None;
                self.measured = None;
                self.measure_job = None;
                self.measure_key = None;
            }
            return None;
        }
        let doc = doc?;
        if render_size == (0, 0) {
            return None;
        }
        let reference = self
            .reference
            .get_or_insert_with(|| ReferenceRenderer::spawn(self.repaint.clone()));
        reference.request(doc.version, &doc.scene, render_size, spp);
        if let Some(r) = reference.latest()
            && self.latest.as_ref().is_none_or(|old| old.seq != r.seq)
        {
            viewport.set_reference(Arc::clone(&r.image));
            self.latest = Some(r);
        }
        let mut error = None;
        if let Some(r) = self.measure_job.as_ref().and_then(|j| j.poll()) {
            self.measure_job = None;
            match r {
                Ok(m) => self.measured = Some(m),
                Err(e) => error = Some(e),
            }
        }
        self.measure(viewport);
        error
    }

    /// Starts comparing the live frame with the reference when both show the same
    /// version at the same size, the pair is new and `MEASURE_EVERY` has passed;
    /// otherwise wakes the window again after the interval.
    fn measure(&mut self, viewport: &Viewport) {
        let (Some(live), Some(r)) = (viewport.frame(), &self.latest) else {
            return;
        };
        let key = (live.finished, r.seq);
        let comparable = live.version == r.version
            && !live.preview
            && live.estimate.size() == (r.image.width(), r.image.height());
        if comparable
            && self.measure_job.is_none()
            && self.measure_key != Some(key)
            && self.measure_started.elapsed() >= MEASURE_EVERY
        {
            self.measure_key = Some(key);
            self.measure_started = Instant::now();
            let (reference, live, reference_spp) = (Arc::clone(&r.image), live.image(), r.spp);
            self.measure_job = Some(Job::spawn("comparing", self.repaint.clone(), move || {
                let comparison =
                    metrics::compare(&reference, &live, 0.0).map_err(|e| e.to_string())?;
                Ok(Measured {
                    reference,
                    live,
                    reference_spp,
                    comparison,
                })
            }));
        } else if (!comparable || self.measure_key != Some(key))
            && let Some(ctx) = &self.repaint
        {
            // Wake up again to compare once the interval has passed.
            ctx.request_repaint_after(MEASURE_EVERY);
        }
    }

    /// The status bar's part: the live mode, the reference and the numbers.
    pub fn status(&self, ui: &mut Ui, live: (ModeKind, Device)) {
        ui.label(format!("live: {}", mode_name(live.0, live.1)));
        match &self.latest {
            Some(r) => ui.label(format!("reference: spmm, {} spp", r.spp)),
            None => ui.label("reference: starting"),
        };
        if let Some(m) = &self.measured {
            let c = &m.comparison;
            ui.label(format!(
                "RMSE {:.4} · PSNR {:.2} dB · MSSIM {:.4}",
                c.rmse, c.psnr_db, c.mssim
            ));
        }
        if let Some(e) = self.reference.as_ref().and_then(|r| r.error()) {
            ui.colored_label(ui.visuals().error_fg_color, format!("reference: {e}"));
        }
    }
}
