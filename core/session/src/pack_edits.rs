//! The pack-edit language: the options of `meso pack edit` (scale weights per cluster,
//! basis or texel mask, mute, solo, residual off, remove or add a basis), also what a
//! studio script's `pack = "..."` edit says. One clap definition reads both, and one
//! function applies them through the same core operations as the material panel
//! (`SpmmMaterial::with_weight_scale`, `with_view_applied`, ...). Every index names the
//! input pack; the edits run in a fixed order (scales, mutes and solos, residual
//! switches, removals, the addition) so a script reads the same whatever the order.

use std::path::{Path, PathBuf};

use clap::{Args, Parser};
use glam::DVec3;
use meso_materials::brdf::{AnalyticBrdf, BasisFunction, BrdfModel, warp};
use meso_materials::spmm::{BasisView, Falloff, SpmmMaterial, TexelMask, WeightTarget};

#[derive(Args, Debug, Clone, Default)]
pub struct PackEditOptions {
    /// The cluster the following --scale options apply to.
    #[arg(long, value_name = "C")]
    pub cluster: Vec<usize>,
    /// The basis the next --scale applies to (without one, a --scale applies to its
    /// cluster's whole mixture).
    #[arg(long, value_name = "B")]
    pub basis: Vec<usize>,
    /// Multiply weights per channel (R,G,B) or by one factor; repeatable.
    #[arg(long, value_name = "R,G,B", allow_hyphen_values = true)]
    pub scale: Vec<String>,
    /// Remove the weights of basis B of cluster C (the basis stays in the dictionary);
    /// repeatable.
    #[arg(long, value_name = "C:B")]
    pub mute: Vec<String>,
    /// Keep only the soloed bases' weights in their cluster (and switch its residual
    /// off); repeatable.
    #[arg(long, value_name = "C:B")]
    pub solo: Vec<String>,
    /// Switch cluster C's residual off; repeatable.
    #[arg(long, value_name = "C")]
    pub residual_off: Vec<usize>,
    /// Remove basis B of cluster C and its weights; repeatable.
    #[arg(long, value_name = "C:B")]
    pub remove_basis: Vec<String>,
    /// Append a basis to cluster C (needs --model).
    #[arg(long, value_name = "C")]
    pub add_basis: Option<usize>,
    /// The added basis's BRDF model (docs/brdf.md names).
    #[arg(long, value_name = "NAME", requires = "add_basis")]
    pub model: Option<String>,
    /// A parameter of the added basis; repeatable; the others keep their defaults.
    #[arg(long, value_name = "K=V", requires = "add_basis")]
    pub param: Vec<String>,
    /// The added basis's normal, polar and azimuth angles in radians (default +z).
    #[arg(
        long,
        value_name = "THETA,PHI",
        requires = "add_basis",
        allow_hyphen_values = true
    )]
    pub normal: Option<String>,
    /// Weight given to the added basis on the cluster's texels (within --texels).
    #[arg(
        long,
        value_name = "R,G,B",
        requires = "add_basis",
        allow_hyphen_values = true
    )]
    pub add_weight: Option<String>,
    /// Limit --scale and --add-weight to a mask image in texel space (grey = strength).
    #[arg(long, value_name = "MASK.png")]
    pub texels: Option<PathBuf>,
    /// Limit --scale and --add-weight to a brush dab: a disc of RADIUS texels centred
    /// at texel (X, Y) (x right, y down, wrapping as packs tile), strength falling
    /// linearly to 0 at its edge; with --texels, the product of both.
    #[arg(long, value_name = "X,Y,RADIUS", allow_hyphen_values = true)]
    pub brush: Option<String>,
}

/// A parsed list of pack edits with the order its `--cluster`, `--basis` and
/// `--scale` options came in (clap keeps each option's values, not how they
/// interleave).
#[derive(Debug, Clone)]
pub struct PackEdits {
    pub options: PackEditOptions,
    scales: Vec<Scale>,
}

/// One `--scale` with the cluster and basis it applies to.
#[derive(Debug, Clone)]
struct Scale {
    cluster: usize,
    basis: Option<usize>,
    text: String,
}

/// What an edit did: the material and, if a basis was added, its (cluster, index).
pub struct Edited {
    pub material: SpmmMaterial,
    pub added: Option<(usize, usize)>,
}

