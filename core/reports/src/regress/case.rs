//! One regression case: a scene, an optional material substitution, a mode and
//! device, size, frames and tolerance; its stable name (which names its golden EXR,
//! picks its shard and titles its report row) and the substitution itself.

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use meso_render::scene::{Material, Scene};
use meso_render::{Device, ModeKind};

/// In `materials = [...]`, the scene's own material (no substitution).
pub const NO_SUBSTITUTION: &str = "scene";

/// The bounds a new render must keep against its golden. At least one is set.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Tolerance {
    /// RMSE divided by the golden's mean over pixels and channels: a dim scene is held
    /// as tightly as a bright one.
    pub max_relative_rmse: Option<f64>,
    pub min_mssim: Option<f64>,
}

impl Tolerance {
    /// What exceeds the bounds, one phrase each; empty if the render passes.
    pub fn violations(&self, relative_rmse: f64, mssim: f64) -> Vec<String> {
        let mut out = Vec::new();
        if let Some(max) = self.max_relative_rmse
            && (relative_rmse.is_nan() || relative_rmse > max)
        {
            out.push(format!("relative RMSE {relative_rmse:.4e} > {max}"));
        }
        if let Some(min) = self.min_mssim
            && (mssim.is_nan() || mssim < min)
        {
            out.push(format!("MSSIM {mssim:.6} < {min}"));
        }
        out
    }
}

#[derive(Clone, Debug, PartialEq)]
pub struct Case {
    pub name: String,
    /// The manifest's key of the scene.
    pub scene: String,
    /// The manifest's key of the substituted material; `None` renders the scene as is.
    pub material: Option<String>,
    /// The scene's material that `material` replaces.
    pub replace: Option<String>,
    pub mode: ModeKind,
    pub device: Device,
    /// `None`: the scene's own.
    pub width: Option<u32>,
    pub height: Option<u32>,
    pub frames: Option<u32>,
    pub seed: Option<u64>,
    pub tolerance: Tolerance,
    /// Where the manifest makes it (`matrix[0] (line 12)`), for messages.
    pub origin: String,
}

impl Case {
    /// The golden EXR of this case in the goldens folder.
    pub fn golden_path(&self, goldens: &Path) -> PathBuf {
        goldens.join(format!("{}.exr", self.name))
    }

    /// The material column of reports: the substitution, or `scene`.
    pub fn material_label(&self) -> &str {
        self.material.as_deref().unwrap_or(NO_SUBSTITUTION)
    }
}

/// The stable name of a matrix case: `SCENE.MATERIAL.MODE-DEVICE` (`MATERIAL` is
/// `scene` without a substitution). It depends on nothing else, so settings can change
/// without renaming goldens, and adding a case renames none.
pub fn case_name(scene: &str, material: Option<&str>, mode: ModeKind, device: Device) -> String {
    format!(
        "{scene}.{}.{}-{}",
        material.unwrap_or(NO_SUBSTITUTION),
        mode.name(),
        device.name()
    )
}

/// Why `name` cannot key a scene or material: names become parts of file names.
pub fn check_key(name: &str) -> Option<String> {
    let ok = !name.is_empty()
        && name.len() <= 64
        && name
            .bytes()
            .all(|b| b.is_ascii_lowercase() || b.is_ascii_digit() || b == b'_' || b == b'-');
    (!ok).then(|| {
        format!("`{name}`: names are 1 to 64 of a-z, 0-9, `_` and `-` (they become file names)")
    })
}

/// Why `name` cannot name an explicit case (it names the golden file).
pub fn check_case_name(name: &str) -> Option<String> {
    let ok = !name.is_empty()
        && name.len() <= 128
        && !name.starts_with('.')
        && name
            .bytes()
            .all(|b| b.is_ascii_alphanumeric() || matches!(b, b'_' | b'-' | b'.'));
    (!ok).then(|| {
        format!(
            "`{name}`: case names are 1 to 128 of A-Z, a-z, 0-9, `_`, `-` and `.`, not starting with `.` (they name the golden file)"
        )
    })
}

