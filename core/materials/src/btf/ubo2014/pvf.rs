//! PVF files: one PCA per view direction (docs/formats/ubo.md). Each view slot stores
//! a mean, coefficients and weights; one of the two sides runs over the texels and
//! stays in the file, the other (over the lights) is read at open.

use std::io::{Read, Seek, SeekFrom};

use rayon::prelude::*;

use super::{
    Cursor, Header, Kind, TexelRect, UboErrorKind, file_texel, read_common, read_extent,
    read_sampling, read_scalar, scalar_bytes, to_f32,
};

/// btflib's mark of the old layout: no meta data, the extent before the sampling.
const OLD_MAGIC: i32 = 301_074;

/// Which side a view slot's weights run over.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Side {
    /// Coefficients over (channel, light), weights over texels.
    Texels,
    /// Coefficients over (channel, texel), weights over lights.
    Lights,
}

/// One view's factorisation: value = coefficients[row] . weights[col] + mean[row].
struct Slot {
    scalar: u8,
    components: usize,
    /// `Side::Texels`: the means and coefficients over (channel, light), in memory.
    /// `Side::Lights`: the weights over lights (lights x components), in memory.
    means: Vec<f32>,
    small: Vec<f32>,
    /// Where the texel side starts: the weights (`Texels`), or the means then the
    /// coefficients (`Lights`).
    means_at: u64,
    texel_side_at: u64,
}

pub(super) struct PerView {
    side: Side,
    slots: Vec<Slot>,
}

/// Parses a PVF file's header and view slots.
pub(super) fn read<R: Read + Seek>(
    c: &mut Cursor<'_, R>,
    signature: &'static str,
) -> Result<(Header, PerView), UboErrorKind> {
    c.skip(signature.len() as u64, "the signature")?;
    let mut header = Header::empty(signature, Kind::Pvf);
    let slots = if c.i32("the PVF layout mark")? == OLD_MAGIC {
        c.u32("the largest component count")?;
        read_extent(c, &mut header)?;
        let slots = c.u32("the view-slot count")?;
        read_sampling(c, &mut header)?;
        slots
    } else {
        c.pos -= 4;
        c.src.seek(SeekFrom::Start(c.pos))?;
        read_common(c, &mut header)?;
        c.u32("the largest component count")?;
        c.u32("the view-slot count")?
    };
    let nv = header.view_angles.len();
    if slots as usize != nv {
        return Err(c.field(
            "the view-slot count",
            slots,
            &format!("must be the {nv} views (one factorisation per view)"),
        ));
    }
    let nl = header.light_angles.len() as u64;
    let texels = u64::from(header.width) * u64::from(header.height);
    let mut side = None;
    let mut parsed = Vec::with_capacity(nv);
    for v in 0..nv {
        let name = format!("view {v}'s factorisation");
        let scalar = read_scalar(c, &format!("{name}'s scalar size"))?;
        let k = u64::from(c.u32(&format!("{name}'s component count"))?);
        if k == 0 {
            return Err(c.field(
                &format!("{name}'s component count"),
                0,
                "must be at least 1",
            ));
        }
        let weights = u64::from(c.u32(&format!("{name}'s weight count"))?);
        let dimension = u64::from(c.u32(&format!("{name}'s dimension"))?);
        // btflib tells the layouts apart by the coefficients' rows, (channel, light)
        // first.
        let this = if dimension == 3 * nl && weights == texels {
            Side::Texels
        } else if dimension == 3 * texels && weights == nl {
            Side::Lights
        } else {
            return Err(c.field(
                &format!("{name}'s dimension"),
                format!("{dimension} (with {weights} weights)"),
                &format!(
                    "must be 3 x {nl} lights with {texels} texel weights, or 3 x {texels} texels with {nl} light weights"
                ),
            ));
        };
        if *side.get_or_insert(this) != this {
            return Err(c.field(
                &format!("{name}'s dimension"),
                dimension,
                "every view must store the same sides as view 0",
            ));
        }
        let s = scalar_bytes(scalar);
        let total = (k + dimension)
            .saturating_add(dimension.saturating_mul(k))
            .saturating_add(weights.saturating_mul(k))
            .saturating_mul(s);
        c.need(total, &format!("{name} ({k} components)"))?;
        c.skip(k * s, &format!("{name}'s eigenvalues"))?;
        let means_at = c.pos;
        let slot = match this {
            Side::Texels => {
                let means = to_f32(&c.bytes(dimension * s, &format!("{name}'s means"))?, scalar);
                let small = to_f32(
                    &c.bytes(dimension * k * s, &format!("{name}'s coefficients"))?,
                    scalar,
                );
                let texel_side_at = c.pos;
                c.skip(weights * k * s, &format!("{name}'s weights"))?;
                Slot {
                    scalar,
                    components: k as usize,
                    means,
                    small,
                    means_at,
                    texel_side_at,
                }
            }
            Side::Lights => {
                c.skip(dimension * s, &format!("{name}'s means"))?;
                let texel_side_at = c.pos;
                c.skip(dimension * k * s, &format!("{name}'s coefficients"))?;
                let small = to_f32(
                    &c.bytes(weights * k * s, &format!("{name}'s weights"))?,
                    scalar,
                );
                Slot {
                    scalar,
                    components: k as usize,
                    means: Vec::new(),
                    small,
                    means_at,
                    texel_side_at,
                }
            }
        };
        parsed.push(slot);
    }
    let side = side.unwrap_or(Side::Texels);
    Ok((
        header,
        PerView {
            side,
            slots: parsed,
        },
    ))
}

