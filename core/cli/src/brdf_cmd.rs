//! `meso brdf ...`: evaluate a model of the analytic dictionary on CSV directions
//! (docs/cli.md), estimate its directional albedo by Monte Carlo, and plot its lobe.

use std::io::{BufRead, Write};
use std::path::PathBuf;

use anyhow::anyhow;
use clap::{Args, Subcommand};
use glam::DVec3;
use meso_materials::brdf::{AnalyticBrdf, BrdfModel, directional_albedo};
use serde_json::json;

use crate::failure::{CliError, ResultExt};

#[derive(Subcommand, Debug)]
pub enum BrdfCommand {
    /// Read CSV rows `wix,wiy,wiz,wox,woy,woz` (tangent frame) from stdin, print f per row.
    Eval {
        #[command(flatten)]
        model: ModelArgs,
        /// Print one JSON object instead of one value per line.
        #[arg(long)]
        json: bool,
    },
    /// Directional albedo (integral of f cos_i over the hemisphere) by importance-sampled Monte Carlo.
    Albedo {
        #[command(flatten)]
        model: ModelArgs,
        /// Angles of the fixed direction from the normal, in degrees (comma-separated, each in [0, 90)).
        #[arg(long, value_delimiter = ',', default_values_t = [0.0, 15.0, 30.0, 45.0, 60.0, 75.0, 85.0, 89.0])]
        theta_deg: Vec<f64>,
        /// Azimuth of the fixed direction in degrees (matters for anisotropic models).
        #[arg(long, default_value_t = 0.0, allow_negative_numbers = true)]
        phi_deg: f64,
        /// Monte Carlo samples per angle.
        #[arg(long, default_value_t = 1_000_000)]
        samples: u32,
        /// Seed of the replayable random numbers.
        #[arg(long, default_value_t = 0)]
        seed: u64,
        #[arg(long)]
        json: bool,
    },
    /// Polar plot of the lobe in the plane of incidence, written as a PNG.
    Plot {
        #[command(flatten)]
        model: ModelArgs,
        /// Incidence angle in degrees from the normal.
        #[arg(long, default_value_t = 45.0)]
        theta_i_deg: f64,
        /// Azimuth of the plane of incidence in degrees (matters for anisotropic models).
        #[arg(long, default_value_t = 0.0, allow_negative_numbers = true)]
        phi_deg: f64,
        /// Image width and height in pixels.
        #[arg(long, default_value_t = 480)]
        size: u32,
        /// Output PNG.
        #[arg(short = 'o', long)]
        output: PathBuf,
    },
}

#[derive(Args, Debug)]
pub struct ModelArgs {
    /// One of: lambertian, oren_nayar, blinn_phong, ward, cook_torrance, lafortune, ashikhmin_shirley.
    #[arg(long)]
    model: String,
    /// A model parameter as KEY=VALUE (repeat for each parameter; see docs/brdf.md).
    #[arg(long = "param", value_name = "KEY=VALUE")]
    params: Vec<String>,
}

impl ModelArgs {
    /// Parses and validates the model and its parameters (exit 2 on any fault).
    pub fn build(&self) -> Result<AnalyticBrdf, CliError> {
        let model = BrdfModel::from_name(&self.model).bad_input_ctx(|| "--model".into())?;
        let mut params = Vec::with_capacity(self.params.len());
        for raw in &self.params {
            let (key, value) = raw.split_once('=').ok_or_else(|| {
                CliError::bad_input(anyhow!("--param `{raw}`: expected KEY=VALUE"))
            })?;
            let value: f64 = value.trim().parse().map_err(|_| {
                CliError::bad_input(anyhow!("--param `{raw}`: `{value}` is not a number"))
            })?;
            params.push((key.trim(), value));
        }
        AnalyticBrdf::new(model, &params).bad_input_ctx(|| "--param".into())
    }
}

pub fn run(command: BrdfCommand) -> Result<(), CliError> {
    match command {
        BrdfCommand::Eval { model, json } => eval(&model, json),
        BrdfCommand::Albedo {
            model,
            theta_deg,
            phi_deg,
            samples,
            seed,
            json,
        } => albedo(&model, &theta_deg, phi_deg, samples, seed, json),
        BrdfCommand::Plot {
            model,
            theta_i_deg,
            phi_deg,
            size,
            output,
        } => {
            let brdf = model.build()?;
            crate::plot::write_lobe_plot(&brdf, theta_i_deg, phi_deg, size, &output)
        }
    }
}

fn eval(model: &ModelArgs, json: bool) -> Result<(), CliError> {
    let brdf = model.build()?;
    let stdin = std::io::stdin();
    let rows = parse_direction_rows(stdin.lock())?;
    let values: Vec<f64> = rows.iter().map(|&(wi, wo)| brdf.eval(wi, wo)).collect();
    if json {
        return crate::print_json(&json!({
            "model": brdf.model().name(),
            "params": params_json(&brdf),
            "values": values,
        }));
    }
    let stdout = std::io::stdout();
    let mut out = std::io::BufWriter::new(stdout.lock());
    for v in &values {
        // Nine significant digits: enough to round-trip an f32 exactly (docs/cli.md).
        writeln!(out, "{:.8e}", v).failure_ctx(|| "writing to stdout".into())?;
    }
    out.flush().failure_ctx(|| "writing to stdout".into())
}