#[derive(Parser, Debug)]
#[command(no_binary_name = true, name = "pack edit", disable_help_flag = true)]
struct ScriptLine {
    #[command(flatten)]
    options: PackEditOptions,
}

impl PackEdits {
    /// Reads `text`, the options as a script writes them (`--cluster 0 --scale 1.5`);
    /// words are split at blanks, and quotes ("..." or '...') keep blanks in a word.
    pub fn parse(text: &str) -> Result<Self, String> {
        let words = split_words(text)?;
        let line = ScriptLine::try_parse_from(&words).map_err(|e| {
            let rendered = e.to_string();
            rendered
                .lines()
                .next()
                .unwrap_or("bad options")
                .trim_start_matches("error: ")
                .to_string()
        })?;
        Self::from_options(line.options, &words)
    }

    /// Options clap already read from `argv`, paired with their order there.
    pub fn from_options(options: PackEditOptions, argv: &[String]) -> Result<Self, String> {
        let scales = scales(&options, argv)?;
        if options.add_basis.is_some() && options.model.is_none() {
            return Err("--add-basis needs --model NAME".into());
        }
        Ok(Self { options, scales })
    }

    /// Applies the edits to `input`; a relative `--texels` path is taken from `dir`.
    pub fn apply(&self, input: &SpmmMaterial, dir: &Path) -> Result<Edited, String> {
        let mut mask = match &self.options.texels {
            Some(p) => Some(
                TexelMask::read_image(&dir.join(p), input.width(), input.height())
                    .map_err(|e| format!("--texels: {e}"))?,
            ),
            None => None,
        };
        if let Some(text) = &self.options.brush {
            let v = numbers("--brush", text, 3)?;
            if v[2] <= 0.0 {
                return Err(format!("--brush `{text}`: the radius must be positive"));
            }
            let mut dab = TexelMask::empty(input.width(), input.height());
            dab.stamp(glam::DVec2::new(v[0], v[1]), v[2], 1.0, Falloff::Linear);
            mask = Some(match mask {
                Some(m) => m.intersected(&dab).map_err(|e| format!("--brush: {e}"))?,
                None => dab,
            });
        }
        edit(input, &self.options, &self.scales, mask.as_ref())
    }
}

/// Splits a script's option string into words (blanks separate, quotes group).
fn split_words(text: &str) -> Result<Vec<String>, String> {
    let mut words = Vec::new();
    let mut word: Option<String> = None;
    let mut quote = None;
    for ch in text.chars() {
        match (quote, ch) {
            (Some(q), c) if c == q => quote = None,
            (Some(_), c) => word.get_or_insert_with(String::new).push(c),
            (None, '"' | '\'') => {
                quote = Some(ch);
                word.get_or_insert_with(String::new);
            }
            (None, c) if c.is_whitespace() => words.extend(word.take()),
            (None, c) => word.get_or_insert_with(String::new).push(c),
        }
    }
    if let Some(q) = quote {
        return Err(format!("unclosed {q} quote"));
    }
    words.extend(word);
    Ok(words)
}

/// `index`-th occurrence of `option` (1-based in messages).
fn nth(option: &str, index: usize) -> String {
    format!("{option} #{}", index + 1)
}

fn numbers(option: &str, text: &str, n: usize) -> Result<Vec<f64>, String> {
    let values: Option<Vec<f64>> = text
        .split(',')
        .map(|v| v.trim().parse::<f64>().ok().filter(|v| v.is_finite()))
        .collect();
    match values {
        Some(v) if v.len() == n => Ok(v),
        _ => Err(format!(
            "{option} `{text}`: expected {n} finite numbers separated by commas"
        )),
    }
}

fn rgb(option: &str, text: &str) -> Result<[f64; 3], String> {
    if !text.contains(',') {
        let v = numbers(option, text, 1)?[0];
        return Ok([v; 3]);
    }
    let v = numbers(option, text, 3)?;
    Ok([v[0], v[1], v[2]])
}

fn pair(option: &str, text: &str) -> Result<(usize, usize), String> {
    text.split_once(':')
        .and_then(|(c, b)| Some((c.trim().parse().ok()?, b.trim().parse().ok()?)))
        .ok_or_else(|| format!("{option} `{text}`: expected CLUSTER:BASIS"))
}

