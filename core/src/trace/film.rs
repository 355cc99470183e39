//! The progressive film: per pixel a running sum in f64 and a sample count, so any
//! number of frames averages without drift; a non-finite sample is dropped and
//! counted, never added (STYLE.md). `mean()` gives the image so far.

use crate::image::Image;

#[derive(Clone, Debug, PartialEq)]
pub struct Film {
    width: u32,
    height: u32,
    sum: Vec<[f64; 3]>,
    count: Vec<u32>,
    dropped: u64,
}

impl Film {
    pub fn new(width: u32, height: u32) -> Self {
        let n = width as usize * height as usize;
        Self {
            width,
            height,
            sum: vec![[0.0; 3]; n],
            count: vec![0; n],
            dropped: 0,
        }
    }

    pub fn width(&self) -> u32 {
        self.width
    }
    pub fn height(&self) -> u32 {
        self.height
    }

    /// Adds one sample to pixel `index` (row-major); returns false if it was dropped.
    pub fn add(&mut self, index: usize, rgb: [f64; 3]) -> bool {
        if rgb.iter().all(|c| c.is_finite()) {
            let s = &mut self.sum[index];
            for c in 0..3 {
                s[c] += rgb[c];
            }
            self.count[index] += 1;
            true
        } else {
            self.dropped += 1;
            false
        }
    }

    /// Adds a whole frame of samples (one per pixel, row-major).
    pub fn add_frame(&mut self, frame: &[[f64; 3]]) {
        for (i, rgb) in frame.iter().enumerate() {
            self.add(i, *rgb);
        }
    }

    /// Samples dropped for being NaN or infinite.
    pub fn dropped(&self) -> u64 {
        self.dropped
    }

    /// The fewest samples any pixel has.
    pub fn min_samples(&self) -> u32 {
        self.count.iter().copied().min().unwrap_or(0)
    }

    /// Forgets every sample (a camera or geometry change).
    pub fn reset(&mut self) {
        self.sum.iter_mut().for_each(|s| *s = [0.0; 3]);
        self.count.iter_mut().for_each(|c| *c = 0);
        self.dropped = 0;
    }

    /// The mean per pixel (black where no sample landed yet).
    pub fn mean(&self) -> Image {
        let mut img = Image::new(self.width, self.height);
        for (p, (s, &n)) in img
            .pixels_mut()
            .iter_mut()
            .zip(self.sum.iter().zip(&self.count))
        {
            if n > 0 {
                let inv = 1.0 / n as f64;
                *p = [
                    (s[0] * inv) as f32,
                    (s[1] * inv) as f32,
                    (s[2] * inv) as f32,
                ];
            }
        }
        img
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn averages_and_drops_non_finite_samples() {
        let mut f = Film::new(2, 1);
        assert!(f.add(0, [1.0, 2.0, 3.0]));
        assert!(f.add(0, [3.0, 2.0, 1.0]));
        assert!(!f.add(0, [f64::NAN, 0.0, 0.0]));
        assert!(!f.add(1, [0.0, f64::INFINITY, 0.0]));
        assert_eq!(f.dropped(), 2);
        assert_eq!(f.mean().get(0, 0), [2.0, 2.0, 2.0]);
        assert_eq!(f.mean().get(1, 0), [0.0; 3], "no valid sample yet");
        assert_eq!(f.min_samples(), 0);
        f.reset();
        assert_eq!((f.dropped(), f.mean().get(0, 0)), (0, [0.0; 3]));
    }

    #[test]
    fn long_accumulation_does_not_drift() {
        // 10^6 samples of 0.1 (not exact in binary): an f32 running sum would be off by
        // ~1e-2 relative; the f64 sum stays within 1e-9.
        let mut f = Film::new(1, 1);
        for _ in 0..1_000_000 {
            f.add(0, [0.1, 1e-3, 10.0]);
        }
        let m = f.mean().get(0, 0);
        assert!(
            (m[0] as f64 - 0.1).abs() < 1e-8 && (m[2] as f64 - 10.0).abs() < 1e-6,
            "{m:?}"
        );
    }
}