/// Reads `wix,wiy,wiz,wox,woy,woz` rows; blank lines and lines starting with `#`
/// are skipped. Each direction is normalised; a zero or non-finite vector is an
/// error naming the line.
pub fn parse_direction_rows(input: impl BufRead) -> Result<Vec<(DVec3, DVec3)>, CliError> {
    let mut rows = Vec::new();
    for (index, line) in input.lines().enumerate() {
        let line_no = index + 1;
        let line = line.bad_input_ctx(|| format!("stdin line {line_no}: cannot read"))?;
        let trimmed = line.trim();
        if trimmed.is_empty() || trimmed.starts_with('#') {
            continue;
        }
        let fields: Vec<&str> = trimmed.split(',').map(str::trim).collect();
        if fields.len() != 6 {
            return Err(CliError::bad_input(anyhow!(
                "stdin line {line_no}: expected 6 comma-separated numbers wix,wiy,wiz,wox,woy,woz, found {} field(s) in `{trimmed}`",
                fields.len()
            )));
        }
        let mut v = [0.0f64; 6];
        for (k, field) in fields.iter().enumerate() {
            v[k] = field.parse().map_err(|_| {
                CliError::bad_input(anyhow!(
                    "stdin line {line_no}, field {}: `{field}` is not a number",
                    k + 1
                ))
            })?;
        }
        let wi = unit_direction(DVec3::new(v[0], v[1], v[2]), "wi", line_no)?;
        let wo = unit_direction(DVec3::new(v[3], v[4], v[5]), "wo", line_no)?;
        rows.push((wi, wo));
    }
    Ok(rows)
}

fn unit_direction(v: DVec3, name: &str, line_no: usize) -> Result<DVec3, CliError> {
    if !v.is_finite() {
        return Err(CliError::bad_input(anyhow!(
            "stdin line {line_no}: {name} = {v} is not finite"
        )));
    }
    let len = v.length();
    if len == 0.0 || !len.is_finite() {
        return Err(CliError::bad_input(anyhow!(
            "stdin line {line_no}: {name} is the zero vector and has no direction"
        )));
    }
    Ok(v / len)
}

pub fn params_json(brdf: &AnalyticBrdf) -> serde_json::Value {
    let specs = brdf.model().param_specs();
    let map: serde_json::Map<String, serde_json::Value> = specs
        .iter()
        .zip(brdf.param_values())
        .map(|(spec, value)| (spec.name.to_string(), json!(value)))
        .collect();
    serde_json::Value::Object(map)
}

fn albedo(
    model: &ModelArgs,
    theta_deg: &[f64],
    phi_deg: f64,
    samples: u32,
    seed: u64,
    json: bool,
) -> Result<(), CliError> {
    let brdf = model.build()?;
    if samples == 0 {
        return Err(CliError::bad_input(anyhow!("--samples must be at least 1")));
    }
    if !phi_deg.is_finite() {
        return Err(CliError::bad_input(anyhow!(
            "--phi-deg {phi_deg} is not finite"
        )));
    }
    let mut rows = Vec::with_capacity(theta_deg.len());
    for &theta in theta_deg {
        if !(0.0..90.0).contains(&theta) {
            return Err(CliError::bad_input(anyhow!(
                "--theta-deg {theta}: each angle must lie in [0, 90) degrees"
            )));
        }
        let (t, p) = (theta.to_radians(), phi_deg.to_radians());
        let wo = DVec3::new(t.sin() * p.cos(), t.sin() * p.sin(), t.cos());
        rows.push((theta, directional_albedo(&brdf, wo, samples, seed)));
    }
    if json {
        let table: Vec<_> = rows
            .iter()
            .map(|(theta, a)| json!({"theta_deg": theta, "albedo": a.mean, "std_error": a.std_error}))
            .collect();
        return crate::print_json(&json!({
            "model": brdf.model().name(),
            "params": params_json(&brdf),
            "phi_deg": phi_deg,
            "samples": samples,
            "seed": seed,
            "albedo": table,
        }));
    }
    println!(
        "directional albedo of {} {}, phi = {phi_deg} deg, {samples} importance samples per angle (seed {seed})",
        brdf.model().name(),
        params_json(&brdf)
    );
    println!("{:>10}  {:>12}  {:>12}", "theta_deg", "albedo", "std_error");
    for (theta, a) in &rows {
        println!("{theta:>10.3}  {:>12.6}  {:>12.2e}", a.mean, a.std_error);
    }
    Ok(())
}
