//! The difference between two states of one SPMM material on the same texel grid and
//! cluster map: what the editor's undo steps and its recovery journal keep instead of
//! whole copies. A brush stroke's delta holds the texels it touched, a basis edit its
//! cluster's dictionary; the residual is recorded only when an edit changed it. A
//! delta holds both sides, so it steps either way: `before.stepped(&d, Step::Forward)`
//! is `after` and `after.stepped(&d, Step::Back)` is `before`, equal in every stored
//! part and in the view. The byte form (`encode`, `decode`) is what the journal writes.

use std::sync::Arc;

use glam::DVec3;

use super::material::Header;
use super::{BasisView, Cluster, Residual, SparseWeights, SpmmError, SpmmMaterial};
use crate::brdf::{AnalyticBrdf, BasisFunction, BrdfModel};

/// Which way to step through a delta.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Step {
    /// From the state it was taken from to the state it leads to.
    Forward,
    /// Back.
    Back,
}

impl Step {
    fn side(self) -> usize {
        match self {
            Step::Forward => 1,
            Step::Back => 0,
        }
    }
}

/// The weights of some texels, in CSR form.
#[derive(Clone, Debug, Default, PartialEq)]
struct Entries {
    /// One per changed texel and one.
    offsets: Vec<u32>,
    basis: Vec<u16>,
    rgb: Vec<[f32; 3]>,
}

impl Entries {
    fn push(&mut self, basis: &[u16], rgb: &[[f32; 3]]) {
        if self.offsets.is_empty() {
            self.offsets.push(0);
        }
        self.basis.extend_from_slice(basis);
        self.rgb.extend_from_slice(rgb);
        self.offsets.push(self.basis.len() as u32);
    }

    fn of(&self, k: usize) -> (&[u16], &[[f32; 3]]) {
        let r = self.offsets[k] as usize..self.offsets[k + 1] as usize;
        (&self.basis[r.clone()], &self.rgb[r])
    }
}

/// A material's state before and after an edit, as far as the edit changed it.
#[derive(Clone, Debug, PartialEq)]
pub struct PackDelta {
    /// The grid and cluster count both sides share (checked when stepping).
    width: u32,
    height: u32,
    header: Option<[Header; 2]>,
    /// Changed clusters: index, dictionary before and after.
    clusters: Vec<(u32, [Cluster; 2])>,
    /// Changed texels (ascending) and their weights on each side.
    texels: Vec<u32>,
    weights: [Entries; 2],
    residual: Option<[Option<Arc<Residual>>; 2]>,
    view: Option<[BasisView; 2]>,
}

/// Why a delta cannot be taken, stepped or read.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum DeltaError {
    #[error("the two materials do not share a texel grid and cluster map")]
    Unrelated,
    #[error("the delta is for a {0}x{1} material with {2} clusters, this one differs")]
    Mismatch(u32, u32, usize),
    #[error("texel {0} does not hold the weights the delta starts from")]
    Diverged(u32),
    #[error("the delta is damaged: {0}")]
    Damaged(String),
    #[error(transparent)]
    Invalid(#[from] SpmmError),
}

impl SpmmMaterial {
    /// What turns `self` into `after`, or `Unrelated` when they do not share a texel
    /// grid and cluster map (then only a whole copy describes the change).
    pub fn delta_to(&self, after: &SpmmMaterial) -> Result<PackDelta, DeltaError> {
        if (self.width(), self.height()) != (after.width(), after.height())
            || self.clusters().len() != after.clusters().len()
            || self.texel_cluster() != after.texel_cluster()
        {
            return Err(DeltaError::Unrelated);
        }
        let (h0, h1) = (self.header(), after.header());
        let clusters = (0..self.clusters().len())
            .filter(|&c| self.clusters()[c] != after.clusters()[c])
            .map(|c| {
                (
                    c as u32,
                    [self.clusters()[c].clone(), after.clusters()[c].clone()],
                )
            })
            .collect();
        let mut texels = Vec::new();
        let mut weights = [Entries::default(), Entries::default()];
        let (w0, w1) = (self.weights(), after.weights());
        // Equal arrays (an edit of the dictionary alone) need no texel walk.
        if w0 != w1 {
            for t in 0..self.texel_cluster().len() {
                let r0 = w0.offsets[t] as usize..w0.offsets[t + 1] as usize;
                let r1 = w1.offsets[t] as usize..w1.offsets[t + 1] as usize;
                if w0.basis[r0.clone()] != w1.basis[r1.clone()]
                    || w0.rgb[r0.clone()] != w1.rgb[r1.clone()]
                {
                    texels.push(t as u32);
                    weights[0].push(&w0.basis[r0.clone()], &w0.rgb[r0]);
                    weights[1].push(&w1.basis[r1.clone()], &w1.rgb[r1]);
                }
            }
        }
        let residual = match (self.shared_residual(), after.shared_residual()) {
            (Some(a), Some(b)) if Arc::ptr_eq(a, b) || a == b => None,
            (None, None) => None,
            (a, b) => Some([a.cloned(), b.cloned()]),
        };
        Ok(PackDelta {
            width: self.width(),
            height: self.height(),
            header: (h0 != h1).then_some([h0, h1]),
            clusters,
            texels,
            weights,
            residual,
            view: (self.view() != after.view())
                .then(|| [self.view().clone(), after.view().clone()]),
        })
    }

