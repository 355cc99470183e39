//! Manifest parsing: the expansion of matrices and cases, and every error naming the
//! file, the line and the key.

use super::*;

const BASE: &str = r#"version = 1
goldens = "goldens"

[defaults]
width = 32
height = 24
frames = 2
max_relative_rmse = 0.05

[scenes.bunny]
path = "scenes/bunny.toml"
replace = "leather"

[scenes.box]
path = "scenes/box.toml"

[materials.wool]
kind = "spmm"
pack = "wool.spmm"

[materials.gold]
kind = "brdf"
model = "ward"
params = { ax = 0.1, ay = 0.2 }
"#;

fn parse(extra: &str) -> Result<Manifest, ManifestError> {
    parse_manifest(Path::new("/m/manifest.toml"), format!("{BASE}{extra}"))
}

fn err(extra: &str) -> ManifestError {
    parse(extra).expect_err("refused")
}

/// The line of `needle`'s first occurrence in the whole manifest text.
fn line_of_text(extra: &str, needle: &str) -> usize {
    let text = format!("{BASE}{extra}");
    let at = text.find(needle).expect("needle present");
    text[..at].matches('\n').count() + 1
}

#[test]
fn matrices_expand_to_the_product_in_order_with_stable_names() {
    let m = parse(
        r#"
[[matrix]]
scenes = ["bunny"]
materials = ["scene", "wool", "gold"]
modes = ["spmm", "biscale"]
devices = ["cpu", "gpu"]
frames = 5

[[case]]
scene = "box"
mode = "adaptive"
min_mssim = 0.9
max_relative_rmse = 0.5
seed = 3

[[case]]
name = "bunny-wool-big"
scene = "bunny"
material = "wool"
mode = "spmm"
width = 128
"#,
    )
    .expect("valid");
    let names: Vec<&str> = m.cases.iter().map(|c| c.name.as_str()).collect();
    assert_eq!(names.len(), 3 * 2 * 2 + 2);
    assert_eq!(
        &names[..4],
        [
            "bunny.scene.spmm-cpu",
            "bunny.scene.spmm-gpu",
            "bunny.scene.biscale-cpu",
            "bunny.scene.biscale-gpu"
        ]
    );
    assert_eq!(names[4], "bunny.wool.spmm-cpu");
    assert_eq!(names[12], "box.scene.adaptive-cpu");
    assert_eq!(names[13], "bunny-wool-big");
    let wool = &m.cases[4];
    assert_eq!(wool.material.as_deref(), Some("wool"));
    assert_eq!(wool.replace.as_deref(), Some("leather"));
    assert_eq!(
        (wool.width, wool.height, wool.frames),
        (Some(32), Some(24), Some(5))
    );
    assert_eq!(wool.tolerance.max_relative_rmse, Some(0.05));
    assert_eq!(wool.tolerance.min_mssim, None);
    assert!(
        wool.origin.starts_with("matrix[0] (line "),
        "{}",
        wool.origin
    );
    let own = &m.cases[0];
    assert_eq!(
        (own.material.as_deref(), own.replace.as_deref()),
        (None, None)
    );
    let explicit = &m.cases[12];
    assert_eq!(explicit.seed, Some(3));
    assert_eq!(explicit.frames, Some(2), "the default");
    assert_eq!(explicit.tolerance.min_mssim, Some(0.9));
    assert_eq!(explicit.tolerance.max_relative_rmse, Some(0.5));
    assert_eq!(m.cases[13].width, Some(128));
    assert_eq!(m.goldens, Path::new("/m/goldens"));
    assert_eq!(m.scenes["bunny"].path, Path::new("/m/scenes/bunny.toml"));
    assert_eq!(
        m.cases[13].golden_path(&m.goldens),
        Path::new("/m/goldens/bunny-wool-big.exr")
    );
    // The digest follows the text.
    let other = parse("\n[[case]]\nscene = \"box\"\nmode = \"spmm\"\n").expect("valid");
    assert_ne!(m.digest, other.digest);
}

