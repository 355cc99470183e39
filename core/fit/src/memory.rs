//! The memory budget of `--max-memory`: its parsing (`256MB`, `4GB`, powers of 1024)
//! and what it allows. A fit holds the model (the sample's features or one cluster's
//! residual matrix while it is found, then the design and the residual tables), every
//! texel's small result, and one block of texel values; the budget sizes the block.
//! The model does not depend on the budget (the shards of a split fit must agree on
//! it), so a budget too small for the model is refused, naming what to lower.

use crate::{FitError, FitSettings};

/// `--max-memory`'s default: 2 GiB.
pub const DEFAULT_MAX_MEMORY: u64 = 2 << 30;
/// Largest block of texels read at once: more buys nothing (blocks are already far
/// larger than the threads' work items).
const MAX_BLOCK: usize = 4096;
/// What the process holds besides the fit's data (code, thread stacks, allocator slack).
const OVERHEAD: u64 = 48 << 20;

/// Parses a byte count: digits with an optional suffix B, KB, MB, GB, TB (or K, M, G,
/// T; any case; powers of 1024).
pub fn parse_bytes(text: &str) -> Result<u64, String> {
    let t = text.trim();
    let split = t.find(|c: char| !c.is_ascii_digit()).unwrap_or(t.len());
    let (digits, suffix) = t.split_at(split);
    if digits.is_empty() {
        return Err(format!(
            "`{text}` is not a byte count (digits with an optional suffix B, KB, MB, GB, TB)"
        ));
    }
    let shift = match suffix.trim().to_ascii_uppercase().as_str() {
        "" | "B" => 0,
        "K" | "KB" | "KIB" => 10,
        "M" | "MB" | "MIB" => 20,
        "G" | "GB" | "GIB" => 30,
        "T" | "TB" | "TIB" => 40,
        other => {
            return Err(format!(
                "`{text}`: unknown suffix `{other}` (B, KB, MB, GB or TB, powers of 1024)"
            ));
        }
    };
    digits
        .parse::<u64>()
        .ok()
        .and_then(|n| n.checked_mul(1u64 << shift))
        .ok_or_else(|| format!("`{text}` is more bytes than 2^64"))
}

/// Bytes of the sample stage at its largest besides its block: the sample's features,
/// or the design with one cluster's residual matrix (at most `residual_texels`
/// texels), its Gram matrix and eigenvectors.
pub(crate) fn model_bytes(settings: &FitSettings, texels: usize, pairs: usize) -> u64 {
    let sample = settings.sample_texels.min(texels) as u64;
    let features = sample * settings.feature_pairs.min(pairs) as u64 * 3 * 4;
    let n = settings.residual_texels.min(texels) as u64;
    let residual = n * pairs as u64 * 3 * 8 + 3 * n * n * 8;
    features.max(design_bytes(settings, pairs) + residual) + OVERHEAD
}

/// The design: at most `subclusters` representatives of up to 3 bases per cluster,
/// each basis at every pair.
fn design_bytes(settings: &FitSettings, pairs: usize) -> u64 {
    settings.clusters as u64 * settings.subclusters as u64 * 3 * pairs as u64 * 8
}

/// Bytes held through the texel stage whatever the block: the design, the residual
/// tables in f64 and f32, the pack being assembled and each texel's result.
pub(crate) fn fixed_bytes(settings: &FitSettings, texels: usize, pairs: usize) -> u64 {
    let d = pairs as u64 * 3;
    let k = settings.clusters as u64;
    let design = design_bytes(settings, pairs);
    let tables = k * (settings.npca as u64 + 1) * d * (8 + 4 + 4);
    let per_texel = 96 + settings.max_bases as u64 * 16 + settings.npca as u64 * (8 + 4);
    design + tables + texels as u64 * per_texel + OVERHEAD
}

/// Texels per block under `max_memory`, or a refusal naming what needs more.
pub(crate) fn block_texels(
    settings: &FitSettings,
    texels: usize,
    pairs: usize,
) -> Result<usize, FitError> {
    let budget = settings.max_memory;
    let per_texel = pairs as u64 * 3 * 4;
    let model = model_bytes(settings, texels, pairs);
    let fixed = fixed_bytes(settings, texels, pairs);
    let needed = model.max(fixed) + per_texel;
    if budget < needed {
        return Err(FitError::Memory(format!(
            "--max-memory {budget} bytes is below the {needed} this fit needs ({} MiB): the sample stage takes {} MiB (--sample-texels, --residual-texels) and the texel stage {} MiB before its blocks (--clusters, --npca, the texel count); raise --max-memory or lower those",
            needed.div_ceil(1 << 20),
            model >> 20,
            fixed >> 20
        )));
    }
    let held = model.max(fixed);
    Ok((((budget - held) / per_texel) as usize).clamp(1, MAX_BLOCK))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn byte_counts_take_binary_suffixes_and_refuse_the_rest() {
        assert_eq!(parse_bytes("256MB"), Ok(256 << 20));
        assert_eq!(parse_bytes("4GB"), Ok(4 << 30));
        assert_eq!(parse_bytes("4gb"), Ok(4 << 30));
        assert_eq!(parse_bytes("2G"), Ok(2 << 30));
        assert_eq!(parse_bytes("1TB"), Ok(1 << 40));
        assert_eq!(parse_bytes("512KiB"), Ok(512 << 10));
        assert_eq!(parse_bytes("1000"), Ok(1000));
        assert_eq!(parse_bytes("7B"), Ok(7));
        assert_eq!(parse_bytes(" 3 MB "), Ok(3 << 20));
        for bad in ["", "MB", "1.5GB", "12XB", "-4GB", "99999999999TB"] {
            let e = parse_bytes(bad).expect_err(bad);
            assert!(e.contains(&format!("`{bad}`")), "{bad}: {e}");
        }
        assert!(
            parse_bytes("12XB")
                .unwrap_err()
                .contains("unknown suffix `XB`")
        );
    }

    #[test]
    fn blocks_grow_with_the_budget_and_a_small_budget_is_refused() {
        let mut s = FitSettings::default();
        let (texels, pairs) = (128 * 128, 6561);
        s.max_memory = 256 << 20;
        let small = block_texels(&s, texels, pairs).expect("256 MiB is enough");
        s.max_memory = 1 << 30;
        let large = block_texels(&s, texels, pairs).expect("1 GiB is enough");
        assert!(
            small >= 1 && large > small && large <= MAX_BLOCK,
            "{small} {large}"
        );
        // The block and what is held besides stay within the budget.
        let per = pairs as u64 * 12;
        let held = fixed_bytes(&s, texels, pairs).max(model_bytes(&s, texels, pairs));
        assert!(held + large as u64 * per <= s.max_memory);
        s.max_memory = 64 << 20;
        let e = block_texels(&s, texels, pairs).expect_err("64 MiB is too little");
        assert!(e.to_string().contains("--max-memory 67108864 bytes"), "{e}");
    }
}
