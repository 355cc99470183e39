//! `meso pack edit IN -o OUT`: scripted weight and dictionary edits of an SPMM pack,
//! through the same core functions as the studio (`SpmmMaterial::with_weight_scale`,
//! `with_view_applied`, `with_basis_removed`, `with_basis_added`, ...). Every index
//! names the input pack; the edits run in a fixed order (scales, mutes, residual
//! switches, removals, the addition) so a script reads the same whatever the option
//! order. The output is written atomically, with the input's residual precision.

use std::path::PathBuf;

use anyhow::anyhow;
use clap::Args;
use glam::DVec3;
use meso_materials::brdf::{AnalyticBrdf, BasisFunction, BrdfModel, warp};
use meso_materials::spmm::pack;
use meso_materials::spmm::{BasisView, SpmmMaterial, TexelMask, WeightTarget};
use serde_json::json;

use crate::failure::{CliError, ResultExt};

#[derive(Args, Debug)]
pub struct PackEditArgs {
    /// The pack to edit.
    input: PathBuf,
    /// Where to write the edited pack (may be the input).
    #[arg(short = 'o', long)]
    output: PathBuf,
    /// The cluster the following --scale options apply to.
    #[arg(long, value_name = "C")]
    cluster: Vec<usize>,
    /// The basis the next --scale applies to (without one, a --scale applies to its
    /// cluster's whole mixture).
    #[arg(long, value_name = "B")]
    basis: Vec<usize>,
    /// Multiply weights per channel (R,G,B) or by one factor; repeatable.
    #[arg(long, value_name = "R,G,B", allow_hyphen_values = true)]
    scale: Vec<String>,
    /// Remove the weights of basis B of cluster C (the basis stays in the dictionary);
    /// repeatable.
    #[arg(long, value_name = "C:B")]
    mute: Vec<String>,
    /// Keep only the soloed bases' weights in their cluster (and switch its residual
    /// off); repeatable.
    #[arg(long, value_name = "C:B")]
    solo: Vec<String>,
    /// Switch cluster C's residual off; repeatable.
    #[arg(long, value_name = "C")]
    residual_off: Vec<usize>,
    /// Remove basis B of cluster C and its weights; repeatable.
    #[arg(long, value_name = "C:B")]
    remove_basis: Vec<String>,
    /// Append a basis to cluster C (needs --model).
    #[arg(long, value_name = "C")]
    add_basis: Option<usize>,
    /// The added basis's BRDF model (docs/brdf.md names).
    #[arg(long, value_name = "NAME", requires = "add_basis")]
    model: Option<String>,
    /// A parameter of the added basis; repeatable; the others keep their defaults.
    #[arg(long, value_name = "K=V", requires = "add_basis")]
    param: Vec<String>,
    /// The added basis's normal, polar and azimuth angles in radians (default +z).
    #[arg(
        long,
        value_name = "THETA,PHI",
        requires = "add_basis",
        allow_hyphen_values = true
    )]
    normal: Option<String>,
    /// Weight given to the added basis on the cluster's texels (within --texels).
    #[arg(
        long,
        value_name = "R,G,B",
        requires = "add_basis",
        allow_hyphen_values = true
    )]
    add_weight: Option<String>,
    /// Limit --scale and --add-weight to a mask image in texel space (grey = strength).
    #[arg(long, value_name = "MASK.png")]
    texels: Option<PathBuf>,
    #[arg(long)]
    json: bool,
}

/// `index`-th occurrence of `option` (1-based in messages).
fn nth(option: &str, index: usize) -> String {
    format!("{option} #{}", index + 1)
}

fn numbers(option: &str, text: &str, n: usize) -> Result<Vec<f64>, CliError> {
    let values: Option<Vec<f64>> = text
        .split(',')
        .map(|v| v.trim().parse::<f64>().ok().filter(|v| v.is_finite()))
        .collect();
    match values {
        Some(v) if v.len() == n => Ok(v),
        _ => Err(CliError::bad_input(anyhow!(
            "{option} `{text}`: expected {n} finite numbers separated by commas"
        ))),
    }
}

fn rgb(option: &str, text: &str) -> Result<[f64; 3], CliError> {
    if !text.contains(',') {
        let v = numbers(option, text, 1)?[0];
        return Ok([v; 3]);
    }
    let v = numbers(option, text, 3)?;
    Ok([v[0], v[1], v[2]])
}

