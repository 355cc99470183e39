//! The scene's materials and lights as the device reads them: the data words of
//! `shaders/` (material records, the light table with room to grow, the prepared
//! packs of the clusters the scene's UVs reach) and which materials the moving flag
//! changes.

use super::*;

pub(super) const MATERIAL_WORDS: usize = 8;
/// Words of one light record (`shaders/lights.wgsl`).
pub(super) const LIGHT_WORDS: usize = 24;

/// The scene's materials and lights as data words, with where their tables start.
pub(super) struct SceneData {
    pub(super) words: Words,
    pub(super) material_table: u32,
    /// The light table, last in `words`, with room for `light_capacity` lights.
    pub(super) light_table: u32,
    pub(super) light_capacity: usize,
    /// Per material: the moving flag changes it (an SPMM residual in use with more
    /// components than a moving camera keeps, `MOVING_NPCA`).
    pub(super) moving_changes: Vec<bool>,
    /// Per SPMM material, the clusters uploaded (`reach::reachable_clusters`).
    pub(super) reach: Reach,
}

fn f(v: f64) -> u32 {
    (v as f32).to_bits()
}

/// The light table of `shaders/lights.wgsl`, one record per light: kind, position or
/// corner, edges; the film layer its samples go to and the factor they are multiplied
/// by (`Layers::light_targets`: one, or its emission in a bounded film's shared layer);
/// and above `MANY_LIGHTS` the CPU's selection table (`LightSelection`: alias bin,
/// pmf, 1 / area, the resampling weight's scale, the emitting normal).
pub(super) fn light_table(scene: &Scene, layers: &Layers) -> Vec<u32> {
    let targets = layers.light_targets(scene);
    let selection = LightSampling::Auto
        .stochastic(scene.lights.len())
        .then(|| LightSelection::new(&scene.lights))
        .flatten();
    // The scale only matters relative to the other lights' (it cancels in the
    // estimate): divided by the largest, so f32 holds it whatever the emissions.
    let max_scale = selection.as_ref().map_or(1.0, |sel| {
        sel.lights.iter().map(|l| l.w_scale).fold(0.0, f64::max)
    });
    let mut table = vec![0u32; scene.lights.len() * LIGHT_WORDS];
    for (k, (light, rec)) in scene
        .lights
        .iter()
        .zip(table.chunks_exact_mut(LIGHT_WORDS))
        .enumerate()
    {
        let (kind, a, b, c) = match *light {
            Light::Point { position, .. } => (0, position, DVec3::ZERO, DVec3::ZERO),
            Light::Area {
                corner,
                edge_u,
                edge_v,
                ..
            } => (1, corner, edge_u, edge_v),
        };
        rec[0] = kind;
        for (i, v) in [a, b, c].iter().enumerate() {
            rec[1 + 3 * i..4 + 3 * i].copy_from_slice(&[f(v.x), f(v.y), f(v.z)]);
        }
        rec[10] = targets[k].layer as u32;
        let factor = targets[k].factor.min(DVec3::splat(f64::from(f32::MAX)));
        rec[11..14].copy_from_slice(&[f(factor.x), f(factor.y), f(factor.z)]);
        if let Some(sel) = &selection {
            let (keep, alias) = sel.table.bins()[k];
            let l = &sel.lights[k];
            rec[14] = f(keep);
            rec[15] = alias;
            rec[16] = f(sel.table.pmf()[k]);
            rec[17] = f(l.inv_area);
            rec[18] = f(l.w_scale / max_scale);
            rec[19..22].copy_from_slice(&[f(l.normal.x), f(l.normal.y), f(l.normal.z)]);
        }
    }
    table
}

/// Room for the light table: at least `MANY_LIGHTS`, and a power of two above, so
/// light edits rewrite it in place and an added light seldom re-uploads the data.
pub(super) fn light_capacity(lights: usize) -> usize {
    lights.max(MANY_LIGHTS).next_power_of_two()
}

