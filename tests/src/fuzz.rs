//! Every reader survives hostile input: mutated scene files (structure-aware: numbers,
//! keys, tables and lines of the shipped scenes), OBJ text, EXR, `.spmm`, `.btf`,
//! Bonn's UBO2014 files and UBO2003 zips, MERL bytes, the studio's recovery
//! journals and the parts of sharded fits; `.btf` through both the in-memory and the
//! out-of-core reader. The property for each case: the reader returns a value or an error
//! whose message is one line; it never panics, never takes longer than a bound, and a
//! size claimed by a header is checked before anything that large is allocated (an
//! allocation failure would abort the test process, so it cannot pass unnoticed).
//! Scenes that load are also prepared and rendered for one 8x8 frame, which is where
//! the tracer meets what the file said.
//!
//! `MESO_FUZZ_CASES=N` sets the cases per reader (default: the CI subset below);
//! `MESO_FUZZ_SEED=S` another stream of mutations. A long run for releases:
//! `MESO_FUZZ_CASES=100000 cargo test --release -p meso-tests fuzz -- --nocapture`
//! (docs/fuzzing.md). Inputs that once failed live in tests/fuzz_corpus/ and are
//! replayed by `the_corpus_of_past_failures_is_handled`.

use std::panic::{AssertUnwindSafe, catch_unwind};
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use meso_render::scene::load_scene;
use meso_render::{Prepare, run_frames};

/// Cases per reader in the test suite (about a minute in all on 2 cores).
const CI_CASES: u64 = 300;
/// The slowest a single case may take: far above any real input of these sizes.
const TIME_BOUND: Duration = Duration::from_secs(10);

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

fn cases() -> u64 {
    std::env::var("MESO_FUZZ_CASES")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(CI_CASES)
}

fn seed() -> u64 {
    std::env::var("MESO_FUZZ_SEED")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(0x5eed)
}

/// SplitMix64: a small, fast, replayable stream for choosing mutations.
struct Rng(u64);

impl Rng {
    fn new(seed: u64, case: u64) -> Self {
        Self(seed ^ case.wrapping_mul(0x9E37_79B9_7F4A_7C15))
    }
    fn next(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }
    fn below(&mut self, n: usize) -> usize {
        (self.next() % n.max(1) as u64) as usize
    }
    fn pick<'a, T>(&mut self, items: &'a [T]) -> &'a T {
        &items[self.below(items.len())]
    }
}

/// Values that break readers: extremes, non-finite, wrong types, empty containers.
const HOSTILE_VALUES: &[&str] = &[
    "1e308",
    "-1e308",
    "nan",
    "inf",
    "-inf",
    "0",
    "-1",
    "0.0",
    "-0.0",
    "1e-308",
    "1e39",
    "-1e39",
    "18446744073709551615",
    "9223372036854775807",
    "-9223372036854775808",
    "4294967296",
    "65536",
    "16385",
    "\"x\"",
    "[]",
    "[1.0]",
    "[0.0, 0.0, 0.0]",
    "{}",
    "true",
    "1e7",
    "-1e7",
    "3e38",
    "1e20",
];

/// Byte offsets of the numbers in `text` (a number: an optional sign, digits, dots,
/// exponents), to replace one by a hostile value.
fn number_spans(text: &str) -> Vec<(usize, usize)> {
    let b = text.as_bytes();
    let mut spans = Vec::new();
    let mut i = 0;
    while i < b.len() {
        let starts = b[i].is_ascii_digit()
            || ((b[i] == b'-' || b[i] == b'+') && b.get(i + 1).is_some_and(u8::is_ascii_digit));
        let after_word = i > 0 && (b[i - 1].is_ascii_alphanumeric() || b[i - 1] == b'_');
        if starts && !after_word {
            let s = i;
            i += 1;
            while i < b.len()
                && (b[i].is_ascii_digit()
                    || matches!(b[i], b'.' | b'e' | b'E')
                    || (matches!(b[i], b'-' | b'+') && matches!(b[i - 1], b'e' | b'E')))
            {
                i += 1;
            }
            spans.push((s, i));
        } else {
            i += 1;
        }
    }
    spans
}

