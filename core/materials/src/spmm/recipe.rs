//! Authoring an SPMM material without measured data (`meso pack new`): a TOML recipe
//! names the clusters, each with its dictionary of basis functions (model, parameters,
//! normal) and per-basis RGB weight maps (constants or images over the texel grid),
//! plus a cluster map image. The residual is empty. Format: docs/formats/spmm.md.

use std::path::{Path, PathBuf};

use glam::DVec3;
use serde::Deserialize;

use super::{Cluster, SparseWeights, SpmmError, SpmmMaterial};
use crate::brdf::{AnalyticBrdf, BasisFunction, BrdfError, BrdfModel};
use crate::image::{self, Image, ImageError};

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RecipeFile {
    version: u32,
    name: String,
    width: u32,
    height: u32,
    /// Grey image over the texel grid: 8-bit value k (0..255) puts a texel in cluster k.
    cluster_map: Option<PathBuf>,
    #[serde(rename = "cluster")]
    clusters: Vec<ClusterRecipe>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct ClusterRecipe {
    #[serde(default)]
    name: String,
    #[serde(rename = "basis")]
    bases: Vec<BasisRecipe>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct BasisRecipe {
    model: String,
    #[serde(default)]
    params: toml::Table,
    /// Unit normal in the tangent frame; default (0, 0, 1).
    normal: Option<[f64; 3]>,
    /// Constant RGB weight, or the scale applied to `weight_map`.
    weight: Option<[f32; 3]>,
    /// RGB image over the texel grid (PNG: sRGB-decoded to linear; EXR: as stored).
    weight_map: Option<PathBuf>,
}

#[derive(Debug, thiserror::Error)]
#[error("`{}`: {kind}", path.display())]
pub struct RecipeError {
    pub path: PathBuf,
    /// Boxed: errors are rare and the kinds carry paths and messages.
    pub kind: Box<RecipeErrorKind>,
}

#[derive(Debug, thiserror::Error)]
pub enum RecipeErrorKind {
    #[error("cannot read: {0}")]
    Io(#[from] std::io::Error),
    #[error("{0}")]
    Toml(String),
    #[error("version {0}: this build reads recipe version 1")]
    Version(u32),
    #[error("cluster {cluster} ({name}) basis {basis}: {source}")]
    Basis {
        cluster: usize,
        name: String,
        basis: usize,
        source: BrdfError,
    },
    #[error("cluster {cluster} basis {basis}: parameter `{param}` is not a number")]
    ParamType {
        cluster: usize,
        basis: usize,
        param: String,
    },
    #[error("cluster {cluster} basis {basis}: give `weight`, `weight_map` or both (scale and map)")]
    NoWeight { cluster: usize, basis: usize },
    #[error("{what} `{}`: {source}", path.display())]
    Image {
        what: &'static str,
        path: PathBuf,
        source: ImageError,
    },
    #[error("{what} `{}` is {found_w}x{found_h}, the texel grid is {width}x{height}", path.display())]
    ImageSize {
        what: &'static str,
        path: PathBuf,
        found_w: u32,
        found_h: u32,
        width: u32,
        height: u32,
    },
    #[error(
        "cluster_map: texel ({x}, {y}) has value {value}, but only {clusters} cluster(s) are defined"
    )]
    ClusterValue {
        x: u32,
        y: u32,
        value: u32,
        clusters: usize,
    },
    #[error("{0}")]
    Material(#[from] SpmmError),
}

/// Reads a recipe and builds the material it describes; image paths are relative to
/// the recipe's folder.
pub fn build_from_recipe(path: &Path) -> Result<SpmmMaterial, RecipeError> {
    let at = |kind: RecipeErrorKind| RecipeError {
        path: path.to_path_buf(),
        kind: Box::new(kind),
    };
    let text = std::fs::read_to_string(path).map_err(|e| at(e.into()))?;
    // toml's message carries the line, column and key at fault.
    let recipe: RecipeFile =
        toml::from_str(&text).map_err(|e| at(RecipeErrorKind::Toml(e.to_string())))?;
    let folder = path.parent().unwrap_or(Path::new("."));
    // Provenance names the recipe by its folder and file name only, so the same recipe
    // builds the same bytes wherever it is checked out.
    let tail: Vec<String> = path
        .iter()
        .rev()
        .take(2)
        .map(|c| c.to_string_lossy().into_owned())
        .collect();
    let source: Vec<&str> = tail.iter().rev().map(String::as_str).collect();
    build(&recipe, folder, &source.join("/")).map_err(at)
}

fn load(
    what: &'static str,
    folder: &Path,
    rel: &Path,
    width: u32,
    height: u32,
) -> Result<Image, RecipeErrorKind> {
    let path = folder.join(rel);
    let img = image::read_image(&path).map_err(|source| RecipeErrorKind::Image {
        what,
        path: path.clone(),
        source,
    })?;
    if img.width() != width || img.height() != height {
        return Err(RecipeErrorKind::ImageSize {
            what,
            path,
            found_w: img.width(),
            found_h: img.height(),
            width,
            height,
        });
    }
    Ok(img)
}

fn build(
    recipe: &RecipeFile,
    folder: &Path,
    source: &str,
) -> Result<SpmmMaterial, RecipeErrorKind> {
    if recipe.version != 1 {
        return Err(RecipeErrorKind::Version(recipe.version));
    }
    let (w, h) = (recipe.width, recipe.height);
    if !(1..=16384).contains(&w) || !(1..=16384).contains(&h) {
        return Err(SpmmError::GridSize {
            width: w,
            height: h,
        }
        .into());
    }
    let texels = w as usize * h as usize;
    let texel_cluster: Vec<u32> = match &recipe.cluster_map {
        None => vec![0; texels],
        Some(rel) => {
            let img = load("cluster_map", folder, rel, w, h)?;
            let mut ids = Vec::with_capacity(texels);
            for (i, p) in img.pixels().iter().enumerate() {
                // The map is an index image: undo the sRGB decoding of an 8-bit PNG.
                let value = (image::srgb_encode(p[0]) * 255.0).round() as u32;
                if value as usize >= recipe.clusters.len() {
                    let (x, y) = ((i % w as usize) as u32, (i / w as usize) as u32);
                    return Err(RecipeErrorKind::ClusterValue {
                        x,
                        y,
                        value,
                        clusters: recipe.clusters.len(),
                    });
                }
                ids.push(value);
            }
            ids
        }
    };
    let mut clusters = Vec::with_capacity(recipe.clusters.len());
    // Per cluster and basis: the RGB weight of every texel (applied only to the
    // cluster's own texels).
    let mut weight_fields: Vec<Vec<Vec<[f32; 3]>>> = Vec::new();
    for (ci, c) in recipe.clusters.iter().enumerate() {
        let mut bases = Vec::new();
        let mut fields = Vec::new();
        for (bi, b) in c.bases.iter().enumerate() {
            let basis_err = |source| RecipeErrorKind::Basis {
                cluster: ci,
                name: c.name.clone(),
                basis: bi,
                source,
            };
            let model = BrdfModel::from_name(&b.model).map_err(basis_err)?;
            let mut params = Vec::new();
            for (k, v) in &b.params {
                let value = v
                    .as_float()
                    .or_else(|| v.as_integer().map(|i| i as f64))
                    .ok_or_else(|| RecipeErrorKind::ParamType {
                        cluster: ci,
                        basis: bi,
                        param: k.clone(),
                    })?;
                params.push((k.as_str(), value));
            }
            let brdf = AnalyticBrdf::new(model, &params).map_err(basis_err)?;
            let normal = b.normal.map_or(DVec3::Z, DVec3::from_array);
            bases.push(BasisFunction::new(brdf, normal).map_err(basis_err)?);
            let scale = b.weight.unwrap_or([1.0; 3]);
            let field: Vec<[f32; 3]> = match (&b.weight_map, b.weight) {
                (Some(rel), _) => {
                    let img = load("weight_map", folder, rel, w, h)?;
                    img.pixels()
                        .iter()
                        .map(|p| [p[0] * scale[0], p[1] * scale[1], p[2] * scale[2]])
                        .collect()
                }
                (None, Some(weight)) => vec![weight; texels],
                (None, None) => {
                    return Err(RecipeErrorKind::NoWeight {
                        cluster: ci,
                        basis: bi,
                    });
                }
            };
            fields.push(field);
        }
        clusters.push(Cluster { bases });
        weight_fields.push(fields);
    }
    let mut weights = SparseWeights {
        offsets: vec![0],
        ..Default::default()
    };
    for (t, &c) in texel_cluster.iter().enumerate() {
        for (j, field) in weight_fields
            .get(c as usize)
            .into_iter()
            .flatten()
            .enumerate()
        {
            let rgb = field[t];
            // Sparse: a basis that contributes nothing to this texel is not stored.
            if rgb != [0.0; 3] {
                weights.basis.push(j as u16);
                weights.rgb.push(rgb);
            }
        }
        weights.offsets.push(weights.basis.len() as u32);
    }
    Ok(SpmmMaterial::new(
        recipe.name.clone(),
        format!("meso pack new from recipe {source}"),
        w,
        h,
        clusters,
        texel_cluster,
        weights,
        None,
    )?)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::image::{srgb_decode, write_png};

    fn write(dir: &Path, name: &str, text: &str) -> PathBuf {
        let p = dir.join(name);
        std::fs::write(&p, text).expect("write recipe");
        p
    }

    /// A 4x2 index image: the left half cluster 0, the right half cluster 1.
    fn cluster_map(dir: &Path) {
        let mut img = Image::new(4, 2);
        for y in 0..2 {
            for x in 0..4 {
                let k = if x < 2 { 0.0 } else { 1.0 };
                img.set(x, y, [srgb_decode(k / 255.0); 3]);
            }
        }
        write_png(&dir.join("clusters.png"), &img, 0.0).expect("png");
        let mut w = Image::new(4, 2);
        for (i, p) in w.pixels_mut().iter_mut().enumerate() {
            // Texel 5 gets weight 0: it must not be stored.
            *p = if i == 5 { [0.0; 3] } else { [0.5; 3] };
        }
        write_png(&dir.join("w.png"), &w, 0.0).expect("png");
    }

    const GOOD: &str = r#"
version = 1
name = "test"
width = 4
height = 2
cluster_map = "clusters.png"
[[cluster]]
name = "a"
[[cluster.basis]]
model = "lambertian"
weight = [0.5, 0.25, 0.125]
[[cluster]]
name = "b"
[[cluster.basis]]
model = "ward"
params = { ax = 0.2, ay = 0.1 }
normal = [0.0, 0.6, 0.8]
weight = [2.0, 2.0, 2.0]
weight_map = "w.png"
"#;

    #[test]
    fn builds_clusters_dictionaries_and_sparse_weights() {
        let dir = tempfile::tempdir().expect("temp dir");
        cluster_map(dir.path());
        let m = build_from_recipe(&write(dir.path(), "r.toml", GOOD)).expect("valid recipe");
        assert_eq!(m.texel_cluster(), &[0, 0, 1, 1, 0, 0, 1, 1]);
        assert_eq!(
            m.clusters()[1].bases[0].brdf().param_values(),
            vec![0.2, 0.1]
        );
        assert_eq!(m.clusters()[1].bases[0].normal(), DVec3::new(0.0, 0.6, 0.8));
        assert_eq!(
            m.texel_weights(0).collect::<Vec<_>>(),
            vec![(0, [0.5, 0.25, 0.125])]
        );
        // Map value 0.5 (linear; 8-bit sRGB in the file, so within its quantisation)
        // times the scale 2: weight 1.
        let (b, w) = m.texel_weights(2).next().expect("one weight");
        assert_eq!(b, 0);
        assert!(w.iter().all(|c| (c - 1.0).abs() < 1e-2), "{w:?}");
        assert_eq!(
            m.texel_weights(5).count(),
            1,
            "texel 5 is cluster 0: the constant weight"
        );
        assert_eq!(m.texel_weights(6).count(), 1);
        assert!(m.residual().is_none());
        assert!(m.provenance().contains("r.toml"));
    }

    #[test]
    fn zero_weights_are_not_stored() {
        let dir = tempfile::tempdir().expect("temp dir");
        cluster_map(dir.path());
        let text = GOOD.replace("cluster_map = \"clusters.png\"", "").replace(
            "[[cluster]]\nname = \"b\"",
            "[[cluster.basis]]\nmodel = \"lambertian\"\nweight_map = \"w.png\"\n[[cluster]]\nname = \"b\"",
        );
        let m = build_from_recipe(&write(dir.path(), "r.toml", &text)).expect("valid recipe");
        // All texels in cluster 0 with two bases, but texel 5's map weight is 0.
        assert_eq!(m.texel_weights(4).count(), 2);
        assert_eq!(m.texel_weights(5).count(), 1);
    }

    #[test]
    fn errors_name_the_recipe_and_the_fault() {
        let dir = tempfile::tempdir().expect("temp dir");
        cluster_map(dir.path());
        let cases: Vec<(String, &[&str])> = vec![
            (GOOD.replace("version = 1", "version = 2"), &["version 2"]),
            (GOOD.replace("width = 4", "widht = 4"), &["widht", "line"]),
            (
                GOOD.replace("ax = 0.2", "ax = 3.0"),
                &["cluster 1", "ax", "3"],
            ),
            (
                GOOD.replace("model = \"ward\"", "model = \"warp\""),
                &["cluster 1", "warp"],
            ),
            (
                GOOD.replace("normal = [0.0, 0.6, 0.8]", "normal = [0.0, 0.0, -1.0]"),
                &["cluster 1", "normal"],
            ),
            (
                GOOD.replace("width = 4", "width = 5"),
                &["clusters.png", "4x2", "5x2"],
            ),
            (
                GOOD.replace("\"w.png\"", "\"missing.png\""),
                &["missing.png"],
            ),
            (
                GOOD.replace("weight = [0.5, 0.25, 0.125]\n", ""),
                &["cluster 0 basis 0", "weight"],
            ),
            (
                GOOD.replace("ax = 0.2", "ax = \"rough\""),
                &["ax", "not a number"],
            ),
        ];
        for (i, (text, needles)) in cases.iter().enumerate() {
            let err = build_from_recipe(&write(dir.path(), "bad.toml", text))
                .expect_err("must fail")
                .to_string();
            assert!(err.contains("bad.toml"), "case {i}: {err}");
            for n in *needles {
                assert!(err.contains(n), "case {i}: `{n}` missing from: {err}");
            }
        }
        // A cluster map value without a cluster.
        let one_cluster = GOOD
            .split("[[cluster]]\nname = \"b\"")
            .next()
            .expect("prefix")
            .to_string();
        let err = build_from_recipe(&write(dir.path(), "bad.toml", &one_cluster))
            .expect_err("value 1 has no cluster");
        assert!(
            err.to_string().contains("texel (2, 0) has value 1"),
            "{err}"
        );
    }
}
