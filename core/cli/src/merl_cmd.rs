//! `meso merl ...`: summarise, validate and look up measured BRDFs in the MERL binary
//! format (docs/formats/merl.md), and tabulate an analytic model into one (docs/cli.md).
//! Every reading or validation fault is bad input (exit 2); a failed write is exit 1.

use std::io::Write;
use std::path::{Path, PathBuf};

use anyhow::anyhow;
use clap::Subcommand;
use glam::DVec3;
use meso_materials::merl::{self, MerlBrdf};
use serde_json::json;

use crate::brdf_cmd::{ModelArgs, params_json, parse_direction_rows};
use crate::failure::{CliError, ResultExt};

#[derive(Subcommand, Debug)]
pub enum MerlCommand {
    /// Summary of a MERL file: resolution, cells without data, value ranges, albedo at normal view.
    Info {
        file: PathBuf,
        #[arg(long)]
        json: bool,
    },
    /// Full check of a MERL file: exit 0 if valid, 2 with the fault named.
    Validate {
        file: PathBuf,
        #[arg(long)]
        json: bool,
    },
    /// Read CSV rows `wix,wiy,wiz,wox,woy,woz` (tangent frame) from stdin, print `r,g,b` per row.
    Eval {
        file: PathBuf,
        /// Interpolate between the eight nearest cells instead of the reference reader's nearest cell.
        #[arg(long)]
        trilinear: bool,
        #[arg(long)]
        json: bool,
    },
    /// Write an analytic BRDF (times an RGB albedo) as a MERL file, each cell at its bin centre.
    Tabulate {
        #[command(flatten)]
        model: ModelArgs,
        /// RGB factor applied to the model, each component finite and at least 0.
        #[arg(long, value_name = "R,G,B", default_value = "1,1,1")]
        albedo: String,
        /// Output file (conventionally `.binary`).
        #[arg(short = 'o', long)]
        output: PathBuf,
        #[arg(long)]
        json: bool,
    },
}

pub fn run(command: MerlCommand) -> Result<(), CliError> {
    match command {
        MerlCommand::Info { file, json } => info(&file, json),
        MerlCommand::Validate { file, json } => validate(&file, json),
        MerlCommand::Eval {
            file,
            trilinear,
            json,
        } => eval(&file, trilinear, json),
        MerlCommand::Tabulate {
            model,
            albedo,
            output,
            json,
        } => tabulate(&model, &albedo, &output, json),
    }
}

fn load(file: &Path) -> Result<MerlBrdf, CliError> {
    // `MerlError` names the file itself.
    MerlBrdf::read(file).map_err(CliError::bad_input)
}

fn validate(file: &Path, json: bool) -> Result<(), CliError> {
    let brdf = load(file)?;
    let no_data = brdf.no_data_cells();
    if json {
        return crate::print_json(&json!({
            "file": file.display().to_string(),
            "valid": true,
            "no_data_cells": no_data,
        }));
    }
    println!(
        "{}: valid MERL BRDF (90 x 90 x 180 cells, {no_data} without data)",
        file.display()
    );
    Ok(())
}

