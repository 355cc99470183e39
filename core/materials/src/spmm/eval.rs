//! Evaluating an SPMM material at a shading point (Silva & Santos 2013 eq. 1-3):
//! the sparse basis sum sum_j alpha_j(t) rho_j(wi, wo) plus the cluster's residual
//! eps_bar(c) + sum_k coef_k(t) b_k(c), interpolated over the tabulated light and view
//! directions (directions.rs: at most 3 x 3 table reads). The residual can be switched
//! off and N_PCA limited at run time, the seed's quality/speed knobs.

use glam::{DVec2, DVec3};

use super::SpmmMaterial;

/// How a UV position picks texels.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum TexelFilter {
    #[default]
    Nearest,
    /// Blends the four nearest texel centres (wrapping, since packs tile).
    Bilinear,
}

/// Principal components the viewport keeps while the camera moves: the residual's mean
/// and its first four. The seed skips the whole residual while moving; on a pack whose
/// residual carries much of its look that makes the image jump when the camera stops
/// (the shipped 3-cluster grain leather renders at MSSIM 0.933 without its residual
/// against 0.994 with four components, for about 9% more CPU frame time:
/// docs/rendering.md, "The moving camera").
pub const MOVING_NPCA: usize = 4;

/// Run-time quality settings of an evaluation.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct EvalSettings {
    /// Add the PCA residual.
    pub residual: bool,
    /// Use at most this many principal components (fewer if the pack has fewer).
    pub max_npca: usize,
    pub filter: TexelFilter,
    /// Texture tiling: the UV is multiplied by this before wrapping.
    pub uv_scale: DVec2,
}

impl Default for EvalSettings {
    fn default() -> Self {
        Self {
            residual: true,
            max_npca: usize::MAX,
            filter: TexelFilter::Nearest,
            uv_scale: DVec2::ONE,
        }
    }
}

impl SpmmMaterial {
    /// BTF(t, wi, wo), RGB, for texel `t` (row-major) with unit `wi`, `wo` in the tangent
    /// frame; 0 unless both lie above the surface. Includes the foreshortening cosine,
    /// like every rho_j (docs/brdf.md): shading integrates L_i BTF dwi.
    pub fn eval_texel(
        &self,
        t: usize,
        wi: DVec3,
        wo: DVec3,
        residual: bool,
        max_npca: usize,
    ) -> DVec3 {
        self.eval_texel_in(self.view(), t, wi, wo, residual, max_npca)
    }

    /// `eval_texel` as `view` shows the material (the default view: as stored).
    pub(super) fn eval_texel_in(
        &self,
        view: &super::BasisView,
        t: usize,
        wi: DVec3,
        wo: DVec3,
        residual: bool,
        max_npca: usize,
    ) -> DVec3 {
        if wi.z <= 0.0 || wo.z <= 0.0 {
            return DVec3::ZERO;
        }
        let c = self.texel_cluster()[t] as usize;
        let bases = &self.clusters()[c].bases;
        let all_shown = view.is_empty();
        let mut rgb = DVec3::ZERO;
        for (j, w) in self.texel_weights(t) {
            if all_shown || view.shows(c, usize::from(j)) {
                rgb += DVec3::new(w[0] as f64, w[1] as f64, w[2] as f64)
                    * bases[usize::from(j)].eval(wi, wo);
            }
        }
        if residual
            && (all_shown || view.shows_residual(c))
            && let (Some(r), Some((lights, views))) = (self.residual(), self.residual_tables())
        {
            let (nl, nv, npca) = (r.light_dirs.len(), r.view_dirs.len(), r.npca);
            let k_used = npca.min(max_npca);
            let coef = &r.coefficients[t * npca..t * npca + k_used];
            for (l, wl) in lights.cosine_weights(wi) {
                for (v, wv) in views.weights(wo) {
                    let w = wl * wv;
                    if w == 0.0 {
                        continue;
                    }
                    let (l, v) = (l as usize, v as usize);
                    let at = |table: &[f32], i: usize| {
                        DVec3::new(table[i] as f64, table[i + 1] as f64, table[i + 2] as f64)
                    };
                    let mut e = at(&r.mean, ((c * nl + l) * nv + v) * 3);
                    for (k, &a) in coef.iter().enumerate() {
                        e += a as f64 * at(&r.components, (((c * npca + k) * nl + l) * nv + v) * 3);
                    }
                    rgb += w * e;
                }
            }
        }
        rgb
    }