/// One to three textual mutations of `text`: a number replaced by a hostile value, a
/// line deleted or duplicated, a key misspelt, a table header changed, or the text cut.
fn mutate_text(text: &str, rng: &mut Rng) -> String {
    let mut t = text.to_string();
    for _ in 0..1 + rng.below(3) {
        match rng.below(10) {
            0..=4 => {
                let spans = number_spans(&t);
                if !spans.is_empty() {
                    let (a, b) = *rng.pick(&spans);
                    let v: &&str = rng.pick(HOSTILE_VALUES);
                    t.replace_range(a..b, v);
                }
            }
            5 => {
                let mut lines: Vec<&str> = t.lines().collect();
                if !lines.is_empty() {
                    lines.remove(rng.below(lines.len()));
                }
                t = lines.join("\n");
            }
            6 => {
                let mut lines: Vec<String> = t.lines().map(str::to_string).collect();
                if !lines.is_empty() {
                    let i = rng.below(lines.len());
                    lines.insert(i, lines[i].clone());
                }
                t = lines.join("\n");
            }
            7 => {
                if let Some(eq) = t.find(" = ").map(|_| {
                    let eqs: Vec<usize> = t.match_indices(" = ").map(|(i, _)| i).collect();
                    *rng.pick(&eqs)
                }) {
                    t.insert(eq, 'x');
                }
            }
            8 => {
                let headers = [
                    "[render]",
                    "[camera]",
                    "[[mesh]]",
                    "[[quad]]",
                    "[[light]]",
                    "[ambient]",
                    "[environment]",
                    "[background]",
                    "f 1 2 3",
                    "v 0 0 0",
                    "vt 0 0",
                    "vn 0 0 1",
                ];
                let lines: Vec<&str> = t.lines().collect();
                let i = rng.below(lines.len() + 1);
                let mut out: Vec<String> = lines.iter().map(|s| s.to_string()).collect();
                out.insert(i.min(out.len()), rng.pick(&headers).to_string());
                t = out.join("\n");
            }
            _ => {
                let cut = rng.below(t.len() + 1);
                let cut = (0..=cut)
                    .rev()
                    .find(|&c| t.is_char_boundary(c))
                    .unwrap_or(0);
                t.truncate(cut);
            }
        }
    }
    t
}

/// One to four byte-level mutations: bit flips, random or extreme bytes, an
/// overwritten 4- or 8-byte field (huge, negative, zero), a cut, an insertion.
fn mutate_bytes(bytes: &[u8], rng: &mut Rng) -> Vec<u8> {
    let mut b = bytes.to_vec();
    // Headers hold the claims: aim half of the mutations at the first 512 bytes.
    let at = |rng: &mut Rng, len: usize| {
        if rng.below(2) == 0 {
            rng.below(len.min(512))
        } else {
            rng.below(len)
        }
    };
    for _ in 0..1 + rng.below(4) {
        if b.is_empty() {
            b.push(0);
        }
        let len = b.len();
        match rng.below(6) {
            0 => {
                let i = at(rng, len);
                b[i] ^= 1 << rng.below(8);
            }
            1 => {
                let i = at(rng, len);
                let random = rng.next() as u8;
                b[i] = *rng.pick(&[0u8, 0xff, 0x7f, 0x80, b'{', b'"', random]);
            }
            2 => {
                let i = at(rng, len);
                let v: u64 = *rng.pick(&[
                    u64::MAX,
                    0,
                    1 << 31,
                    1 << 40,
                    u32::MAX as u64,
                    0x7ff8_0000_0000_0000,
                ]);
                for (k, byte) in v
                    .to_le_bytes()
                    .iter()
                    .take(if rng.below(2) == 0 { 4 } else { 8 })
                    .enumerate()
                {
                    if i + k < len {
                        b[i + k] = *byte;
                    }
                }
            }
            3 => b.truncate(rng.below(len)),
            4 => {
                let i = at(rng, len);
                let n = 1 + rng.below(16);
                let insert: Vec<u8> = (0..n).map(|_| rng.next() as u8).collect();
                b.splice(i..i, insert);
            }
            _ => {
                let i = at(rng, len);
                let n = rng.below(64).min(len - i);
                b.drain(i..i + n);
            }
        }
    }
    b
}

