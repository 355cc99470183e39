//! Lossless biclustering of the transfer matrix (Sun et al. 2010, section 4.3,
//! Algorithm 1, the priority queue of section 6.1.2) and the run-time product of
//! Algorithm 2. A bicluster is a submatrix whose every column is constant (eq. 4); its
//! product with L costs W = r + 2l - 1 FLOPs (eq. 7). Starting from a random nonzero,
//! rows and columns are inserted or deleted while the change of cost of eq. 9,
//! dW = 2 nnz(M) - (r + 2l - 1) - 2 nnz(M_R), grows; then the bicluster is subtracted
//! (its residual stays in the matrix) until the matrix is zero, so the sum of the
//! biclusters is T exactly. Entries are integers (sub-ray counts) times a per-column
//! scale, so equality tests are exact.

use std::collections::BinaryHeap;
use std::sync::atomic::{AtomicUsize, Ordering};

use rayon::prelude::*;

use super::transfer::TransferMatrix;
use meso_materials::rng::SampleStream;
use meso_render::{Cancelled, Prepare};

/// A matrix whose entry (j, k) is `level * scale[k]`, as the algorithm sees it.
#[derive(Clone, Debug, PartialEq)]
pub struct LevelMatrix {
    pub rows: usize,
    pub cols: usize,
    /// Per row, (column, level) sorted by column, no zero levels.
    pub entries: Vec<Vec<(u32, i32)>>,
    pub scale: Vec<f32>,
}

impl LevelMatrix {
    pub fn from_transfer(t: &TransferMatrix) -> Self {
        let entries = (0..t.rows)
            .map(|j| {
                let r = t.row_offsets[j] as usize..t.row_offsets[j + 1] as usize;
                t.columns[r.clone()]
                    .iter()
                    .zip(&t.counts[r])
                    .map(|(&k, &c)| (k, i32::from(c)))
                    .collect()
            })
            .collect();
        Self {
            rows: t.rows,
            cols: t.cols,
            entries,
            scale: t.column_scale.clone(),
        }
    }

    pub fn nonzeros(&self) -> usize {
        self.entries.iter().map(Vec::len).sum()
    }
}

/// The biclusters, laid out for Algorithm 2: per bicluster its columns and constant
/// values; per matrix row the biclusters that contain it (I_j).
#[derive(Clone, Debug, PartialEq, Default)]
pub struct Biclustering {
    pub rows: usize,
    pub cols: usize,
    /// Per bicluster, the range of its columns in `columns` / `values`.
    pub col_offsets: Vec<u32>,
    pub columns: Vec<u32>,
    pub values: Vec<f32>,
    /// Per matrix row, the range of its biclusters in `row_biclusters`.
    pub row_offsets: Vec<u32>,
    pub row_biclusters: Vec<u32>,
}

