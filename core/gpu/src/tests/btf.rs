//! Tabulated BTF materials on the GPU: the tables in WGSL against core's, a BTF
//! scene's image against the CPU's, and what the mode accepts (BTFs, many lights).

use glam::DVec3;
use meso_materials::brdf::{AnalyticBrdf, BrdfModel};

use crate::data::Words;

use super::kernel_cases::{Case, direction_pairs, evaluate, excess};
use super::{gpu_mode, image_of_scene_agrees_with_the_cpu, test_scene};

/// `btf` tables in WGSL against `BtfTable::eval_texel` (f64 over the same values): a
/// tabulated Ward BRDF on the Bonn 81 directions held as f32, and the same with its
/// values rounded to f16 (held as f16, two to a word), on random and grazing pairs
/// (outside the sets' hull too): within 1e-4 relative plus 1e-5 of the texel's scale.
#[test]
fn btf_tables_match_the_cpu() {
    use meso_materials::btf::table::{BtfTable, Storage};
    let dirs = meso_materials::btf::directions::bonn81();
    let brdf = AnalyticBrdf::new(BrdfModel::Ward, &[("ax", 0.2), ("ay", 0.4)]).expect("valid");
    let f32_btf = meso_materials::btf::Btf::from_brdf(
        &brdf,
        DVec3::new(0.8, 0.5, 0.3),
        2,
        1,
        dirs.clone(),
        dirs.clone(),
    )
    .expect("valid BTF");
    let halves: Vec<f32> = f32_btf
        .data()
        .iter()
        .enumerate()
        .map(|(i, &v)| half::f16::from_f32(v * if i % 7 == 0 { 0.5 } else { 1.0 }).to_f32())
        .collect();
    let f16_btf = meso_materials::btf::Btf::new(
        "halves".into(),
        "test".into(),
        2,
        1,
        dirs.clone(),
        dirs,
        halves,
    )
    .expect("valid BTF");
    let tables = [
        BtfTable::new(&f32_btf).expect("shadeable"),
        BtfTable::new(&f16_btf).expect("shadeable"),
    ];
    assert_eq!(tables[0].storage(), Storage::F32);
    assert_eq!(tables[1].storage(), Storage::F16);
    let pairs = direction_pairs(21, 600);
    let mut words = Words::default();
    let mut cases = Vec::new();
    let mut reference = Vec::new();
    for table in &tables {
        let record = words
            .push_btf(table, glam::DVec2::ONE)
            .expect("a table held in memory");
        for t in 0..2u32 {
            for &(wi, wo) in &pairs {
                cases.push(Case {
                    kind: 10,
                    record,
                    wi,
                    wo,
                    texel: t,
                    residual: false,
                });
                reference.push((
                    format!("{:?} texel {t}", table.storage()),
                    wi,
                    wo,
                    table.eval_texel(t as usize, wi, wo),
                ));
            }
        }
    }
    let got = evaluate(&words.words, &cases);
    let mut worst = 0.0f64;
    for (g, (what, wi, wo, c)) in got.iter().zip(&reference) {
        for ch in 0..3 {
            assert!(g[ch].is_finite(), "{what}: {g:?}");
            let e = excess(g[ch], c[ch], 1e-4, 1e-5 * (1.0 + c.abs().max_element()));
            assert!(e <= 1.0, "{what} at wi {wi} wo {wo}: gpu {g:?}, f64 {c}");
            worst = worst.max(e);
        }
    }
    eprintln!("btf tables: worst {worst:.3} of the tolerance");
}

/// A scene with a `btf` material (the residual panel's pack replaced by a tabulated
/// anisotropic Ward table, tiled 2 x 2) on the GPU against the CPU: the image rule.
#[test]
fn a_btf_scene_on_the_gpu_agrees_with_the_cpu() {
    let mut scene = meso_render::scene::test_scenes::edit_test_scene();
    scene.materials[1] = meso_render::scene::test_scenes::tabulated_btf(
        &AnalyticBrdf::new(BrdfModel::Ward, &[("ax", 0.25), ("ay", 0.5)]).expect("valid"),
        DVec3::new(0.7, 0.5, 0.3),
        glam::DVec2::splat(2.0),
    );
    image_of_scene_agrees_with_the_cpu("btf panel", scene, 24, 16);
}

