//! `meso btf synth|import|export|info|slice`: make BTFs by ray tracing a mesostructure
//! recipe, import measured BTFs (image folders, Bonn's UBO2003 zips and UBO2014
//! files), export a `.btf` in Bonn's DFMF format, summarise a `.btf`, and render one
//! direction pair of a BTF (optionally beside an SPMM pack's fit) as an image.

use std::io::Read;
use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::anyhow;
use clap::{Subcommand, ValueEnum};
use glam::DVec3;
use meso_materials::btf::crop::{self, TexelRect};
use meso_materials::btf::on_disk::OnDiskBtf;
use meso_materials::btf::texels::TexelSource;
use meso_materials::btf::{self, Btf, directions, file, synth, ubo2003, ubo2014};
use meso_materials::image::Image;
use meso_materials::spmm::pack;
use serde_json::json;

use crate::failure::{CliError, ResultExt};
use crate::progress::{ProgressLine, cancel_flag};

#[derive(Subcommand, Debug)]
pub enum BtfCommand {
    /// Ray trace a height-field mesostructure recipe (TOML) into a BTF.
    Synth {
        recipe: PathBuf,
        #[arg(short = 'o', long)]
        output: PathBuf,
        /// Store the values as f32 (default: f16 when every value fits).
        #[arg(long)]
        f32: bool,
        #[arg(long)]
        json: bool,
    },
    /// Build a BTF from a folder of images listed in directions.csv or directions.toml,
    /// a UBO2003/ATRIUM zip of JPEGs, or a UBO2014 file (told apart by content).
    Import {
        path: PathBuf,
        #[arg(short = 'o', long)]
        output: PathBuf,
        /// The BTF's name (default: the folder's or file's name).
        #[arg(long)]
        name: Option<String>,
        /// Keep only these texels: X,Y,WIDTH,HEIGHT, row 0 the top row.
        #[arg(long, value_name = "X,Y,W,H")]
        texels: Option<String>,
        /// Most bytes of values (as f32) a UBO2003/ATRIUM zip import builds (`2GB`,
        /// `6GB`; powers of 1024); default 8GB, the most any import builds.
        #[arg(long, default_value = "8GB")]
        max_memory: String,
        #[arg(long)]
        f32: bool,
        #[arg(long)]
        json: bool,
    },
    /// Write a .btf in another format (ubo2014: Bonn's DFMF, `!DFMF08FCR`).
    Export {
        file: PathBuf,
        #[arg(long, value_enum)]
        format: ExportFormat,
        #[arg(short = 'o', long)]
        output: PathBuf,
        #[arg(long)]
        json: bool,
    },
    /// Summary of a .btf file (validated on load), or of a UBO2014 file's header.
    Info {
        file: PathBuf,
        #[arg(long)]
        json: bool,
    },
    /// The texel grid at one light and view direction (nearest tabulated pair) as PNG
    /// or EXR; with --pack, the pack without and with its residual beside it.
    Slice {
        file: PathBuf,
        #[arg(short = 'o', long)]
        output: PathBuf,
        /// Light direction THETA,PHI in degrees.
        #[arg(long, value_name = "THETA,PHI", allow_hyphen_values = true)]
        light: String,
        /// View direction THETA,PHI in degrees.
        #[arg(long, value_name = "THETA,PHI", allow_hyphen_values = true)]
        view: String,
        /// An SPMM pack fitted to this BTF, shown beside it.
        #[arg(long)]
        pack: Option<PathBuf>,
        /// Pixels per texel.
        #[arg(long, default_value_t = 4)]
        scale: u32,
        /// Exposure in stops for PNG output.
        #[arg(long, default_value_t = 0.0, allow_negative_numbers = true)]
        exposure: f64,
        /// Most bytes of the BTF's values read at once (`256MB`, `4GB`; powers of
        /// 1024): the file is read in blocks of texels this size, never whole.
        #[arg(long, default_value = "256MB")]
        max_memory: String,
    },
}