    /// The row-major texel index a UV position falls in (nearest filtering).
    pub fn texel_at(&self, uv: DVec2, scale: DVec2) -> usize {
        TexelGrid::of(self).nearest(uv, scale)
    }

    /// Continuous texel coordinates of a UV position after tiling (x right, y down,
    /// texel centres at +0.5), as nearest filtering reads them: where a brush lands.
    pub fn texel_position(&self, uv: DVec2, scale: DVec2) -> DVec2 {
        TexelGrid::of(self).position(uv, scale)
    }

    /// BTF at a surface UV position, with the settings' filter, tiling and residual knobs.
    pub fn eval_uv(&self, uv: DVec2, wi: DVec3, wo: DVec3, s: &EvalSettings) -> DVec3 {
        TexelGrid::of(self).filter(uv, s, |t| {
            self.eval_texel(t, wi, wo, s.residual, s.max_npca)
        })
    }
}

/// UV to texel mapping, shared by the reference and the prepared evaluation.
#[derive(Clone, Copy, Debug)]
pub struct TexelGrid {
    pub width: u32,
    pub height: u32,
}

impl TexelGrid {
    pub fn of(m: &SpmmMaterial) -> Self {
        Self {
            width: m.width(),
            height: m.height(),
        }
    }

    /// Texel coordinates (continuous, texel centres at +0.5) after tiling: u to the
    /// right, v up (row 0 is the top), wrapping outside [0, 1).
    pub fn position(&self, uv: DVec2, scale: DVec2) -> DVec2 {
        let u = (uv.x * scale.x).rem_euclid(1.0);
        let v = (uv.y * scale.y).rem_euclid(1.0);
        DVec2::new(u * self.width as f64, (1.0 - v) * self.height as f64)
    }

    pub fn nearest(&self, uv: DVec2, scale: DVec2) -> usize {
        let p = self.position(uv, scale);
        let x = (p.x.floor() as i64).clamp(0, self.width as i64 - 1) as usize;
        let y = (p.y.floor() as i64).clamp(0, self.height as i64 - 1) as usize;
        y * self.width as usize + x
    }

    /// Applies the settings' filter to `texel_value`; 0 for a non-finite UV.
    pub fn filter(
        &self,
        uv: DVec2,
        s: &EvalSettings,
        texel_value: impl Fn(usize) -> DVec3,
    ) -> DVec3 {
        if !uv.is_finite() {
            return DVec3::ZERO;
        }
        match s.filter {
            TexelFilter::Nearest => texel_value(self.nearest(uv, s.uv_scale)),
            TexelFilter::Bilinear => {
                let p = self.position(uv, s.uv_scale) - DVec2::splat(0.5);
                let (w, h) = (self.width as i64, self.height as i64);
                let (x0, y0) = (p.x.floor(), p.y.floor());
                let (fx, fy) = (p.x - x0, p.y - y0);
                let texel = |dx: i64, dy: i64| {
                    let x = (x0 as i64 + dx).rem_euclid(w) as usize;
                    let y = (y0 as i64 + dy).rem_euclid(h) as usize;
                    texel_value(y * w as usize + x)
                };
                (texel(0, 0) * (1.0 - fx) + texel(1, 0) * fx) * (1.0 - fy)
                    + (texel(0, 1) * (1.0 - fx) + texel(1, 1) * fx) * fy
            }
        }
    }
}