fn pair(option: &str, text: &str) -> Result<(usize, usize), CliError> {
    text.split_once(':')
        .and_then(|(c, b)| Some((c.trim().parse().ok()?, b.trim().parse().ok()?)))
        .ok_or_else(|| CliError::bad_input(anyhow!("{option} `{text}`: expected CLUSTER:BASIS")))
}

/// One `--scale` with the cluster and basis it applies to.
struct Scale<'a> {
    cluster: usize,
    basis: Option<usize>,
    text: &'a str,
}

/// Pairs each `--scale` with the last `--cluster` before it and the `--basis` given
/// since the previous `--scale` (none: the cluster's whole mixture). Clap keeps each
/// option's values but not how they interleave, so the order is read from the
/// command line itself; the values were already checked by clap.
fn scales<'a>(args: &'a PackEditArgs, argv: &[String]) -> Result<Vec<Scale<'a>>, CliError> {
    let mut order = Vec::new();
    let mut tokens = argv.iter();
    while let Some(t) = tokens.next() {
        for name in ["--cluster", "--basis", "--scale"] {
            if t == name {
                tokens.next();
                order.push(name);
            } else if t.starts_with(&format!("{name}=")) {
                order.push(name);
            }
        }
        if t == "--" {
            break;
        }
    }
    let (mut c, mut b, mut s) = (0, 0, 0);
    let mut cluster = None;
    let mut basis = None;
    let mut out = Vec::new();
    let mut pending = false;
    for name in order {
        pending = name != "--scale";
        match name {
            "--cluster" => {
                cluster = args.cluster.get(c).copied();
                c += 1;
            }
            "--basis" => {
                basis = args.basis.get(b).copied();
                b += 1;
            }
            _ => {
                let Some(cluster) = cluster else {
                    return Err(CliError::bad_input(anyhow!(
                        "{} `{}`: no --cluster before it",
                        nth("--scale", s),
                        args.scale.get(s).map_or("", |t| t.as_str())
                    )));
                };
                if let Some(text) = args.scale.get(s) {
                    out.push(Scale {
                        cluster,
                        basis: basis.take(),
                        text,
                    });
                }
                s += 1;
            }
        }
    }
    if out.len() != args.scale.len() || pending {
        return Err(CliError::bad_input(anyhow!(
            "--cluster and --basis choose what the next --scale applies to; give --scale after them"
        )));
    }
    Ok(out)
}

pub fn run(args: &PackEditArgs, argv: &[String]) -> Result<(), CliError> {
    let scales = scales(args, argv)?;
    if args.add_basis.is_some() && args.model.is_none() {
        return Err(CliError::bad_input(anyhow!(
            "--add-basis needs --model NAME"
        )));
    }
    let bytes =
        std::fs::read(&args.input).bad_input_ctx(|| format!("`{}`", args.input.display()))?;
    let input = pack::decode_pack(&bytes)
        .map_err(|e| CliError::bad_input(anyhow!("`{}`: {e}", args.input.display())))?;
    let precision = pack::residual_precision(&bytes);
    let mask = match &args.texels {
        Some(p) => Some(
            TexelMask::read_image(p, input.width(), input.height())
                .map_err(|e| CliError::bad_input(anyhow!("--texels: {e}")))?,
        ),
        None => None,
    };
    let (m, added) = edit(&input, args, &scales, mask.as_ref())?;
    pack::write_pack(&args.output, &m, precision).map_err(CliError::failure)?;
    let changed = input
        .changed_texels(&m)
        .map_or(m.texel_cluster().len(), |c| {
            c.iter().filter(|&&b| b).count()
        });
    if args.json {
        return crate::print_json(&json!({
            "input": args.input.display().to_string(),
            "output": args.output.display().to_string(),
            "edited": m.edited(),
            "changed_texels": changed,
            "weights": m.weights().basis.len(),
            "added_basis": added.map(|(c, j)| json!({"cluster": c, "basis": j})),
            "bases_per_cluster": m.clusters().iter().map(|c| c.bases.len()).collect::<Vec<_>>(),
        }));
    }
    println!(
        "wrote {} ({changed} texels changed, {} weights{})",
        args.output.display(),
        m.weights().basis.len(),
        added.map_or(String::new(), |(c, j)| format!(
            ", basis {j} added to cluster {c}"
        ))
    );
    Ok(())
}

