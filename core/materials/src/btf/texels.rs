//! Where a fit reads texels from: a BTF in memory (`Btf`) or one read from disk block by
//! block (`on_disk::OnDiskBtf`). The fitter asks for runs of consecutive texels, so a
//! source needs neither the whole BTF in memory nor random access finer than a texel.

use glam::DVec3;

use super::Btf;

/// Texels on demand: the directions and grid of a BTF, and its values (texel-major,
/// `L * V * 3` per texel as in `Btf::texel`) read a run of texels at a time.
pub trait TexelSource: Sync {
    fn name(&self) -> &str;
    fn width(&self) -> u32;
    fn height(&self) -> u32;
    fn light_dirs(&self) -> &[DVec3];
    fn view_dirs(&self) -> &[DVec3];
    /// Fills `out` with the texels from `first` on (`out.len()` must be a multiple of
    /// `pairs() * 3`); a source that cannot says which texel and why.
    fn read_texels(&self, first: usize, out: &mut [f32]) -> Result<(), String>;

    fn texels(&self) -> usize {
        self.width() as usize * self.height() as usize
    }
    /// Direction pairs per texel, `L * V`.
    fn pairs(&self) -> usize {
        self.light_dirs().len() * self.view_dirs().len()
    }
    /// Whether every value is known to be an f16 without reading it (an F16 file).
    fn values_are_f16(&self) -> bool {
        false
    }
    /// `read_texels` into f16 values, for a source that holds them so (an F16 file);
    /// None for one that does not.
    fn read_texels_f16(&self, _first: usize, _out: &mut [half::f16]) -> Option<Result<(), String>> {
        None
    }
    /// Whether `read_rows` reads only the rows asked for (a file: one positioned read),
    /// so that a cache may hold blocks of single rows; a source that computes whole
    /// texels (the default `read_rows`) keeps the cache's blocks whole texels.
    fn reads_rows(&self) -> bool {
        false
    }
    /// Fills `out` with rows from `first` on, a row being one texel's values for one
    /// light (`V * 3`, row `t * L + l`; `out.len()` a multiple of `V * 3`). By default
    /// through `read_texels` of the texels they lie in.
    fn read_rows(&self, first: usize, out: &mut [f32]) -> Result<(), String> {
        let row = self.view_dirs().len() * 3;
        let lights = self.light_dirs().len();
        let count = out.len() / row.max(1);
        let rows = self.texels() * lights;
        if row == 0 || !out.len().is_multiple_of(row) || first + count > rows {
            return Err(format!(
                "rows {first}..{}: outside the {rows} rows (texel x light) of the BTF",
                first + out.len().div_ceil(row.max(1))
            ));
        }
        if count == 0 {
            return Ok(());
        }
        let (t0, t1) = (first / lights, (first + count - 1) / lights + 1);
        let mut texels = vec![0.0f32; (t1 - t0) * lights * row];
        self.read_texels(t0, &mut texels)?;
        let skip = (first - t0 * lights) * row;
        out.copy_from_slice(&texels[skip..skip + out.len()]);
        Ok(())
    }
    /// `read_rows` into f16 values, for a source that holds them so; None otherwise.
    fn read_rows_f16(&self, _first: usize, _out: &mut [half::f16]) -> Option<Result<(), String>> {
        None
    }
}

impl TexelSource for Btf {
    fn name(&self) -> &str {
        Btf::name(self)
    }
    fn width(&self) -> u32 {
        Btf::width(self)
    }
    fn height(&self) -> u32 {
        Btf::height(self)
    }
    fn light_dirs(&self) -> &[DVec3] {
        Btf::light_dirs(self)
    }
    fn view_dirs(&self) -> &[DVec3] {
        Btf::view_dirs(self)
    }
    fn read_texels(&self, first: usize, out: &mut [f32]) -> Result<(), String> {
        let n = Btf::pairs(self) * 3;
        let start = first * n;
        let end = start + out.len();
        if !out.len().is_multiple_of(n) || end > self.data().len() {
            return Err(format!(
                "texels {first}..{}: outside the {} texels of the BTF",
                first + out.len().div_ceil(n),
                Btf::texels(self)
            ));
        }
        out.copy_from_slice(&self.data()[start..end]);
        Ok(())
    }
}
