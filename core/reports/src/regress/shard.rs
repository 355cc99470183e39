//! Shards for more than one machine: `K/N` selects the cases whose name hashes to
//! `K - 1` modulo `N` (FNV-1a, 64 bits, of the name's bytes). A case's shard depends on
//! its own name and `N` only: adding or removing a case moves no other, and every
//! case is in exactly one of the `N` shards.

use std::fmt;

/// One of `count` shards, `index` in `1..=count` (what a job matrix or a Slurm array
/// numbered from 1 passes).
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct Shard {
    pub index: u32,
    pub count: u32,
}

/// The most shards a run may be split into.
pub const MAX_SHARDS: u32 = 10_000;

impl Shard {
    /// Parses `K/N` with `1 <= K <= N <= MAX_SHARDS`.
    pub fn parse(text: &str) -> Result<Shard, String> {
        let bad = || format!("`{text}`: a shard is K/N with 1 <= K <= N <= {MAX_SHARDS}");
        let (k, n) = text.split_once('/').ok_or_else(bad)?;
        let index: u32 = k.trim().parse().map_err(|_| bad())?;
        let count: u32 = n.trim().parse().map_err(|_| bad())?;
        if !(1..=MAX_SHARDS).contains(&count) || !(1..=count).contains(&index) {
            return Err(bad());
        }
        Ok(Shard { index, count })
    }

    /// True if the case named `name` belongs to this shard.
    pub fn contains(&self, name: &str) -> bool {
        shard_of(name, self.count) == self.index
    }
}

impl fmt::Display for Shard {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}/{}", self.index, self.count)
    }
}

/// The shard (1-based) of `name` among `count`.
pub fn shard_of(name: &str, count: u32) -> u32 {
    (fnv1a64(name.as_bytes()) % u64::from(count.max(1))) as u32 + 1
}

pub use meso_materials::hash::fnv1a64;

#[cfg(test)]
mod tests {
    use super::*;

    fn names(n: usize) -> Vec<String> {
        (0..n)
            .map(|i| format!("scene{}.pack{}.spmm-cpu", i % 7, i / 7))
            .collect()
    }

    #[test]
    fn shards_partition_the_cases_for_every_count_up_to_seven() {
        let cases = names(200);
        for count in 1..=7 {
            let mut seen = vec![0u32; cases.len()];
            let mut sizes = Vec::new();
            for index in 1..=count {
                let shard = Shard { index, count };
                let mine = cases.iter().filter(|c| shard.contains(c)).count();
                sizes.push(mine);
                for (i, c) in cases.iter().enumerate() {
                    seen[i] += u32::from(shard.contains(c));
                }
            }
            assert!(seen.iter().all(|&s| s == 1), "N = {count}: {seen:?}");
            // A hash split is only roughly even; each shard gets a share.
            assert!(sizes.iter().all(|&s| s > 0), "N = {count}: {sizes:?}");
        }
    }

    #[test]
    fn shard_syntax_is_checked() {
        assert_eq!(Shard::parse("2/4"), Ok(Shard { index: 2, count: 4 }));
        assert_eq!(Shard::parse("1/1"), Ok(Shard { index: 1, count: 1 }));
        for bad in ["0/4", "5/4", "1/0", "a/2", "2", "1/2/3", "-1/2", "1/10001"] {
            let e = Shard::parse(bad).expect_err(bad);
            assert!(e.contains(bad) && e.contains("K/N"), "{e}");
        }
    }
}