/// Pairs each `--scale` with the last `--cluster` before it and the `--basis` given
/// since the previous `--scale` (none: the cluster's whole mixture), reading the
/// order from the words themselves; the values were already checked by clap.
fn scales(args: &PackEditOptions, argv: &[String]) -> Result<Vec<Scale>, String> {
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
                    return Err(format!(
                        "{} `{}`: no --cluster before it",
                        nth("--scale", s),
                        args.scale.get(s).map_or("", |t| t.as_str())
                    ));
                };
                if let Some(text) = args.scale.get(s) {
                    out.push(Scale {
                        cluster,
                        basis: basis.take(),
                        text: text.clone(),
                    });
                }
                s += 1;
            }
        }
    }
    if out.len() != args.scale.len() || pending {
        return Err(
            "--cluster and --basis choose what the next --scale applies to; give --scale after them"
                .into(),
        );
    }
    Ok(out)
}

fn edit(
    input: &SpmmMaterial,
    args: &PackEditOptions,
    scales: &[Scale],
    mask: Option<&TexelMask>,
) -> Result<Edited, String> {
    let at = |option: String| move |e: meso_materials::spmm::SpmmError| format!("{option}: {e}");
    let mut m = input.clone();
    for (i, s) in scales.iter().enumerate() {
        let scale = rgb(&nth("--scale", i), &s.text)?;
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
        .collect::<Result<Vec<_>, String>>()?;
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
    Ok(Edited { material: m, added })
}

fn new_basis(
    model: &str,
    params: &[String],
    normal: Option<&str>,
) -> Result<BasisFunction, String> {
    let model = BrdfModel::from_name(model).map_err(|e| format!("--model: {e}"))?;
    let mut values = Vec::new();
    for (i, p) in params.iter().enumerate() {
        let (k, v) = p
            .split_once('=')
            .and_then(|(k, v)| Some((k.trim(), v.trim().parse::<f64>().ok()?)))
            .ok_or_else(|| format!("{} `{p}`: expected NAME=NUMBER", nth("--param", i)))?;
        values.push((k, v));
    }
    let brdf = AnalyticBrdf::new(model, &values).map_err(|e| format!("--param: {e}"))?;
    let n = match normal {
        Some(text) => {
            let v = numbers("--normal", text, 2)?;
            warp::spherical(v[0].cos(), v[1])
        }
        None => DVec3::Z,
    };
    BasisFunction::new(brdf, n).map_err(|e| format!("--normal: {e}"))
}

#[cfg(test)]
mod tests {
    use super::*;
    use meso_materials::spmm::testing::sample_material;

    #[test]
    fn a_script_line_reads_as_the_command_line_does() {
        let m = sample_material(8, 8, 3, Some(1));
        let e = PackEdits::parse("--cluster 0 --basis 1 --scale 1.5,1.5,1.2 --mute '1:0'")
            .expect("parse");
        let got = e.apply(&m, Path::new(".")).expect("apply").material;
        let t = WeightTarget::basis(0, 1);
        let mut view = BasisView::default();
        view.set_muted(1, 0, true);
        let want = m
            .with_weight_scale(&t, [1.5, 1.5, 1.2])
            .and_then(|m| m.with_view(view))
            .and_then(|m| m.with_view_applied())
            .expect("edit");
        assert!(got.stores_same(&want));
    }

    #[test]
    fn bad_lines_name_the_option_at_fault() {
        let m = sample_material(8, 8, 3, Some(1));
        for (line, needle) in [
            ("--scale 2", "no --cluster"),
            ("--cluster 0 --scale 2,2", "--scale #1"),
            ("--cluster 9 --scale 2", "--cluster 9"),
            ("--mute 1-0", "--mute #1"),
            ("--frobnicate 3", "--frobnicate"),
            ("--cluster 0 --scale '2", "unclosed"),
            ("--add-basis 0", "--model"),
        ] {
            let err = PackEdits::parse(line)
                .and_then(|e| e.apply(&m, Path::new(".")).map(|_| ()))
                .expect_err(line);
            assert!(err.contains(needle), "{line}: {err}");
        }
    }
}
