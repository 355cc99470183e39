//! The analytic BRDF dictionary of docs/brdf.md: seven models, exactly as specified,
//! as a closed `Copy` enum of validated parameter sets, with importance sampling and
//! the matching pdfs. Evaluated in `f64`: exponents up to 1e5 amplify the rounding
//! of cos_h by the exponent, which `f32` arithmetic cannot keep within float precision.
//! Vectors are in the local shading frame (z = normal); `wi` points to the light.

mod albedo;
mod ashikhmin_shirley;
mod basis;
mod blinn_phong;
mod cook_torrance;
mod frame;
mod lafortune;
mod lambertian;
mod lobe;
mod oren_nayar;
mod ward;
pub mod warp;

#[cfg(any(test, feature = "testing"))]
pub mod chi2_tests;
#[cfg(test)]
mod tests;

use glam::{DVec2, DVec3};

pub use albedo::{AlbedoEstimate, directional_albedo};
pub use ashikhmin_shirley::AshikhminShirley;
pub use basis::BasisFunction;
pub use blinn_phong::BlinnPhong;
pub use cook_torrance::CookTorrance;
pub use frame::Frame;
pub use lafortune::Lafortune;
pub use lambertian::Lambertian;
pub use lobe::{LobePoint, incidence_plane_lobe};
pub use oren_nayar::OrenNayar;
pub use ward::Ward;

/// The seven models, by their command-line names.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum BrdfModel {
    Lambertian,
    OrenNayar,
    BlinnPhong,
    Ward,
    CookTorrance,
    Lafortune,
    AshikhminShirley,
}

/// One parameter of a model: its CLI name, the spec's closed range, a default, and
/// hints for editors.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ParamSpec {
    pub name: &'static str,
    pub min: f64,
    pub max: f64,
    pub default: f64,
    /// Exponents and roughnesses span decades: a slider should move logarithmically.
    pub log_scale: bool,
    /// One line for tooltips and docs, with the unit.
    pub doc: &'static str,
}

const fn spec(
    name: &'static str,
    min: f64,
    max: f64,
    default: f64,
    log_scale: bool,
    doc: &'static str,
) -> ParamSpec {
    ParamSpec {
        name,
        min,
        max,
        default,
        log_scale,
        doc,
    }
}

const OREN_NAYAR_PARAMS: [ParamSpec; 1] = [spec(
    "sigma",
    0.0,
    std::f64::consts::FRAC_PI_2,
    0.3,
    false,
    "roughness: standard deviation of the facet slope angle (radians)",
)];
const BLINN_PHONG_PARAMS: [ParamSpec; 1] = [spec(
    "n",
    0.0,
    1e5,
    50.0,
    true,
    "specular exponent (dimensionless)",
)];
const WARD_PARAMS: [ParamSpec; 2] = [
    spec(
        "ax",
        1e-4,
        1.0,
        0.2,
        true,
        "roughness along the tangent x (slope std. dev.)",
    ),
    spec(
        "ay",
        1e-4,
        1.0,
        0.2,
        true,
        "roughness along the bitangent y (slope std. dev.)",
    ),
];
const COOK_TORRANCE_PARAMS: [ParamSpec; 2] = [
    spec(
        "m",
        1e-4,
        1.0,
        0.3,
        true,
        "Beckmann roughness (RMS facet slope)",
    ),
    spec(
        "f0",
        0.0,
        1.0,
        0.04,
        false,
        "Fresnel reflectance at normal incidence (Schlick)",
    ),
];
const LAFORTUNE_PARAMS: [ParamSpec; 4] = [
    spec("cx", -1e3, 1e3, -1.0, false, "lobe weight on wi.x wo.x"),
    spec("cy", -1e3, 1e3, -1.0, false, "lobe weight on wi.y wo.y"),
    spec("cz", -1e3, 1e3, 1.0, false, "lobe weight on wi.z wo.z"),
    spec("n", 0.0, 1e4, 20.0, true, "lobe exponent (dimensionless)"),
];
const ASHIKHMIN_SHIRLEY_PARAMS: [ParamSpec; 3] = [
    spec("nu", 1.0, 1e5, 100.0, true, "exponent along the tangent x"),
    spec(
        "nv",
        1.0,
        1e5,
        100.0,
        true,
        "exponent along the bitangent y",
    ),
    spec(
        "rs",
        0.0,
        1.0,
        0.5,
        false,
        "specular reflectance at normal incidence (Schlick)",
    ),
];