/// Formats `meso btf export` writes.
#[derive(Clone, Copy, Debug, ValueEnum)]
pub enum ExportFormat {
    /// Bonn's UBO2014 DFMF layout, as btflib and btf_extractor read it.
    Ubo2014,
}

pub fn run(command: BtfCommand) -> Result<(), CliError> {
    match command {
        BtfCommand::Synth {
            recipe,
            output,
            f32,
            json,
        } => synth_cmd(&recipe, &output, f32, json),
        BtfCommand::Import {
            path,
            output,
            name,
            texels,
            max_memory,
            f32,
            json,
        } => {
            let max_bytes = meso_fit::memory::parse_bytes(&max_memory)
                .map_err(|e| CliError::bad_input(anyhow!("--max-memory {e}")))?;
            import_cmd(
                &path,
                &output,
                name,
                texels.as_deref(),
                max_bytes,
                f32,
                json,
            )
        }
        BtfCommand::Export {
            file,
            format: ExportFormat::Ubo2014,
            output,
            json,
        } => export_cmd(&file, &output, json),
        BtfCommand::Info { file, json } => info(&file, json),
        BtfCommand::Slice {
            file,
            output,
            light,
            view,
            pack,
            scale,
            exposure,
            max_memory,
        } => slice(
            &file,
            &output,
            (&light, &view),
            pack.as_deref(),
            (scale, exposure),
            &max_memory,
        ),
    }
}

pub fn load(path: &Path) -> Result<Btf, CliError> {
    file::read_btf(path).map_err(CliError::bad_input)
}

fn write(output: &Path, b: &Btf, force_f32: bool) -> Result<u64, CliError> {
    let precision = if force_f32 {
        file::BtfPrecision::F32
    } else {
        file::best_precision(b)
    };
    file::write_btf(output, b, precision).map_err(CliError::failure)?;
    Ok(std::fs::metadata(output).map(|m| m.len()).unwrap_or(0))
}

fn synth_cmd(recipe: &Path, output: &Path, force_f32: bool, as_json: bool) -> Result<(), CliError> {
    let setup = synth::load_recipe(recipe).map_err(CliError::bad_input)?;
    let started = Instant::now();
    let bar = ProgressLine::new();
    let result = synth::synthesize(&setup, cancel_flag(), &|d, n| bar.update("synthesis", d, n));
    bar.finish();
    let b = match result {
        Ok(b) => b,
        Err(synth::SynthErrorKind::Cancelled) => {
            return Err(CliError::failure(anyhow!(
                "cancelled (Ctrl-C); `{}` was not written",
                output.display()
            )));
        }
        Err(e) => return Err(CliError::failure(anyhow!("`{}`: {e}", recipe.display()))),
    };
    let seconds = started.elapsed().as_secs_f64();
    let bytes = write(output, &b, force_f32)?;
    if as_json {
        return crate::print_json(&json!({
            "output": output.display().to_string(),
            "width": b.width(), "height": b.height(),
            "lights": b.light_dirs().len(), "views": b.view_dirs().len(),
            "supersample": setup.supersample,
            "interreflection_samples": setup.interreflection_samples,
            "seconds": seconds,
            "bytes": bytes,
            "mean_reflectance": b.mean_value(),
        }));
    }
    println!(
        "wrote {} ({}x{} texels, {} x {} directions, {bytes} bytes) in {seconds:.1} s",
        output.display(),
        b.width(),
        b.height(),
        b.light_dirs().len(),
        b.view_dirs().len()
    );
    Ok(())
}

/// What `meso btf import` was given.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Source {
    Folder,
    Zip,
    Ubo2014,
}

