//! The `env` words of `shaders/environment.wgsl`: the environment map with the CPU's
//! own importance-sampling tables (`EnvironmentSampler::tables`, in f32) and the
//! background image, behind a header of offsets. What rays that leave the scene see
//! is `Params::background` (`escape`).

use std::sync::Arc;

use meso_materials::image::Image;
use meso_render::environment::EnvironmentSampler;
use meso_render::scene::{Background, Environment, Scene};

const HEADER_WORDS: usize = 24;

/// The map sampled in two parts, its peaks and its remainder, each with its own
/// sampler (`meso_render::environment::sampled_parts`).
pub(super) type MapParts = [(EnvironmentSampler, Arc<Image>); 2];

/// `params.background` of `shaders/environment.wgsl` (`ESCAPE_*`).
pub(super) fn escape(scene: &Scene) -> u32 {
    match (&scene.background, &scene.environment) {
        (Background::Color(_), _) => 1,
        (Background::Environment(_), _) => 2,
        (Background::FromEnvironment, Some(_)) => 3,
        (Background::FromEnvironment, None) => 0,
    }
}

fn f(v: f64) -> u32 {
    (v as f32).to_bits()
}

fn push_rgb(words: &mut Vec<u32>, image: &meso_materials::image::Image) -> u32 {
    let at = words.len() as u32;
    words.extend(
        image
            .pixels()
            .iter()
            .flat_map(|p| [p[0].to_bits(), p[1].to_bits(), p[2].to_bits()]),
    );
    at
}

/// How the frames sample the environment map: whole, or in two parts where it has
/// peaks and `split` asks for them (the adaptive mode's frames).
pub(super) struct MapSampling {
    pub split: bool,
    /// The whole map's sampler (`None`: no environment, a black map, or `parts`).
    pub whole: Option<EnvironmentSampler>,
    pub parts: Option<MapParts>,
}

impl MapSampling {
    pub fn new(environment: Option<&Environment>, split: bool) -> Self {
        let map = environment.map(|e| &e.map);
        let parts = map
            .filter(|_| split)
            .and_then(meso_render::environment::sampled_parts);
        Self {
            split,
            whole: map
                .filter(|_| parts.is_none())
                .and_then(|m| EnvironmentSampler::new(m)),
            parts,
        }
    }
}

/// A sampler's tables after `w`: the offsets of its row CDF, column CDFs and pdfs.
fn push_tables(w: &mut Vec<u32>, sampler: &EnvironmentSampler) -> [u32; 3] {
    let (rows, cols, pdfs) = sampler.tables();
    let rows_at = w.len() as u32;
    w.extend(rows.iter().map(|&v| f(v)));
    let cols_at = w.len() as u32;
    w.extend(cols.iter().map(|&v| f(v)));
    let pdfs_at = w.len() as u32;
    w.extend(pdfs.map(f));
    [rows_at, cols_at, pdfs_at]
}

/// The words for `scene`'s environment and background (a bare header without
/// either). With `sampling.parts`, the frames draw the map's peaks and its remainder
/// each with its own tables (`ENV_PARTS`) instead of the whole map's.
pub(super) fn words(scene: &Scene, sampling: &MapSampling) -> Vec<u32> {
    let (sampler, parts) = (sampling.whole.as_ref(), sampling.parts.as_ref());
    let mut w = vec![0u32; HEADER_WORDS];
    if let Some(env) = &scene.environment {
        let (s, c) = env.rotate_y_deg.to_radians().sin_cos();
        w[1] = env.map.width();
        w[2] = env.map.height();
        w[3] = u32::from(env.mis);
        w[4] = f(c);
        w[5] = f(s);
        match (sampler, parts) {
            (_, Some([(peaks, peak_map), (rest, rest_map)])) => {
                w[0] = 1;
                w[13] = 2;
                let at = push_tables(&mut w, peaks);
                w[6..9].copy_from_slice(&at);
                w[14] = push_rgb(&mut w, peak_map);
                let at = push_tables(&mut w, rest);
                w[16..19].copy_from_slice(&at);
                w[19] = push_rgb(&mut w, rest_map);
            }
            (Some(sampler), None) => {
                w[0] = 1;
                let at = push_tables(&mut w, sampler);
                w[6..9].copy_from_slice(&at);
            }
            (None, None) => {}
        }
        w[9] = push_rgb(&mut w, &env.map);
    }
    if let Background::Environment(image) = &scene.background {
        w[10] = image.width();
        w[11] = image.height();
        w[12] = push_rgb(&mut w, image);
    }
    w
}

/// The words `words` makes for this environment and background at most (the
/// sampling tables counted whether or not the map is black, and twice more with
/// their radiance when the map is sampled in `split` parts): checked against the
/// device's limits before anything is built.
pub(super) fn word_count(
    environment: Option<&Environment>,
    background: &Background,
    split: bool,
) -> usize {
    let mut n = HEADER_WORDS;
    if let Some(e) = environment {
        let (w, h) = (e.map.width() as usize, e.map.height() as usize);
        let tables = (h + 1) + h * (w + 1) + w * h;
        n += tables + w * h * 3;
        if split {
            n += tables + 2 * w * h * 3;
        }
    }
    if let Background::Environment(image) = background {
        n += image.width() as usize * image.height() as usize * 3;
    }
    n
}
