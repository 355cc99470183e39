use super::*;

#[test]
fn the_texel_lobe_is_the_sum_of_its_bases() {
    let m = meso_materials::spmm::pack::read_pack(std::path::Path::new(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../materials/leather.spmm"
    )))
    .expect("the shipped leather pack");
    let (sum, parts) = texel_lobes(&m, 0, 0.6);
    assert_eq!(parts.len(), m.texel_weights(0).count());
    for (k, p) in sum.iter().enumerate() {
        let s: f64 = parts.iter().map(|b| b[k].value).sum();
        assert!((p.value - s).abs() <= 1e-12 * s.abs().max(1e-12));
    }
    assert!(sum.iter().any(|p| p.value > 0.0));
}