impl Biclustering {
    pub fn len(&self) -> usize {
        self.col_offsets.len().saturating_sub(1)
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// FLOPs of one product per colour channel: sum of r + 2l - 1 (eq. 7).
    pub fn flops(&self) -> u64 {
        (2 * self.columns.len() + self.row_biclusters.len()) as u64 - self.len() as u64
    }

    /// Bytes of the run-time representation.
    pub fn bytes(&self) -> u64 {
        4 * (self.col_offsets.len()
            + self.columns.len()
            + self.values.len()
            + self.row_offsets.len()
            + self.row_biclusters.len()) as u64
    }

    /// Algorithm 2: every bicluster's scalar sum_m t_m L_{k_m} into a buffer, then per
    /// row the sum of its biclusters' scalars. RGB, f32.
    pub fn apply(&self, light: &[[f32; 3]]) -> Vec<[f32; 3]> {
        let buffer: Vec<[f32; 3]> = (0..self.len())
            .into_par_iter()
            .with_min_len(256)
            .map(|i| {
                let r = self.col_offsets[i] as usize..self.col_offsets[i + 1] as usize;
                let mut acc = [0.0f32; 3];
                for (&k, &t) in self.columns[r.clone()].iter().zip(&self.values[r]) {
                    let l = light[k as usize];
                    acc[0] += t * l[0];
                    acc[1] += t * l[1];
                    acc[2] += t * l[2];
                }
                acc
            })
            .collect();
        (0..self.rows)
            .into_par_iter()
            .with_min_len(256)
            .map(|j| {
                let r = self.row_offsets[j] as usize..self.row_offsets[j + 1] as usize;
                let mut acc = [0.0f32; 3];
                for &i in &self.row_biclusters[r] {
                    let p = buffer[i as usize];
                    acc[0] += p[0];
                    acc[1] += p[1];
                    acc[2] += p[2];
                }
                acc
            })
            .collect()
    }

    /// Why these arrays cannot be a biclustering of a rows x cols matrix.
    pub fn problem(&self) -> Option<String> {
        let monotone = |o: &[u32], end: usize, what: &str| -> Option<String> {
            if o.first() != Some(&0) || o.windows(2).any(|w| w[0] > w[1]) {
                return Some(format!("{what} offsets are not increasing from 0"));
            }
            let last = *o.last()?;
            (last as usize != end).then(|| format!("{what} offsets end at {last} not {end}"))
        };
        if self.columns.len() != self.values.len() {
            return Some("bicluster columns and values differ in length".into());
        }
        if self.row_offsets.len() != self.rows + 1 {
            return Some(format!(
                "{} row offsets for {} rows",
                self.row_offsets.len(),
                self.rows
            ));
        }
        monotone(&self.col_offsets, self.columns.len(), "bicluster column")
            .or_else(|| monotone(&self.row_offsets, self.row_biclusters.len(), "row"))
            .or_else(|| {
                self.columns
                    .iter()
                    .find(|&&k| k as usize >= self.cols)
                    .map(|k| format!("column {k} out of range ({} columns)", self.cols))
            })
            .or_else(|| {
                self.row_biclusters
                    .iter()
                    .find(|&&i| i as usize >= self.len())
                    .map(|i| format!("bicluster {i} out of range ({})", self.len()))
            })
            .or_else(|| {
                self.values
                    .iter()
                    .position(|v| !v.is_finite())
                    .map(|i| format!("value {i} is not finite"))
            })
    }
}

/// One bicluster found: rows, columns and each column's constant level.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Found {
    pub rows: Vec<u32>,
    pub columns: Vec<(u32, i32)>,
}

/// The four operations of Algorithm 1.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Op {
    InsertRow(u32),
    DeleteRow(u32),
    InsertCol(u32),
    DeleteCol(u32),
}

/// Heap entry: (key, index, version); stale when the version moved on.
type Entry = (i64, u32, u32);

/// The greedy search's state: the residual matrix T_c (by rows and by columns) and
/// the current bicluster with its influence bookkeeping.
struct Search {
    rows_c: Vec<Vec<(u32, i32)>>,
    cols_c: Vec<Vec<(u32, i32)>>,
    in_r: Vec<bool>,
    in_c: Vec<bool>,
    t_of: Vec<i32>,
    r_list: Vec<u32>,
    c_list: Vec<u32>,
    /// Per row: nonzeros in C columns, and how many equal their column's constant.
    nnz_c: Vec<i64>,
    match_c: Vec<i64>,
    /// Per column: histogram of its levels over the R rows.
    hist: Vec<Vec<(i32, i64)>>,
    row_version: Vec<u32>,
    col_version: Vec<u32>,
    touched_rows: Vec<u32>,
    touched_cols: Vec<u32>,
    row_seen: Vec<bool>,
    col_seen: Vec<bool>,
    ins_row: BinaryHeap<Entry>,
    del_row: BinaryHeap<Entry>,
    ins_col: BinaryHeap<Entry>,
    del_col: BinaryHeap<Entry>,
    /// dW of the current bicluster (eq. 9), tracked incrementally.
    delta_w: i64,
}

fn level_at(list: &[(u32, i32)], i: u32) -> i32 {
    list.binary_search_by_key(&i, |e| e.0)
        .map_or(0, |p| list[p].1)
}

fn hist_count(h: &[(i32, i64)], level: i32) -> i64 {
    h.iter().find(|e| e.0 == level).map_or(0, |e| e.1)
}

fn hist_add(h: &mut Vec<(i32, i64)>, level: i32, d: i64) {
    if let Some(e) = h.iter_mut().find(|e| e.0 == level) {
        e.1 += d;
    } else {
        h.push((level, d));
    }
}

/// The most frequent level (ties: the smallest) and its count.
fn hist_mode(h: &[(i32, i64)]) -> Option<(i32, i64)> {
    h.iter()
        .filter(|e| e.1 > 0)
        .max_by_key(|e| (e.1, -e.0))
        .copied()
}

