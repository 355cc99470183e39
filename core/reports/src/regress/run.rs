//! Running the selected cases: load each scene and substituted material once, make
//! every case's scene, render the cases on `jobs` workers (each in its own thread pool
//! of the threads left, so a render is the same bits on any split: the spmm mode draws
//! every sample from (seed, sample, pixel, dimension)), compare each with its golden,
//! write the report's pictures, and with `--update` rewrite the goldens (golden.rs).

use std::collections::BTreeMap;
use std::path::Path;
use std::sync::Mutex;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::Instant;

use super::RegressError;
use super::case::{Case, substitute};
use super::golden::{UpdateRequest, write_goldens};
use super::manifest::Manifest;
use super::report::{CaseMetrics, CaseReport, IMAGES_DIR, Status, images};
use meso_materials::atomic::write_bytes_atomic;
use meso_materials::image::{Image, read_exr};
use meso_materials::metrics::compare;

use meso_render::scene::{Scene, load_scene};
use meso_render::{ModeError, Prepare, run_frames};

/// How to run.
pub struct RunOptions<'a> {
    /// Cases rendered at once (at least 1).
    pub jobs: usize,
    /// Threads shared by the jobs (each gets `threads / jobs`, at least 1).
    pub threads: usize,
    /// Rewrite the goldens of the rendered cases, logging why.
    pub update: Option<&'a UpdateRequest>,
    /// Where the report's pictures go (`REPORT_DIR/images`), if a report is written.
    pub report_dir: Option<&'a Path>,
    /// Called as each case ends (progress lines), with (done, total).
    pub on_case: &'a (dyn Fn(&CaseReport, usize, usize) + Sync),
}

/// What a case needs before it renders.
enum Plan {
    Render(Box<Scene>),
    /// Not rendered, and why.
    Skip(String),
}

/// A judged case, with its new image when `--update` will write it.
type Judged = (CaseReport, Option<Image>);

/// The result of one render.
struct Rendered {
    image: Image,
    seconds: f64,
    trace_seconds: f64,
    rays: u64,
    dropped: u64,
    width: u32,
    height: u32,
    frames: u32,
}

/// Renders and judges `cases`; the rows come back in the order of `cases`. Bad input
/// (a scene or substitution that does not load) is an error before anything renders.
pub fn run(
    manifest: &Manifest,
    cases: &[&Case],
    options: &RunOptions,
) -> Result<Vec<CaseReport>, RegressError> {
    let plans = plan(manifest, cases)?;
    if let Some(dir) = options.report_dir {
        let images = dir.join(IMAGES_DIR);
        std::fs::create_dir_all(&images).map_err(|e| RegressError::Output {
            what: format!("the report folder `{}`", images.display()),
            message: e.to_string(),
        })?;
    }
    let jobs = options.jobs.max(1).min(cases.len().max(1));
    let threads_per_job = (options.threads.max(1) / jobs).max(1);
    let next = AtomicUsize::new(0);
    let done = AtomicUsize::new(0);
    let rows: Mutex<Vec<Option<Judged>>> = Mutex::new((0..cases.len()).map(|_| None).collect());
    let failure: Mutex<Option<RegressError>> = Mutex::new(None);
    std::thread::scope(|scope| {
        for _ in 0..jobs {
            scope.spawn(|| {
                let pool = match rayon::ThreadPoolBuilder::new()
                    .num_threads(threads_per_job)
                    .build()
                {
                    Ok(p) => p,
                    Err(e) => {
                        *failure.lock().expect("not poisoned") = Some(RegressError::Output {
                            what: "a render thread pool".into(),
                            message: e.to_string(),
                        });
                        return;
                    }
                };
                loop {
                    let i = next.fetch_add(1, Ordering::Relaxed);
                    if i >= cases.len() {
                        break;
                    }
                    let case = cases[i];
                    let rendered = match &plans[i] {
                        Plan::Render(scene) => {
                            Some(pool.install(|| render(case, (**scene).clone())))
                        }
                        Plan::Skip(_) => None,
                    };
                    let skip = match &plans[i] {
                        Plan::Skip(reason) => Some(reason.as_str()),
                        Plan::Render(_) => None,
                    };
                    match judge(manifest, case, skip, rendered, options) {
                        Ok((row, image)) => {
                            let n = done.fetch_add(1, Ordering::Relaxed) + 1;
                            (options.on_case)(&row, n, cases.len());
                            rows.lock().expect("not poisoned")[i] = Some((row, image));
                        }
                        Err(e) => {
                            failure.lock().expect("not poisoned").get_or_insert(e);
                            next.store(cases.len(), Ordering::Relaxed);
                        }
                    }
                }
            });
        }
    });
    if let Some(e) = failure.into_inner().expect("not poisoned") {
        return Err(e);
    }
    let rows: Vec<Judged> = rows
        .into_inner()
        .expect("not poisoned")
        .into_iter()
        .map(|r| r.expect("every case was judged"))
        .collect();
    if let Some(request) = options.update {
        let updates: Vec<_> = rows
            .iter()
            .zip(cases)
            .filter_map(|((row, image), case)| {
                image
                    .as_ref()
                    .filter(|_| row.status == Status::Updated)
                    .map(|img| (case.golden_path(&manifest.goldens), case.name.as_str(), img))
            })
            .collect();
        if !updates.is_empty() {
            write_goldens(&manifest.goldens, request, &updates).map_err(|e| {
                RegressError::Output {
                    what: "the goldens".into(),
                    message: e.to_string(),
                }
            })?;
        }
    }
    Ok(rows.into_iter().map(|(row, _)| row).collect())
}