/// Tells the source apart by what it is, not by its name: a folder, a zip archive
/// (local-file or end-of-directory signature), or a Bonn signature.
fn detect(path: &Path) -> Result<Source, CliError> {
    if path.is_dir() {
        return Ok(Source::Folder);
    }
    let mut head = Vec::with_capacity(10);
    std::fs::File::open(path)
        .and_then(|f| f.take(10).read_to_end(&mut head))
        .map_err(|e| CliError::bad_input(anyhow!("`{}`: cannot read: {e}", path.display())))?;
    if head.starts_with(b"PK\x03\x04") || head.starts_with(b"PK\x05\x06") {
        Ok(Source::Zip)
    } else if ubo2014::identify(&head).is_some() {
        Ok(Source::Ubo2014)
    } else {
        Err(CliError::bad_input(anyhow!(
            "`{}`: not a folder of images, a zip archive (UBO2003/ATRIUM) or a UBO2014 file (`!DFMF08FCR`, `!FMF12FCER`, ...): it starts with {:?}",
            path.display(),
            String::from_utf8_lossy(&head)
        )))
    }
}

fn import_cmd(
    path: &Path,
    output: &Path,
    name: Option<String>,
    texels: Option<&str>,
    max_bytes: u64,
    force_f32: bool,
    as_json: bool,
) -> Result<(), CliError> {
    let source = detect(path)?;
    let name = name.unwrap_or_else(|| {
        let n = if source == Source::Folder {
            path.file_name()
        } else {
            path.file_stem()
        };
        n.map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_else(|| "imported".into())
    });
    let rect = texels
        .map(TexelRect::parse)
        .transpose()
        .map_err(|e| CliError::bad_input(anyhow!("--texels: {e}")))?;
    let b = match source {
        Source::Folder => {
            let b = btf::import::import_dir(path, &name).map_err(CliError::bad_input)?;
            match rect {
                Some(r) => crop::crop(&b, r)
                    .map_err(|e| CliError::bad_input(anyhow!("`{}`: {e}", path.display())))?,
                None => b,
            }
        }
        Source::Zip => {
            ubo2003::import_zip(path, &name, rect, max_bytes).map_err(CliError::bad_input)?
        }
        Source::Ubo2014 => ubo2014::import_path(path, &name, rect).map_err(CliError::bad_input)?,
    };
    let bytes = write(output, &b, force_f32)?;
    let format = match source {
        Source::Folder => "folder",
        Source::Zip => "ubo2003",
        Source::Ubo2014 => "ubo2014",
    };
    if as_json {
        return crate::print_json(&json!({
            "output": output.display().to_string(),
            "source": format,
            "width": b.width(), "height": b.height(),
            "lights": b.light_dirs().len(), "views": b.view_dirs().len(),
            "bytes": bytes,
        }));
    }
    println!(
        "wrote {} ({}x{} texels, {} x {} directions, from a {format} source)",
        output.display(),
        b.width(),
        b.height(),
        b.light_dirs().len(),
        b.view_dirs().len()
    );
    Ok(())
}

fn export_cmd(path: &Path, output: &Path, as_json: bool) -> Result<(), CliError> {
    let b = load(path)?;
    ubo2014::check_writable(&b)
        .map_err(|e| CliError::bad_input(anyhow!("`{}`: {e}", path.display())))?;
    ubo2014::write_dfmf(output, &b).map_err(CliError::failure)?;
    let bytes = std::fs::metadata(output).map(|m| m.len()).unwrap_or(0);
    let components = b.pairs().min(b.texels());
    if as_json {
        return crate::print_json(&json!({
            "output": output.display().to_string(),
            "format": "ubo2014",
            "signature": "!DFMF08FCR",
            "width": b.width(), "height": b.height(),
            "lights": b.light_dirs().len(), "views": b.view_dirs().len(),
            "components": components,
            "bytes": bytes,
        }));
    }
    println!(
        "wrote {} (UBO2014 DFMF, {}x{} texels, {} x {} directions, {components} components per channel, {bytes} bytes)",
        output.display(),
        b.width(),
        b.height(),
        b.light_dirs().len(),
        b.view_dirs().len()
    );
    Ok(())
}

