//! `meso pack info FILE` and `meso pack validate FILE`: summarise an SPMM pack, or
//! check it fully (exit 0, or 2 with the first fault named), per docs/cli.md; `new`,
//! `preview`, `eval` (with each basis's contribution in JSON) and `edit`
//! (`pack_edit_cmd.rs`).

use std::path::{Path, PathBuf};

use anyhow::anyhow;
use clap::Subcommand;
use glam::DVec2;
use meso_materials::image::Image;
use meso_materials::spmm::pack::{self, PackError};
use meso_materials::spmm::{EvalSettings, PrepareRequest, SpmmMaterial, TexelFilter, recipe};
use serde_json::json;

use crate::failure::{CliError, ResultExt};

#[derive(Subcommand, Debug)]
pub enum PackCommand {
    /// Summary of a pack: resolution, clusters and their dictionaries, weights per texel, N_PCA, sizes by part.
    Info {
        file: PathBuf,
        #[arg(long)]
        json: bool,
    },
    /// Full consistency check: exit 0 if valid, 2 with the first fault named. A basis
    /// over the lobe bound is a warning, or a fault with --strict.
    Validate {
        file: PathBuf,
        #[arg(long)]
        json: bool,
        /// Refuse a pack whose basis peaks over the lobe bound (exit 2).
        #[arg(long)]
        strict: bool,
    },
    /// Build a pack from a TOML recipe (clusters, dictionaries, weight maps); no residual.
    New {
        recipe: PathBuf,
        #[arg(short = 'o', long)]
        output: PathBuf,
        #[arg(long)]
        json: bool,
    },
    /// Render a tiled flat patch of the material under two directional lights, as PNG or EXR.
    Preview {
        file: PathBuf,
        #[arg(short = 'o', long)]
        output: PathBuf,
        /// Image side in pixels.
        #[arg(long, default_value_t = 256)]
        size: u32,
        /// Tiles of the texture across the image.
        #[arg(long, default_value_t = 2.0)]
        tiles: f64,
        /// Exposure in stops for PNG output.
        #[arg(long, default_value_t = 0.0, allow_negative_numbers = true)]
        exposure: f64,
    },
    /// Scripted edits: scale weights per basis or cluster, mute, remove or add bases, within a texel mask.
    Edit(Box<crate::pack_edit_cmd::PackEditArgs>),
    /// Keep, over all clusters, the residual components that remove the most table
    /// error, as many as fit in a byte budget (per-cluster N_PCA; docs/fitting.md).
    Trim {
        file: PathBuf,
        #[arg(short = 'o', long)]
        output: PathBuf,
        /// Largest file size in bytes.
        #[arg(long, required_unless_present = "npca", conflicts_with = "npca")]
        max_bytes: Option<u64>,
        /// Instead: the first N components in every cluster (an even split, what
        /// `meso fit --npca N` gives), to compare with a budget at equal bytes.
        #[arg(long)]
        npca: Option<usize>,
        /// Precision of the output's residual tables (default: the input's); a budget
        /// counts this precision.
        #[arg(long, value_enum)]
        precision: Option<crate::fit_cmd::PrecisionArg>,
        #[arg(long)]
        json: bool,
    },
    /// Read CSV rows `wix,wiy,wiz,wox,woy,woz` from stdin, print the RGB BTF value of one texel per row.
    Eval {
        file: PathBuf,
        /// Texture coordinates U,V of the texel (u right, v up, wrapping outside [0, 1)).
        #[arg(long, value_name = "U,V")]
        texel: String,
        /// Leave out the PCA residual.
        #[arg(long)]
        no_residual: bool,
        /// Use at most this many principal components.
        #[arg(long)]
        npca: Option<usize>,
        /// Blend the four nearest texels instead of taking the nearest.
        #[arg(long)]
        bilinear: bool,
        #[arg(long)]
        json: bool,
    },
}