/// Runs one case: no panic, one-line errors, within the time bound. Returns whether
/// the input was accepted.
fn check<T, E: std::fmt::Display>(
    label: &str,
    case: &dyn std::fmt::Display,
    f: impl FnOnce() -> Result<T, E>,
) -> bool {
    let start = Instant::now();
    let outcome = catch_unwind(AssertUnwindSafe(f));
    let took = start.elapsed();
    let accepted = match outcome {
        Ok(Ok(_)) => true,
        Ok(Err(e)) => {
            let msg = e.to_string();
            assert!(
                !msg.contains('\n'),
                "{label} {case}: a multi-line error: {msg}"
            );
            assert!(!msg.is_empty(), "{label} {case}: an empty error");
            false
        }
        Err(_) => panic!("{label}: the reader panicked (see the message above) on: {case}"),
    };
    assert!(took < TIME_BOUND, "{label} {case}: took {took:?}");
    accepted
}

/// Scene text with paths made absolute, so a mutated copy can live in a temp folder.
fn absolute_scene(path: &Path) -> String {
    let folder = path.parent().expect("scene folder").display().to_string();
    std::fs::read_to_string(path)
        .expect("shipped scene")
        .replace("path = \"", &format!("path = \"{folder}/"))
        .replace("pack = \"", &format!("pack = \"{folder}/"))
}

/// Loads a scene and, if it loads, renders one 8x8 frame in its mode.
fn load_and_render(path: &Path) -> Result<(), String> {
    let scene = load_scene(path).map_err(|e| e.to_string())?;
    let (kind, device) = (scene.render.mode, scene.render.device);
    let mut mode = meso_modes::create(kind, device, scene, 8, 8, Prepare::quietly())
        .map_err(|e| e.to_string())?;
    run_frames(mode.as_mut(), 1, |_, _| {});
    let img = mode.image();
    assert_eq!((img.width(), img.height()), (8, 8));
    Ok(())
}

/// Runs `cases()` mutations of each seed through `read`, reporting counts.
fn fuzz<S>(
    label: &str,
    seeds: &[S],
    mutate: impl Fn(&S, &mut Rng) -> Vec<u8>,
    read: impl Fn(&[u8]) -> bool,
) {
    let n = cases();
    let start = Instant::now();
    let mut accepted = 0;
    for case in 0..n {
        let mut rng = Rng::new(seed(), case);
        let s = rng.pick(seeds);
        let input = mutate(s, &mut rng);
        // Kept where a failure can be picked up for the corpus (tests/fuzz_corpus/).
        let keep = std::env::temp_dir().join(format!("meso-fuzz-last-{label}"));
        std::fs::write(&keep, &input).expect("write the case");
        if read(&input) {
            accepted += 1;
        }
    }
    eprintln!(
        "fuzz {label}: {n} cases (seed {:#x}) in {:.1} s, {accepted} accepted, {} refused, no panic",
        seed(),
        start.elapsed().as_secs_f64(),
        n - accepted
    );
}

#[test]
fn fuzz_scene_files() {
    let dir = tempfile::tempdir().expect("temp dir");
    let scenes: Vec<String> = ["default.toml", "cornell.toml", "env.toml", "fitted.toml"]
        .iter()
        .map(|s| absolute_scene(&root().join("scenes").join(s)))
        .collect();
    let path = dir.path().join("case.toml");
    fuzz(
        "scene",
        &scenes,
        |s, rng| mutate_text(s, rng).into_bytes(),
        |input| {
            std::fs::write(&path, input).expect("write case");
            check("scene", &String::from_utf8_lossy(input), || {
                load_and_render(&path)
            })
        },
    );
}