fn info(file: &Path, json: bool) -> Result<(), CliError> {
    let brdf = load(file)?;
    // Per channel, over the cells with data: count, largest and mean value in 1/sr.
    let mut with_data = [0usize; 3];
    let mut max = [0.0f64; 3];
    let mut sum = [0.0f64; 3];
    for cell in 0..merl::CELLS {
        let stored = brdf.stored()[cell];
        let value = brdf.cell_value(cell);
        for c in 0..3 {
            if stored[c] >= 0.0 {
                with_data[c] += 1;
                max[c] = max[c].max(value[c]);
                sum[c] += value[c];
            }
        }
    }
    let mean: [f64; 3] = [0, 1, 2].map(|c| sum[c] / with_data[c] as f64);
    let albedo = brdf.albedo_at_normal().to_array();
    let no_data = brdf.no_data_cells();
    if json {
        let channels: Vec<serde_json::Value> = (0..3)
            .map(|c| {
                json!({
                    "channel": merl::CHANNELS[c],
                    "scale": merl::SCALE[c],
                    "cells_with_data": with_data[c],
                    "max": max[c],
                    "mean": mean[c],
                    "albedo_at_normal": albedo[c],
                })
            })
            .collect();
        return crate::print_json(&json!({
            "file": file.display().to_string(),
            "dimensions": [merl::THETA_H_RES, merl::THETA_D_RES, merl::PHI_D_RES],
            "cells": merl::CELLS,
            "bytes": merl::FILE_BYTES,
            "no_data_cells": no_data,
            "channels": channels,
        }));
    }
    println!("{}: MERL BRDF", file.display());
    println!(
        "cells        {} x {} x {} (theta_h, theta_d, phi_d) = {}, {no_data} without data",
        merl::THETA_H_RES,
        merl::THETA_D_RES,
        merl::PHI_D_RES,
        merl::CELLS
    );
    println!(
        "{:<8} {:>10} {:>14} {:>14} {:>14} {:>16}",
        "channel", "scale", "cells w/ data", "max (1/sr)", "mean (1/sr)", "albedo at normal"
    );
    for c in 0..3 {
        println!(
            "{:<8} {:>10.6} {:>14} {:>14.6} {:>14.6} {:>16.6}",
            merl::CHANNELS[c],
            merl::SCALE[c],
            with_data[c],
            max[c],
            mean[c],
            albedo[c]
        );
    }
    Ok(())
}

fn eval(file: &Path, trilinear: bool, json: bool) -> Result<(), CliError> {
    let brdf = load(file)?;
    let stdin = std::io::stdin();
    let rows = parse_direction_rows(stdin.lock())?;
    let values: Vec<DVec3> = rows
        .iter()
        .map(|&(wi, wo)| {
            if trilinear {
                brdf.eval_trilinear(wi, wo)
            } else {
                brdf.eval(wi, wo)
            }
        })
        .collect();
    if json {
        return crate::print_json(&json!({
            "file": file.display().to_string(),
            "lookup": if trilinear { "trilinear" } else { "nearest" },
            "values": values.iter().map(|v| v.to_array()).collect::<Vec<_>>(),
        }));
    }
    let stdout = std::io::stdout();
    let mut out = std::io::BufWriter::new(stdout.lock());
    for v in &values {
        // Nine significant digits, like `meso brdf eval`.
        writeln!(out, "{:.8e},{:.8e},{:.8e}", v.x, v.y, v.z)
            .failure_ctx(|| "writing to stdout".into())?;
    }
    out.flush().failure_ctx(|| "writing to stdout".into())
}

fn parse_albedo(raw: &str) -> Result<DVec3, CliError> {
    let fields: Vec<&str> = raw.split(',').map(str::trim).collect();
    if fields.len() != 3 {
        return Err(CliError::bad_input(anyhow!(
            "--albedo `{raw}`: expected three comma-separated numbers R,G,B"
        )));
    }
    let mut v = [0.0f64; 3];
    for (k, field) in fields.iter().enumerate() {
        let x: f64 = field.parse().map_err(|_| {
            CliError::bad_input(anyhow!("--albedo `{raw}`: `{field}` is not a number"))
        })?;
        if !x.is_finite() || x < 0.0 {
            return Err(CliError::bad_input(anyhow!(
                "--albedo `{raw}`: {} component {x} must be finite and at least 0",
                merl::CHANNELS[k]
            )));
        }
        v[k] = x;
    }
    Ok(DVec3::from_array(v))
}

fn tabulate(model: &ModelArgs, albedo: &str, output: &Path, json: bool) -> Result<(), CliError> {
    let brdf = model.build()?;
    let albedo = parse_albedo(albedo)?;
    let table = merl::tabulate(&brdf, albedo).bad_input_ctx(|| "--albedo".into())?;
    table.write(output).map_err(CliError::failure)?;
    let no_data = table.no_data_cells();
    if json {
        return crate::print_json(&json!({
            "output": output.display().to_string(),
            "model": brdf.model().name(),
            "params": params_json(&brdf),
            "albedo": albedo.to_array(),
            "cells": merl::CELLS,
            "no_data_cells": no_data,
            "bytes": merl::FILE_BYTES,
        }));
    }
    println!(
        "{}: {} {} x albedo {:?} tabulated on {} cells ({no_data} below the horizon hold no data)",
        output.display(),
        brdf.model().name(),
        params_json(&brdf),
        albedo.to_array(),
        merl::CELLS
    );
    Ok(())
}