pub fn run(command: PackCommand) -> Result<(), CliError> {
    match command {
        PackCommand::New {
            recipe,
            output,
            json,
        } => new(&recipe, &output, json),
        PackCommand::Preview {
            file,
            output,
            size,
            tiles,
            exposure,
        } => preview(&file, &output, size, tiles, exposure),
        PackCommand::Eval {
            file,
            texel,
            no_residual,
            npca,
            bilinear,
            json,
        } => eval(&file, &texel, !no_residual, npca, bilinear, json),
        PackCommand::Info { file, json } => info(&file, json),
        PackCommand::Trim {
            file,
            output,
            max_bytes,
            npca,
            precision,
            json,
        } => trim(
            &file,
            &output,
            max_bytes,
            npca,
            precision.map(Into::into),
            json,
        ),
        PackCommand::Edit(args) => {
            crate::pack_edit_cmd::run(&args, &std::env::args().collect::<Vec<_>>())
        }
        PackCommand::Validate { file, json, strict } => {
            let m = load(&file)?;
            // The bound is about the fit's quality, not the file's consistency: a pack
            // over it renders as written (possibly with fireflies where the lobe
            // peaks), so it is a warning unless the caller asks for refusal.
            let warning = match meso_materials::spmm::lobe_bound::check_lobes(&m) {
                Ok(()) => None,
                Err(e) if strict => {
                    return Err(CliError::bad_input(anyhow::anyhow!(
                        "`{}`: {e}",
                        file.display()
                    )));
                }
                Err(e) => Some(format!("`{}`: {e}", file.display())),
            };
            if let Some(w) = &warning {
                eprintln!("warning: {w}");
            }
            if json {
                return crate::print_json(&json!({
                    "file": file.display().to_string(),
                    "valid": true,
                    "name": m.name(),
                    "warnings": warning.into_iter().collect::<Vec<_>>(),
                }));
            }
            println!(
                "{}: valid SPMM pack `{}` ({}x{} texels, {} clusters)",
                file.display(),
                m.name(),
                m.width(),
                m.height(),
                m.clusters().len()
            );
            Ok(())
        }
    }
}

fn trim(
    file: &Path,
    output: &Path,
    max_bytes: Option<u64>,
    npca: Option<usize>,
    precision: Option<pack::ResidualPrecision>,
    json: bool,
) -> Result<(), CliError> {
    use meso_fit::budget;
    let bytes = std::fs::read(file).bad_input_ctx(|| format!("reading `{}`", file.display()))?;
    let m = pack::decode_pack(&bytes).map_err(|kind| {
        CliError::bad_input(PackError {
            path: file.to_path_buf(),
            kind,
        })
    })?;
    let input_precision = pack::residual_precision(&bytes);
    let precision = precision.unwrap_or(input_precision);
    let before: f64 = budget::component_energies(&m).iter().flatten().sum();
    let (mut t, how) = match (max_bytes, npca) {
        (Some(b), _) => (
            budget::trim_to_bytes(&m, b, precision)
                .map_err(|e| CliError::bad_input(anyhow!("`{}`: {e}", file.display())))?,
            format!("--max-bytes {b}"),
        ),
        (None, Some(k)) => {
            if k > m.npca() {
                return Err(CliError::bad_input(anyhow!(
                    "--npca {k}: `{}` has {} components per cluster",
                    file.display(),
                    m.npca()
                )));
            }
            (
                budget::keep_first(&m, k, precision)
                    .map_err(|e| CliError::bad_input(anyhow!("`{}`: {e}", file.display())))?,
                format!("--npca {k}"),
            )
        }
        (None, None) => unreachable!("clap requires one of them"),
    };
    // Trimming lowers the residual and with it the pack's own maximum, which the
    // lobe bound's hemisphere check compares against: weights it no longer allows
    // are lowered to it.
    let (clamped, lowered) = budget::clamp_to_lobe_bound(&t.material)
        .map_err(|e| CliError::failure(anyhow!("`{}` ({how}): {e}", file.display())))?;
    t.material = clamped;
    let how = if precision == input_precision {
        how
    } else {
        format!("{how} --precision {}", precision.name())
    };
    t.material
        .set_provenance(format!("{}; meso pack trim {how}", m.provenance()));
    let encoded = pack::encode_pack(&t.material, precision);
    meso_materials::atomic::write_bytes_atomic(output, &encoded)
        .failure_ctx(|| format!("writing `{}`", output.display()))?;
    if json {
        return crate::print_json(&json!({
            "output": output.display().to_string(),
            "pack_bytes": encoded.len(),
            "cluster_npca": t.cluster_npca,
            "dropped_energy": t.dropped_energy,
            "weights_lowered": lowered,
            "component_energy": before,
        }));
    }
    let list: Vec<String> = t.cluster_npca.iter().map(usize::to_string).collect();
    println!(
        "wrote {} ({} bytes): N_PCA per cluster [{}]; {lowered} weight entries lowered to the lobe bound",
        output.display(),
        encoded.len(),
        list.join(", ")
    );
    Ok(())
}

fn load(file: &Path) -> Result<SpmmMaterial, CliError> {
    // Every reading or validation fault of a pack is bad input (exit 2).
    pack::read_pack(file).map_err(|e: PackError| CliError::bad_input(e))
}

