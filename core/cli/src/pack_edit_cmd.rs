//! `meso pack edit IN -o OUT`: scripted weight and dictionary edits of an SPMM pack in
//! the pack-edit language of `meso_session::pack_edits` (also a studio script's
//! `pack = "..."` edits), through the same core functions as the studio. The output
//! is written atomically, with the input's residual precision.

use std::path::{Path, PathBuf};

use anyhow::anyhow;
use clap::Args;
use meso_materials::spmm::pack;
use meso_session::pack_edits::{Edited, PackEditOptions, PackEdits};
use serde_json::json;

use crate::failure::{CliError, ResultExt};

#[derive(Args, Debug)]
pub struct PackEditArgs {
    /// The pack to edit.
    input: PathBuf,
    /// Where to write the edited pack (may be the input).
    #[arg(short = 'o', long)]
    output: PathBuf,
    #[command(flatten)]
    edits: PackEditOptions,
    #[arg(long)]
    json: bool,
}

pub fn run(args: &PackEditArgs, argv: &[String]) -> Result<(), CliError> {
    let edits = PackEdits::from_options(args.edits.clone(), argv)
        .map_err(|e| CliError::bad_input(anyhow!(e)))?;
    let bytes =
        std::fs::read(&args.input).bad_input_ctx(|| format!("`{}`", args.input.display()))?;
    let input = pack::decode_pack(&bytes)
        .map_err(|e| CliError::bad_input(anyhow!("`{}`: {e}", args.input.display())))?;
    let precision = pack::residual_precision(&bytes);
    let Edited { material: m, added } = edits
        .apply(&input, Path::new("."))
        .map_err(|e| CliError::bad_input(anyhow!(e)))?;
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
