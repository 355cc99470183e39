//! A `.btf` read texel block by texel block from disk, never whole: what lets
//! `meso fit` work on BTFs larger than memory (a 400 x 400 texel BTF on the Bonn
//! layout is 12.6 GB as f32). Opening parses only the container's header and the two
//! direction tensors and checks them as `file::read_btf` does (format, version,
//! metadata, tensor names, dtypes, shapes, offsets against the file's size, the
//! directions); values are read on demand with positioned reads (no shared cursor, so
//! rayon workers read at once) and checked finite as they arrive. No cache: the fitter
//! reads each block once, in order, and its few random reads are of the texel sample.

use std::collections::HashMap;
use std::fs::File;
use std::path::{Path, PathBuf};

use glam::DVec3;

use super::file::{BtfFileError, BtfFileErrorKind, FORMAT, VERSION};
use super::texels::TexelSource;
use super::{BtfError, MAX_SIDE, check_dirs};
use crate::container::ContainerError;

/// Largest container header read (the directions are tensors, so the header is small).
const MAX_HEADER_BYTES: u64 = 1 << 20;
/// Tensors of the format (docs/formats/btf.md).
const TENSORS: [&str; 3] = ["light_dirs", "view_dirs", "reflectance"];

/// The element type of the reflectance tensor.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Elem {
    F16,
    F32,
}

impl Elem {
    fn bytes(self) -> usize {
        match self {
            Elem::F16 => 2,
            Elem::F32 => 4,
        }
    }
}

/// An open `.btf` whose values stay on disk.
#[derive(Debug)]
pub struct OnDiskBtf {
    path: PathBuf,
    file: File,
    name: String,
    provenance: String,
    width: u32,
    height: u32,
    light_dirs: Vec<DVec3>,
    view_dirs: Vec<DVec3>,
    /// Byte offset of texel 0's first value.
    values_at: u64,
    elem: Elem,
}

/// One tensor's entry in the container header.
struct Entry {
    dtype: String,
    shape: Vec<usize>,
    range: (u64, u64),
}

fn invalid(problem: String) -> ContainerError {
    ContainerError::Invalid(problem)
}

/// A container header: its tensors by name and its metadata.
type Header = (HashMap<String, Entry>, HashMap<String, String>);

/// The header's tensors and metadata, parsed from its JSON.
fn parse_header(json: &[u8]) -> Result<Header, ContainerError> {
    let value: serde_json::Value =
        serde_json::from_slice(json).map_err(|e| invalid(format!("header is not JSON: {e}")))?;
    let object = value
        .as_object()
        .ok_or_else(|| invalid("header is not a JSON object".into()))?;
    let mut tensors = HashMap::new();
    let mut metadata = HashMap::new();
    for (key, v) in object {
        if key == "__metadata__" {
            let map = v
                .as_object()
                .ok_or_else(|| invalid("`__metadata__` is not an object".into()))?;
            for (k, s) in map {
                let s = s
                    .as_str()
                    .ok_or_else(|| invalid(format!("metadata `{k}` is not a string")))?;
                metadata.insert(k.clone(), s.to_string());
            }
            continue;
        }
        let bad = |what: &str| invalid(format!("tensor `{key}`: {what}"));
        let dtype = v["dtype"]
            .as_str()
            .ok_or_else(|| bad("no dtype"))?
            .to_string();
        let shape = v["shape"]
            .as_array()
            .ok_or_else(|| bad("no shape"))?
            .iter()
            .map(|d| {
                d.as_u64()
                    .map(|d| d as usize)
                    .ok_or_else(|| bad("shape is not counts"))
            })
            .collect::<Result<Vec<usize>, _>>()?;
        let offsets = v["data_offsets"]
            .as_array()
            .filter(|a| a.len() == 2)
            .ok_or_else(|| bad("no data_offsets [begin, end]"))?;
        let (Some(a), Some(b)) = (offsets[0].as_u64(), offsets[1].as_u64()) else {
            return Err(bad("data_offsets are not byte counts"));
        };
        if a > b {
            return Err(bad("data_offsets end before they begin"));
        }
        tensors.insert(
            key.clone(),
            Entry {
                dtype,
                shape,
                range: (a, b),
            },
        );
    }
    Ok((tensors, metadata))
}

