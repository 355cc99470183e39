//! Materials built in code for tests, here and in the crates above (feature
//! `testing`).

use glam::DVec3;

use super::*;
use crate::brdf::{AnalyticBrdf, BasisFunction, BrdfModel};
use crate::rng::SampleStream;

/// A small but complete material: `clusters` clusters of mixed models, 1-4 weights
/// per texel, and (optionally) a residual on 5 x 4 directions with `npca` terms.
pub fn sample_material(w: u32, h: u32, clusters: usize, residual: Option<usize>) -> SpmmMaterial {
    let models = [
        AnalyticBrdf::with_defaults(BrdfModel::Lambertian),
        AnalyticBrdf::new(BrdfModel::Ward, &[("ax", 0.1), ("ay", 0.3)]).expect("valid"),
        AnalyticBrdf::new(
            BrdfModel::AshikhminShirley,
            &[("nu", 300.0), ("nv", 20.0), ("rs", 0.4)],
        )
        .expect("valid"),
        AnalyticBrdf::new(
            BrdfModel::Lafortune,
            &[("cx", -1.0), ("cy", -0.7), ("cz", 0.9), ("n", 12.0)],
        )
        .expect("valid"),
        AnalyticBrdf::new(BrdfModel::OrenNayar, &[("sigma", 0.6)]).expect("valid"),
    ];
    let clusters: Vec<Cluster> = (0..clusters)
        .map(|c| Cluster {
            bases: (0..3 + c % 3)
                .map(|j| {
                    let n = DVec3::new(0.05 * j as f64, -0.03 * c as f64, 1.0).normalize();
                    BasisFunction::new(models[(c + j) % models.len()], n).expect("unit normal")
                })
                .collect(),
        })
        .collect();
    let texels = (w * h) as usize;
    let texel_cluster: Vec<u32> = (0..texels)
        .map(|t| (t * 7 % clusters.len()) as u32)
        .collect();
    let mut weights = SparseWeights {
        offsets: vec![0],
        ..Default::default()
    };
    for (t, &c) in texel_cluster.iter().enumerate() {
        let dict = clusters[c as usize].bases.len();
        for j in 0..(1 + t % 4).min(dict) {
            weights.basis.push(((j + t) % dict) as u16);
            let u = SampleStream::new(&[3, t as u64, j as u64]);
            weights
                .rgb
                .push([u.at(0) as f32, u.at(1) as f32 * 0.5, u.at(2) as f32 * 0.25]);
        }
        weights.offsets.push(weights.basis.len() as u32);
    }
    let residual = residual.map(|npca| {
        let light_dirs: Vec<DVec3> = (0..5)
            .map(|i| crate::brdf::warp::spherical(0.3 + 0.15 * i as f64, i as f64))
            .collect();
        let view_dirs: Vec<DVec3> = (0..4)
            .map(|i| crate::brdf::warp::spherical(0.4 + 0.2 * i as f64, 2.0 * i as f64))
            .collect();
        let table = light_dirs.len() * view_dirs.len() * 3;
        let noise = |n: usize, key: u64| -> Vec<f32> {
            (0..n)
                .map(|i| (SampleStream::new(&[key, i as u64]).at(0) - 0.5) as f32 * 0.1)
                .collect()
        };
        Residual {
            light_dirs,
            view_dirs,
            npca,
            mean: noise(clusters.len() * table, 1),
            components: noise(clusters.len() * npca * table, 2),
            coefficients: noise(texels * npca, 3),
        }
    });
    SpmmMaterial::new(
        "sample".into(),
        "unit test".into(),
        w,
        h,
        clusters,
        texel_cluster,
        weights,
        residual,
    )
    .expect("the sample material is valid")
}
