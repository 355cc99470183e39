//! BDI files: Bonn's directional images, every texel's values as half floats in chunks
//! of scan lines (docs/formats/ubo.md). Meso reads the uncompressed forms btflib reads,
//! full (every texel stored) and sparse (only the texels of a mask), one texel at a
//! time straight from the file.

use std::io::{Read, Seek, SeekFrom};

use super::{
    Cursor, Header, Kind, TexelRect, UboErrorKind, file_texel, read_extent, read_meta,
    read_sampling, skip_rotations,
};

/// btflib's compression codes.
const FULL: u8 = 0;
const BZIP2: u8 = 1;
const SPARSE: u8 = 2;

/// Where each stored texel's values are.
pub(super) struct Chunks {
    sparse: bool,
    /// Texels per chunk: the width times the scan lines per chunk.
    per_chunk: u64,
    /// Where each chunk's values start (after its byte count).
    starts: Vec<u64>,
    /// Sparse files: the storage index of each file texel (x + width y), `None` where
    /// the mask leaves it out.
    storage: Vec<Option<u32>>,
    stored: u64,
    lines: u32,
}

/// Parses a BDI header and finds its chunks (reading only their byte counts).
pub(super) fn read<R: Read + Seek>(
    c: &mut Cursor<'_, R>,
    signature: &'static str,
    header_flag: bool,
) -> Result<(Header, Chunks), UboErrorKind> {
    c.skip(signature.len() as u64, "the signature")?;
    let mut header = Header::empty(signature, Kind::Bdi { header_flag });
    read_meta(c, &mut header)?;
    read_sampling(c, &mut header)?;
    read_extent(c, &mut header)?;
    let lines = c.u32("the scan lines per chunk")?;
    if lines == 0 {
        return Err(c.field("the scan lines per chunk", 0, "must be at least 1"));
    }
    // Without the header flag btflib takes the chunks to be bzip2-compressed.
    let compression = if header_flag {
        c.u8("the compression")?
    } else {
        BZIP2
    };
    match compression {
        FULL | SPARSE => {}
        BZIP2 => {
            return Err(UboErrorKind::Unsupported {
                signature,
                what: "bzip2-compressed BDI (btflib does not read them either)",
            });
        }
        other => {
            return Err(UboErrorKind::Field {
                part: "the compression".into(),
                offset: c.pos - 1,
                value: other.to_string(),
                rule: "must be 0 (full) or 2 (sparse); 1 (bzip2) is not read".into(),
            });
        }
    }
    let (w, h) = (header.width as usize, header.height as usize);
    // btflib reads the mask as a width x height matrix: the byte of (x, y) is y + h x.
    let mask = c.bytes((w * h) as u64, "the texel mask")?;
    // A third-last `R` (as in `!BDIF06R2!`) also means rotations follow (btflib).
    let sig = signature.as_bytes();
    if sig.ends_with(b"R") || sig.get(sig.len().saturating_sub(3)) == Some(&b'R') {
        header.rotations = skip_rotations(c)?;
    }
    let sparse = compression == SPARSE;
    let mut storage = Vec::new();
    let stored = if sparse {
        storage = vec![None; w * h];
        let mut n = 0u32;
        // Storage order is x fastest, then y (btflib's logical index).
        for y in 0..h {
            for x in 0..w {
                if mask[y + h * x] != 0 {
                    storage[x + w * y] = Some(n);
                    n += 1;
                }
            }
        }
        u64::from(n)
    } else {
        (w * h) as u64
    };
    let per_chunk = w as u64 * u64::from(lines);
    let count = stored.div_ceil(per_chunk);
    let texel_bytes = texel_bytes(&header);
    let mut starts = Vec::with_capacity(count as usize);
    for chunk in 0..count {
        let part = format!("chunk {chunk}'s byte count");
        let bytes = u64::from(c.u32(&part)?);
        let holds = per_chunk.min(stored - chunk * per_chunk);
        if bytes < holds * texel_bytes {
            return Err(c.field(
                &part,
                bytes,
                &format!(
                    "must hold its {holds} texels of {texel_bytes} bytes ({} bytes)",
                    holds * texel_bytes
                ),
            ));
        }
        starts.push(c.pos);
        c.skip(bytes, &format!("chunk {chunk}"))?;
    }
    // As in btflib, bytes after the last chunk are not looked at.
    Ok((
        header,
        Chunks {
            sparse,
            per_chunk,
            starts,
            storage,
            stored,
            lines,
        },
    ))
}

/// Bytes of one texel's values: 3 channels x lights x views half floats.
fn texel_bytes(header: &Header) -> u64 {
    3 * 2 * (header.light_angles.len() * header.view_angles.len()) as u64
}

impl Chunks {
    pub(super) fn describe(&self, header: &Header) -> String {
        format!(
            "directional images in {} chunk{} of {} scan lines, half floats, {} of {} texels stored{}",
            self.starts.len(),
            if self.starts.len() == 1 { "" } else { "s" },
            self.lines,
            self.stored,
            u64::from(header.width) * u64::from(header.height),
            if self.sparse {
                " (the others read as 0)"
            } else {
                ""
            }
        )
    }

    /// The values of the texels in `rect`, in Meso's order (texel, light, view,
    /// channel); texels the mask leaves out are 0, as btflib returns them.
    pub(super) fn read_texels<R: Read + Seek>(
        &self,
        source: &mut R,
        header: &Header,
        rect: TexelRect,
    ) -> Result<Vec<f32>, UboErrorKind> {
        let (nl, nv) = (header.light_angles.len(), header.view_angles.len());
        let per_texel = nl * nv * 3;
        let mut data = vec![0.0f32; rect.texels() * per_texel];
        let mut raw = vec![0u8; texel_bytes(header) as usize];
        for (t, out) in data.chunks_mut(per_texel).enumerate() {
            let (x, y) = (t as u32 % rect.width, t as u32 / rect.width);
            let j = file_texel(header, rect.x + x, rect.y + y);
            let index = if self.sparse {
                match self.storage[j] {
                    Some(i) => u64::from(i),
                    None => continue,
                }
            } else {
                j as u64
            };
            let (chunk, within) = (index / self.per_chunk, index % self.per_chunk);
            source.seek(SeekFrom::Start(
                self.starts[chunk as usize] + within * raw.len() as u64,
            ))?;
            source.read_exact(&mut raw)?;
            // The file runs channel fastest, then light, then view.
            for (i, h) in raw.chunks_exact(2).enumerate() {
                let (ch, l, v) = (i % 3, i / 3 % nl, i / (3 * nl));
                out[(l * nv + v) * 3 + ch] = half::f16::from_le_bytes([h[0], h[1]]).to_f32();
            }
        }
        Ok(data)
    }
}