#[test]
fn fuzz_obj_files() {
    use glam::{DMat3, DVec3};
    use meso_render::scene::mesh::{Placement, load_obj};
    let dir = tempfile::tempdir().expect("temp dir");
    let teapot = std::fs::read_to_string(root().join("scenes/meshes/teapot.obj")).expect("teapot");
    // The teapot's first 60 vertices and faces among them, plus a tiny hand-made OBJ
    // with normals and texture coordinates.
    let small_teapot: String = {
        let v: Vec<&str> = teapot
            .lines()
            .filter(|l| l.starts_with("v "))
            .take(60)
            .collect();
        let f: Vec<String> = (0..40)
            .map(|i| format!("f {} {} {}", 1 + i, 2 + i, 3 + i))
            .collect();
        format!("{}\n{}\n", v.join("\n"), f.join("\n"))
    };
    let quad = "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nvt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\nvn 0 0 1\nf 1/1/1 2/2/1 3/3/1\nf 1/1/1 3/3/1 4/4/1\n".to_string();
    let path = dir.path().join("case.obj");
    let placement = Placement {
        scale: 1.0,
        rotation: DMat3::IDENTITY,
        translate: DVec3::ZERO,
    };
    fuzz(
        "obj",
        &[small_teapot, quad],
        |s, rng| mutate_text(s, rng).into_bytes(),
        |input| {
            std::fs::write(&path, input).expect("write case");
            check("obj", &String::from_utf8_lossy(input), || {
                load_obj(&path, &placement, 0).map(|m| {
                    // What the tracer receives: finite and within the scene extent.
                    assert!(m.positions.iter().all(|p| p.is_finite()));
                    meso_render::geometry::SceneBvh::build(std::slice::from_ref(&m));
                })
            })
        },
    );
}

/// A few small EXRs as Meso writes them, and one as another writer made them.
fn exr_seeds() -> Vec<Vec<u8>> {
    let dir = tempfile::tempdir().expect("temp dir");
    let mut seeds = Vec::new();
    for (w, h) in [(8u32, 8u32), (3, 17)] {
        let mut img = meso_materials::image::Image::new(w, h);
        for (i, p) in img.pixels_mut().iter_mut().enumerate() {
            *p = [i as f32 * 0.1, 1.0, (i % 3) as f32];
        }
        let p = dir.path().join("seed.exr");
        meso_materials::image::write_exr(&p, &img).expect("write seed");
        seeds.push(std::fs::read(&p).expect("read seed"));
    }
    for entry in std::fs::read_dir(root().join("reference/metrics_fixtures")).expect("fixtures") {
        let p = entry.expect("entry").path();
        if p.extension().is_some_and(|e| e == "exr") && seeds.len() < 5 {
            seeds.push(std::fs::read(&p).expect("fixture"));
        }
    }
    seeds
}

#[test]
fn fuzz_exr_files() {
    let dir = tempfile::tempdir().expect("temp dir");
    let path = dir.path().join("case.exr");
    fuzz(
        "exr",
        &exr_seeds(),
        |s, rng| mutate_bytes(s, rng),
        |input| {
            std::fs::write(&path, input).expect("write case");
            check("exr", &format!("({} bytes)", input.len()), || {
                meso_materials::image::read_image(&path)
            })
        },
    );
}

#[test]
fn fuzz_spmm_packs() {
    let seeds: Vec<Vec<u8>> = ["leather.spmm", "brushed_metal.spmm"]
        .iter()
        .map(|p| std::fs::read(root().join("../materials").join(p)).expect("shipped pack"))
        .collect();
    fuzz(
        "spmm",
        &seeds,
        |s, rng| mutate_bytes(s, rng),
        |input| {
            check("spmm", &format!("({} bytes)", input.len()), || {
                meso_materials::spmm::pack::decode_pack(input)
            })
        },
    );
}

/// Small BTFs (3x2 texels, 6 light and 4 view directions on rings) as Meso writes
/// them, in both precisions.
fn btf_seeds() -> Vec<Vec<u8>> {
    use meso_materials::btf::file::{BtfPrecision, encode_btf};
    use meso_materials::btf::{Btf, directions::rings};
    let (light, view) = (rings(&[(0.0, 1), (45.0, 5)]), rings(&[(0.0, 1), (60.0, 3)]));
    let data: Vec<f32> = (0..3 * 2 * light.len() * view.len() * 3)
        .map(|i| (i % 17) as f32 * 0.05)
        .collect();
    let btf = Btf::new("fuzz".into(), "test".into(), 3, 2, light, view, data).expect("valid");
    [BtfPrecision::F16, BtfPrecision::F32]
        .iter()
        .map(|p| encode_btf(&btf, *p).expect("encodes"))
        .collect()
}

