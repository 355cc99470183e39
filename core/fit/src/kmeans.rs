//! k-means clustering (Lloyd's iterations) with k-means++ seeding (Arthur and
//! Vassilvitskii 2007), used twice by the SPMM fit of Wu et al. 2011 (Silva & Santos
//! 2013, section 3): texels into clusters, then each cluster's texels into
//! sub-clusters whose means are the representatives. Deterministic for a seed: the
//! seeding draws from `SampleStream`, centroid sums run in index order.

use rayon::prelude::*;

use meso_materials::rng::SampleStream;

/// Cluster assignment of every point and the centroids (`k x dim`, row-major).
#[derive(Clone, Debug, PartialEq)]
pub struct Clustering {
    pub k: usize,
    pub assignment: Vec<u32>,
    pub centroids: Vec<f32>,
}

fn dist2(a: &[f32], b: &[f32]) -> f64 {
    a.iter()
        .zip(b)
        .map(|(x, y)| {
            let d = f64::from(*x) - f64::from(*y);
            d * d
        })
        .sum()
}

/// Clusters `n = points.len() / dim` points into at most `k` clusters (fewer when
/// there are fewer points). `max_iter` bounds Lloyd's iterations.
pub fn kmeans(points: &[f32], dim: usize, k: usize, seed: u64, max_iter: usize) -> Clustering {
    let n = points.len() / dim.max(1);
    if n == 0 {
        // Nothing to cluster (a cluster no sample texel is nearest to has no members).
        return Clustering {
            k: 0,
            assignment: Vec::new(),
            centroids: Vec::new(),
        };
    }
    let k = k.min(n).max(1);
    let point = |i: usize| &points[i * dim..(i + 1) * dim];
    let stream = SampleStream::new(&[seed, 0x6b6d_6561_6e73]);
    // k-means++: the first centre uniformly, then each next one with probability
    // proportional to the squared distance to the nearest chosen centre.
    let mut centres: Vec<usize> = vec![((stream.at(0) * n as f64) as usize).min(n - 1)];
    let mut d2: Vec<f64> = (0..n)
        .into_par_iter()
        .map(|i| dist2(point(i), point(centres[0])))
        .collect();
    while centres.len() < k {
        let total: f64 = d2.iter().sum();
        let next = if total <= 0.0 {
            // All remaining points coincide with a centre: take the first unused one.
            (0..n).find(|i| !centres.contains(i)).unwrap_or(0)
        } else {
            let target = stream.at(centres.len() as u64) * total;
            let mut acc = 0.0;
            let mut pick = n - 1;
            for (i, d) in d2.iter().enumerate() {
                acc += d;
                if acc > target {
                    pick = i;
                    break;
                }
            }
            pick
        };
        centres.push(next);
        let c = point(next).to_vec();
        d2.par_iter_mut()
            .enumerate()
            .for_each(|(i, d)| *d = d.min(dist2(point(i), &c)));
    }
    let mut centroids: Vec<f32> = centres.iter().flat_map(|&i| point(i).to_vec()).collect();
    let mut assignment = vec![u32::MAX; n];
    for _ in 0..max_iter {
        let nearest: Vec<(u32, f64)> = (0..n)
            .into_par_iter()
            .map(|i| {
                let mut best = (0u32, f64::INFINITY);
                for c in 0..k {
                    let d = dist2(point(i), &centroids[c * dim..(c + 1) * dim]);
                    if d < best.1 {
                        best = (c as u32, d);
                    }
                }
                best
            })
            .collect();
        let changed = nearest.iter().zip(&assignment).any(|((c, _), a)| c != a);
        for (a, (c, _)) in assignment.iter_mut().zip(&nearest) {
            *a = *c;
        }
        // New centroids in index order (deterministic sums).
        let mut sums = vec![0.0f64; k * dim];
        let mut counts = vec![0usize; k];
        for (i, &a) in assignment.iter().enumerate() {
            let c = a as usize;
            counts[c] += 1;
            for (s, x) in sums[c * dim..(c + 1) * dim].iter_mut().zip(point(i)) {
                *s += f64::from(*x);
            }
        }
        // An empty cluster takes the point farthest from its centroid among those
        // whose cluster keeps another point and that no other empty cluster took this
        // round (several empty clusters taking one point left all but one empty).
        let mut taken = vec![false; n];
        for c in 0..k {
            if counts[c] > 0 {
                continue;
            }
            let far = (0..n)
                .filter(|&i| !taken[i] && counts[assignment[i] as usize] > 1)
                .max_by(|&a, &b| nearest[a].1.total_cmp(&nearest[b].1).then(b.cmp(&a)));
            let Some(far) = far else {
                continue;
            };
            taken[far] = true;
            let old = assignment[far] as usize;
            counts[old] -= 1;
            for (s, x) in sums[old * dim..(old + 1) * dim].iter_mut().zip(point(far)) {
                *s -= f64::from(*x);
            }
            assignment[far] = c as u32;
            counts[c] = 1;
            for (s, x) in sums[c * dim..(c + 1) * dim].iter_mut().zip(point(far)) {
                *s = f64::from(*x);
            }
        }
        for c in 0..k {
            for d in 0..dim {
                centroids[c * dim + d] = (sums[c * dim + d] / counts[c].max(1) as f64) as f32;
            }
        }
        if !changed {
            break;
        }
    }
    Clustering {
        k,
        assignment,
        centroids,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn separates_blobs_and_is_deterministic() {
        // Three well-separated 2-D blobs of 50 points.
        let mut pts = Vec::new();
        for b in 0..3 {
            for i in 0..50 {
                let s = SampleStream::new(&[9, b, i]);
                pts.push(10.0 * b as f32 + s.at(0) as f32);
                pts.push(-5.0 * b as f32 + s.at(1) as f32);
            }
        }
        let a = kmeans(&pts, 2, 3, 7, 100);
        assert_eq!(a, kmeans(&pts, 2, 3, 7, 100));
        for b in 0..3 {
            let first = a.assignment[b * 50];
            assert!(
                a.assignment[b * 50..(b + 1) * 50]
                    .iter()
                    .all(|&c| c == first)
            );
        }
        let mut labels: Vec<u32> = (0..3).map(|b| a.assignment[b * 50]).collect();
        labels.sort();
        assert_eq!(labels, [0, 1, 2]);
        // Coinciding points leave clusters empty after the seeding; each empty cluster
        // takes a point of its own, and no cluster is left without one.
        let mut same = vec![0.5f32; 2 * 10];
        same.extend_from_slice(&[3.0, 3.0, -2.0, 1.0]);
        let e = kmeans(&same, 2, 5, 4, 20);
        assert_eq!(e.k, 5);
        for c in 0..5 {
            assert!(
                e.assignment.contains(&c),
                "cluster {c} empty: {:?}",
                e.assignment
            );
        }
        assert_eq!(kmeans(&[], 2, 3, 1, 5).k, 0);
        // More clusters than points: one per point.
        let few = kmeans(&pts[..4], 2, 8, 1, 10);
        assert_eq!(few.k, 2);
    }
}