impl Search {
    fn new(m: &LevelMatrix) -> Self {
        let mut cols_c = vec![Vec::new(); m.cols];
        for (j, row) in m.entries.iter().enumerate() {
            for &(k, v) in row {
                cols_c[k as usize].push((j as u32, v));
            }
        }
        Self {
            rows_c: m.entries.clone(),
            cols_c,
            in_r: vec![false; m.rows],
            in_c: vec![false; m.cols],
            t_of: vec![0; m.cols],
            r_list: Vec::new(),
            c_list: Vec::new(),
            nnz_c: vec![0; m.rows],
            match_c: vec![0; m.rows],
            hist: vec![Vec::new(); m.cols],
            row_version: vec![0; m.rows],
            col_version: vec![0; m.cols],
            touched_rows: Vec::new(),
            touched_cols: Vec::new(),
            row_seen: vec![false; m.rows],
            col_seen: vec![false; m.cols],
            ins_row: BinaryHeap::new(),
            del_row: BinaryHeap::new(),
            ins_col: BinaryHeap::new(),
            del_col: BinaryHeap::new(),
            delta_w: 0,
        }
    }

    fn touch_row(&mut self, j: u32) {
        if !self.row_seen[j as usize] {
            self.row_seen[j as usize] = true;
            self.touched_rows.push(j);
        }
    }

    fn touch_col(&mut self, k: u32) {
        if !self.col_seen[k as usize] {
            self.col_seen[k as usize] = true;
            self.touched_cols.push(k);
        }
    }

    /// Re-files row j in the heap of its current operation.
    fn push_row(&mut self, j: u32) {
        let ju = j as usize;
        self.row_version[ju] = self.row_version[ju].wrapping_add(1);
        let v = self.row_version[ju];
        let s = 2 * (self.nnz_c[ju] + self.match_c[ju]);
        if self.in_r[ju] {
            self.del_row.push((-s, j, v));
        } else {
            self.ins_row.push((s, j, v));
        }
    }

    fn push_col(&mut self, k: u32) {
        let ku = k as usize;
        self.col_version[ku] = self.col_version[ku].wrapping_add(1);
        let v = self.col_version[ku];
        let nnz: i64 = self.hist[ku].iter().map(|e| e.1).sum();
        if self.in_c[ku] {
            let cnt = hist_count(&self.hist[ku], self.t_of[ku]);
            self.del_col.push((-2 * (nnz + cnt), k, v));
        } else if let Some((_, cnt)) = hist_mode(&self.hist[ku]) {
            self.ins_col.push((2 * (nnz + cnt), k, v));
        }
    }

    fn r(&self) -> i64 {
        self.r_list.len() as i64
    }
    fn l(&self) -> i64 {
        self.c_list.len() as i64
    }

    /// The best valid entry of a heap (stale entries dropped), without removing it.
    fn top(
        heap: &mut BinaryHeap<Entry>,
        version: &[u32],
        member: &[bool],
        want: bool,
    ) -> Option<Entry> {
        while let Some(&e) = heap.peek() {
            if version[e.1 as usize] == e.2 && member[e.1 as usize] == want {
                return Some(e);
            }
            heap.pop();
        }
        None
    }

    /// The operation that raises dW most, with its gain; `None` when none raises it.
    fn best(&mut self) -> Option<(Op, i64)> {
        let (r, l) = (self.r(), self.l());
        let mut best: Option<(Op, i64)> = None;
        let mut consider = |op: Op, gain: i64| {
            if gain > 0 && best.is_none_or(|b| gain > b.1) {
                best = Some((op, gain));
            }
        };
        if let Some(e) = Self::top(&mut self.ins_row, &self.row_version, &self.in_r, false) {
            consider(Op::InsertRow(e.1), e.0 - 1 - 2 * l);
        }
        if r > 1
            && let Some(e) = Self::top(&mut self.del_row, &self.row_version, &self.in_r, true)
        {
            consider(Op::DeleteRow(e.1), e.0 + 1 + 2 * l);
        }
        if let Some(e) = Self::top(&mut self.ins_col, &self.col_version, &self.in_c, false) {
            consider(Op::InsertCol(e.1), e.0 - 2 - 2 * r);
        }
        if l > 1
            && let Some(e) = Self::top(&mut self.del_col, &self.col_version, &self.in_c, true)
        {
            consider(Op::DeleteCol(e.1), e.0 + 2 + 2 * r);
        }
        best
    }