#[test]
fn fuzz_btf_files() {
    fuzz(
        "btf",
        &btf_seeds(),
        |s, rng| mutate_bytes(s, rng),
        |input| {
            check("btf", &format!("({} bytes)", input.len()), || {
                meso_materials::btf::file::decode_btf(input)
            }) | check("btf on disk", &format!("({} bytes)", input.len()), || {
                read_btf_from_disk(input)
            })
        },
    );
}

/// The out-of-core reader (`meso fit`'s) over the same bytes: opened from a file, then
/// every texel read one at a time. A header it accepts must not claim more values than
/// the file holds (two bytes each at the least).
fn read_btf_from_disk(input: &[u8]) -> Result<(), String> {
    use meso_materials::btf::on_disk::OnDiskBtf;
    use meso_materials::btf::texels::TexelSource;
    let dir = tempfile::tempdir().map_err(|e| e.to_string())?;
    let path = dir.path().join("fuzz.btf");
    std::fs::write(&path, input).map_err(|e| e.to_string())?;
    let btf = OnDiskBtf::open(&path).map_err(|e| e.to_string())?;
    let per_texel = btf.pairs() * 3;
    assert!(
        btf.texels().saturating_mul(per_texel).saturating_mul(2) <= input.len(),
        "the on-disk reader accepted {} texels of {per_texel} values in {} bytes",
        btf.texels(),
        input.len()
    );
    let mut texel = vec![0f32; per_texel];
    for t in 0..btf.texels() {
        btf.read_block(t, &mut texel).map_err(|e| e.to_string())?;
    }
    Ok(())
}

/// A part of a sharded fit (`meso fit --shard`) of the BTF seed, as `meso fit merge`
/// reads it.
/// Half the time, `bytes` with their last 8 replaced by the FNV-1a checksum of the rest,
/// as the fit's files end: the mutation then reaches the parser behind the checksum.
fn with_checksum(mut bytes: Vec<u8>, rng: &mut Rng) -> Vec<u8> {
    if bytes.len() >= 8 && rng.below(2) == 0 {
        let body = bytes.len() - 8;
        let sum = meso_materials::hash::fnv1a64(&bytes[..body]);
        bytes[body..].copy_from_slice(&sum.to_le_bytes());
    }
    bytes
}

/// The settings of the fit seeds: small, and still sampling.
fn fit_seed_settings() -> meso_fit::FitSettings {
    meso_fit::FitSettings {
        clusters: 2,
        subclusters: 1,
        max_bases: 2,
        npca: 2,
        fit_pairs: 20,
        sample_texels: 6,
        residual_texels: 3,
        ..meso_fit::FitSettings::default()
    }
}

fn fit_part_seed() -> Vec<u8> {
    use meso_fit::{Shard, fit_part};
    let btf = meso_materials::btf::file::decode_btf(&btf_seeds()[1]).expect("the seed reads");
    let settings = fit_seed_settings();
    let shard = Shard::new(1, 2).expect("a shard");
    let cancel = std::sync::atomic::AtomicBool::new(false);
    fit_part(
        &btf,
        ("fuzz", "test", "fuzz.btf"),
        &settings,
        shard,
        &cancel,
        &|_, _, _| {},
    )
    .expect("the seed fits")
    .encode()
}

/// Parts come from other machines, over networks and shared disks: a damaged one is
/// refused by name, never a panic.
#[test]
fn fuzz_fit_parts() {
    let seed = fit_part_seed();
    meso_fit::Part::decode(&seed).expect("the seed part reads");
    fuzz(
        "fit part",
        &[seed],
        |s, rng| with_checksum(mutate_bytes(s, rng), rng),
        |input| {
            check("fit part", &format!("({} bytes)", input.len()), || {
                meso_fit::Part::decode(input)
            })
        },
    );
}