#[test]
fn every_error_names_the_file_the_line_and_the_key() {
    // (extra text, key expected, a word of the message, text on the line at fault)
    let cases: &[(&str, &str, &str, &str)] = &[
        (
            "\nfrobnicate = 1\n",
            "frobnicate",
            "unknown field",
            "frobnicate",
        ),
        (
            "\n[scenes.cube]\npath = \"c.toml\"\ncolour = 1\n",
            "colour",
            "unknown field",
            "colour",
        ),
        (
            "\n[[matrix]]\nscenes = [\"bunny\"]\nmodes = [\"spmm\"]\nframes = \"four\"\n",
            "frames",
            "invalid type",
            "frames = \"four\"",
        ),
        (
            "\n[[matrix]]\nscenes = [\"bunny\"]\nmodes = [\"spmm\"]\nframes = 0\n",
            "matrix[0].frames",
            "at least 1",
            "frames = 0",
        ),
        (
            "\n[[matrix]]\nscenes = [\"bunny\"]\nmodes = [\"spmm\"]\nwidth = 0\n",
            "matrix[0].width",
            "outside 1..=16384",
            "width = 0",
        ),
        (
            "\n[[matrix]]\nscenes = [\"bunny\"]\nmodes = [\"spmm\"]\nmax_relative_rmse = -1.0\n",
            "matrix[0].max_relative_rmse",
            "non-negative",
            "max_relative_rmse = -1.0",
        ),
        (
            "\n[[matrix]]\nscenes = [\"bunny\"]\nmodes = [\"spmm\"]\nmax_relative_rmse = nan\n",
            "matrix[0].max_relative_rmse",
            "finite",
            "max_relative_rmse = nan",
        ),
        (
            "\n[[matrix]]\nscenes = [\"bunny\"]\nmodes = [\"spmm\"]\nmin_mssim = 2.0\n",
            "matrix[0].min_mssim",
            "[-1, 1]",
            "min_mssim = 2.0",
        ),
        (
            "\n[[matrix]]\nscenes = [\"rabbit\"]\nmodes = [\"spmm\"]\n",
            "matrix[0].scenes",
            "no scene `rabbit` in the manifest (defined: box, bunny)",
            "scenes = [\"rabbit\"]",
        ),
        (
            "\n[[matrix]]\nscenes = [\"bunny\"]\nmaterials = [\"silk\"]\nmodes = [\"spmm\"]\n",
            "matrix[0].materials",
            "no material `silk`",
            "materials = [\"silk\"]",
        ),
        (
            "\n[[matrix]]\nscenes = [\"bunny\"]\nmodes = [\"raster\"]\n",
            "matrix[0].modes",
            "`raster`: modes are spmm, biscale, adaptive",
            "modes = [\"raster\"]",
        ),
        (
            "\n[[matrix]]\nscenes = [\"bunny\"]\nmodes = [\"spmm\"]\ndevices = [\"tpu\"]\n",
            "matrix[0].devices",
            "`tpu`: devices are cpu, gpu",
            "devices = [\"tpu\"]",
        ),
        (
            "\n[[matrix]]\nscenes = []\nmodes = [\"spmm\"]\n",
            "matrix[0].scenes",
            "is empty",
            "scenes = []",
        ),
        (
            "\n[[matrix]]\nscenes = [\"bunny\", \"bunny\"]\nmodes = [\"spmm\"]\n",
            "matrix[0].scenes",
            "names `bunny` twice",
            "scenes = [\"bunny\", \"bunny\"]",
        ),
        (
            "\n[[matrix]]\nscenes = [\"box\"]\nmaterials = [\"wool\"]\nmodes = [\"spmm\"]\n",
            "matrix[0].materials",
            "scene `box` has no `replace`",
            "materials = [\"wool\"]",
        ),
        (
            "\n[[case]]\nscene = \"box\"\nmaterial = \"wool\"\nmode = \"spmm\"\n",
            "case[0].replace",
            "say which of its materials `wool` replaces",
            "[[case]]",
        ),
        (
            "\n[[case]]\nscene = \"bunny\"\nreplace = \"floor\"\nmode = \"spmm\"\n",
            "case[0].replace",
            "without `material` replaces nothing",
            "replace = \"floor\"",
        ),
        (
            "\n[[case]]\nname = \"Has Space\"\nscene = \"bunny\"\nmode = \"spmm\"\n",
            "case[0].name",
            "case names are",
            "name = \"Has Space\"",
        ),
        (
            "\n[[case]]\nscene = \"bunny\"\nmode = \"fast\"\n",
            "case[0].mode",
            "`fast`: modes are",
            "mode = \"fast\"",
        ),
        (
            "\n[[case]]\nscene = \"bunny\"\nmode = \"spmm\"\ndevice = \"fpga\"\n",
            "case[0].device",
            "`fpga`: devices are",
            "device = \"fpga\"",
        ),
        (
            "\n[[case]]\nscene = \"nowhere\"\nmode = \"spmm\"\n",
            "case[0].scene",
            "no scene `nowhere`",
            "scene = \"nowhere\"",
        ),
        (
            "\n[[case]]\nscene = \"bunny\"\nmaterial = \"silk\"\nmode = \"spmm\"\n",
            "case[0].material",
            "no material `silk`",
            "material = \"silk\"",
        ),
        (
            // The matrix makes `bunny.scene.spmm-cpu`; the case is named the same.
            "\n[[matrix]]\nscenes = [\"bunny\"]\nmodes = [\"spmm\"]\n\n[[case]]\nname = \"bunny.scene.spmm-cpu\"\nscene = \"box\"\nmode = \"spmm\"\n",
            "case[0] (line",
            "is also made by matrix[0] (line",
            "[[case]]",
        ),
        (
            "\n[scenes.Bad]\npath = \"b.toml\"\n",
            "scenes.Bad",
            "names are 1 to 64 of a-z",
            "[scenes.Bad]",
        ),
        (
            "\n[materials.scene]\nkind = \"mirror\"\nreflectance = [1.0, 1.0, 1.0]\n",
            "materials.scene",
            "is reserved",
            "[materials.scene]",
        ),
    ];
    for (extra, key, words, line_text) in cases {
        let e = err(extra);
        assert_eq!(e.file, Path::new("/m/manifest.toml"), "{extra}");
        assert!(
            e.key.as_deref().is_some_and(|k| k.starts_with(key)),
            "{extra}: key {:?}, expected {key}: {e}",
            e.key
        );
        assert!(e.message.contains(words), "{extra}: {e}");
        let expected = line_of_text(extra, line_text);
        // A repeated line text (e.g. `[[case]]`) is found in `extra` after the base.
        let expected = if line_text.starts_with("[[") {
            BASE.matches('\n').count()
                + extra[..extra.rfind(line_text).expect("in extra")]
                    .matches('\n')
                    .count()
                + 1
        } else {
            expected
        };
        assert_eq!(e.line, Some(expected), "{extra}: {e}");
        let shown = e.to_string();
        assert!(
            shown.starts_with(&format!("`/m/manifest.toml` line {expected}, `")),
            "{shown}"
        );
    }
}

