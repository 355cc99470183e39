//! The packs shipped in materials/ validate, and each is exactly what its recipe builds
//! today (so a recipe edit without a rebuilt pack, or the reverse, fails here).

use std::path::PathBuf;

use meso_materials::spmm::{pack, recipe};

const PACKS: [&str; 3] = ["woven_wool", "leather", "brushed_metal"];

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("..")
}

#[test]
fn shipped_packs_validate_and_match_their_recipes() {
    for name in PACKS {
        let file = root().join("materials").join(format!("{name}.spmm"));
        let bytes = std::fs::read(&file).expect("the pack is shipped");
        assert!(
            bytes.len() <= 2 << 20,
            "{name}: {} bytes, over 2 MB",
            bytes.len()
        );
        let shipped = pack::read_pack(&file).expect("the shipped pack validates");
        let built = recipe::build_from_recipe(
            &root()
                .join("materials/recipes")
                .join(name)
                .join("recipe.toml"),
        )
        .expect("the recipe builds");
        assert_eq!(shipped, built, "{name}: rebuild with `meso pack new`");
        assert_eq!(
            pack::encode_pack(&built, pack::ResidualPrecision::F32),
            bytes,
            "{name}: bytes differ"
        );
    }
}

/// The packs fitted to synthesized BTFs (docs/fitting.md): valid, at most 4 MB, with a
/// residual tabulated on the 81 x 81 Bonn directions.
#[test]
fn fitted_packs_validate_and_stay_small() {
    let bonn = meso_materials::btf::directions::bonn81();
    for name in ["knitted_wool", "woven_cloth", "grain_leather", "corduroy"] {
        let file = root().join("materials").join(format!("{name}.spmm"));
        let len = std::fs::metadata(&file).expect("the pack is shipped").len();
        assert!(len <= 4 << 20, "{name}: {len} bytes, over 4 MB");
        let m = pack::read_pack(&file).expect("the shipped pack validates");
        assert!(
            root()
                .join("materials/btf_recipes")
                .join(format!("{name}.toml"))
                .exists(),
            "{name}: its BTF recipe is shipped"
        );
        let r = m.residual().expect("a fitted pack has a residual");
        assert_eq!(
            (r.light_dirs.as_slice(), r.view_dirs.as_slice()),
            (bonn.as_slice(), bonn.as_slice())
        );
        // The pack is what materials/btf_recipes/rebuild.sh fits: its provenance holds
        // the script's settings for it (and the default seed).
        let provenance = m.provenance();
        assert!(
            provenance.starts_with(&format!("meso fit {name}.btf ")),
            "{name}: {provenance}"
        );
        let settings = rebuild_settings(name);
        for pair in settings.chunks(2) {
            let want = format!("{} {}", pair[0], pair[1]);
            assert!(
                provenance.contains(&want),
                "{name}: {provenance} lacks {want}"
            );
        }
        let npca: usize = settings
            .chunks(2)
            .find(|p| p[0] == "--npca")
            .map(|p| p[1].parse().expect("a number"))
            .expect("rebuild.sh sets --npca");
        // A pack trimmed to a byte budget (`meso pack trim`, per-cluster N_PCA) says so
        // after the fit, with the script's budget; it keeps at most the fit's N_PCA.
        match rebuild_trim(name) {
            None => {
                assert!(provenance.ends_with("--seed 0"), "{name}: {provenance}");
                assert_eq!(r.npca, npca, "{name}");
            }
            Some(trim) => {
                let want = format!("--seed 0; meso pack trim {trim}");
                assert!(
                    provenance.ends_with(&want),
                    "{name}: {provenance} vs {want}"
                );
                assert!(r.npca <= npca, "{name}");
                let words: Vec<&str> = trim.split_whitespace().collect();
                let value = |option: &str| {
                    words
                        .windows(2)
                        .find(|w| w[0] == option)
                        .map(|w| w[1].to_string())
                };
                let budget: u64 = value("--max-bytes")
                    .and_then(|b| b.parse().ok())
                    .expect("trim=\"--max-bytes N ...\"");
                assert!(
                    len <= budget,
                    "{name}: {len} bytes over its budget {budget}"
                );
                // The file is stored at the precision the script asks for.
                let bytes = std::fs::read(&file).expect("the pack is shipped");
                let precision = pack::residual_precision(&bytes).name();
                assert_eq!(
                    value("--precision").as_deref().unwrap_or("f16"),
                    precision,
                    "{name}"
                );
            }
        }
    }
}

/// The `meso pack trim` options rebuild.sh applies to `name`'s fit, if any.
fn rebuild_trim(name: &str) -> Option<String> {
    let script = std::fs::read_to_string(root().join("materials/btf_recipes/rebuild.sh"))
        .expect("the rebuild script is shipped");
    let line = script.lines().map(str::trim).find(|l| {
        l.contains("settings=\"")
            && l.split(')')
                .next()
                .is_some_and(|names| names.split('|').any(|n| n.trim() == name))
    })?;
    line.split("trim=\"")
        .nth(1)
        .and_then(|rest| rest.split('"').next())
        .filter(|t| !t.is_empty())
        .map(str::to_string)
}

/// The `meso fit` settings materials/btf_recipes/rebuild.sh uses for `name`, as
/// (option, value) words.
fn rebuild_settings(name: &str) -> Vec<String> {
    let script = std::fs::read_to_string(root().join("materials/btf_recipes/rebuild.sh"))
        .expect("the rebuild script is shipped");
    let line = script
        .lines()
        .map(str::trim)
        .find(|l| {
            l.contains("settings=\"")
                && l.split(')')
                    .next()
                    .is_some_and(|names| names.split('|').any(|n| n.trim() == name))
        })
        .unwrap_or_else(|| panic!("rebuild.sh has no settings for {name}"));
    let quoted = line.split('"').nth(1).expect("settings=\"...\"");
    quoted.split_whitespace().map(str::to_string).collect()
}