fn info(file: &Path, as_json: bool) -> Result<(), CliError> {
    let m = load(file)?;
    let bytes = std::fs::read(file).bad_input_ctx(|| format!("`{}`", file.display()))?;
    let sizes = pack::tensor_sizes(&bytes).bad_input_ctx(|| format!("`{}`", file.display()))?;
    let texels = m.width() as usize * m.height() as usize;
    let counts: Vec<usize> = (0..texels).map(|t| m.texel_weights(t).count()).collect();
    let mean_weights = counts.iter().sum::<usize>() as f64 / texels as f64;
    let max_weights = counts.iter().copied().max().unwrap_or(0);
    let mut texels_per_cluster = vec![0usize; m.clusters().len()];
    for &c in m.texel_cluster() {
        texels_per_cluster[c as usize] += 1;
    }
    let clusters: Vec<serde_json::Value> = m
        .clusters()
        .iter()
        .zip(&texels_per_cluster)
        .enumerate()
        .map(|(i, (c, &n))| {
            let bases: Vec<serde_json::Value> = c
                .bases
                .iter()
                .map(|b| {
                    let params: serde_json::Map<String, serde_json::Value> = b
                        .brdf()
                        .model()
                        .param_specs()
                        .iter()
                        .zip(b.brdf().param_values())
                        .map(|(s, v)| (s.name.to_string(), json!(v)))
                        .collect();
                    json!({"model": b.brdf().model().name(), "params": params, "normal": b.normal().to_array()})
                })
                .collect();
            json!({"cluster": i, "texels": n, "bases": bases})
        })
        .collect();
    // What a render of every cluster would hold, with and without the residual.
    let eval_bytes = |residual| {
        m.prepare(&PrepareRequest {
            used_clusters: None,
            residual,
            max_npca: usize::MAX,
        })
        .bytes()
    };
    let (eval_on, eval_off) = (eval_bytes(true), eval_bytes(false));
    let precision = pack::residual_precision(&bytes).name();
    let residual = m.residual().map(|r| json!({"light_dirs": r.light_dirs.len(), "view_dirs": r.view_dirs.len(), "npca": r.npca, "precision": precision}));
    if as_json {
        return crate::print_json(&json!({
            "file": file.display().to_string(),
            "name": m.name(),
            "provenance": m.provenance(),
            "edited": m.edited(),
            "width": m.width(),
            "height": m.height(),
            "npca": m.npca(),
            "residual": residual,
            "weights_per_texel": {"mean": mean_weights, "max": max_weights},
            "clusters": clusters,
            "bytes": sizes.iter().map(|(n, s)| json!({"part": n, "bytes": s})).collect::<Vec<_>>(),
            "total_bytes": bytes.len(),
            "evaluation_bytes": {"residual_on": eval_on, "residual_off": eval_off},
        }));
    }
    println!(
        "{}: SPMM pack `{}`{}",
        file.display(),
        m.name(),
        if m.edited() { " (edited)" } else { "" }
    );
    println!("provenance   {}", m.provenance());
    println!("texels       {} x {}", m.width(), m.height());
    println!("weights      {mean_weights:.2} per texel on average, at most {max_weights}");
    match m.residual() {
        Some(r) => println!(
            "residual     N_PCA = {} on {} light x {} view directions, {precision} tables",
            r.npca,
            r.light_dirs.len(),
            r.view_dirs.len()
        ),
        None => println!("residual     none"),
    }
    println!("clusters     {}", m.clusters().len());
    for (i, (c, n)) in m.clusters().iter().zip(&texels_per_cluster).enumerate() {
        println!(
            "  cluster {i}: {n} texels, {} basis functions",
            c.bases.len()
        );
        for (j, b) in c.bases.iter().enumerate() {
            let params: Vec<String> = b
                .brdf()
                .model()
                .param_specs()
                .iter()
                .zip(b.brdf().param_values())
                .map(|(s, v)| format!("{}={v}", s.name))
                .collect();
            let n = b.normal();
            println!(
                "    {j}: {} {} normal ({:.4}, {:.4}, {:.4})",
                b.brdf().model().name(),
                params.join(" "),
                n.x,
                n.y,
                n.z
            );
        }
    }
    println!(
        "evaluation   {} bytes with the residual, {} without (bases {}, weights {}, residual {})",
        eval_on.total(),
        eval_off.total(),
        eval_on.bases,
        eval_on.weights,
        eval_on.residual
    );
    println!("bytes        {} in all", bytes.len());
    for (name, size) in &sizes {
        println!("  {name:<24} {size:>10}");
    }
    Ok(())
}