    fn insert_row(&mut self, j: u32) {
        self.in_r[j as usize] = true;
        self.r_list.push(j);
        self.touch_row(j);
        let row = std::mem::take(&mut self.rows_c[j as usize]);
        for &(k, v) in &row {
            self.touch_col(k);
            hist_add(&mut self.hist[k as usize], v, 1);
            self.push_col(k);
        }
        self.rows_c[j as usize] = row;
        self.push_row(j);
    }

    fn delete_row(&mut self, j: u32) {
        self.in_r[j as usize] = false;
        self.r_list.retain(|&x| x != j);
        let row = std::mem::take(&mut self.rows_c[j as usize]);
        for &(k, v) in &row {
            hist_add(&mut self.hist[k as usize], v, -1);
            self.push_col(k);
        }
        self.rows_c[j as usize] = row;
        self.push_row(j);
    }

    fn insert_col(&mut self, k: u32, t: i32) {
        self.in_c[k as usize] = true;
        self.t_of[k as usize] = t;
        self.c_list.push(k);
        self.touch_col(k);
        let col = std::mem::take(&mut self.cols_c[k as usize]);
        for &(j, v) in &col {
            self.touch_row(j);
            self.nnz_c[j as usize] += 1;
            if v == t {
                self.match_c[j as usize] += 1;
            }
            self.push_row(j);
        }
        self.cols_c[k as usize] = col;
        self.push_col(k);
    }

    fn delete_col(&mut self, k: u32) {
        let t = self.t_of[k as usize];
        self.in_c[k as usize] = false;
        self.c_list.retain(|&x| x != k);
        let col = std::mem::take(&mut self.cols_c[k as usize]);
        for &(j, v) in &col {
            self.nnz_c[j as usize] -= 1;
            if v == t {
                self.match_c[j as usize] -= 1;
            }
            self.push_row(j);
        }
        self.cols_c[k as usize] = col;
        self.push_col(k);
    }

    /// dW of the current bicluster recomputed from the residual matrix (eq. 9).
    fn delta_w_from_scratch(&self) -> i64 {
        let (mut nnz, mut resid) = (0i64, 0i64);
        for &j in &self.r_list {
            for &k in &self.c_list {
                let v = level_at(&self.rows_c[j as usize], k);
                nnz += i64::from(v != 0);
                resid += i64::from(v != self.t_of[k as usize]);
            }
        }
        2 * nnz - (self.r() + 2 * self.l() - 1) - 2 * resid
    }

    /// Grows one bicluster from the nonzero (j, k) (Algorithm 1, lines 5-21), subtracts
    /// it from T_c and returns it. With `check`, every accepted operation's dW is
    /// recomputed from scratch and must have grown.
    fn grow(&mut self, j: u32, k: u32, check: bool) -> Found {
        let t = level_at(&self.rows_c[j as usize], k);
        debug_assert_ne!(t, 0, "the seed is a nonzero");
        self.insert_row(j);
        self.insert_col(k, t);
        self.delta_w = 0;
        while let Some((op, gain)) = self.best() {
            match op {
                Op::InsertRow(j) => self.insert_row(j),
                Op::DeleteRow(j) => self.delete_row(j),
                Op::InsertCol(k) => {
                    let t = hist_mode(&self.hist[k as usize])
                        .expect("a column in the insert heap has a level in R")
                        .0;
                    self.insert_col(k, t)
                }
                Op::DeleteCol(k) => self.delete_col(k),
            }
            let before = self.delta_w;
            self.delta_w += gain;
            if check {
                let exact = self.delta_w_from_scratch();
                assert_eq!(exact, self.delta_w, "tracked dW after {op:?}");
                assert!(exact > before, "{op:?} did not lower the cost");
            }
        }
        let mut rows = self.r_list.clone();
        rows.sort_unstable();
        let mut columns: Vec<(u32, i32)> = self
            .c_list
            .iter()
            .map(|&k| (k, self.t_of[k as usize]))
            .collect();
        columns.sort_unstable();
        self.subtract(&rows, &columns);
        self.reset();
        Found { rows, columns }
    }

