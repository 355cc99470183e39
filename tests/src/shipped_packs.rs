//! The packs shipped in materials/ validate, and each is exactly what its recipe builds
//! today (so a recipe edit without a rebuilt pack, or the reverse, fails here).

use std::path::PathBuf;

use meso_core::spmm::{pack, recipe};

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
    let bonn = meso_core::btf::directions::bonn81();
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
        assert_eq!(r.npca, 5);
    }
}
