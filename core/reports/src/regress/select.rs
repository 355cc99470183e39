//! Which cases a run renders: `--only PATTERN` (globs over case names, `*` any run of
//! characters, `?` one character, alternatives separated by commas) and `--shard K/N`.

use super::case::Case;
use super::shard::Shard;

/// Comma-separated globs; a name matches if any glob matches it whole.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Pattern {
    globs: Vec<String>,
}

impl Pattern {
    pub fn parse(text: &str) -> Result<Pattern, String> {
        let globs: Vec<String> = text
            .split(',')
            .map(|g| g.trim().to_string())
            .filter(|g| !g.is_empty())
            .collect();
        if globs.is_empty() {
            return Err(format!("`{text}` holds no pattern"));
        }
        Ok(Pattern { globs })
    }

    pub fn matches(&self, name: &str) -> bool {
        self.globs
            .iter()
            .any(|g| glob(g.as_bytes(), name.as_bytes()))
    }
}

impl std::fmt::Display for Pattern {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}", self.globs.join(","))
    }
}

/// Whole-string glob match with `*` and `?`, iterative with one backtrack point (linear
/// in practice, never exponential).
fn glob(pattern: &[u8], text: &[u8]) -> bool {
    let (mut p, mut t) = (0, 0);
    let mut star: Option<(usize, usize)> = None;
    while t < text.len() {
        if p < pattern.len() && (pattern[p] == b'?' || pattern[p] == text[t]) {
            p += 1;
            t += 1;
        } else if p < pattern.len() && pattern[p] == b'*' {
            star = Some((p, t));
            p += 1;
        } else if let Some((sp, st)) = star {
            p = sp + 1;
            t = st + 1;
            star = Some((sp, st + 1));
        } else {
            return false;
        }
    }
    pattern[p..].iter().all(|&c| c == b'*')
}

/// The cases of `cases` that `only` and `shard` select, in manifest order.
pub fn select<'a>(
    cases: &'a [Case],
    only: Option<&Pattern>,
    shard: Option<Shard>,
) -> Vec<&'a Case> {
    cases
        .iter()
        .filter(|c| only.is_none_or(|p| p.matches(&c.name)))
        .filter(|c| shard.is_none_or(|s| s.contains(&c.name)))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::regress::case::{Tolerance, case_name};
    use meso_render::{Device, ModeKind};

    #[test]
    fn globs_match_whole_names() {
        let p = Pattern::parse("cloth.*,*.leather.spmm-?pu").expect("valid");
        assert!(p.matches("cloth.scene.spmm-cpu"));
        assert!(p.matches("default.leather.spmm-gpu"));
        assert!(!p.matches("default.leather.spmm-cpux"));
        assert!(!p.matches("xcloth.scene.spmm-cpu"));
        assert!(Pattern::parse("a").expect("valid").matches("a"));
        assert!(!Pattern::parse("a").expect("valid").matches("ab"));
        assert!(Pattern::parse("*a*b*").expect("valid").matches("xxaxxbxx"));
        assert!(!Pattern::parse("*a*b").expect("valid").matches("xxaxxbxx"));
        assert!(Pattern::parse(" , ").is_err());
    }

    fn cases(scenes: usize, packs: usize) -> Vec<Case> {
        let mut out = Vec::new();
        for s in 0..scenes {
            for p in 0..packs {
                let scene = format!("s{s}");
                let material = format!("p{p}");
                out.push(Case {
                    name: case_name(&scene, Some(&material), ModeKind::Spmm, Device::Cpu),
                    scene,
                    material: Some(material),
                    replace: Some("m".into()),
                    mode: ModeKind::Spmm,
                    device: Device::Cpu,
                    width: None,
                    height: None,
                    frames: None,
                    seed: None,
                    tolerance: Tolerance::default(),
                    origin: "matrix[0]".into(),
                });
            }
        }
        out
    }

    fn names(selected: &[&Case]) -> Vec<String> {
        selected.iter().map(|c| c.name.clone()).collect()
    }

    #[test]
    fn shard_selection_is_a_partition_for_n_up_to_seven() {
        let all = cases(5, 9);
        for count in 1..=7 {
            let mut union: Vec<String> = Vec::new();
            for index in 1..=count {
                let picked = names(&select(&all, None, Some(Shard { index, count })));
                for n in &picked {
                    assert!(!union.contains(n), "N = {count}: {n} in two shards");
                }
                union.extend(picked);
            }
            union.sort();
            let mut expected = names(&select(&all, None, None));
            expected.sort();
            assert_eq!(union, expected, "N = {count}: every case in some shard");
        }
    }

    #[test]
    fn adding_cases_moves_no_case_between_shards() {
        let before = cases(5, 9);
        // Two more scenes and three more packs: the manifest grows in both directions,
        // and cases are inserted between existing ones.
        let after = cases(7, 12);
        for count in 2..=7 {
            for index in 1..=count {
                let shard = Some(Shard { index, count });
                let old = names(&select(&before, None, shard));
                let new = names(&select(&after, None, shard));
                assert!(
                    old.iter().all(|n| new.contains(n)),
                    "shard {index}/{count} lost cases: {old:?} vs {new:?}"
                );
                // And no old case arrived in this shard from another.
                let arrived: Vec<&String> = new
                    .iter()
                    .filter(|n| before.iter().any(|c| &c.name == *n) && !old.contains(n))
                    .collect();
                assert!(arrived.is_empty(), "{arrived:?}");
            }
        }
    }

    #[test]
    fn only_and_shard_combine() {
        let all = cases(3, 3);
        let only = Pattern::parse("s1.*").expect("valid");
        let picked = select(&all, Some(&only), None);
        assert_eq!(picked.len(), 3);
        let mut sharded = 0;
        for index in 1..=2 {
            sharded += select(&all, Some(&only), Some(Shard { index, count: 2 })).len();
        }
        assert_eq!(sharded, 3);
    }
}