#[cfg(unix)]
fn read_at(file: &File, buf: &mut [u8], at: u64) -> std::io::Result<()> {
    std::os::unix::fs::FileExt::read_exact_at(file, buf, at)
}

#[cfg(windows)]
fn read_at(file: &File, mut buf: &mut [u8], mut at: u64) -> std::io::Result<()> {
    use std::os::windows::fs::FileExt;
    while !buf.is_empty() {
        match file.seek_read(buf, at)? {
            0 => return Err(std::io::ErrorKind::UnexpectedEof.into()),
            n => {
                buf = &mut buf[n..];
                at += n as u64;
            }
        }
    }
    Ok(())
}

impl OnDiskBtf {
    /// Opens `path` and checks everything but the values (see the module comment).
    pub fn open(path: &Path) -> Result<Self, BtfFileError> {
        Self::open_inner(path).map_err(|kind| BtfFileError::at(path, kind))
    }

    fn open_inner(path: &Path) -> Result<Self, BtfFileErrorKind> {
        let io = |e: std::io::Error| BtfFileErrorKind::from(ContainerError::Io(e));
        let file = File::open(path).map_err(io)?;
        let file_len = file.metadata().map_err(io)?.len();
        let mut len = [0u8; 8];
        read_at(&file, &mut len, 0)
            .map_err(|_| invalid(format!("{file_len} bytes: too short for a header")))?;
        let header_len = u64::from_le_bytes(len);
        if header_len > MAX_HEADER_BYTES || 8 + header_len > file_len {
            return Err(invalid(format!(
                "header of {header_len} bytes does not fit the file ({file_len} bytes; at most {MAX_HEADER_BYTES})"
            ))
            .into());
        }
        let mut json = vec![0u8; header_len as usize];
        read_at(&file, &mut json, 8).map_err(io)?;
        let (tensors, meta) = parse_header(&json)?;
        let text = |key: &'static str| {
            meta.get(key)
                .cloned()
                .ok_or_else(|| ContainerError::missing_metadata(key))
        };
        let found = text("format")?;
        if found != FORMAT {
            return Err(ContainerError::Metadata {
                key: "format",
                problem: format!("`{found}`, expected `{FORMAT}`"),
            }
            .into());
        }
        let found = text("version")?;
        if found != VERSION {
            return Err(ContainerError::Metadata {
                key: "version",
                problem: format!("`{found}`, this build reads `{VERSION}`"),
            }
            .into());
        }
        let count = |key: &'static str| -> Result<u32, ContainerError> {
            let raw = text(key)?;
            match raw.parse::<u32>() {
                Ok(v) if (1..=MAX_SIDE).contains(&v) => Ok(v),
                Ok(v) => Err(ContainerError::Metadata {
                    key,
                    problem: format!("{v} is outside 1..={MAX_SIDE}"),
                }),
                Err(_) => Err(ContainerError::Metadata {
                    key,
                    problem: format!("`{raw}` is not a count"),
                }),
            }
        };
        let (width, height) = (count("width")?, count("height")?);
        if let Some(n) = tensors.keys().find(|n| !TENSORS.contains(&n.as_str())) {
            return Err(ContainerError::UnknownTensor {
                name: n.clone(),
                format: ".btf format",
                version: VERSION,
            }
            .into());
        }
        let data_at = 8 + header_len;
        let end = tensors.values().map(|e| e.range.1).max().unwrap_or(0);
        if data_at + end != file_len {
            return Err(invalid(format!(
                "the tensors end at byte {}, the file has {file_len} bytes",
                data_at + end
            ))
            .into());
        }
        let entry =
            |name: &'static str| tensors.get(name).ok_or(ContainerError::MissingTensor(name));
        let dirs = |name: &'static str| -> Result<Vec<DVec3>, BtfFileErrorKind> {
            let e = entry(name)?;
            if e.dtype != "F64" {
                return Err(ContainerError::Dtype {
                    name,
                    found: e.dtype.clone(),
                    expected: "F64",
                }
                .into());
            }
            let n = e.shape.first().copied().unwrap_or(0);
            if e.shape.len() != 2 || e.shape[1] != 3 || e.range.1 - e.range.0 != n as u64 * 24 {
                return Err(ContainerError::Shape {
                    name,
                    found: e.shape.clone(),
                    expected: "[N, 3]".into(),
                }
                .into());
            }
            let mut bytes = vec![0u8; n * 24];
            read_at(&file, &mut bytes, data_at + e.range.0).map_err(io)?;
            Ok(super::file::dirs_of_bytes(&bytes))
        };
        let light_dirs = dirs("light_dirs")?;
        let view_dirs = dirs("view_dirs")?;
        check_dirs("light_dirs", &light_dirs).map_err(BtfFileErrorKind::Btf)?;
        check_dirs("view_dirs", &view_dirs).map_err(BtfFileErrorKind::Btf)?;
        let r = entry("reflectance")?;
        let elem = match r.dtype.as_str() {
            "F16" => Elem::F16,
            "F32" => Elem::F32,
            other => {
                return Err(ContainerError::Dtype {
                    name: "reflectance",
                    found: other.to_string(),
                    expected: "F16 or F32",
                }
                .into());
            }
        };
        let expected = [
            height as usize,
            width as usize,
            light_dirs.len(),
            view_dirs.len(),
            3,
        ];
        if r.shape != expected {
            return Err(ContainerError::Shape {
                name: "reflectance",
                found: r.shape.clone(),
                expected: format!("{expected:?} (height, width, lights, views, rgb)"),
            }
            .into());
        }
        let values = expected.iter().product::<usize>() as u64;
        if r.range.1 - r.range.0 != values * elem.bytes() as u64 {
            return Err(invalid(format!(
                "tensor `reflectance`: {} bytes for {values} values of {}",
                r.range.1 - r.range.0,
                r.dtype
            ))
            .into());
        }
        Ok(Self {
            path: path.to_path_buf(),
            values_at: data_at + r.range.0,
            file,
            name: text("name")?,
            provenance: text("provenance")?,
            width,
            height,
            light_dirs,
            view_dirs,
            elem,
        })
    }

    pub fn path(&self) -> &Path {
        &self.path
    }
    pub fn provenance(&self) -> &str {
        &self.provenance
    }
    /// Whether the file holds its values as F16 (else F32).
    pub fn stored_as_f16(&self) -> bool {
        self.elem == Elem::F16
    }

    /// Reads texels `first..` into `out` (see `TexelSource::read_texels`) and checks
    /// every value finite, naming the first that is not.
    pub fn read_block(&self, first: usize, out: &mut [f32]) -> Result<(), BtfFileError> {
        let per_texel = self.pairs() * 3;
        self.check_run("texels", first, out.len(), per_texel, self.texels())?;
        self.read_values(first * per_texel, out)
    }

    /// Reads rows `first..` into `out` (see `TexelSource::read_rows`: a row is one
    /// texel's values for one light), checked as `read_block` checks them.
    pub fn read_rows_f32(&self, first: usize, out: &mut [f32]) -> Result<(), BtfFileError> {
        let row = self.view_dirs.len() * 3;
        let rows = self.texels() * self.light_dirs.len();
        self.check_run("rows", first, out.len(), row, rows)?;
        self.read_values(first * row, out)
    }

    /// Whether `len` values from unit `first` on are whole units of `unit` values
    /// within the file's `units`; else an error naming the run.
    fn check_run(
        &self,
        what: &str,
        first: usize,
        len: usize,
        unit: usize,
        units: usize,
    ) -> Result<(), BtfFileError> {
        let count = len / unit.max(1);
        if unit == 0 || !len.is_multiple_of(unit) || first + count > units {
            return Err(BtfFileError::at(
                &self.path,
                BtfFileErrorKind::from(invalid(format!(
                    "{what} {first}..{}: outside the {units} {what} of the file",
                    first + len.div_ceil(unit.max(1))
                ))),
            ));
        }
        Ok(())
    }

    /// The error for value `i` (counted from the first of the file) that is not finite.
    fn non_finite(&self, i: usize, value: f32) -> BtfFileError {
        let (l, v) = (self.light_dirs.len(), self.view_dirs.len());
        BtfFileError::at(
            &self.path,
            BtfFileErrorKind::from(BtfError::NonFinite {
                texel: i / (l * v * 3),
                light: i / (v * 3) % l,
                view: i / 3 % v,
                channel: i % 3,
                value,
            }),
        )
    }

    /// Reads values `first..` (counted from the file's first) into `out`, checked finite.
    fn read_values(&self, first: usize, out: &mut [f32]) -> Result<(), BtfFileError> {
        let at = |kind: BtfFileErrorKind| BtfFileError::at(&self.path, kind);
        let size = self.elem.bytes();
        let offset = self.values_at + (first * size) as u64;
        // Read in slices of at most 4 MiB so the byte buffer stays small next to `out`.
        let chunk_values = (4 << 20) / size;
        let mut bytes = vec![0u8; chunk_values.min(out.len()) * size];
        for (i, part) in out.chunks_mut(chunk_values).enumerate() {
            let buf = &mut bytes[..part.len() * size];
            let pos = offset + (i * chunk_values * size) as u64;
            read_at(&self.file, buf, pos).map_err(|e| at(ContainerError::Io(e).into()))?;
            match self.elem {
                Elem::F16 => {
                    for (o, c) in part.iter_mut().zip(buf.chunks_exact(2)) {
                        *o = half::f16::from_le_bytes([c[0], c[1]]).to_f32();
                    }
                }
                Elem::F32 => {
                    for (o, c) in part.iter_mut().zip(buf.chunks_exact(4)) {
                        *o = f32::from_le_bytes([c[0], c[1], c[2], c[3]]);
                    }
                }
            }
        }
        if let Some(i) = out.iter().position(|x| !x.is_finite()) {
            return Err(self.non_finite(first + i, out[i]));
        }
        Ok(())
    }
}

