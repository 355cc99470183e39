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

/// The lobe sampler of a `btf` table in WGSL against `BtfTable::pdf` and
/// `BtfTable::sample` (a tabulated Cook-Torrance, m 0.3, on the Bonn 81 directions):
/// pdfs within 1e-4 relative away from the lobe grid's cell edges, drawn directions
/// within 1e-3 on all but 2% (f32 rescales the first number three times, so a draw
/// next to a CDF step can land in the neighbouring cell).
#[test]
fn btf_lobe_sampling_matches_the_cpu() {
    use glam::DVec2;
    use meso_materials::btf::lobe::{RINGS, SECTORS};
    use meso_materials::btf::table::BtfTable;
    use meso_materials::rng::SampleStream;
    let dirs = meso_materials::btf::directions::bonn81();
    let brdf =
        AnalyticBrdf::new(BrdfModel::CookTorrance, &[("m", 0.3), ("f0", 0.04)]).expect("valid");
    let btf = meso_materials::btf::Btf::from_brdf(
        &brdf,
        DVec3::new(0.8, 0.5, 0.3),
        1,
        1,
        dirs.clone(),
        dirs,
    )
    .expect("valid BTF");
    let table = BtfTable::new(&btf).expect("shadeable");
    let mut words = Words::default();
    let record = words
        .push_btf(&table, glam::DVec2::ONE)
        .expect("a table held in memory");
    let pairs = direction_pairs(23, 600);
    let mut stream = SampleStream::new(&[31]);
    let us: Vec<DVec2> = pairs
        .iter()
        .map(|_| {
            DVec2::new(stream.next(), stream.next())
                .as_vec2()
                .as_dvec2()
        })
        .collect();
    let mut cases = Vec::new();
    for (&(wi, wo), &u) in pairs.iter().zip(&us) {
        let case = Case {
            kind: 12,
            record,
            wi,
            wo,
            texel: 0,
            residual: false,
        };
        cases.push(case);
        cases.push(Case {
            kind: 13,
            wi: DVec3::new(u.x, u.y, 0.0),
            ..case
        });
    }
    let got = evaluate(&words.words, &cases);
    // Distance of `wi` to the nearest edge of the lobe grid's cells, in grid units.
    let edge_distance = |wi: DVec3| {
        let ring = (1.0 - wi.z).max(0.0).sqrt() * RINGS as f64;
        let sector = wi.y.atan2(wi.x).rem_euclid(std::f64::consts::TAU) / std::f64::consts::TAU
            * SECTORS as f64;
        let off = |x: f64| (x - x.round()).abs();
        // The horizon is no edge: both clamp into the outermost ring.
        let ring_off = if ring > RINGS as f64 - 0.5 {
            1.0
        } else {
            off(ring)
        };
        ring_off.min(off(sector))
    };
    let (mut compared, mut drawn, mut dir_off) = (0, 0, 0);
    for (k, (&(wi, wo), &u)) in pairs.iter().zip(&us).enumerate() {
        let gp = got[2 * k][0] as f64;
        let cp = table.pdf(wi, wo);
        assert!(gp.is_finite() && gp >= 0.0, "pdf at {wi} {wo}: {gp}");
        if edge_distance(wi) > 1e-4 {
            compared += 1;
            assert!(
                (gp - cp).abs() <= 1e-4 * cp,
                "pdf at wi {wi} wo {wo}: gpu {gp}, f64 {cp}"
            );
        }
        let g = got[2 * k + 1];
        let g = DVec3::new(g[0] as f64, g[1] as f64, g[2] as f64);
        match table.sample(wo, u) {
            Some((c, _)) => {
                drawn += 1;
                if (g - c).abs().max_element() > 1e-3 {
                    dir_off += 1;
                }
            }
            None => assert!(g.z <= 1e-6, "only the GPU draws at wo {wo}: {g}"),
        }
    }
    eprintln!(
        "btf lobe: {compared} of {} pdfs compared, direction off on {dir_off} of {drawn}",
        pairs.len()
    );
    assert!(compared * 10 >= pairs.len() * 9, "{compared} compared");
    assert!(
        drawn * 2 > pairs.len() && dir_off * 50 <= drawn,
        "off on {dir_off}"
    );
}

/// A scene with `btf` materials (the residual panel's pack replaced by a tabulated
/// anisotropic Ward table, tiled 2 x 2, and the floor by the same table tiled 5 x 5)
/// on the GPU against the CPU: the image rule. The two materials share one table,
/// which goes up once: the device's `btf_tables` bytes are one material's plus one
/// header.
#[test]
fn a_btf_scene_on_the_gpu_agrees_with_the_cpu() {
    use meso_render::scene::Material;
    let mut scene = meso_render::scene::test_scenes::edit_test_scene();
    scene.materials[1] = meso_render::scene::test_scenes::tabulated_btf(
        &AnalyticBrdf::new(BrdfModel::Ward, &[("ax", 0.25), ("ay", 0.5)]).expect("valid"),
        DVec3::new(0.7, 0.5, 0.3),
        glam::DVec2::splat(2.0),
    );
    let Material::Btf { table, .. } = &scene.materials[1] else {
        unreachable!("a btf material")
    };
    let mut one = Words::default();
    one.push_btf(table, glam::DVec2::ONE)
        .expect("held in memory");
    scene.materials[0] = Material::Btf {
        table: std::sync::Arc::clone(table),
        uv_scale: glam::DVec2::splat(5.0),
    };
    let header = 11 * 4;
    let bytes = gpu_mode(scene.clone(), 8).device_bytes().btf_tables;
    assert_eq!(
        bytes,
        one.bytes.btf_tables + header,
        "the table uploaded once"
    );
    image_of_scene_agrees_with_the_cpu("btf panel and floor", scene, 24, 16);
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