/// A fit's model file travels to every shard's machine like the parts come back: a
/// damaged one is refused, never a panic.
#[test]
fn fuzz_fit_models() {
    let btf = meso_materials::btf::file::decode_btf(&btf_seeds()[1]).expect("the seed reads");
    let cancel = std::sync::atomic::AtomicBool::new(false);
    let seed = meso_fit::find_model(
        &btf,
        "fuzz.btf",
        &fit_seed_settings(),
        &cancel,
        &|_, _, _| {},
    )
    .expect("the seed's model")
    .encode();
    meso_fit::FitModel::decode(&seed).expect("the seed model reads");
    fuzz(
        "fit model",
        &[seed],
        |s, rng| with_checksum(mutate_bytes(s, rng), rng),
        |input| {
            check("fit model", &format!("({} bytes)", input.len()), || {
                meso_fit::FitModel::decode(input)
            })
        },
    );
}

/// Bonn's UBO2014 files: the reference fixtures (DFMF in half floats and f32 with
/// two colour models, FMF with dynamic-range reduction, Meso's own export, PVF with
/// either side over the texels and in the old layout, full and sparse BDI).
#[test]
fn fuzz_ubo2014_files() {
    let seeds: Vec<Vec<u8>> = [
        "dfmf_rgb.btf",
        "dfmf_logyuv.btf",
        "fmf_drr.btf",
        "meso_export.btf",
        "pvf_texels.btf",
        "pvf_lights.btf",
        "pvf_old.btf",
        "bdi_full.btf",
        "bdi_sparse.btf",
    ]
    .iter()
    .map(|p| std::fs::read(root().join("reference/ubo").join(p)).expect("fixture"))
    .collect();
    fuzz(
        "ubo2014",
        &seeds,
        |s, rng| mutate_bytes(s, rng),
        |input| {
            check("ubo2014", &format!("({} bytes)", input.len()), || {
                meso_materials::btf::ubo2014::decode(input)
            })
        },
    );
}

fn read_ubo2003(input: &[u8]) -> Result<meso_materials::btf::Btf, impl std::fmt::Display> {
    meso_materials::btf::ubo2003::read_zip(std::io::Cursor::new(input), "fuzz", "fuzz", None)
}

/// UBO2003 zips: the reference fixture (deflated 8x6 JPEGs in a folder, and a readme).
#[test]
fn fuzz_ubo2003_zips() {
    let seeds = vec![std::fs::read(root().join("reference/ubo/ubo2003.zip")).expect("fixture")];
    fuzz(
        "ubo2003",
        &seeds,
        |s, rng| mutate_bytes(s, rng),
        |input| {
            check("ubo2003", &format!("({} bytes)", input.len()), || {
                read_ubo2003(input)
            })
        },
    );
}

/// MERL tables are 35 MB each: fewer cases (a fiftieth), mutated where the claims
/// are (the header) and anywhere in the table.
#[test]
fn fuzz_merl_files() {
    use meso_materials::brdf::{AnalyticBrdf, BrdfModel};
    use meso_materials::merl::{MerlBrdf, tabulate};
    let table = tabulate(
        &AnalyticBrdf::with_defaults(BrdfModel::Lambertian),
        glam::DVec3::splat(0.5),
    )
    .expect("tabulates");
    let seed_bytes = table.to_bytes();
    let n = (cases() / 50).max(10);
    let start = Instant::now();
    let mut accepted = 0;
    let mut input = seed_bytes.clone();
    for case in 0..n {
        let mut rng = Rng::new(seed(), case);
        input.clone_from(&seed_bytes);
        let mutated = match rng.below(3) {
            0 => mutate_bytes(&input[..64], &mut rng)
                .into_iter()
                .chain(input[64..].iter().copied())
                .collect(),
            1 => {
                for _ in 0..1 + rng.below(8) {
                    let i = rng.below(input.len());
                    input[i] = rng.next() as u8;
                }
                input.clone()
            }
            _ => mutate_bytes(&input, &mut rng),
        };
        if check(
            "merl",
            &format!("case {case} ({} bytes)", mutated.len()),
            || MerlBrdf::from_bytes(&mutated),
        ) {
            accepted += 1;
        }
    }
    eprintln!(
        "fuzz merl: {n} cases in {:.1} s, {accepted} accepted, no panic",
        start.elapsed().as_secs_f64()
    );
}

