//! The WGSL sources (the workspace's `shaders/`, one file per concept, embedded at
//! build time) and the modules made of them. WGSL has no imports: a module is its
//! parts concatenated, and each entry file declares the bindings the parts read
//! (`data` for the BRDF and SPMM parts).

pub(super) const BRDF: &str = include_str!("../../../shaders/brdf.wgsl");
pub(super) const SPMM: &str = include_str!("../../../shaders/spmm.wgsl");
pub(super) const TRAVERSAL: &str = include_str!("../../../shaders/traversal.wgsl");
pub(super) const SAMPLER: &str = include_str!("../../../shaders/sampler.wgsl");
pub(super) const LIGHTS: &str = include_str!("../../../shaders/lights.wgsl");
pub(super) const INTEGRATOR: &str = include_str!("../../../shaders/integrator.wgsl");
pub(super) const ENVIRONMENT: &str = include_str!("../../../shaders/environment.wgsl");
pub(super) const MERL: &str = include_str!("../../../shaders/merl.wgsl");
pub(super) const CDF: &str = include_str!("../../../shaders/cdf.wgsl");
pub(super) const BTF_TABLE: &str = include_str!("../../../shaders/btf.wgsl");
pub(super) const FILM: &str = include_str!("../../../shaders/film.wgsl");
pub(super) const DISPLAY: &str = include_str!("../../../shaders/display.wgsl");
pub(super) const GUIDES: &str = include_str!("../../../shaders/guides.wgsl");
pub(super) const DENOISE: &str = include_str!("../../../shaders/denoise.wgsl");
pub(super) const BISCALE: &str = include_str!("../../../shaders/biscale.wgsl");
pub(super) const ADAPTIVE: &str = include_str!("../../../shaders/adaptive.wgsl");
pub(super) const ADAPTIVE_RENDER: &str = include_str!("../../../shaders/adaptive_render.wgsl");
pub(super) const ADAPTIVE_PASS: &str = include_str!("../../../shaders/adaptive_pass.wgsl");

/// The test kernels: evaluations of BRDFs and SPMM texels, and primary-ray hits.
#[cfg(test)]
pub(super) const TEST_KERNELS: &str = include_str!("../../../shaders/test_kernels.wgsl");

/// The module of `parts`, in order. Tests read the files as they are on disk (the
/// same sources), so a shader edit needs no rebuild of the crate.
pub(super) fn module(parts: &[&str]) -> String {
    #[cfg(test)]
    let parts: Vec<String> = parts.iter().map(|p| from_disk(p)).collect();
    parts.join("\n")
}

/// The file on disk whose embedded text is `embedded`.
#[cfg(test)]
fn from_disk(embedded: &str) -> String {
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../shaders");
    for entry in std::fs::read_dir(&dir).expect("shaders/ exists") {
        let path = entry.expect("an entry").path();
        let text = std::fs::read_to_string(&path).expect("a readable shader");
        let first = |s: &str| s.lines().next().unwrap_or_default().to_string();
        if path.extension().is_some_and(|e| e == "wgsl") && first(&text) == first(embedded) {
            return text;
        }
    }
    embedded.to_string()
}

/// The integrator's module with the entry file `entry` after it: the parts every
/// frame kind shares (sampler, traversal, materials, lights, environment).
fn integrator_with(entry: &str) -> String {
    module(&[
        INTEGRATOR,
        entry,
        SAMPLER,
        TRAVERSAL,
        BRDF,
        SPMM,
        LIGHTS,
        ENVIRONMENT,
        MERL,
        CDF,
        BTF_TABLE,
    ])
}

/// The integrator: one sample per pixel per dispatch (`render`), and the denoiser's
/// guides (`guides`).
pub(super) fn integrator() -> String {
    integrator_with(GUIDES)
}

/// The biscale mode's frames: the integrator's module with `render_biscale` after it.
pub(super) fn biscale() -> String {
    integrator_with(BISCALE)
}

/// The adaptive mode's samples: the integrator's module with `render_adaptive`
/// after it (its plan and up-sampling are `ADAPTIVE`'s module of their own).
pub(super) fn adaptive() -> String {
    integrator_with(ADAPTIVE_RENDER)
}

/// The adaptive mode's bandwidth pass: the integrator's module with the pass's
/// kernels after it (they shade as the samples do).
pub(super) fn adaptive_pass() -> String {
    integrator_with(ADAPTIVE_PASS)
}

#[cfg(test)]
mod tests {
    /// The shader's direction grid is the CPU table's: the device reads the CPU's
    /// cell lists by index.
    #[test]
    fn the_direction_grid_matches_the_cpu_tables() {
        let line = format!(
            "const DIRECTION_GRID: u32 = {}u;",
            meso_materials::spmm::directions::DirectionTable::GRID
        );
        assert!(
            super::SPMM.contains(&line),
            "shaders/spmm.wgsl lacks `{line}`"
        );
    }

    /// The adaptive frames' chunk of samples and `aux` words are the shaders' own.
    #[test]
    fn the_adaptive_constants_match_the_shaders() {
        let lines = [
            (
                super::ADAPTIVE_RENDER,
                format!(
                    "const ADAPTIVE_CHUNK: u32 = {}u;",
                    crate::mode::ADAPTIVE_CHUNK
                ),
            ),
            (
                super::ADAPTIVE,
                format!("const AUX_SIGMA: u32 = {}u;", crate::film::AUX_SIGMA),
            ),
            (
                super::ADAPTIVE,
                format!("const AUX_PLANNED: u32 = {}u;", crate::film::AUX_PLANNED),
            ),
            (
                super::ADAPTIVE_RENDER,
                format!("const AUX_PLANNED: u32 = {}u;", crate::film::AUX_PLANNED),
            ),
        ];
        for (source, line) in lines {
            assert!(source.contains(&line), "an adaptive shader lacks `{line}`");
        }
    }

    /// A moving camera keeps as many residual components on the device as on the CPU.
    #[test]
    fn the_moving_components_match_the_cpus() {
        let line = format!(
            "const MOVING_NPCA: u32 = {}u;",
            meso_materials::spmm::MOVING_NPCA
        );
        assert!(
            super::SPMM.contains(&line),
            "shaders/spmm.wgsl lacks `{line}`"
        );
    }
}