impl BrdfModel {
    pub const ALL: [BrdfModel; 7] = [
        BrdfModel::Lambertian,
        BrdfModel::OrenNayar,
        BrdfModel::BlinnPhong,
        BrdfModel::Ward,
        BrdfModel::CookTorrance,
        BrdfModel::Lafortune,
        BrdfModel::AshikhminShirley,
    ];

    /// The name used on the command line, in scene files and packs.
    pub fn name(self) -> &'static str {
        match self {
            BrdfModel::Lambertian => "lambertian",
            BrdfModel::OrenNayar => "oren_nayar",
            BrdfModel::BlinnPhong => "blinn_phong",
            BrdfModel::Ward => "ward",
            BrdfModel::CookTorrance => "cook_torrance",
            BrdfModel::Lafortune => "lafortune",
            BrdfModel::AshikhminShirley => "ashikhmin_shirley",
        }
    }

    pub fn from_name(name: &str) -> Result<Self, BrdfError> {
        Self::ALL
            .into_iter()
            .find(|m| m.name() == name)
            .ok_or_else(|| BrdfError::UnknownModel {
                name: name.to_string(),
            })
    }

    /// The parameters in their fixed order (the order of `AnalyticBrdf::param_values`).
    pub fn param_specs(self) -> &'static [ParamSpec] {
        match self {
            BrdfModel::Lambertian => &[],
            BrdfModel::OrenNayar => &OREN_NAYAR_PARAMS,
            BrdfModel::BlinnPhong => &BLINN_PHONG_PARAMS,
            BrdfModel::Ward => &WARD_PARAMS,
            BrdfModel::CookTorrance => &COOK_TORRANCE_PARAMS,
            BrdfModel::Lafortune => &LAFORTUNE_PARAMS,
            BrdfModel::AshikhminShirley => &ASHIKHMIN_SHIRLEY_PARAMS,
        }
    }
}

fn known_models() -> String {
    BrdfModel::ALL.map(BrdfModel::name).join(", ")
}

fn param_names(model: BrdfModel) -> String {
    let names: Vec<&str> = model.param_specs().iter().map(|p| p.name).collect();
    if names.is_empty() {
        "none".to_string()
    } else {
        names.join(", ")
    }
}

/// Everything that can be wrong with a model name or its parameters.
#[derive(Debug, thiserror::Error, Clone, PartialEq)]
pub enum BrdfError {
    #[error("unknown BRDF model `{name}` (known: {})", known_models())]
    UnknownModel { name: String },
    #[error("model `{}` has no parameter `{param}` (its parameters: {})", model.name(), param_names(*model))]
    UnknownParam { model: BrdfModel, param: String },
    #[error("parameter `{param}` of model `{}` is given twice", model.name())]
    DuplicateParam { model: BrdfModel, param: String },
    #[error("model `{}` needs parameter `{param}` in [{min}, {max}]", model.name())]
    MissingParam {
        model: BrdfModel,
        param: &'static str,
        min: f64,
        max: f64,
    },
    #[error("parameter `{param}` of model `{}` is {value}, outside its range [{min}, {max}]", model.name())]
    OutOfRange {
        model: BrdfModel,
        param: &'static str,
        value: f64,
        min: f64,
        max: f64,
    },
    #[error(
        "basis normal {normal:?} is not a unit vector in the upper hemisphere (|n| must be 1 within 1e-3 and n.z > 0)"
    )]
    BadNormal { normal: [f64; 3] },
}

/// Checks one value against the spec of parameter `index` of `model`.
fn validate(model: BrdfModel, index: usize, value: f64) -> Result<f64, BrdfError> {
    let s = &model.param_specs()[index];
    // NaN fails both comparisons and so is out of range.
    if value >= s.min && value <= s.max {
        Ok(value)
    } else {
        Err(BrdfError::OutOfRange {
            model,
            param: s.name,
            value,
            min: s.min,
            max: s.max,
        })
    }
}