    /// This material stepped through `delta` (`Step::Forward` from the side it was
    /// taken from). The texels it changed must hold the weights it starts from.
    pub fn stepped(&self, delta: &PackDelta, step: Step) -> Result<SpmmMaterial, DeltaError> {
        let (from, to) = (1 - step.side(), step.side());
        if (self.width(), self.height()) != (delta.width, delta.height)
            || delta
                .clusters
                .iter()
                .any(|(c, _)| *c as usize >= self.clusters().len())
        {
            return Err(DeltaError::Mismatch(
                delta.width,
                delta.height,
                self.clusters().len(),
            ));
        }
        let header = match &delta.header {
            Some(h) => h[to].clone(),
            None => self.header(),
        };
        let mut clusters = self.clusters().to_vec();
        for (c, sides) in &delta.clusters {
            clusters[*c as usize] = sides[to].clone();
        }
        let weights = if delta.texels.is_empty() {
            self.weights().clone()
        } else {
            self.weights_stepped(delta, from, to)?
        };
        let residual = match &delta.residual {
            Some(r) => r[to].clone(),
            None => self.shared_residual().cloned(),
        };
        let view = match &delta.view {
            Some(v) => v[to].clone(),
            None => self.view().clone(),
        };
        Ok(self.with_parts(header, clusters, weights, residual, view)?)
    }

    fn weights_stepped(
        &self,
        delta: &PackDelta,
        from: usize,
        to: usize,
    ) -> Result<SparseWeights, DeltaError> {
        let old = self.weights();
        let texels = self.texel_cluster().len();
        let mut w = SparseWeights {
            offsets: Vec::with_capacity(old.offsets.len()),
            basis: Vec::with_capacity(old.basis.len()),
            rgb: Vec::with_capacity(old.rgb.len()),
        };
        w.offsets.push(0);
        let mut next = 0;
        for (k, &t) in delta.texels.iter().enumerate() {
            let t = t as usize;
            if t >= texels || t < next {
                return Err(DeltaError::Damaged(format!(
                    "texel {t} out of order or range"
                )));
            }
            // The unchanged run before t, copied as a block.
            let (a, b) = (old.offsets[next] as usize, old.offsets[t] as usize);
            let shift = w.basis.len() as i64 - a as i64;
            w.basis.extend_from_slice(&old.basis[a..b]);
            w.rgb.extend_from_slice(&old.rgb[a..b]);
            w.offsets.extend(
                old.offsets[next + 1..=t]
                    .iter()
                    .map(|&o| (i64::from(o) + shift) as u32),
            );
            let here = b..old.offsets[t + 1] as usize;
            let (basis, rgb) = delta.weights[from].of(k);
            if old.basis[here.clone()] != *basis || old.rgb[here] != *rgb {
                return Err(DeltaError::Diverged(t as u32));
            }
            let (basis, rgb) = delta.weights[to].of(k);
            w.basis.extend_from_slice(basis);
            w.rgb.extend_from_slice(rgb);
            w.offsets.push(w.basis.len() as u32);
            next = t + 1;
        }
        let a = old.offsets[next] as usize;
        let shift = w.basis.len() as i64 - a as i64;
        w.basis.extend_from_slice(&old.basis[a..]);
        w.rgb.extend_from_slice(&old.rgb[a..]);
        w.offsets.extend(
            old.offsets[next + 1..=texels]
                .iter()
                .map(|&o| (i64::from(o) + shift) as u32),
        );
        Ok(w)
    }
}

impl PackDelta {
    /// Whether the two sides are equal (nothing to undo or journal).
    pub fn is_empty(&self) -> bool {
        self.header.is_none()
            && self.clusters.is_empty()
            && self.texels.is_empty()
            && self.residual.is_none()
            && self.view.is_none()
    }

