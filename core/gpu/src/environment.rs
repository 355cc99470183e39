//! The `env` words of `shaders/environment.wgsl`: the environment map with the CPU's
//! own importance-sampling tables (`EnvironmentSampler::tables`, in f32) and the
//! background image, behind a header of offsets. What rays that leave the scene see
//! is `Params::background` (`escape`).

use meso_render::environment::EnvironmentSampler;
use meso_render::scene::{Background, Environment, Scene};

const HEADER_WORDS: usize = 16;

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

/// The words for `scene`'s environment and background (a bare header without
/// either). `sampler` is the environment map's (`None`: no environment, or black).
pub(super) fn words(scene: &Scene, sampler: Option<&EnvironmentSampler>) -> Vec<u32> {
    let mut w = vec![0u32; HEADER_WORDS];
    if let Some(env) = &scene.environment {
        let (s, c) = env.rotate_y_deg.to_radians().sin_cos();
        w[1] = env.map.width();
        w[2] = env.map.height();
        w[3] = u32::from(env.mis);
        w[4] = f(c);
        w[5] = f(s);
        if let Some(sampler) = sampler {
            let (rows, cols, pdfs) = sampler.tables();
            w[0] = 1;
            w[6] = w.len() as u32;
            w.extend(rows.iter().map(|&v| f(v)));
            w[7] = w.len() as u32;
            w.extend(cols.iter().map(|&v| f(v)));
            w[8] = w.len() as u32;
            w.extend(pdfs.map(f));
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
/// sampling tables counted whether or not the map is black): checked against the
/// device's limits before anything is built.
pub(super) fn word_count(environment: Option<&Environment>, background: &Background) -> usize {
    let mut n = HEADER_WORDS;
    if let Some(e) = environment {
        let (w, h) = (e.map.width() as usize, e.map.height() as usize);
        n += (h + 1) + h * (w + 1) + w * h * 4;
    }
    if let Background::Environment(image) = background {
        n += image.width() as usize * image.height() as usize * 3;
    }
    n
}