/// One basis BRDF with valid parameters. `Copy` and small, so it maps onto a GPU
/// struct and costs nothing to pass by value in the shading loop.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum AnalyticBrdf {
    Lambertian(Lambertian),
    OrenNayar(OrenNayar),
    BlinnPhong(BlinnPhong),
    Ward(Ward),
    CookTorrance(CookTorrance),
    Lafortune(Lafortune),
    AshikhminShirley(AshikhminShirley),
}

/// A direction drawn by `AnalyticBrdf::sample` and its solid-angle density.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BrdfSample {
    pub wi: DVec3,
    pub pdf: f64,
}

impl AnalyticBrdf {
    /// Builds a model from named parameters. Every parameter is required; unknown,
    /// duplicate, missing, non-finite and out-of-range parameters are errors.
    pub fn new(model: BrdfModel, params: &[(&str, f64)]) -> Result<Self, BrdfError> {
        let specs = model.param_specs();
        let mut values: Vec<Option<f64>> = vec![None; specs.len()];
        for &(name, value) in params {
            let index = specs.iter().position(|s| s.name == name).ok_or_else(|| {
                BrdfError::UnknownParam {
                    model,
                    param: name.to_string(),
                }
            })?;
            if values[index].is_some() {
                return Err(BrdfError::DuplicateParam {
                    model,
                    param: name.to_string(),
                });
            }
            values[index] = Some(validate(model, index, value)?);
        }
        let mut checked = Vec::with_capacity(specs.len());
        for (s, v) in specs.iter().zip(values) {
            checked.push(v.ok_or(BrdfError::MissingParam {
                model,
                param: s.name,
                min: s.min,
                max: s.max,
            })?);
        }
        Self::from_values(model, &checked)
    }

    /// The model with the default of every parameter.
    pub fn with_defaults(model: BrdfModel) -> Self {
        let values: Vec<f64> = model.param_specs().iter().map(|s| s.default).collect();
        Self::from_values(model, &values).expect("the defaults lie inside the spec ranges")
    }

    /// Builds from values in `param_specs` order (each validated by the model's `new`).
    fn from_values(model: BrdfModel, v: &[f64]) -> Result<Self, BrdfError> {
        Ok(match model {
            BrdfModel::Lambertian => AnalyticBrdf::Lambertian(Lambertian),
            BrdfModel::OrenNayar => AnalyticBrdf::OrenNayar(OrenNayar::new(v[0])?),
            BrdfModel::BlinnPhong => AnalyticBrdf::BlinnPhong(BlinnPhong::new(v[0])?),
            BrdfModel::Ward => AnalyticBrdf::Ward(Ward::new(v[0], v[1])?),
            BrdfModel::CookTorrance => AnalyticBrdf::CookTorrance(CookTorrance::new(v[0], v[1])?),
            BrdfModel::Lafortune => {
                AnalyticBrdf::Lafortune(Lafortune::new(v[0], v[1], v[2], v[3])?)
            }
            BrdfModel::AshikhminShirley => {
                AnalyticBrdf::AshikhminShirley(AshikhminShirley::new(v[0], v[1], v[2])?)
            }
        })
    }

    pub fn model(&self) -> BrdfModel {
        match self {
            AnalyticBrdf::Lambertian(_) => BrdfModel::Lambertian,
            AnalyticBrdf::OrenNayar(_) => BrdfModel::OrenNayar,
            AnalyticBrdf::BlinnPhong(_) => BrdfModel::BlinnPhong,
            AnalyticBrdf::Ward(_) => BrdfModel::Ward,
            AnalyticBrdf::CookTorrance(_) => BrdfModel::CookTorrance,
            AnalyticBrdf::Lafortune(_) => BrdfModel::Lafortune,
            AnalyticBrdf::AshikhminShirley(_) => BrdfModel::AshikhminShirley,
        }
    }

    /// Parameter values in `param_specs` order.
    pub fn param_values(&self) -> Vec<f64> {
        match self {
            AnalyticBrdf::Lambertian(_) => vec![],
            AnalyticBrdf::OrenNayar(b) => vec![b.sigma()],
            AnalyticBrdf::BlinnPhong(b) => vec![b.n()],
            AnalyticBrdf::Ward(b) => vec![b.ax(), b.ay()],
            AnalyticBrdf::CookTorrance(b) => vec![b.m(), b.f0()],
            AnalyticBrdf::Lafortune(b) => vec![b.cx(), b.cy(), b.cz(), b.n()],
            AnalyticBrdf::AshikhminShirley(b) => vec![b.nu(), b.nv(), b.rs()],
        }
    }