    /// Texels whose weights differ.
    pub fn changed_texels(&self) -> &[u32] {
        &self.texels
    }

    /// Bytes this delta keeps in memory (what an undo budget counts). A residual it
    /// holds counts whole, though it may be shared with a live material.
    pub fn bytes(&self) -> usize {
        let entries = |e: &Entries| e.offsets.len() * 4 + e.basis.len() * 2 + e.rgb.len() * 12;
        let residual = |r: &Option<Arc<Residual>>| {
            r.as_ref().map_or(0, |r| {
                (r.mean.len() + r.components.len() + r.coefficients.len()) * 4
                    + (r.light_dirs.len() + r.view_dirs.len()) * 24
            })
        };
        std::mem::size_of::<Self>()
            + self.texels.len() * 4
            + self.weights.iter().map(entries).sum::<usize>()
            + self
                .clusters
                .iter()
                .map(|(_, s)| 8 + (s[0].bases.len() + s[1].bases.len()) * 128)
                .sum::<usize>()
            + self.header.as_ref().map_or(0, |h| {
                h.iter()
                    .map(|h| h.name.len() + h.provenance.len() + h.edited_clusters.len())
                    .sum()
            })
            + self
                .residual
                .as_ref()
                .map_or(0, |r| residual(&r[0]) + residual(&r[1]))
    }
}

// ---- byte form ----

const MAGIC: &[u8; 4] = b"MPD1";

/// Little-endian writer of the byte form.
#[derive(Default)]
struct Out(Vec<u8>);

impl Out {
    fn u8(&mut self, v: u8) {
        self.0.push(v);
    }
    fn u32(&mut self, v: u32) {
        self.0.extend_from_slice(&v.to_le_bytes());
    }
    fn len(&mut self, n: usize) {
        self.u32(n as u32);
    }
    fn f32s(&mut self, v: &[f32]) {
        self.len(v.len());
        for x in v {
            self.0.extend_from_slice(&x.to_le_bytes());
        }
    }
    fn f64(&mut self, v: f64) {
        self.0.extend_from_slice(&v.to_le_bytes());
    }
    fn text(&mut self, s: &str) {
        self.len(s.len());
        self.0.extend_from_slice(s.as_bytes());
    }
    fn header(&mut self, h: &Header) {
        self.text(&h.name);
        self.text(&h.provenance);
        self.u8(u8::from(h.edited));
        self.len(h.edited_clusters.len());
        self.0
            .extend(h.edited_clusters.iter().map(|&b| u8::from(b)));
    }
    fn cluster(&mut self, c: &Cluster) {
        self.len(c.bases.len());
        for b in &c.bases {
            self.u8(super::pack::model_id(b.brdf().model()));
            let p = b.brdf().param_values();
            self.len(p.len());
            p.iter().for_each(|&v| self.f64(v));
            b.normal().to_array().iter().for_each(|&v| self.f64(v));
        }
    }
    fn entries(&mut self, e: &Entries) {
        self.len(e.offsets.len());
        e.offsets.iter().for_each(|&o| self.u32(o));
        self.len(e.basis.len());
        for (b, rgb) in e.basis.iter().zip(&e.rgb) {
            self.0.extend_from_slice(&b.to_le_bytes());
            rgb.iter()
                .for_each(|x| self.0.extend_from_slice(&x.to_le_bytes()));
        }
    }
    fn dirs(&mut self, d: &[DVec3]) {
        self.len(d.len());
        for v in d {
            v.to_array().iter().for_each(|&x| self.f64(x));
        }
    }
    fn residual(&mut self, r: &Option<Arc<Residual>>) {
        match r {
            None => self.u8(0),
            Some(r) => {
                self.u8(1);
                self.dirs(&r.light_dirs);
                self.dirs(&r.view_dirs);
                self.len(r.npca);
                self.f32s(&r.mean);
                self.f32s(&r.components);
                self.f32s(&r.coefficients);
            }
        }
    }
    fn view(&mut self, v: &BasisView) {
        for set in v.entries() {
            self.len(set.len());
            for (c, b) in set {
                self.len(c);
                self.len(b);
            }
        }
    }
}

/// Reader of the byte form; every length is checked against what is left.
struct In<'a>(&'a [u8]);

fn damaged(what: &str) -> DeltaError {
    DeltaError::Damaged(format!("{what} runs past the end"))
}