impl OnDiskBtf {
    /// `read_block` for an F16 file, into f16 values as stored (no round trip through
    /// f32): what an out-of-core table's cache reads, twice as few bytes to convert.
    /// None for an F32 file.
    pub fn read_block_f16(
        &self,
        first: usize,
        out: &mut [half::f16],
    ) -> Option<Result<(), BtfFileError>> {
        let per_texel = self.pairs() * 3;
        let run = self.check_run("texels", first, out.len(), per_texel, self.texels());
        self.read_values_f16(run.map(|()| first * per_texel), out)
    }

    /// `read_rows_f32` into f16 values as stored; None for an F32 file.
    pub fn read_rows_f16(
        &self,
        first: usize,
        out: &mut [half::f16],
    ) -> Option<Result<(), BtfFileError>> {
        let row = self.view_dirs.len() * 3;
        let rows = self.texels() * self.light_dirs.len();
        let run = self.check_run("rows", first, out.len(), row, rows);
        self.read_values_f16(run.map(|()| first * row), out)
    }

    /// Values `first..` of an F16 file as stored, checked finite; None for an F32 file.
    fn read_values_f16(
        &self,
        first: Result<usize, BtfFileError>,
        out: &mut [half::f16],
    ) -> Option<Result<(), BtfFileError>> {
        if self.elem != Elem::F16 {
            return None;
        }
        let first = match first {
            Ok(first) => first,
            Err(e) => return Some(Err(e)),
        };
        let offset = self.values_at + (first * 2) as u64;
        let chunk_values = 2 << 20;
        let mut bytes = vec![0u8; chunk_values.min(out.len()) * 2];
        for (i, part) in out.chunks_mut(chunk_values).enumerate() {
            let buf = &mut bytes[..part.len() * 2];
            let pos = offset + (i * chunk_values * 2) as u64;
            if let Err(e) = read_at(&self.file, buf, pos) {
                return Some(Err(BtfFileError::at(
                    &self.path,
                    BtfFileErrorKind::from(ContainerError::Io(e)),
                )));
            }
            for (o, c) in part.iter_mut().zip(buf.chunks_exact(2)) {
                *o = half::f16::from_le_bytes([c[0], c[1]]);
            }
        }
        if let Some(i) = out.iter().position(|x| !x.is_finite()) {
            return Some(Err(self.non_finite(first + i, out[i].to_f32())));
        }
        Some(Ok(()))
    }
}