/// The mode refuses by name what it does not render yet, and an edit that brings it.
/// Nothing the CPU mode renders is refused on the GPU: BTF materials and more than
/// 16 lights are accepted, and so is an edit that brings a BTF.
#[test]
fn btf_materials_and_many_lights_are_supported() {
    use meso_render::{RenderMode, SceneEdit};
    let mut scene = test_scene("cornell.toml");
    let btf = meso_render::scene::test_scenes::tabulated_btf(
        &AnalyticBrdf::with_defaults(BrdfModel::Lambertian),
        DVec3::splat(0.5),
        glam::DVec2::ONE,
    );
    let mut with_btf = scene.clone();
    with_btf.materials[0] = btf.clone();
    crate::GpuSpmmMode::supports(&with_btf).expect("a BTF material");
    let light = scene.lights[0];
    scene.lights = vec![light; 17];
    crate::GpuSpmmMode::supports(&scene).expect("17 lights");
    let mut gpu = gpu_mode(scene, 8);
    gpu.apply(SceneEdit::Material {
        index: 0,
        material: btf,
    })
    .expect("a BTF edit");
    assert!(matches!(
        gpu.scene().materials[0],
        meso_render::scene::Material::Btf { .. }
    ));
    assert!(gpu.device_bytes().btf_tables > 0);
    // A table no mesh carries goes up not at all.
    let mut bare = gpu.scene().clone();
    bare.meshes.retain(|m| m.material != 0);
    assert_eq!(gpu_mode(bare, 8).device_bytes().btf_tables, 0);
}

/// A BTF held out of core (larger than its memory bound) is refused by name, before
/// any device is asked for, and so is an edit that brings one: uploading it would hold
/// it whole. Held whole, it goes.
#[test]
fn a_btf_read_out_of_core_is_refused_naming_the_material() {
    use meso_materials::btf::file::{BtfPrecision, write_btf};
    use meso_materials::btf::table::{BtfTable, MemoryBound};
    let dirs = meso_materials::btf::directions::rings(&[(0.0, 1), (45.0, 4)]);
    let btf = meso_materials::btf::Btf::from_brdf(
        &AnalyticBrdf::with_defaults(BrdfModel::Lambertian),
        DVec3::splat(0.5),
        8,
        8,
        dirs.clone(),
        dirs,
    )
    .expect("valid BTF");
    let dir = tempfile::tempdir().expect("temp dir");
    let path = dir.path().join("l.btf");
    write_btf(&path, &btf, BtfPrecision::F32).expect("write");
    let texel = (btf.pairs() * 3 * 4) as u64;
    let tight = MemoryBound {
        max_bytes: 8 * texel,
        block_bytes: texel,
        threads: 1,
    };
    let mut scene = test_scene("cornell.toml");
    let material = |bound| meso_render::scene::Material::Btf {
        table: std::sync::Arc::new(BtfTable::open(&path, bound).expect("opens")),
        uv_scale: glam::DVec2::ONE,
    };
    scene.materials[0] = material(tight);
    let e = crate::GpuSpmmMode::supports(&scene)
        .expect_err("out of core")
        .to_string();
    let name = scene.material_name(0);
    assert!(e.contains(&name) && e.contains("--max-memory"), "{e}");
    scene.materials[0] = material(MemoryBound::default());
    crate::GpuSpmmMode::supports(&scene).expect("held whole");
    // An edit that brings it to a running mode is refused the same way.
    use meso_render::{RenderMode, SceneEdit};
    let mut gpu = gpu_mode(scene, 8);
    let e = gpu
        .apply(SceneEdit::Material {
            index: 0,
            material: material(tight),
        })
        .expect_err("out of core")
        .to_string();
    assert!(e.contains(&name) && e.contains("--max-memory"), "{e}");
}