#[test]
fn file_level_errors() {
    let no_version =
        parse_manifest(Path::new("m.toml"), "goldens = \"g\"\n".into()).expect_err("refused");
    assert!(
        no_version.message.contains("missing field `version`"),
        "{no_version}"
    );
    let v2 = parse_manifest(
        Path::new("m.toml"),
        "version = 2\ngoldens = \"g\"\n[[case]]\n".into(),
    )
    .expect_err("refused");
    assert!(
        v2.message.contains("missing field"),
        "a case without scene: {v2}"
    );
    let v2 = parse_manifest(Path::new("m.toml"), "version = 2\ngoldens = \"g\"\n".into())
        .expect_err("refused");
    assert_eq!(
        (v2.line, v2.key.as_deref()),
        (Some(1), Some("version")),
        "{v2}"
    );
    let no_goldens =
        parse_manifest(Path::new("m.toml"), "version = 1\n".into()).expect_err("refused");
    assert!(no_goldens.message.contains("`goldens`"), "{no_goldens}");
    let empty = parse("").expect_err("no cases");
    assert!(empty.message.contains("names no case"), "{empty}");
    let no_tolerance = parse_manifest(
        Path::new("m.toml"),
        "version = 1\ngoldens = \"g\"\n[scenes.a]\npath = \"a.toml\"\n\n[[case]]\nscene = \"a\"\nmode = \"spmm\"\n"
            .into(),
    )
    .expect_err("no tolerance");
    assert_eq!(no_tolerance.key.as_deref(), Some("case[0]"));
    assert_eq!(no_tolerance.line, Some(6));
    assert!(
        no_tolerance.message.contains("has no tolerance"),
        "{no_tolerance}"
    );
    let unreadable = load_manifest(Path::new("/no/such/manifest.toml")).expect_err("missing");
    assert!(
        unreadable
            .to_string()
            .starts_with("`/no/such/manifest.toml`: cannot read")
    );
}

#[test]
fn substituted_materials_build_like_scene_materials_and_a_missing_btf_is_named() {
    let dir = tempfile::tempdir().expect("temp dir");
    let path = dir.path().join("manifest.toml");
    let text = format!(
        "{BASE}\n[materials.velvet]\nkind = \"btf\"\npath = \"velvet.btf\"\n\n[materials.bad_ward]\nkind = \"brdf\"\nmodel = \"ward\"\nparams = {{ ax = -1.0, ay = 0.2 }}\n\n[[case]]\nscene = \"bunny\"\nmode = \"spmm\"\n"
    );
    let m = parse_manifest(&path, text.clone()).expect("valid");
    let (gold, sets_uv) = m.material("gold").expect("an analytic BRDF");
    assert!(matches!(gold, Material::Brdf { .. }) && !sets_uv);
    // A pack that is not there: the manifest's file, line and key, and the pack's path.
    let e = m.material("wool").expect_err("no pack");
    assert_eq!(e.file, path);
    assert_eq!(e.key.as_deref(), Some("materials.wool.pack"));
    assert_eq!(e.line, Some(line_of_text("", "pack = \"wool.spmm\"")));
    assert!(e.message.contains("wool.spmm"), "{e}");
    let e = m.material("bad_ward").expect_err("ax < 0");
    assert_eq!(e.key.as_deref(), Some("materials.bad_ward.params"));
    assert!(e.message.contains("ax"), "{e}");
    // A BTF that is not there: named like the missing pack.
    let e = m.material("velvet").expect_err("no such BTF file");
    assert_eq!(e.key.as_deref(), Some("materials.velvet.path"));
    assert_eq!(
        e.line,
        Some(line_of_text(&text[BASE.len()..], "path = \"velvet.btf\""))
    );
    assert!(e.message.contains("velvet.btf"), "{e}");
    assert_eq!(
        m.material_line("velvet"),
        Some(line_of_text(&text[BASE.len()..], "[materials.velvet]"))
    );
}