impl<'a> In<'a> {
    fn take(&mut self, n: usize, what: &str) -> Result<&'a [u8], DeltaError> {
        if n > self.0.len() {
            return Err(damaged(what));
        }
        let (a, b) = self.0.split_at(n);
        self.0 = b;
        Ok(a)
    }
    fn u8(&mut self, what: &str) -> Result<u8, DeltaError> {
        Ok(self.take(1, what)?[0])
    }
    fn u32(&mut self, what: &str) -> Result<u32, DeltaError> {
        Ok(u32::from_le_bytes(
            self.take(4, what)?.try_into().expect("4 bytes"),
        ))
    }
    /// A count of items of `size` bytes each that must fit in what is left.
    fn len(&mut self, size: usize, what: &str) -> Result<usize, DeltaError> {
        let n = self.u32(what)? as usize;
        if n.saturating_mul(size) > self.0.len() {
            return Err(damaged(what));
        }
        Ok(n)
    }
    fn f64(&mut self, what: &str) -> Result<f64, DeltaError> {
        Ok(f64::from_le_bytes(
            self.take(8, what)?.try_into().expect("8 bytes"),
        ))
    }
    fn f32s(&mut self, what: &str) -> Result<Vec<f32>, DeltaError> {
        let n = self.len(4, what)?;
        Ok(self
            .take(n * 4, what)?
            .chunks_exact(4)
            .map(|c| f32::from_le_bytes(c.try_into().expect("4 bytes")))
            .collect())
    }
    fn text(&mut self, what: &str) -> Result<String, DeltaError> {
        let n = self.len(1, what)?;
        String::from_utf8(self.take(n, what)?.to_vec())
            .map_err(|_| DeltaError::Damaged(format!("{what} is not UTF-8")))
    }
    fn header(&mut self) -> Result<Header, DeltaError> {
        let name = self.text("name")?;
        let provenance = self.text("provenance")?;
        let edited = self.u8("edited")? != 0;
        let n = self.len(1, "edited clusters")?;
        let edited_clusters = self
            .take(n, "edited clusters")?
            .iter()
            .map(|&b| b != 0)
            .collect();
        Ok(Header {
            name,
            provenance,
            edited,
            edited_clusters,
        })
    }
    fn cluster(&mut self) -> Result<Cluster, DeltaError> {
        let n = self.len(33, "bases")?;
        let mut bases = Vec::with_capacity(n);
        for _ in 0..n {
            let id = self.u8("basis model")?;
            let model = *BrdfModel::ALL
                .get(usize::from(id))
                .ok_or_else(|| DeltaError::Damaged(format!("basis model id {id}")))?;
            let count = self.len(8, "basis parameters")?;
            let values = (0..count)
                .map(|_| self.f64("basis parameters"))
                .collect::<Result<Vec<_>, _>>()?;
            let named: Vec<(&str, f64)> = model
                .param_specs()
                .iter()
                .map(|s| s.name)
                .zip(values)
                .collect();
            let n = DVec3::new(
                self.f64("normal")?,
                self.f64("normal")?,
                self.f64("normal")?,
            );
            let brdf = AnalyticBrdf::new(model, &named)
                .map_err(|e| DeltaError::Damaged(format!("basis: {e}")))?;
            bases.push(
                BasisFunction::new(brdf, n)
                    .map_err(|e| DeltaError::Damaged(format!("basis: {e}")))?,
            );
        }
        Ok(Cluster { bases })
    }
    fn entries(&mut self, texels: usize) -> Result<Entries, DeltaError> {
        let n = self.len(4, "weight offsets")?;
        if n != texels + usize::from(texels > 0) {
            return Err(DeltaError::Damaged(
                "weight offsets do not match the texels".into(),
            ));
        }
        let offsets = (0..n)
            .map(|_| self.u32("weight offsets"))
            .collect::<Result<Vec<_>, _>>()?;
        let m = self.len(14, "weights")?;
        let mut e = Entries {
            offsets,
            basis: Vec::with_capacity(m),
            rgb: Vec::with_capacity(m),
        };
        for _ in 0..m {
            let b = self.take(14, "weights")?;
            e.basis.push(u16::from_le_bytes([b[0], b[1]]));
            let f = |i: usize| f32::from_le_bytes(b[i..i + 4].try_into().expect("4 bytes"));
            e.rgb.push([f(2), f(6), f(10)]);
        }
        let ok = e.offsets.first().is_none_or(|&o| o == 0)
            && e.offsets.windows(2).all(|w| w[0] <= w[1])
            && e.offsets.last().is_none_or(|&o| o as usize == m);
        if !ok {
            return Err(DeltaError::Damaged(
                "weight offsets are not a CSR index".into(),
            ));
        }
        Ok(e)
    }
    fn dirs(&mut self, what: &str) -> Result<Vec<DVec3>, DeltaError> {
        let n = self.len(24, what)?;
        (0..n)
            .map(|_| {
                Ok(DVec3::new(
                    self.f64(what)?,
                    self.f64(what)?,
                    self.f64(what)?,
                ))
            })
            .collect()
    }
    fn residual(&mut self) -> Result<Option<Arc<Residual>>, DeltaError> {
        if self.u8("residual")? == 0 {
            return Ok(None);
        }
        Ok(Some(Arc::new(Residual {
            light_dirs: self.dirs("residual light directions")?,
            view_dirs: self.dirs("residual view directions")?,
            npca: self.u32("residual npca")? as usize,
            mean: self.f32s("residual mean")?,
            components: self.f32s("residual components")?,
            coefficients: self.f32s("residual coefficients")?,
        })))
    }
    fn view(&mut self) -> Result<BasisView, DeltaError> {
        let mut v = BasisView::default();
        for solo in [false, true] {
            let n = self.len(8, "view")?;
            for _ in 0..n {
                let (c, b) = (self.u32("view")? as usize, self.u32("view")? as usize);
                if solo {
                    v.set_solo(c, b, true);
                } else {
                    v.set_muted(c, b, true);
                }
            }
        }
        Ok(v)
    }
}