/// Loads what the cases need (each scene and material once) and makes each case's
/// scene; decides which cases cannot render here and why.
fn plan(manifest: &Manifest, cases: &[&Case]) -> Result<Vec<Plan>, RegressError> {
    let mut scenes: BTreeMap<&str, Scene> = BTreeMap::new();
    let mut materials = BTreeMap::new();
    let mut plans = Vec::with_capacity(cases.len());
    for case in cases {
        let bad = |message: String| RegressError::Case {
            case: case.name.clone(),
            origin: case.origin.clone(),
            message,
        };
        let scene_ref = &manifest.scenes[&case.scene];
        if !scenes.contains_key(case.scene.as_str()) {
            let scene = load_scene(&scene_ref.path)
                .map_err(|e| bad(format!("scene `{}`: {e}", case.scene)))?;
            scenes.insert(&case.scene, scene);
        }
        let mut scene = scenes[case.scene.as_str()].clone();
        if let (Some(material), Some(replace)) = (&case.material, &case.replace) {
            if !materials.contains_key(material) {
                let built = manifest
                    .material(material)
                    .map_err(|e| bad(e.to_string()))?;
                materials.insert(material.clone(), built);
            }
            let (m, sets_uv_scale) = materials[material].clone();
            substitute(&mut scene, replace, m, sets_uv_scale).map_err(|e| {
                bad(format!(
                    "`{}`{}: `replace = \"{replace}\"` of scene `{}` (`{}`): {e}",
                    manifest.path.display(),
                    scene_ref
                        .replace_line
                        .map(|l| format!(" line {l}"))
                        .unwrap_or_default(),
                    case.scene,
                    scene_ref.path.display()
                ))
            })?;
        }
        if let Some(seed) = case.seed {
            scene.render.seed = seed;
        }
        plans.push(match meso_modes::supports(case.mode, case.device, &scene) {
            Ok(()) => Plan::Render(Box::new(scene)),
            Err(e @ ModeError::NotBuilt { .. }) => Plan::Skip(e.to_string()),
            Err(e @ ModeError::Unsupported(_)) => Plan::Skip(e.to_string()),
            Err(e) => return Err(bad(e.to_string())),
        });
    }
    Ok(plans)
}

/// One render, on the calling thread's pool.
fn render(case: &Case, scene: Scene) -> Result<Rendered, String> {
    let start = Instant::now();
    let width = case.width.unwrap_or(scene.render.width);
    let height = case.height.unwrap_or(scene.render.height);
    let frames = case.frames.unwrap_or(scene.render.frames);
    let mut mode = meso_modes::create(
        case.mode,
        case.device,
        scene,
        width,
        height,
        Prepare::quietly(),
    )
    .map_err(|e| e.to_string())?;
    let run = run_frames(mode.as_mut(), frames, |_, _| {});
    let image = mode.image();
    Ok(Rendered {
        image,
        seconds: start.elapsed().as_secs_f64(),
        trace_seconds: run.seconds,
        rays: run.counters.rays.total(),
        dropped: mode.progress().dropped,
        width,
        height,
        frames,
    })
}

/// Mean over pixels and channels.
fn mean(image: &Image) -> f64 {
    let sum: f64 = image
        .pixels()
        .iter()
        .flat_map(|p| p.iter().map(|&c| c as f64))
        .sum();
    sum / (3 * image.pixels().len()).max(1) as f64
}

