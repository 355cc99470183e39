//! Which texels an import keeps, and how many values an imported BTF may hold. Measured
//! BTFs can be larger than memory (a UBO2014 file expands to 400 x 400 texels x 151 x
//! 151 pairs x 3 = 11 billion values), so the importers check the size of what they
//! would build before allocating it and take a rectangle of texels to keep.

use std::fmt;

/// Most values (texels x pairs x 3) an import builds: 2^31 f32 values, 8 GiB, the
/// largest `.btf` Meso reads (`file::MAX_FILE_BYTES`).
pub const MAX_IMPORT_VALUES: u64 = 1 << 31;

/// A rectangle of texels: columns `x .. x + width`, rows `y .. y + height`, row 0 the
/// top row (Meso's convention, docs/formats/btf.md).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct TexelRect {
    pub x: u32,
    pub y: u32,
    pub width: u32,
    pub height: u32,
}

impl fmt::Display for TexelRect {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{},{},{},{}", self.x, self.y, self.width, self.height)
    }
}

/// Why a rectangle or an import size is refused.
#[derive(Debug, thiserror::Error, Clone, PartialEq)]
pub enum CropError {
    #[error("texel rectangle `{0}`: expected X,Y,WIDTH,HEIGHT (four whole numbers)")]
    Syntax(String),
    #[error(
        "texel rectangle {rect} (x, y, width, height) is not inside the {width}x{height} texel grid, or is empty"
    )]
    Outside {
        rect: TexelRect,
        width: u32,
        height: u32,
    },
    #[error(
        "{texels} texels x {pairs} direction pairs x 3 = {values} values ({gib:.1} GiB as f32) is more than an import builds ({MAX_IMPORT_VALUES} values); keep fewer texels with --texels X,Y,W,H (at most {max_texels} texels)"
    )]
    TooLarge {
        texels: u64,
        pairs: u64,
        values: u64,
        gib: f64,
        max_texels: u64,
    },
}

impl TexelRect {
    /// The whole grid.
    pub fn full(width: u32, height: u32) -> Self {
        Self {
            x: 0,
            y: 0,
            width,
            height,
        }
    }

    /// Parses `X,Y,WIDTH,HEIGHT`.
    pub fn parse(text: &str) -> Result<Self, CropError> {
        let n: Vec<u32> = text
            .split(',')
            .map(|p| p.trim().parse::<u32>())
            .collect::<Result<_, _>>()
            .map_err(|_| CropError::Syntax(text.to_string()))?;
        match n[..] {
            [x, y, width, height] => Ok(Self {
                x,
                y,
                width,
                height,
            }),
            _ => Err(CropError::Syntax(text.to_string())),
        }
    }

    /// Checks the rectangle is non-empty and inside a `width` x `height` grid.
    pub fn check_inside(&self, width: u32, height: u32) -> Result<(), CropError> {
        let fits = |start: u32, len: u32, side: u32| {
            len > 0 && u64::from(start) + u64::from(len) <= u64::from(side)
        };
        if fits(self.x, self.width, width) && fits(self.y, self.height, height) {
            Ok(())
        } else {
            Err(CropError::Outside {
                rect: *self,
                width,
                height,
            })
        }
    }

    pub fn texels(&self) -> usize {
        self.width as usize * self.height as usize
    }
}

/// The texels of `rect` of `btf` as a BTF of their own (same directions and name).
pub fn crop(btf: &super::Btf, rect: TexelRect) -> Result<super::Btf, CropError> {
    rect.check_inside(btf.width(), btf.height())?;
    let mut data = Vec::with_capacity(rect.texels() * btf.pairs() * 3);
    for y in rect.y..rect.y + rect.height {
        for x in rect.x..rect.x + rect.width {
            data.extend_from_slice(btf.texel((y * btf.width() + x) as usize));
        }
    }
    Ok(super::Btf::new(
        btf.name().to_string(),
        format!("{} (texels {rect})", btf.provenance()),
        rect.width,
        rect.height,
        btf.light_dirs().to_vec(),
        btf.view_dirs().to_vec(),
        data,
    )
    .expect("a crop of a valid BTF is valid"))
}

/// Checks that `texels` texels of `pairs` direction pairs fit in an import.
pub fn check_budget(texels: u64, pairs: u64) -> Result<(), CropError> {
    let values = texels.saturating_mul(pairs).saturating_mul(3);
    if values <= MAX_IMPORT_VALUES {
        return Ok(());
    }
    Err(CropError::TooLarge {
        texels,
        pairs,
        values,
        gib: values as f64 * 4.0 / f64::from(1u32 << 30),
        max_texels: MAX_IMPORT_VALUES / (3 * pairs.max(1)),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rectangles_parse_and_must_fit() {
        let r = TexelRect::parse("1, 2,3,4").expect("parses");
        assert_eq!((r.x, r.y, r.width, r.height), (1, 2, 3, 4));
        assert_eq!(r.to_string(), "1,2,3,4");
        for bad in ["1,2,3", "1,2,3,4,5", "a,2,3,4", "-1,2,3,4", ""] {
            assert!(TexelRect::parse(bad).is_err(), "{bad}");
        }
        assert!(r.check_inside(4, 6).is_ok());
        assert!(r.check_inside(3, 6).is_err());
        assert!(r.check_inside(4, 5).is_err());
        let empty = TexelRect::parse("0,0,0,1").expect("parses");
        let e = empty.check_inside(4, 4).expect_err("empty").to_string();
        assert!(e.contains("0,0,0,1") && e.contains("4x4"), "{e}");
        // No overflow at the edge of u32.
        let far = TexelRect::parse("4294967295,0,2,1").expect("parses");
        assert!(far.check_inside(u32::MAX, 1).is_err());
    }

    #[test]
    fn a_crop_keeps_the_rectangles_texels() {
        let dirs = crate::btf::directions::rings(&[(0.0, 1), (45.0, 3)]);
        let data = (0..4 * 3 * 16 * 3).map(|i| i as f32).collect();
        let b = super::super::Btf::new("b".into(), "p".into(), 4, 3, dirs.clone(), dirs, data)
            .expect("valid");
        let c = crop(&b, TexelRect::parse("1,1,2,2").expect("rect")).expect("inside");
        assert_eq!((c.width(), c.height()), (2, 2));
        assert_eq!(c.texel(0), b.texel(5));
        assert_eq!(c.texel(3), b.texel(10));
        assert!(c.provenance().ends_with("(texels 1,1,2,2)"));
        assert!(crop(&b, TexelRect::parse("3,0,2,1").expect("rect")).is_err());
    }

    #[test]
    fn the_budget_names_the_largest_crop() {
        assert!(check_budget(256 * 256, 81 * 81).is_ok());
        let e = check_budget(400 * 400, 151 * 151)
            .expect_err("UBO2014 whole")
            .to_string();
        assert!(
            e.contains("--texels") && e.contains("at most 31394 texels"),
            "{e}"
        );
        assert!(check_budget(31394, 151 * 151).is_ok());
        assert!(check_budget(31395, 151 * 151).is_err());
    }
}
