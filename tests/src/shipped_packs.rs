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