impl PackDelta {
    /// The byte form (little-endian; docs/formats/journal.md).
    pub fn encode(&self) -> Vec<u8> {
        let mut o = Out::default();
        o.0.extend_from_slice(MAGIC);
        o.u32(self.width);
        o.u32(self.height);
        match &self.header {
            None => o.u8(0),
            Some(h) => {
                o.u8(1);
                o.header(&h[0]);
                o.header(&h[1]);
            }
        }
        o.len(self.clusters.len());
        for (c, s) in &self.clusters {
            o.u32(*c);
            o.cluster(&s[0]);
            o.cluster(&s[1]);
        }
        o.len(self.texels.len());
        self.texels.iter().for_each(|&t| o.u32(t));
        o.entries(&self.weights[0]);
        o.entries(&self.weights[1]);
        match &self.residual {
            None => o.u8(0),
            Some(r) => {
                o.u8(1);
                o.residual(&r[0]);
                o.residual(&r[1]);
            }
        }
        match &self.view {
            None => o.u8(0),
            Some(v) => {
                o.u8(1);
                o.view(&v[0]);
                o.view(&v[1]);
            }
        }
        o.0
    }

    /// Reads the byte form; damaged or foreign bytes are an error, never a panic.
    /// Whether the delta fits a material is checked when it is stepped.
    pub fn decode(bytes: &[u8]) -> Result<Self, DeltaError> {
        let mut i = In(bytes);
        if i.take(4, "magic")? != MAGIC {
            return Err(DeltaError::Damaged("not a pack delta".into()));
        }
        let (width, height) = (i.u32("width")?, i.u32("height")?);
        let header = match i.u8("header flag")? {
            0 => None,
            _ => Some([i.header()?, i.header()?]),
        };
        let n = i.len(12, "clusters")?;
        let mut clusters = Vec::with_capacity(n);
        for _ in 0..n {
            clusters.push((i.u32("cluster")?, [i.cluster()?, i.cluster()?]));
        }
        let n = i.len(4, "texels")?;
        let texels = (0..n)
            .map(|_| i.u32("texels"))
            .collect::<Result<Vec<_>, _>>()?;
        if texels.windows(2).any(|w| w[0] >= w[1]) {
            return Err(DeltaError::Damaged("texels are not ascending".into()));
        }
        let weights = [i.entries(n)?, i.entries(n)?];
        let residual = match i.u8("residual flag")? {
            0 => None,
            _ => Some([i.residual()?, i.residual()?]),
        };
        let view = match i.u8("view flag")? {
            0 => None,
            _ => Some([i.view()?, i.view()?]),
        };
        if !i.0.is_empty() {
            return Err(DeltaError::Damaged(format!(
                "{} bytes after the end",
                i.0.len()
            )));
        }
        Ok(Self {
            width,
            height,
            header,
            clusters,
            texels,
            weights,
            residual,
            view,
        })
    }
}

#[cfg(test)]
#[path = "delta_tests.rs"]
mod tests;
