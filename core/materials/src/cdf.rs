//! Inverting a tabulated CDF in about two steps instead of a binary search: a guide
//! table (the cutpoint method of Chen and Asau, 1974) holds, for each of m equal
//! slices of [0, 1), the interval where the slice begins, and a lookup walks from
//! there. It picks exactly the interval a binary search picks, and touches one or two
//! cache lines of the CDF where a binary search over a large table touches about
//! log2(n) of them, each likely a miss (the environment map's and the MERL sampler's
//! CDFs are megabytes: docs/performance.md, "Sampling tables").

/// Appends to `guide` the m = `entries` starts of one CDF: entry j is the interval
/// `find` returns for u = j / m. `cdf` is non-decreasing from `cdf[0]` to its last
/// value (1 for a normalised CDF), with at least two entries.
pub fn build_guide(cdf: &[f64], entries: usize, guide: &mut Vec<u32>) {
    let bins = cdf.len() - 1;
    let mut i = 0usize;
    for j in 0..entries {
        let u = j as f64 / entries as f64;
        while i + 1 < bins && cdf[i + 1] <= u {
            i += 1;
        }
        guide.push(i as u32);
    }
}

/// The interval i of `cdf` with cdf[i] <= u < cdf[i + 1] (so never one of zero width),
/// clamped to the last for u at or past the end: what `cdf[1..].partition_point(|c| c
/// <= u)` gives, found from `guide` (the `entries` starts `build_guide` made for this
/// CDF).
#[inline]
pub fn find(cdf: &[f64], guide: &[u32], u: f64) -> usize {
    let bins = cdf.len() - 1;
    let m = guide.len();
    let j = ((u * m as f64).max(0.0) as usize).min(m - 1);
    let mut i = guide[j] as usize;
    // Rounding in u * m can start one slice late: step back where needed.
    while i > 0 && cdf[i] > u {
        i -= 1;
    }
    while i + 1 < bins && cdf[i + 1] <= u {
        i += 1;
    }
    i
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::SampleStream;

    fn binary(cdf: &[f64], u: f64) -> usize {
        cdf[1..].partition_point(|&c| c <= u).min(cdf.len() - 2)
    }

    #[test]
    fn finds_what_a_binary_search_finds() {
        let rng = SampleStream::new(&[0xCDF]);
        let mut draws = 0u64;
        for case in 0..60u64 {
            // Peaked, flat and gappy tables: masses spanning 12 decades, runs of
            // empty bins (zero width) and bins at the ends, 1 to 700 bins.
            let bins = 1 + (rng.at(draws) * 700.0) as usize;
            draws += 1;
            let mut cdf = vec![0.0];
            for k in 0..bins {
                let r = rng.at(draws);
                draws += 1;
                let mass = match case % 3 {
                    0 => 10f64.powf(-12.0 * r),
                    1 => 1.0,
                    _ if r < 0.4 => 0.0,
                    _ => r,
                };
                let mass = if k == bins - 1 && cdf[k] + mass == 0.0 {
                    1.0
                } else {
                    mass
                };
                cdf.push(cdf[k] + mass);
            }
            let total = *cdf.last().expect("entries");
            cdf.iter_mut().for_each(|c| *c /= total);
            for entries in [1, 7, bins, 2 * bins] {
                let mut guide = Vec::new();
                build_guide(&cdf, entries, &mut guide);
                // Random u, every CDF value and its neighbours (the edges), 0 and 1.
                let mut us: Vec<f64> = (0..500).map(|k| rng.at(draws + k)).collect();
                for c in &cdf {
                    us.extend([*c, c.next_down(), c.next_up()]);
                }
                us.extend([0.0, 1.0, 1.0f64.next_down()]);
                for u in us.into_iter().filter(|u| (0.0..=1.0).contains(u)) {
                    assert_eq!(
                        find(&cdf, &guide, u),
                        binary(&cdf, u),
                        "{bins} bins, {entries} entries, u = {u:e}"
                    );
                }
                draws += 500;
            }
        }
    }
}