/// Replaces the scene's material `replace` by `material`. An `spmm` substitution that
/// sets no `uv_scale` keeps the tiling of the `spmm` or `btf` material it replaces (a
/// pack or a BTF is swapped for another on the same object).
pub fn substitute(
    scene: &mut Scene,
    replace: &str,
    material: Material,
    sets_uv_scale: bool,
) -> Result<(), String> {
    let Some(index) = scene.material_names.iter().position(|n| n == replace) else {
        return Err(format!(
            "the scene has no material `{replace}` (it has: {})",
            scene.material_names.join(", ")
        ));
    };
    let kept_tiling = match &scene.materials[index] {
        Material::Spmm { uv_scale, .. } | Material::Btf { uv_scale, .. } if !sets_uv_scale => {
            Some(*uv_scale)
        }
        _ => None,
    };
    let mut material = material;
    if let (Some(kept), Material::Spmm { uv_scale, .. } | Material::Btf { uv_scale, .. }) =
        (kept_tiling, &mut material)
    {
        *uv_scale = kept;
    }
    scene.materials[index] = material;
    if let Some(file) = scene.material_files.get_mut(index) {
        *file = None;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use glam::DVec2;

    use super::*;
    use meso_render::scene::test_scenes::{edit_test_scene, tabulated_btf, tilted_spmm};

    #[test]
    fn a_pack_keeps_the_tiling_it_replaces_unless_it_sets_its_own() {
        let mut scene = edit_test_scene();
        substitute(&mut scene, "panel", tilted_spmm(), false).expect("panel exists");
        let Material::Spmm { uv_scale, .. } = &scene.materials[1] else {
            panic!("an spmm material")
        };
        assert_eq!(*uv_scale, DVec2::splat(2.0), "the replaced panel's tiling");
        assert_eq!(scene.material_files.get(1).cloned().flatten(), None);
        let mut scene = edit_test_scene();
        substitute(&mut scene, "panel", tilted_spmm(), true).expect("panel exists");
        let Material::Spmm { uv_scale, .. } = &scene.materials[1] else {
            panic!("an spmm material")
        };
        assert_eq!(*uv_scale, DVec2::ONE, "its own tiling");
        // Over a non-spmm material there is no tiling to keep.
        let mut scene = edit_test_scene();
        substitute(&mut scene, "floor", tilted_spmm(), false).expect("floor exists");
        assert!(
            matches!(scene.materials[0], Material::Spmm { uv_scale, .. } if uv_scale == DVec2::ONE)
        );
        // A BTF swapped for the pack keeps its tiling too.
        let mut scene = edit_test_scene();
        let lambert = meso_materials::brdf::AnalyticBrdf::with_defaults(
            meso_materials::brdf::BrdfModel::Lambertian,
        );
        let btf = tabulated_btf(&lambert, glam::DVec3::ONE, DVec2::splat(5.0));
        substitute(&mut scene, "panel", btf.clone(), false).expect("panel exists");
        assert!(
            matches!(scene.materials[1], Material::Btf { uv_scale, .. } if uv_scale == DVec2::splat(2.0))
        );
        let mut scene = edit_test_scene();
        substitute(&mut scene, "panel", btf, true).expect("panel exists");
        assert!(
            matches!(scene.materials[1], Material::Btf { uv_scale, .. } if uv_scale == DVec2::splat(5.0))
        );
        let e = substitute(&mut scene, "wall", tilted_spmm(), false).expect_err("no wall");
        assert_eq!(e, "the scene has no material `wall` (it has: floor, panel)");
    }

    #[test]
    fn tolerances_check_only_their_bounds_and_reject_nan() {
        let both = Tolerance {
            max_relative_rmse: Some(0.05),
            min_mssim: Some(0.98),
        };
        assert!(
            both.violations(0.05, 0.98).is_empty(),
            "bounds are inclusive"
        );
        assert_eq!(both.violations(0.06, 0.99).len(), 1);
        assert_eq!(both.violations(0.01, 0.97).len(), 1);
        assert_eq!(both.violations(f64::NAN, f64::NAN).len(), 2);
        assert_eq!(both.violations(f64::INFINITY, 1.0).len(), 1);
        let rmse_only = Tolerance {
            max_relative_rmse: Some(0.05),
            min_mssim: None,
        };
        assert!(rmse_only.violations(0.0, -1.0).is_empty());
    }

    #[test]
    fn names_are_checked_for_file_use() {
        assert_eq!(
            case_name("bunny", None, ModeKind::Spmm, Device::Gpu),
            "bunny.scene.spmm-gpu"
        );
        assert!(check_key("woven_wool-2").is_none());
        for bad in ["", "Wool", "a.b", "a/b", &"x".repeat(65)] {
            assert!(check_key(bad).is_some(), "{bad}");
        }
        assert!(check_case_name("Cornell-96.seed_7").is_none());
        for bad in ["", ".hidden", "a/b", "a b", "../x"] {
            assert!(check_case_name(bad).is_some(), "{bad}");
        }
    }
}