    /// A copy with one parameter changed (validated), for editors.
    pub fn with_param(&self, name: &str, value: f64) -> Result<Self, BrdfError> {
        let model = self.model();
        let index = model
            .param_specs()
            .iter()
            .position(|s| s.name == name)
            .ok_or_else(|| BrdfError::UnknownParam {
                model,
                param: name.to_string(),
            })?;
        let mut values = self.param_values();
        values[index] = validate(model, index, value)?;
        Self::from_values(model, &values)
    }

    /// The BRDF value f(wi, wo) in 1/sr, docs/brdf.md; 0 unless both directions lie
    /// strictly above the surface. `wi` and `wo` must be unit vectors.
    #[inline]
    pub fn eval(&self, wi: DVec3, wo: DVec3) -> f64 {
        if wi.z <= 0.0 || wo.z <= 0.0 {
            return 0.0;
        }
        match self {
            AnalyticBrdf::Lambertian(b) => b.eval(wi, wo),
            AnalyticBrdf::OrenNayar(b) => b.eval(wi, wo),
            AnalyticBrdf::BlinnPhong(b) => b.eval(wi, wo),
            AnalyticBrdf::Ward(b) => b.eval(wi, wo),
            AnalyticBrdf::CookTorrance(b) => b.eval(wi, wo),
            AnalyticBrdf::Lafortune(b) => b.eval(wi, wo),
            AnalyticBrdf::AshikhminShirley(b) => b.eval(wi, wo),
        }
    }

    /// Draws `wi` for a given `wo` from the model's sampling density using the two
    /// uniform numbers `u`. `None` when the drawn direction falls at or below the
    /// horizon (or `wo` does): that probability mass is simply missing, and `pdf`
    /// integrates over the upper hemisphere to the probability of `Some`.
    #[inline]
    pub fn sample(&self, wo: DVec3, u: DVec2) -> Option<BrdfSample> {
        if wo.z <= 0.0 {
            return None;
        }
        let wi = match self {
            AnalyticBrdf::Lambertian(_) | AnalyticBrdf::OrenNayar(_) => warp::cosine_hemisphere(u),
            AnalyticBrdf::BlinnPhong(b) => warp::reflect(wo, b.sample_half(u))?,
            AnalyticBrdf::Ward(b) => warp::reflect(wo, b.sample_half(u))?,
            AnalyticBrdf::CookTorrance(b) => warp::reflect(wo, b.sample_half(u))?,
            AnalyticBrdf::AshikhminShirley(b) => warp::reflect(wo, b.sample_half(u))?,
            AnalyticBrdf::Lafortune(b) => b.sample(wo, u),
        };
        let pdf = self.pdf(wo, wi);
        (wi.z > 0.0 && pdf > 0.0 && pdf.is_finite()).then_some(BrdfSample { wi, pdf })
    }

    /// Solid-angle density with which `sample(wo, ·)` returns `wi`; 0 below the horizon.
    #[inline]
    pub fn pdf(&self, wo: DVec3, wi: DVec3) -> f64 {
        if wi.z <= 0.0 || wo.z <= 0.0 {
            return 0.0;
        }
        match self {
            AnalyticBrdf::Lambertian(_) | AnalyticBrdf::OrenNayar(_) => {
                warp::cosine_hemisphere_pdf(wi)
            }
            AnalyticBrdf::BlinnPhong(b) => warp::half_to_wi_pdf(wo, wi, |h| b.pdf_half(h)),
            AnalyticBrdf::Ward(b) => warp::half_to_wi_pdf(wo, wi, |h| b.pdf_half(h)),
            AnalyticBrdf::CookTorrance(b) => warp::half_to_wi_pdf(wo, wi, |h| b.pdf_half(h)),
            AnalyticBrdf::AshikhminShirley(b) => warp::half_to_wi_pdf(wo, wi, |h| b.pdf_half(h)),
            AnalyticBrdf::Lafortune(b) => b.pdf(wo, wi),
        }
    }
}