impl TexelSource for OnDiskBtf {
    fn name(&self) -> &str {
        &self.name
    }
    fn width(&self) -> u32 {
        self.width
    }
    fn height(&self) -> u32 {
        self.height
    }
    fn light_dirs(&self) -> &[DVec3] {
        &self.light_dirs
    }
    fn view_dirs(&self) -> &[DVec3] {
        &self.view_dirs
    }
    fn read_texels(&self, first: usize, out: &mut [f32]) -> Result<(), String> {
        self.read_block(first, out).map_err(|e| e.to_string())
    }
    fn values_are_f16(&self) -> bool {
        self.stored_as_f16()
    }
    fn read_texels_f16(&self, first: usize, out: &mut [half::f16]) -> Option<Result<(), String>> {
        self.read_block_f16(first, out)
            .map(|r| r.map_err(|e| e.to_string()))
    }
    fn reads_rows(&self) -> bool {
        true
    }
    fn read_rows(&self, first: usize, out: &mut [f32]) -> Result<(), String> {
        self.read_rows_f32(first, out).map_err(|e| e.to_string())
    }
    fn read_rows_f16(&self, first: usize, out: &mut [half::f16]) -> Option<Result<(), String>> {
        OnDiskBtf::read_rows_f16(self, first, out).map(|r| r.map_err(|e| e.to_string()))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::btf::file::{BtfPrecision, write_btf};
    use crate::btf::{Btf, directions};

    fn small(w: u32, h: u32) -> Btf {
        let dirs = directions::rings(&[(0.0, 1), (45.0, 3)]);
        let n = (w * h) as usize * dirs.len() * dirs.len() * 3;
        let data: Vec<f32> = (0..n).map(|i| (i % 97) as f32 * 0.01 + 0.125).collect();
        Btf::new("t".into(), "p".into(), w, h, dirs.clone(), dirs, data).expect("valid")
    }

    #[test]
    fn blocks_equal_the_whole_file_in_both_precisions() {
        let dir = tempfile::tempdir().expect("temp dir");
        let btf = small(5, 3);
        for precision in [BtfPrecision::F32, BtfPrecision::F16] {
            let path = dir.path().join("a.btf");
            write_btf(&path, &btf, precision).expect("write");
            let whole = crate::btf::file::read_btf(&path).expect("read");
            let disk = OnDiskBtf::open(&path).expect("open");
            assert_eq!(
                (
                    TexelSource::width(&disk),
                    TexelSource::height(&disk),
                    disk.provenance()
                ),
                (5, 3, "p")
            );
            assert_eq!(TexelSource::light_dirs(&disk), whole.light_dirs());
            let per = whole.pairs() * 3;
            // Blocks of 4 texels, the last one short, bit-equal to the whole read.
            for first in (0..15).step_by(4) {
                let count = 4.min(15 - first);
                let mut out = vec![0.0f32; count * per];
                disk.read_texels(first, &mut out).expect("block");
                let want = &whole.data()[first * per..(first + count) * per];
                assert!(
                    out.iter()
                        .zip(want)
                        .all(|(a, b)| a.to_bits() == b.to_bits())
                );
            }
            let mut past = vec![0.0f32; 2 * per];
            let e = disk.read_texels(14, &mut past).expect_err("past the end");
            assert!(e.contains("texels 14..16"), "{e}");
        }
    }

    #[test]
    fn rows_equal_the_whole_file_and_the_default_row_reader() {
        let dir = tempfile::tempdir().expect("temp dir");
        let btf = small(3, 2);
        let (nl, row) = (btf.light_dirs().len(), btf.view_dirs().len() * 3);
        let rows = btf.texels() * nl;
        for precision in [BtfPrecision::F32, BtfPrecision::F16] {
            let path = dir.path().join("r.btf");
            write_btf(&path, &btf, precision).expect("write");
            let whole = crate::btf::file::read_btf(&path).expect("read");
            let disk = OnDiskBtf::open(&path).expect("open");
            assert!(disk.reads_rows() && !whole.reads_rows());
            // Runs of 3 rows across texel boundaries, the last one short.
            for first in (0..rows).step_by(3) {
                let count = 3.min(rows - first);
                let want = &whole.data()[first * row..(first + count) * row];
                let mut out = vec![0.0f32; count * row];
                disk.read_rows(first, &mut out).expect("rows");
                assert!(
                    out.iter()
                        .zip(want)
                        .all(|(a, b)| a.to_bits() == b.to_bits())
                );
                // The default reader (through whole texels) agrees.
                let mut via = vec![0.0f32; count * row];
                whole.read_rows(first, &mut via).expect("rows");
                assert!(
                    via.iter()
                        .zip(want)
                        .all(|(a, b)| a.to_bits() == b.to_bits())
                );
                let mut halves = vec![half::f16::ZERO; count * row];
                match TexelSource::read_rows_f16(&disk, first, &mut halves) {
                    Some(r) => {
                        r.expect("f16 rows");
                        assert_eq!(precision, BtfPrecision::F16);
                        assert!(halves.iter().zip(want).all(|(a, b)| a.to_f32() == *b));
                    }
                    None => assert_eq!(precision, BtfPrecision::F32),
                }
            }
            let mut past = vec![0.0f32; 2 * row];
            let e = disk
                .read_rows(rows - 1, &mut past)
                .expect_err("past the end");
            assert!(
                e.contains(&format!("rows {}..{}", rows - 1, rows + 1)),
                "{e}"
            );
            let e = whole
                .read_rows(rows - 1, &mut past)
                .expect_err("past the end");
            assert!(e.contains("rows"), "{e}");
        }
    }

    #[test]
    fn damaged_files_are_refused_naming_the_part() {
        let dir = tempfile::tempdir().expect("temp dir");
        let path = dir.path().join("a.btf");
        write_btf(&path, &small(2, 2), BtfPrecision::F32).expect("write");
        let good = std::fs::read(&path).expect("read");
        // Cut short: the offsets no longer match the size.
        std::fs::write(&path, &good[..good.len() - 4]).expect("write");
        let e = OnDiskBtf::open(&path).expect_err("cut").to_string();
        assert!(e.contains("a.btf") && e.contains("the file has"), "{e}");
        // Another format's name in the metadata.
        let text = String::from_utf8_lossy(&good).replacen("meso-btf", "meso-xyz", 1);
        std::fs::write(&path, text.as_bytes()).expect("write");
        let e = OnDiskBtf::open(&path).expect_err("format").to_string();
        assert!(e.contains("metadata `format`"), "{e}");
        // A NaN value is named by texel when its block is read.
        let mut bad = good.clone();
        let n = bad.len();
        bad[n - 4..].copy_from_slice(&f32::NAN.to_le_bytes());
        std::fs::write(&path, &bad).expect("write");
        let disk = OnDiskBtf::open(&path).expect("the header is fine");
        let per = disk.pairs() * 3;
        let mut out = vec![0.0f32; 4 * per];
        let e = disk.read_texels(0, &mut out).expect_err("NaN");
        assert!(e.contains("texel 3") && e.contains("not finite"), "{e}");
        // Read as rows (the last row of texel 3), named the same way.
        let row = disk.view_dirs().len() * 3;
        let mut last = vec![0.0f32; row];
        let e = disk
            .read_rows(4 * disk.light_dirs().len() - 1, &mut last)
            .expect_err("NaN");
        assert!(e.contains("texel 3") && e.contains("not finite"), "{e}");
        // Not a container at all.
        std::fs::write(&path, b"hello").expect("write");
        assert!(OnDiskBtf::open(&path).is_err());
    }
}