impl SceneData {
    /// Every material (SPMM packs prepared as the CPU mode prepares them, only the
    /// clusters the scene can reach unless `all_clusters`; a pack no mesh carries not
    /// at all) and the light table (`light_table`) with room to grow, so light edits
    /// rewrite it in place.
    pub(super) fn build(scene: &Scene, layers: &Layers, all_clusters: bool) -> Self {
        let reach = if all_clusters {
            scene
                .materials
                .iter()
                .map(|m| match m {
                    Material::Spmm { material, .. } => Some(vec![true; material.clusters().len()]),
                    Material::Btf { .. } => Some(vec![true]),
                    _ => None,
                })
                .collect()
        } else {
            reachable_clusters(scene)
        };
        let mut words = Words::default();
        let mut table = Vec::with_capacity(scene.materials.len() * MATERIAL_WORDS);
        let mut moving_changes = Vec::with_capacity(scene.materials.len());
        let mut merl: Vec<(*const meso_materials::merl::MerlBrdf, u32)> = Vec::new();
        let mut btf: Vec<(*const meso_materials::btf::table::BtfTable, BtfWords)> = Vec::new();
        for (i, m) in scene.materials.iter().enumerate() {
            let mut rec = [0u32; MATERIAL_WORDS];
            let mut changes_when_moving = false;
            match m {
                Material::Brdf { brdf, albedo } => {
                    rec[0] = 0;
                    rec[1] = words.push_brdf(brdf);
                    rec[4..7].copy_from_slice(&[f(albedo.x), f(albedo.y), f(albedo.z)]);
                }
                Material::Spmm {
                    material,
                    uv_scale,
                    residual: wanted,
                    npca,
                } => {
                    let used = reach[i].clone().unwrap_or_default();
                    if !used.contains(&true) {
                        // No ray can shade it: nothing uploaded, a record of no kind.
                        rec[0] = u32::MAX;
                        table.extend_from_slice(&rec);
                        moving_changes.push(false);
                        continue;
                    }
                    let prepared = material.prepare(&PrepareRequest {
                        used_clusters: Some(used.clone()),
                        residual: *wanted,
                        max_npca: *npca,
                    });
                    let uses_residual = *wanted && prepared.has_residual();
                    changes_when_moving = uses_residual
                        && prepared.prepared_npca() > meso_materials::spmm::MOVING_NPCA;
                    rec[0] = 1;
                    rec[1] = words.push_spmm(&prepared, *uv_scale, Some(&used));
                    rec[2] = u32::from(uses_residual);
                }
                Material::Mirror { reflectance } => {
                    rec[0] = 2;
                    rec[4..7].copy_from_slice(&[
                        f(reflectance.x),
                        f(reflectance.y),
                        f(reflectance.z),
                    ]);
                }
                Material::Merl { brdf, tint } => {
                    rec[0] = 3;
                    // A table shared by several materials goes up once.
                    let key = std::sync::Arc::as_ptr(brdf);
                    rec[1] = match merl.iter().find(|(k, _)| *k == key) {
                        Some(&(_, at)) => at,
                        None => {
                            let at = words.push_merl(brdf);
                            merl.push((key, at));
                            at
                        }
                    };
                    rec[4..7].copy_from_slice(&[f(tint.x), f(tint.y), f(tint.z)]);
                }
                Material::Btf { table, uv_scale } => {
                    // Uploaded where a mesh carries it and its values are in memory
                    // (`supports` refuses an out-of-core table before this); else
                    // nothing is uploaded: a record of no kind.
                    let reached = reach[i].as_ref().is_some_and(|r| r.contains(&true));
                    // A table shared by several materials goes up once; each has its
                    // own header (its tiling).
                    let key = std::sync::Arc::as_ptr(table);
                    let shared = match btf.iter().find(|(k, _)| *k == key) {
                        Some(&(_, w)) => Some(w),
                        None if reached => words.push_btf_table(table).inspect(|&w| {
                            btf.push((key, w));
                        }),
                        None => None,
                    };
                    let header = reached.then_some(shared).flatten();
                    match header.map(|w| words.push_btf_header(table, w, *uv_scale)) {
                        Some(at) => {
                            rec[0] = 4;
                            rec[1] = at;
                        }
                        None => rec[0] = u32::MAX,
                    }
                }
            }
            table.extend_from_slice(&rec);
            moving_changes.push(changes_when_moving);
        }
        let before = words.words.len();
        let material_table = words.at();
        words.words.extend_from_slice(&table);
        let light_table = words.at();
        let light_capacity = light_capacity(scene.lights.len());
        let lights = self::light_table(scene, layers);
        words.words.extend_from_slice(&lights);
        words
            .words
            .resize(light_table as usize + light_capacity * LIGHT_WORDS, 0);
        // BRDF records sit among the SPMM data; count the tables as materials.
        words.bytes.materials += 4 * (words.words.len() - before) as u64;
        Self {
            words,
            material_table,
            light_table,
            light_capacity,
            moving_changes,
            reach,
        }
    }
}