fn eval(
    file: &Path,
    texel: &str,
    residual: bool,
    npca: Option<usize>,
    bilinear: bool,
    json: bool,
) -> Result<(), CliError> {
    let uv = texel
        .split_once(',')
        .and_then(|(u, v)| Some(DVec2::new(u.trim().parse().ok()?, v.trim().parse().ok()?)))
        .filter(|uv| uv.is_finite())
        .ok_or_else(|| {
            CliError::bad_input(anyhow!(
                "--texel `{texel}`: expected two finite numbers U,V"
            ))
        })?;
    let m = load(file)?;
    let rows = crate::brdf_cmd::parse_direction_rows(std::io::stdin().lock())?;
    let settings = EvalSettings {
        residual,
        max_npca: npca.unwrap_or(usize::MAX),
        filter: if bilinear {
            TexelFilter::Bilinear
        } else {
            TexelFilter::Nearest
        },
        uv_scale: DVec2::ONE,
    };
    let values: Vec<[f64; 3]> = rows
        .iter()
        .map(|&(wi, wo)| m.eval_uv(uv, wi, wo, &settings).to_array())
        .collect();
    if json {
        // Each part of the nearest texel's value (with --bilinear, `values` blends four
        // texels; the parts stay the nearest one's).
        let texel = m.texel_at(uv, DVec2::ONE);
        let contributions: Vec<serde_json::Value> = rows
            .iter()
            .map(|&(wi, wo)| {
                let c = m.contributions(texel, wi, wo, residual, settings.max_npca);
                json!({
                    "bases": c.bases.iter().map(|b| b.to_array()).collect::<Vec<_>>(),
                    "residual": c.residual.to_array(),
                })
            })
            .collect();
        return crate::print_json(&json!({
            "file": file.display().to_string(),
            "uv": [uv.x, uv.y],
            "texel": texel,
            "cluster": m.texel_cluster()[texel],
            "weights": m.texel_weights(texel).map(|(b, w)| json!({"basis": b, "rgb": w})).collect::<Vec<_>>(),
            "residual": residual,
            "npca": m.npca().min(settings.max_npca),
            "values": values,
            "contributions": contributions,
        }));
    }
    for v in values {
        println!("{:.8e},{:.8e},{:.8e}", v[0], v[1], v[2]);
    }
    Ok(())
}

fn new(recipe_path: &Path, output: &Path, json: bool) -> Result<(), CliError> {
    let m = recipe::build_from_recipe(recipe_path).map_err(CliError::bad_input)?;
    pack::write_pack(output, &m, pack::ResidualPrecision::F32).map_err(CliError::failure)?;
    let bytes = std::fs::metadata(output).map(|md| md.len()).unwrap_or(0);
    if json {
        return crate::print_json(&json!({
            "recipe": recipe_path.display().to_string(),
            "output": output.display().to_string(),
            "name": m.name(),
            "clusters": m.clusters().len(),
            "weights": m.weights().basis.len(),
            "bytes": bytes,
        }));
    }
    println!(
        "wrote {} (`{}`: {}x{} texels, {} clusters, {} weights, {bytes} bytes)",
        output.display(),
        m.name(),
        m.width(),
        m.height(),
        m.clusters().len(),
        m.weights().basis.len()
    );
    Ok(())
}

/// A flat patch seen from 50 degrees elevation, lit by a key light (irradiance pi
/// W/m^2) and a dimmer fill light from the other side, texture tiled `tiles` times:
/// a quick look at a pack's colour, texture and anisotropy without a scene.
fn preview(
    file: &Path,
    output: &Path,
    size: u32,
    tiles: f64,
    exposure: f64,
) -> Result<(), CliError> {
    if !(16..=4096).contains(&size) {
        return Err(CliError::bad_input(anyhow!(
            "--size {size}: must lie in [16, 4096]"
        )));
    }
    if !(tiles.is_finite() && tiles > 0.0 && exposure.is_finite()) {
        return Err(CliError::bad_input(anyhow!(
            "--tiles must be positive and --exposure finite"
        )));
    }
    let m = load(file)?;
    let dir = |elev_deg: f64, azim_deg: f64| {
        let (e, a) = (elev_deg.to_radians(), azim_deg.to_radians());
        glam::DVec3::new(e.cos() * a.cos(), e.cos() * a.sin(), e.sin())
    };
    let wo = dir(50.0, -90.0);
    // The key light sits near the mirror direction of the view, so glossy packs show
    // their highlight; the fill light shows the diffuse texture from the side.
    let lights = [
        (dir(45.0, 80.0), std::f64::consts::PI),
        (dir(30.0, 200.0), 0.4 * std::f64::consts::PI),
    ];
    let settings = EvalSettings {
        filter: TexelFilter::Bilinear,
        ..EvalSettings::default()
    };
    let mut img = Image::new(size, size);
    for y in 0..size {
        for x in 0..size {
            let uv = DVec2::new(
                (x as f64 + 0.5) / size as f64 * tiles,
                1.0 - (y as f64 + 0.5) / size as f64 * tiles,
            );
            let rgb: glam::DVec3 = lights
                .iter()
                .map(|&(wi, e)| e * m.eval_uv(uv, wi, wo, &settings))
                .sum();
            img.set(x, y, rgb.as_vec3().to_array());
        }
    }
    meso_materials::image::write_image(output, &img, exposure)
        .failure_ctx(|| format!("writing `{}`", output.display()))?;
    println!("wrote {}", output.display());
    Ok(())
}