    /// T_c <- T_c - T_b (Algorithm 1, line 16); returns nothing, records new nonzeros.
    fn subtract(&mut self, rows: &[u32], columns: &[(u32, i32)]) {
        for &j in rows {
            let row = &mut self.rows_c[j as usize];
            *row = merge(row, columns.iter().map(|&(k, t)| (k, -t)));
        }
        for &(k, t) in columns {
            let col = &mut self.cols_c[k as usize];
            *col = merge(col, rows.iter().map(|&j| (j, -t)));
        }
    }

    fn reset(&mut self) {
        for &j in &self.touched_rows {
            let ju = j as usize;
            self.in_r[ju] = false;
            self.nnz_c[ju] = 0;
            self.match_c[ju] = 0;
            self.row_seen[ju] = false;
        }
        for &k in &self.touched_cols {
            let ku = k as usize;
            self.in_c[ku] = false;
            self.hist[ku].clear();
            self.col_seen[ku] = false;
        }
        self.touched_rows.clear();
        self.touched_cols.clear();
        self.r_list.clear();
        self.c_list.clear();
        self.ins_row.clear();
        self.del_row.clear();
        self.ins_col.clear();
        self.del_col.clear();
    }
}

/// Sorted sparse `a` plus sorted `b`, zero sums dropped.
fn merge(a: &[(u32, i32)], b: impl Iterator<Item = (u32, i32)>) -> Vec<(u32, i32)> {
    let mut out = Vec::with_capacity(a.len() + 4);
    let mut ai = a.iter().peekable();
    for (k, d) in b {
        while let Some(&&(ka, va)) = ai.peek() {
            if ka < k {
                out.push((ka, va));
                ai.next();
            } else {
                break;
            }
        }
        let mut v = d;
        if let Some(&&(ka, va)) = ai.peek()
            && ka == k
        {
            v += va;
            ai.next();
        }
        if v != 0 {
            out.push((k, v));
        }
    }
    out.extend(ai.copied());
    out
}

/// Rows biclustered together: a matrix with more rows is cut into bands of about this
/// many (a fixed size, so the result does not depend on the thread count), which are
/// biclustered in parallel. A bicluster never spans two bands, which costs a little
/// compression; every band is still exact, so the sum is T (docs/rendering.md,
/// "Biclustering").
pub const BAND_ROWS: usize = 1 << 18;

/// Biclusters `m` completely (Algorithm 1), seeds drawn with `seed`; progress is the
/// fraction of the original nonzeros consumed, as stage "biclustering".
pub fn bicluster(m: &LevelMatrix, seed: u64, prepare: &Prepare) -> Result<Vec<Found>, Cancelled> {
    bicluster_checked(m, seed, prepare, false)
}

pub(crate) fn bicluster_checked(
    m: &LevelMatrix,
    seed: u64,
    prepare: &Prepare,
    check: bool,
) -> Result<Vec<Found>, Cancelled> {
    let bands = m.rows.div_ceil(BAND_ROWS).max(1);
    let size = m.rows.div_ceil(bands).max(1);
    let total = m.nonzeros().max(1);
    let consumed = AtomicUsize::new(0);
    let progress = |seeds: usize| {
        let done = consumed.fetch_add(seeds, Ordering::Relaxed) + seeds;
        prepare.report("biclustering", done.min(total) as f32 / total as f32)
    };
    let parts: Vec<Result<Vec<Found>, Cancelled>> = (0..bands)
        .into_par_iter()
        .map(|b| {
            let (start, end) = (b * size, ((b + 1) * size).min(m.rows));
            let band = LevelMatrix {
                rows: end - start,
                cols: m.cols,
                entries: m.entries[start..end].to_vec(),
                scale: m.scale.clone(),
            };
            // The first band draws as a single band always did.
            let rng = if b == 0 {
                SampleStream::new(&[seed])
            } else {
                SampleStream::new(&[seed, b as u64])
            };
            let mut found = bicluster_band(&band, &rng, &progress, check)?;
            for f in &mut found {
                f.rows.iter_mut().for_each(|j| *j += start as u32);
            }
            Ok(found)
        })
        .collect();
    let mut found = Vec::new();
    for part in parts {
        found.extend(part?);
    }
    prepare.report("biclustering", 1.0)?;
    Ok(found)
}