/// `meso btf info` of a UBO2014 file: its header and factors, without expanding it.
fn ubo2014_info(path: &Path, as_json: bool) -> Result<(), CliError> {
    let f = ubo2014::Ubo2014::open_path(path).map_err(CliError::bad_input)?;
    let h = f.header();
    let deg = |a: &[[f32; 2]]| -> Vec<[f64; 2]> {
        a.iter()
            .map(|d| {
                let (t, p) = directions::to_angles_deg(directions::from_angles_deg(
                    f64::from(d[0]).to_degrees(),
                    f64::from(d[1]).to_degrees(),
                ));
                [t, p]
            })
            .collect()
    };
    let (nl, nv) = (h.light_angles.len(), h.view_angles.len());
    let max_texels = crop::MAX_IMPORT_VALUES / (3 * (nl * nv) as u64);
    if as_json {
        return crate::print_json(&json!({
            "file": path.display().to_string(),
            "signature": h.signature,
            "width": h.width, "height": h.height,
            "light_dirs_deg": deg(&h.light_angles), "view_dirs_deg": deg(&h.view_angles),
            "color_model": h.color_model, "cosine_flag": h.cosine_flag,
            "components": f.components(),
            "storage": f.storage(),
            "measurement_setup": h.measurement_setup,
            "max_import_texels": max_texels,
        }));
    }
    println!("{}: UBO2014 BTF ({})", path.display(), h.signature);
    println!("setup        {}", h.measurement_setup);
    println!("texels       {} x {}", h.width, h.height);
    println!("directions   {nl} light x {nv} view");
    println!("storage      {}", f.storage());
    println!("cosine flag  {}", u8::from(h.cosine_flag));
    println!("import       at most {max_texels} texels at once (--texels X,Y,W,H)");
    Ok(())
}

fn info(path: &Path, as_json: bool) -> Result<(), CliError> {
    if !path.is_dir() && detect(path).ok() == Some(Source::Ubo2014) {
        return ubo2014_info(path, as_json);
    }
    let b = load(path)?;
    let angles = |d: &[DVec3]| -> Vec<[f64; 2]> {
        d.iter()
            .map(|v| {
                let (t, p) = directions::to_angles_deg(*v);
                [t, p]
            })
            .collect()
    };
    let (lo, hi) = b
        .data()
        .iter()
        .fold((f32::INFINITY, f32::NEG_INFINITY), |(a, c), &x| {
            (a.min(x), c.max(x))
        });
    if as_json {
        return crate::print_json(&json!({
            "file": path.display().to_string(),
            "name": b.name(), "provenance": b.provenance(),
            "width": b.width(), "height": b.height(),
            "light_dirs_deg": angles(b.light_dirs()), "view_dirs_deg": angles(b.view_dirs()),
            "mean": b.mean_value(), "min": lo, "max": hi,
        }));
    }
    println!("{}: BTF `{}`", path.display(), b.name());
    println!("provenance   {}", b.provenance());
    println!("texels       {} x {}", b.width(), b.height());
    println!(
        "directions   {} light x {} view",
        b.light_dirs().len(),
        b.view_dirs().len()
    );
    println!(
        "values       mean {:.5}, min {lo:.5}, max {hi:.5}",
        b.mean_value()
    );
    Ok(())
}

fn parse_dir(flag: &str, text: &str) -> Result<DVec3, CliError> {
    let parts: Vec<&str> = text.split(',').map(str::trim).collect();
    let nums: Option<Vec<f64>> = parts.iter().map(|p| p.parse::<f64>().ok()).collect();
    match nums.as_deref() {
        Some([t, p]) if t.is_finite() && p.is_finite() && (0.0..90.0).contains(t) => {
            Ok(directions::from_angles_deg(*t, *p))
        }
        _ => Err(CliError::bad_input(anyhow!(
            "--{flag} `{text}`: expected THETA,PHI in degrees with THETA in [0, 90)"
        ))),
    }
}

fn nearest(dirs: &[DVec3], d: DVec3) -> usize {
    (0..dirs.len())
        .max_by(|&a, &b| dirs[a].dot(d).total_cmp(&dirs[b].dot(d)))
        .unwrap_or(0)
}