/// The edited material and, if a basis was added, its (cluster, index).
fn edit(
    input: &SpmmMaterial,
    args: &PackEditArgs,
    scales: &[Scale],
    mask: Option<&TexelMask>,
) -> Result<(SpmmMaterial, Option<(usize, usize)>), CliError> {
    let at = |option: String| {
        move |e: meso_materials::spmm::SpmmError| CliError::bad_input(anyhow!("{option}: {e}"))
    };
    let mut m = input.clone();
    for (i, s) in scales.iter().enumerate() {
        let scale = rgb(&nth("--scale", i), s.text)?;
        let target = WeightTarget {
            cluster: Some(s.cluster),
            basis: s.basis,
            texels: mask,
        };
        let option = match target.basis {
            Some(b) => format!(
                "--cluster {} --basis {b} ({})",
                s.cluster,
                nth("--scale", i)
            ),
            None => format!("--cluster {} ({})", s.cluster, nth("--scale", i)),
        };
        m = m.with_weight_scale(&target, scale).map_err(at(option))?;
    }
    let mut view = BasisView::default();
    for (i, text) in args.mute.iter().enumerate() {
        let (c, b) = pair(&nth("--mute", i), text)?;
        view.set_muted(c, b, true);
        m.with_view(view.clone())
            .map_err(at(format!("--mute {text}")))?;
    }
    for (i, text) in args.solo.iter().enumerate() {
        let (c, b) = pair(&nth("--solo", i), text)?;
        view.set_solo(c, b, true);
        m.with_view(view.clone())
            .map_err(at(format!("--solo {text}")))?;
    }
    m = m
        .with_view(view)
        .and_then(|v| v.with_view_applied())
        .map_err(at("--mute/--solo".into()))?;
    for &c in &args.residual_off {
        m = m
            .with_cluster_residual_off(c)
            .map_err(at(format!("--residual-off {c}")))?;
    }
    // Highest index first within each cluster, so the input's indices stay valid.
    let mut removals = args
        .remove_basis
        .iter()
        .enumerate()
        .map(|(i, t)| Ok((pair(&nth("--remove-basis", i), t)?, t)))
        .collect::<Result<Vec<_>, CliError>>()?;
    removals.sort_by_key(|r| std::cmp::Reverse(r.0));
    removals.dedup_by(|a, b| a.0 == b.0);
    for ((c, b), text) in removals {
        m = m
            .with_basis_removed(c, b)
            .map_err(at(format!("--remove-basis {text}")))?;
    }
    let mut added = None;
    if let (Some(c), Some(model)) = (args.add_basis, &args.model) {
        let basis = new_basis(model, &args.param, args.normal.as_deref())?;
        let (next, j) = m
            .with_basis_added(c, basis)
            .map_err(at(format!("--add-basis {c}")))?;
        m = next;
        if let Some(text) = &args.add_weight {
            let w = rgb("--add-weight", text)?;
            let target = WeightTarget {
                cluster: Some(c),
                basis: Some(j),
                texels: mask,
            };
            m = m
                .with_weight_added(&target, w)
                .map_err(at("--add-weight".into()))?;
        }
        added = Some((c, j));
    }
    Ok((m, added))
}

fn new_basis(
    model: &str,
    params: &[String],
    normal: Option<&str>,
) -> Result<BasisFunction, CliError> {
    let model =
        BrdfModel::from_name(model).map_err(|e| CliError::bad_input(anyhow!("--model: {e}")))?;
    let mut values = Vec::new();
    for (i, p) in params.iter().enumerate() {
        let (k, v) = p
            .split_once('=')
            .and_then(|(k, v)| Some((k.trim(), v.trim().parse::<f64>().ok()?)))
            .ok_or_else(|| {
                CliError::bad_input(anyhow!("{} `{p}`: expected NAME=NUMBER", nth("--param", i)))
            })?;
        values.push((k, v));
    }
    let brdf = AnalyticBrdf::new(model, &values)
        .map_err(|e| CliError::bad_input(anyhow!("--param: {e}")))?;
    let n = match normal {
        Some(text) => {
            let v = numbers("--normal", text, 2)?;
            warp::spherical(v[0].cos(), v[1])
        }
        None => DVec3::Z,
    };
    BasisFunction::new(brdf, n).map_err(|e| CliError::bad_input(anyhow!("--normal: {e}")))
}