/// Algorithm 1 on one band; `progress` is told how many seeds of the first round were
/// visited.
fn bicluster_band(
    m: &LevelMatrix,
    rng: &SampleStream,
    progress: &(dyn Fn(usize) -> Result<(), Cancelled> + Sync),
    check: bool,
) -> Result<Vec<Found>, Cancelled> {
    let mut search = Search::new(m);
    // Seeds: every nonzero in a random order; residual nonzeros the subtractions
    // create are found by a sweep at the end (in another random order).
    let mut order: Vec<(u32, u32)> = m
        .entries
        .iter()
        .enumerate()
        .flat_map(|(j, r)| r.iter().map(move |&(k, _)| (j as u32, k)))
        .collect();
    let mut found = Vec::new();
    let (mut round, mut reported) = (0u64, 0usize);
    loop {
        shuffle(&mut order, rng, round);
        for (i, &(j, k)) in order.iter().enumerate() {
            if round == 0 && i - reported >= 4096 {
                progress(i - reported)?;
                reported = i;
            }
            if level_at(&search.rows_c[j as usize], k) != 0 {
                found.push(search.grow(j, k, check));
            }
        }
        if round == 0 {
            progress(order.len() - reported)?;
        }
        order = search
            .rows_c
            .iter()
            .enumerate()
            .flat_map(|(j, r)| r.iter().map(move |&(k, _)| (j as u32, k)))
            .collect();
        if order.is_empty() {
            break;
        }
        round += 1;
    }
    Ok(found)
}

/// Fisher-Yates with replayable random numbers.
fn shuffle<T>(v: &mut [T], rng: &SampleStream, round: u64) {
    for i in (1..v.len()).rev() {
        let u = rng.at(round.wrapping_mul(0x1_0000_0000) + i as u64);
        let j = ((u * (i + 1) as f64) as usize).min(i);
        v.swap(i, j);
    }
}