/// A studio session's recovery journal on the Cornell scene's brushed-metal pack:
/// strokes, a basis added, a light moved, an undo.
fn journal_seed(state: &Path) -> (PathBuf, Vec<u8>) {
    use meso_session::Document;
    use meso_session::pack_edits::PackEdits;
    let path = root().join("scenes/cornell.toml");
    let mut doc = Document::new(load_scene(&path).expect("cornell"), Some(path));
    doc.journal_to(state);
    for line in [
        "--cluster 0 --scale 1.2 --brush 3,3,2",
        "--cluster 1 --basis 0 --scale 0.5,0.6,0.7",
        "--add-basis 0 --model ward --param ax=0.2 --param ay=0.3 --add-weight 0.1 --brush 9,1,3",
    ] {
        let m = doc.material().expect("the pack");
        let edited = PackEdits::parse(line)
            .and_then(|e| e.apply(&m, Path::new(".")))
            .expect("edit");
        let slot = doc.pack.as_ref().expect("pack").material;
        let mut material = doc.scene.materials[slot].clone();
        if let meso_render::scene::Material::Spmm { material: m, .. } = &mut material {
            *m = std::sync::Arc::new(edited.material);
        }
        doc.apply(&meso_render::SceneEdit::Material {
            index: slot,
            material,
        })
        .expect("applies");
        doc.close_group();
    }
    doc.apply(&meso_render::SceneEdit::LightSamples(3))
        .expect("applies");
    doc.close_group();
    doc.undo();
    doc.journal().expect("journal").flush().expect("written");
    let file = meso_session::journal::journal_files(state)
        .pop()
        .expect("a journal");
    let bytes = std::fs::read(&file).expect("journal bytes");
    doc.close_journal(false);
    (file, bytes)
}

/// Journals are read after crashes, so torn and damaged ones are the normal case:
/// reading one and replaying its pack never panics.
#[test]
fn fuzz_recovery_journals() {
    use meso_session::{journal, recover};
    let state = tempfile::tempdir().expect("temp dir");
    let (path, seed_bytes) = journal_seed(state.path());
    let full = journal::parse(&path, &seed_bytes).expect("the seed reads");
    assert!(full.edits() >= 4 && full.cut_at.is_none());
    recover::pack_of(&full).expect("the seed replays");
    fuzz(
        "journal",
        &[seed_bytes],
        |s, rng| mutate_bytes(s, rng),
        |input| {
            check("journal", &format!("({} bytes)", input.len()), || {
                journal::parse(&path, input).map(|c| recover::pack_of(&c))
            })
        },
    );
}

#[test]
fn the_corpus_of_past_failures_is_handled() {
    use glam::{DMat3, DVec3};
    use meso_render::scene::mesh::{Placement, load_obj};
    let placement = Placement {
        scale: 1.0,
        rotation: DMat3::IDENTITY,
        translate: DVec3::ZERO,
    };
    let mut seen = 0;
    for reader in [
        "scene", "obj", "exr", "spmm", "btf", "ubo2014", "ubo2003", "merl",
    ] {
        let Ok(dir) = std::fs::read_dir(root().join("fuzz_corpus").join(reader)) else {
            continue;
        };
        for entry in dir {
            let path = entry.expect("corpus entry").path();
            let bytes = std::fs::read(&path).expect("corpus file");
            let name = path.display();
            seen += 1;
            match reader {
                "scene" => check(reader, &name, || load_and_render(&path)),
                "obj" => check(reader, &name, || load_obj(&path, &placement, 0)),
                "exr" => check(reader, &name, || meso_materials::image::read_image(&path)),
                "spmm" => check(reader, &name, || {
                    meso_materials::spmm::pack::decode_pack(&bytes)
                }),
                "btf" => check(reader, &name, || {
                    meso_materials::btf::file::decode_btf(&bytes)
                }),
                "ubo2014" => check(reader, &name, || {
                    meso_materials::btf::ubo2014::decode(&bytes)
                }),
                "ubo2003" => check(reader, &name, || read_ubo2003(&bytes)),
                _ => check(reader, &name, || {
                    meso_materials::merl::MerlBrdf::from_bytes(&bytes)
                }),
            };
        }
    }
    assert!(seen >= 7, "the corpus has {seen} files");
}
