//! `meso pack info FILE` and `meso pack validate FILE`: summarise an SPMM pack, or
//! check it fully (exit 0, or 2 with the first fault named), per spec/cli.md.

use std::path::{Path, PathBuf};

use clap::Subcommand;
use meso_core::spmm::SpmmMaterial;
use meso_core::spmm::pack::{self, PackError};
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
    /// Full consistency check: exit 0 if valid, 2 with the first fault named.
    Validate {
        file: PathBuf,
        #[arg(long)]
        json: bool,
    },
}

pub fn run(command: PackCommand) -> Result<(), CliError> {
    match command {
        PackCommand::Info { file, json } => info(&file, json),
        PackCommand::Validate { file, json } => {
            let m = load(&file)?;
            if json {
                return crate::print_json(
                    &json!({"file": file.display().to_string(), "valid": true, "name": m.name()}),
                );
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
    let residual = m.residual().map(|r| json!({"light_dirs": r.light_dirs.len(), "view_dirs": r.view_dirs.len(), "npca": r.npca}));
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
            "residual     N_PCA = {} on {} light x {} view directions",
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
    println!("bytes        {} in all", bytes.len());
    for (name, size) in &sizes {
        println!("  {name:<24} {size:>10}");
    }
    Ok(())
}
