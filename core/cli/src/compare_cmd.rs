//! `meso compare A B`: image error of B against the reference A (docs/cli.md),
//! using the metric definitions of `meso_materials::metrics` (docs/formats/images.md).

use std::path::PathBuf;

use anyhow::anyhow;
use clap::Args;
use meso_materials::{image, metrics};
use serde_json::json;

use crate::failure::{CliError, ResultExt};

#[derive(Args, Debug)]
pub struct CompareArgs {
    /// The reference image (EXR, PNG or HDR).
    reference: PathBuf,
    /// The image to measure against the reference.
    test: PathBuf,
    /// Exposure in stops applied to both images before measuring (scale 2^stops).
    #[arg(long, default_value_t = 0.0, allow_negative_numbers = true)]
    exposure: f64,
    #[arg(long)]
    json: bool,
}

pub fn run(args: &CompareArgs) -> Result<(), CliError> {
    if !args.exposure.is_finite() {
        return Err(CliError::bad_input(anyhow!(
            "--exposure {} is not finite",
            args.exposure
        )));
    }
    let reference =
        image::read_image(&args.reference).bad_input_ctx(|| "reference image".into())?;
    let test = image::read_image(&args.test).bad_input_ctx(|| "test image".into())?;
    let c = metrics::compare(&reference, &test, args.exposure).bad_input_ctx(|| {
        format!(
            "comparing `{}` with `{}`",
            args.test.display(),
            args.reference.display()
        )
    })?;
    if args.json {
        return crate::print_json(&json!({
            "reference": args.reference.display().to_string(),
            "test": args.test.display().to_string(),
            "exposure_stops": args.exposure,
            "width": c.width,
            "height": c.height,
            "rmse": c.rmse,
            // JSON has no infinity: identical images have no finite PSNR.
            "psnr_db": c.psnr_db.is_finite().then_some(c.psnr_db),
            "mssim": c.mssim,
            "max_abs_error": c.max_abs_error,
            "max_error_pixel": c.max_error_pixel,
        }));
    }
    println!(
        "reference  {} ({}x{})",
        args.reference.display(),
        c.width,
        c.height
    );
    println!("test       {}", args.test.display());
    println!("RMSE       {:.6e}", c.rmse);
    if c.psnr_db.is_finite() {
        println!("PSNR       {:.3} dB", c.psnr_db);
    } else {
        println!("PSNR       inf (identical)");
    }
    println!("MSSIM      {:.6}", c.mssim);
    println!(
        "max error  {:.6e} at pixel ({}, {})",
        c.max_abs_error, c.max_error_pixel[0], c.max_error_pixel[1]
    );
    Ok(())
}