/// The case's row: its status against the golden, and the pictures written; the new
/// image comes back when `--update` will write it.
fn judge(
    manifest: &Manifest,
    case: &Case,
    skip: Option<&str>,
    rendered: Option<Result<Rendered, String>>,
    options: &RunOptions,
) -> Result<Judged, RegressError> {
    let golden_path = case.golden_path(&manifest.goldens);
    let mut row = CaseReport {
        name: case.name.clone(),
        scene: case.scene.clone(),
        material: case.material_label().to_string(),
        mode: case.mode.name().to_string(),
        device: case.device.name().to_string(),
        width: case.width.unwrap_or(0),
        height: case.height.unwrap_or(0),
        frames: case.frames.unwrap_or(0),
        status: Status::Fail,
        message: None,
        tolerance: case.tolerance,
        metrics: None,
        seconds: None,
        trace_seconds: None,
        rays: None,
        nonfinite_dropped: None,
        golden_png: None,
        new_png: None,
        diff_png: None,
        diff_scale: None,
    };
    let golden = golden_path
        .exists()
        .then(|| read_exr(&golden_path).map_err(|e| e.to_string()));
    let write_png = |suffix: &str, bytes: &[u8]| -> Result<Option<String>, RegressError> {
        let Some(dir) = options.report_dir else {
            return Ok(None);
        };
        let rel = format!("{IMAGES_DIR}/{}.{suffix}.png", case.name);
        write_bytes_atomic(&dir.join(&rel), bytes).map_err(|e| RegressError::Output {
            what: format!("the report picture `{rel}`"),
            message: e.to_string(),
        })?;
        Ok(Some(rel))
    };
    if let Some(Ok(g)) = &golden {
        row.golden_png = write_png("golden", &images::thumbnail_png(g))?;
    }
    let rendered = match (skip, rendered) {
        (Some(reason), _) => {
            // A case that has a golden but can no longer render has regressed.
            if golden.is_some() {
                row.message = Some(format!(
                    "cannot render, but its golden `{}` exists: {reason}",
                    golden_path.display()
                ));
            } else {
                row.status = Status::Skipped;
                row.message = Some(reason.to_string());
            }
            return Ok((row, None));
        }
        (None, Some(Err(e))) => {
            row.message = Some(format!("the render failed: {e}"));
            return Ok((row, None));
        }
        (None, Some(Ok(r))) => r,
        (None, None) => unreachable!("a case is rendered unless skipped"),
    };
    row.width = rendered.width;
    row.height = rendered.height;
    row.frames = rendered.frames;
    row.seconds = Some(rendered.seconds);
    row.trace_seconds = Some(rendered.trace_seconds);
    row.rays = Some(rendered.rays);
    row.nonfinite_dropped = Some(rendered.dropped);
    row.new_png = write_png("new", &images::thumbnail_png(&rendered.image))?;
    let mut notes = Vec::new();
    if rendered.dropped > 0 {
        notes.push(format!("{} non-finite samples dropped", rendered.dropped));
    }
    match golden {
        None => {
            notes.insert(
                0,
                format!(
                    "no golden `{}`: create it with `meso regress {} --update --reason \"new case\" --only '{}'`",
                    golden_path.display(),
                    manifest.path.display(),
                    case.name
                ),
            );
        }
        Some(Err(e)) => notes.insert(0, format!("the golden cannot be read: {e}")),
        Some(Ok(g)) => match compare(&g, &rendered.image, 0.0) {
            Err(e) => notes.insert(0, format!("cannot compare with the golden: {e}")),
            Ok(c) => {
                let m = mean(&g);
                let relative = if c.rmse == 0.0 {
                    Some(0.0)
                } else if m > 0.0 {
                    Some(c.rmse / m)
                } else {
                    None
                };
                row.metrics = Some(CaseMetrics {
                    rmse: c.rmse,
                    relative_rmse: relative,
                    psnr_db: c.psnr_db.is_finite().then_some(c.psnr_db),
                    mssim: c.mssim,
                    max_abs_error: c.max_abs_error,
                    identical: g == rendered.image,
                });
                let (png, scale) = images::heat_map_png(&g, &rendered.image);
                row.diff_png = write_png("diff", &png)?;
                row.diff_scale = row.diff_png.as_ref().map(|_| scale);
                let violations = case
                    .tolerance
                    .violations(relative.unwrap_or(f64::INFINITY), c.mssim);
                if violations.is_empty() {
                    row.status = Status::Pass;
                } else {
                    notes.insert(0, violations.join(", "));
                }
            }
        },
    }
    let keep = if options.update.is_some() {
        row.status = Status::Updated;
        Some(rendered.image)
    } else {
        None
    };
    row.message = (!notes.is_empty()).then(|| notes.join("; "));
    Ok((row, keep))
}