/// The BTF's value at light `l`, view `v` of every texel, read from disk in blocks of
/// at most `max_memory` bytes of values (every value is read, so every one is checked
/// finite, as loading the whole file would).
fn slice_values(
    b: &OnDiskBtf,
    (l, v): (usize, usize),
    max_memory: u64,
) -> Result<Vec<[f32; 3]>, CliError> {
    let per_texel = b.pairs() * 3;
    let texel_bytes = per_texel as u64 * 4;
    if max_memory < texel_bytes {
        return Err(CliError::bad_input(anyhow!(
            "--max-memory {max_memory} bytes cannot hold one texel of `{}` ({texel_bytes} bytes of values); at least that is needed",
            b.path().display()
        )));
    }
    let block = (max_memory / texel_bytes).min(b.texels() as u64) as usize;
    let at = (l * b.view_dirs().len() + v) * 3;
    let mut buf = vec![0.0f32; block * per_texel];
    let mut out = Vec::with_capacity(b.texels());
    for first in (0..b.texels()).step_by(block) {
        let n = block.min(b.texels() - first);
        let values = &mut buf[..n * per_texel];
        b.read_block(first, values).map_err(CliError::bad_input)?;
        out.extend(
            values
                .chunks_exact(per_texel)
                .map(|t| [t[at], t[at + 1], t[at + 2]]),
        );
    }
    Ok(out)
}

fn slice(
    path: &Path,
    output: &Path,
    (light, view): (&str, &str),
    pack_path: Option<&Path>,
    (scale, exposure): (u32, f64),
    max_memory: &str,
) -> Result<(), CliError> {
    if !(1..=64).contains(&scale) || !exposure.is_finite() {
        return Err(CliError::bad_input(anyhow!(
            "--scale must be in 1..=64 and --exposure finite"
        )));
    }
    let max_memory = meso_fit::memory::parse_bytes(max_memory)
        .map_err(|e| CliError::bad_input(anyhow!("--max-memory {e}")))?;
    let b = OnDiskBtf::open(path).map_err(CliError::bad_input)?;
    let l = nearest(b.light_dirs(), parse_dir("light", light)?);
    let v = nearest(b.view_dirs(), parse_dir("view", view)?);
    let (wi, wo) = (b.light_dirs()[l], b.view_dirs()[v]);
    let values = slice_values(&b, (l, v), max_memory)?;
    let material = match pack_path {
        Some(p) => {
            let m = pack::read_pack(p).map_err(CliError::bad_input)?;
            if (m.width(), m.height()) != (b.width(), b.height()) {
                return Err(CliError::bad_input(anyhow!(
                    "`{}` is {}x{} texels but `{}` is {}x{}",
                    p.display(),
                    m.width(),
                    m.height(),
                    path.display(),
                    b.width(),
                    b.height()
                )));
            }
            Some(m)
        }
        None => None,
    };
    let panels = if material.is_some() { 3 } else { 1 };
    let (w, h) = (b.width() * scale, b.height() * scale);
    let gap = 4;
    let mut img = Image::new(panels * w + (panels - 1) * gap, h);
    for y in 0..h {
        for x in 0..w {
            let t = ((y / scale) * b.width() + x / scale) as usize;
            img.set(x, y, values[t]);
            if let Some(m) = &material {
                let off = m.eval_texel(t, wi, wo, false, 0);
                let on = m.eval_texel(t, wi, wo, true, usize::MAX);
                img.set(w + gap + x, y, off.as_vec3().to_array());
                img.set(2 * (w + gap) + x, y, on.as_vec3().to_array());
            }
        }
    }
    meso_materials::image::write_image(output, &img, exposure)
        .failure_ctx(|| format!("writing `{}`", output.display()))?;
    let (ti, pi) = directions::to_angles_deg(wi);
    let (tv, pv) = directions::to_angles_deg(wo);
    println!(
        "wrote {} (light {ti:.0},{pi:.0} deg, view {tv:.0},{pv:.0} deg{})",
        output.display(),
        if material.is_some() {
            "; panels: BTF, SPMM without residual, SPMM with residual"
        } else {
            ""
        }
    );
    Ok(())
}