/// The run-time layout of `found` for a matrix with `m`'s shape and scales.
pub fn layout(m: &LevelMatrix, found: &[Found]) -> Biclustering {
    let mut b = Biclustering {
        rows: m.rows,
        cols: m.cols,
        col_offsets: vec![0],
        ..Default::default()
    };
    let mut per_row: Vec<Vec<u32>> = vec![Vec::new(); m.rows];
    for (i, f) in found.iter().enumerate() {
        for &(k, t) in &f.columns {
            b.columns.push(k);
            b.values.push(t as f32 * m.scale[k as usize]);
        }
        b.col_offsets.push(b.columns.len() as u32);
        for &j in &f.rows {
            per_row[j as usize].push(i as u32);
        }
    }
    b.row_offsets.push(0);
    for r in per_row {
        b.row_biclusters.extend(r);
        b.row_offsets.push(b.row_biclusters.len() as u32);
    }
    b
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;

    fn matrix(rows: usize, cols: usize, dense: &[i32]) -> LevelMatrix {
        LevelMatrix {
            rows,
            cols,
            entries: (0..rows)
                .map(|j| {
                    (0..cols)
                        .filter(|&k| dense[j * cols + k] != 0)
                        .map(|k| (k as u32, dense[j * cols + k]))
                        .collect()
                })
                .collect(),
            scale: (0..cols).map(|k| 0.25 + 0.01 * k as f32).collect(),
        }
    }

    /// Dense product of a level matrix in f64.
    fn dense_apply(m: &LevelMatrix, light: &[[f32; 3]]) -> Vec<[f64; 3]> {
        m.entries
            .iter()
            .map(|r| {
                let mut acc = [0.0; 3];
                for &(k, v) in r {
                    for c in 0..3 {
                        acc[c] +=
                            v as f64 * m.scale[k as usize] as f64 * light[k as usize][c] as f64;
                    }
                }
                acc
            })
            .collect()
    }

    fn random_light(n: usize, seed: u64) -> Vec<[f32; 3]> {
        let rng = SampleStream::new(&[seed]);
        (0..n)
            .map(|k| {
                let k = k as u64 * 3;
                [
                    rng.at(k) as f32,
                    rng.at(k + 1) as f32,
                    10.0 * rng.at(k + 2) as f32,
                ]
            })
            .collect()
    }

    /// Largest error relative to the largest magnitude of the dense product.
    pub(crate) fn relative_error(dense: &[[f64; 3]], got: &[[f32; 3]]) -> f64 {
        let scale = dense
            .iter()
            .flat_map(|p| p.iter())
            .fold(0.0f64, |a, v| a.max(v.abs()))
            .max(1e-30);
        dense
            .iter()
            .zip(got)
            .flat_map(|(d, g)| (0..3).map(move |c| (d[c] - g[c] as f64).abs()))
            .fold(0.0, f64::max)
            / scale
    }

    #[test]
    fn a_matrix_of_two_constant_column_blocks_is_found_exactly() {
        // Block A: rows 0..12, columns 0..6, column k constant (k % 4 + 1); block B:
        // rows 12..20, columns 6..10, constant 3; one lone entry at (20, 10). The
        // optimal biclustering is the two blocks and a 1 x 1: cost (12 + 12 - 1) +
        // (8 + 8 - 1) + 2.
        let (rows, cols) = (21, 11);
        let mut dense = vec![0; rows * cols];
        for j in 0..12 {
            for k in 0..6 {
                dense[j * cols + k] = (k % 4 + 1) as i32;
            }
        }
        for j in 12..20 {
            for k in 6..10 {
                dense[j * cols + k] = 3;
            }
        }
        dense[20 * cols + 10] = 2;
        let m = matrix(rows, cols, &dense);
        for seed in 0..5 {
            let found = bicluster_checked(&m, seed, &Prepare::quietly(), true).expect("runs");
            let b = layout(&m, &found);
            assert_eq!(b.len(), 3, "seed {seed}: {found:?}");
            assert_eq!(b.flops(), 23 + 15 + 2, "seed {seed}");
            let mut shapes: Vec<(usize, usize)> = found
                .iter()
                .map(|f| (f.rows.len(), f.columns.len()))
                .collect();
            shapes.sort();
            assert_eq!(shapes, [(1, 1), (8, 4), (12, 6)]);
        }
    }

    #[test]
    fn a_noisy_block_keeps_its_residual_and_stays_lossless() {
        // The paper's example pattern: a constant-column block with a few entries off
        // (a different value, or a zero), so the best bicluster leaves a residual.
        let (rows, cols) = (30, 12);
        let rng = SampleStream::new(&[11]);
        let mut dense = vec![0; rows * cols];
        for j in 0..rows {
            for k in 0..cols {
                let u = rng.at((j * cols + k) as u64);
                dense[j * cols + k] = if u < 0.08 {
                    0
                } else if u < 0.15 {
                    1 + (k as i32 + 1) % 4
                } else {
                    1 + k as i32 % 4
                };
            }
        }
        let m = matrix(rows, cols, &dense);
        let found = bicluster_checked(&m, 3, &Prepare::quietly(), true).expect("runs");
        let b = layout(&m, &found);
        assert!(b.problem().is_none(), "{:?}", b.problem());
        // Far cheaper than the dense product's 2 nnz.
        let nnz = m.nonzeros() as u64;
        assert!(b.flops() * 2 < 2 * nnz, "{} vs {}", b.flops(), 2 * nnz);
        for s in 0..3 {
            let light = random_light(cols, s);
            let err = relative_error(&dense_apply(&m, &light), &b.apply(&light));
            assert!(err < 1e-6, "relative error {err}");
        }
    }

    #[test]
    fn random_sparse_matrices_are_reproduced() {
        let (rows, cols) = (200, 90);
        let rng = SampleStream::new(&[21]);
        let dense: Vec<i32> = (0..rows * cols)
            .map(|i| {
                let u = rng.at(i as u64);
                if u < 0.8 {
                    0
                } else {
                    1 + ((u - 0.8) * 20.0) as i32
                }
            })
            .collect();
        let m = matrix(rows, cols, &dense);
        let found = bicluster_checked(&m, 1, &Prepare::quietly(), true).expect("runs");
        let b = layout(&m, &found);
        // Never worse than the dense product: each bicluster has dW >= 0.
        assert!(b.flops() <= 2 * m.nonzeros() as u64);
        let light = random_light(cols, 9);
        let err = relative_error(&dense_apply(&m, &light), &b.apply(&light));
        assert!(err < 1e-6, "relative error {err}");
    }

    #[test]
    fn merging_adds_and_drops_zeros() {
        let a = [(1, 2), (4, 1), (9, 3)];
        let got = merge(&a, [(0, -1), (4, -1), (9, 1)].into_iter());
        assert_eq!(got, [(0, -1), (1, 2), (9, 4)]);
    }
}
