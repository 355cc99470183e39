//! The little-endian binary codec of the fit's own files (a shard's part,
//! docs/formats/fit-part.md; a fit's model, docs/formats/fit-model.md): a writer, a
//! reader whose every error names what it was reading, and the dictionaries' bases,
//! which both files hold. Floats are stored as their bits, never rounded.

use glam::DVec3;

use meso_materials::brdf::{AnalyticBrdf, BasisFunction, BrdfModel};
use meso_materials::spmm::Cluster;
use meso_materials::spmm::pack::model_id;

/// Little-endian writer.
#[derive(Default)]
pub(crate) struct Out(pub(crate) Vec<u8>);

impl Out {
    pub(crate) fn u8(&mut self, v: u8) {
        self.0.push(v);
    }
    pub(crate) fn u16(&mut self, v: u16) {
        self.0.extend_from_slice(&v.to_le_bytes());
    }
    pub(crate) fn u32(&mut self, v: u32) {
        self.0.extend_from_slice(&v.to_le_bytes());
    }
    pub(crate) fn u64(&mut self, v: u64) {
        self.0.extend_from_slice(&v.to_le_bytes());
    }
    pub(crate) fn f32(&mut self, v: f32) {
        self.u32(v.to_bits());
    }
    pub(crate) fn f64(&mut self, v: f64) {
        self.u64(v.to_bits());
    }
    pub(crate) fn str(&mut self, s: &str) {
        self.u32(s.len() as u32);
        self.0.extend_from_slice(s.as_bytes());
    }
    pub(crate) fn f32s(&mut self, v: &[f32]) {
        self.u64(v.len() as u64);
        v.iter().for_each(|&x| self.f32(x));
    }
    pub(crate) fn dirs(&mut self, v: &[DVec3]) {
        self.u32(v.len() as u32);
        v.iter()
            .flat_map(|d| d.to_array())
            .for_each(|x| self.f64(x));
    }
}

/// Little-endian reader; errors say what was being read and where.
pub(crate) struct In<'a> {
    pub(crate) bytes: &'a [u8],
    /// The next byte to read.
    pub(crate) at: usize,
}

impl<'a> In<'a> {
    fn take(&mut self, n: usize, what: &str) -> Result<&'a [u8], String> {
        if self.bytes.len() - self.at < n {
            return Err(format!("cut short at byte {} reading {what}", self.at));
        }
        let s = &self.bytes[self.at..self.at + n];
        self.at += n;
        Ok(s)
    }
    pub(crate) fn u8(&mut self, what: &str) -> Result<u8, String> {
        Ok(self.take(1, what)?[0])
    }
    /// The next `N` bytes as an array.
    fn array<const N: usize>(&mut self, what: &str) -> Result<[u8; N], String> {
        let mut out = [0u8; N];
        out.copy_from_slice(self.take(N, what)?);
        Ok(out)
    }
    pub(crate) fn u16(&mut self, what: &str) -> Result<u16, String> {
        self.array(what).map(u16::from_le_bytes)
    }
    pub(crate) fn u32(&mut self, what: &str) -> Result<u32, String> {
        self.array(what).map(u32::from_le_bytes)
    }
    pub(crate) fn u64(&mut self, what: &str) -> Result<u64, String> {
        self.array(what).map(u64::from_le_bytes)
    }
    pub(crate) fn f32(&mut self, what: &str) -> Result<f32, String> {
        Ok(f32::from_bits(self.u32(what)?))
    }
    pub(crate) fn f64(&mut self, what: &str) -> Result<f64, String> {
        Ok(f64::from_bits(self.u64(what)?))
    }
    /// A count of items of `size` bytes each that must fit in what is left.
    pub(crate) fn count(&mut self, n: u64, size: usize, what: &str) -> Result<usize, String> {
        let left = (self.bytes.len() - self.at) as u64;
        if n.saturating_mul(size as u64) > left {
            return Err(format!(
                "{what}: {n} entries do not fit the {left} bytes left"
            ));
        }
        Ok(n as usize)
    }
    pub(crate) fn str(&mut self, what: &str) -> Result<String, String> {
        let n = self.u32(what)? as u64;
        let n = self.count(n, 1, what)?;
        String::from_utf8(self.take(n, what)?.to_vec()).map_err(|_| format!("{what} is not UTF-8"))
    }
    pub(crate) fn f32s(&mut self, what: &str) -> Result<Vec<f32>, String> {
        let n = self.u64(what)?;
        let n = self.count(n, 4, what)?;
        (0..n).map(|_| self.f32(what)).collect()
    }
    pub(crate) fn dirs(&mut self, what: &str) -> Result<Vec<DVec3>, String> {
        let n = self.u32(what)? as u64;
        let n = self.count(n, 24, what)?;
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
}

/// Each cluster's bases: a count, then per basis its model id, parameter count,
/// parameters and normal.
pub(crate) fn write_clusters(o: &mut Out, clusters: &[Cluster]) {
    for c in clusters {
        o.u32(c.bases.len() as u32);
        for b in &c.bases {
            o.u8(model_id(b.brdf().model()));
            let params = b.brdf().param_values();
            o.u8(params.len() as u8);
            params.iter().for_each(|&x| o.f64(x));
            b.normal().to_array().iter().for_each(|&x| o.f64(x));
        }
    }
}

pub(crate) fn read_basis(i: &mut In, what: &str) -> Result<BasisFunction, String> {
    let id = i.u8(what)? as usize;
    let model = *BrdfModel::ALL
        .get(id)
        .ok_or_else(|| format!("{what}: model id {id} is not 0..=6"))?;
    let n = i.u8(what)? as usize;
    let specs = model.param_specs();
    if n != specs.len() {
        return Err(format!(
            "{what}: {n} parameters, model `{}` has {}",
            model.name(),
            specs.len()
        ));
    }
    let values: Vec<f64> = (0..n).map(|_| i.f64(what)).collect::<Result<_, _>>()?;
    let named: Vec<(&str, f64)> = specs.iter().map(|s| s.name).zip(values).collect();
    let brdf = AnalyticBrdf::new(model, &named).map_err(|e| format!("{what}: {e}"))?;
    let normal = DVec3::new(i.f64(what)?, i.f64(what)?, i.f64(what)?);
    BasisFunction::new(brdf, normal).map_err(|e| format!("{what}: {e}"))
}