impl PerView {
    pub(super) fn components(&self) -> Vec<usize> {
        self.slots.iter().map(|s| s.components).collect()
    }

    pub(super) fn describe(&self) -> String {
        let k = self.components();
        let (lo, hi) = (
            k.iter().min().copied().unwrap_or(0),
            k.iter().max().copied().unwrap_or(0),
        );
        let components = if lo == hi {
            format!("{lo} components each")
        } else {
            format!("{lo} to {hi} components")
        };
        format!(
            "{} per-view factorisations ({components}), weights over {}",
            k.len(),
            match self.side {
                Side::Texels => "texels",
                Side::Lights => "lights",
            }
        )
    }

    /// The stored channels of the texels in `rect`, in Meso's order (texel, light,
    /// view, channel), one view slot read from the file at a time.
    pub(super) fn read_texels<R: Read + Seek>(
        &self,
        source: &mut R,
        header: &Header,
        rect: TexelRect,
    ) -> Result<Vec<f32>, UboErrorKind> {
        let (nl, nv) = (header.light_angles.len(), header.view_angles.len());
        let mut data = vec![0.0f32; rect.texels() * nl * nv * 3];
        for (v, slot) in self.slots.iter().enumerate() {
            let (k, s) = (slot.components, scalar_bytes(slot.scalar));
            // Per texel of `rect`: k weights (Texels), or 3 means and 3 x k coefficients
            // (Lights), read a row of `rect` at a time.
            let per_texel = match self.side {
                Side::Texels => k,
                Side::Lights => 3 + 3 * k,
            };
            let mut texel_side = Vec::with_capacity(rect.texels() * per_texel);
            let w = rect.width as usize;
            for y in rect.y..rect.y + rect.height {
                let j = file_texel(header, rect.x, y) as u64;
                match self.side {
                    Side::Texels => {
                        let at = slot.texel_side_at + j * (k as u64) * s;
                        texel_side.extend(read_at(source, at, w * k, slot.scalar)?);
                    }
                    Side::Lights => {
                        let means = read_at(source, slot.means_at + 3 * j * s, 3 * w, slot.scalar)?;
                        let at = slot.texel_side_at + 3 * j * (k as u64) * s;
                        let coefficients = read_at(source, at, 3 * w * k, slot.scalar)?;
                        for x in 0..w {
                            texel_side.extend_from_slice(&means[3 * x..3 * x + 3]);
                            texel_side.extend_from_slice(&coefficients[3 * k * x..3 * k * (x + 1)]);
                        }
                    }
                }
            }
            let dot = |a: &[f32], b: &[f32]| a.iter().zip(b).map(|(x, y)| x * y).sum::<f32>();
            data.par_chunks_mut(nl * nv * 3)
                .zip(texel_side.par_chunks(per_texel))
                .for_each(|(out, texel)| {
                    for l in 0..nl {
                        for ch in 0..3 {
                            out[(l * nv + v) * 3 + ch] = match self.side {
                                Side::Texels => {
                                    // Row channel + 3 light (btflib's sub2ind).
                                    let row = ch + 3 * l;
                                    dot(texel, &slot.small[row * k..(row + 1) * k])
                                        + slot.means[row]
                                }
                                Side::Lights => {
                                    let c = &texel[3 + ch * k..3 + (ch + 1) * k];
                                    dot(c, &slot.small[l * k..(l + 1) * k]) + texel[ch]
                                }
                            };
                        }
                    }
                });
        }
        Ok(data)
    }
}

/// `n` scalars of `scalar` bytes at byte `at` (inside the file: checked at open).
fn read_at<R: Read + Seek>(
    source: &mut R,
    at: u64,
    n: usize,
    scalar: u8,
) -> Result<Vec<f32>, UboErrorKind> {
    let mut raw = vec![0u8; n * usize::from(scalar)];
    source.seek(SeekFrom::Start(at))?;
    source.read_exact(&mut raw)?;
    Ok(to_f32(&raw, scalar))
}
