//! OpenEXR files through the `exr` crate: read the first flat layer's R,G,B channels (or
//! a Y luminance channel, as grey) at full resolution, half, float or uint samples; write
//! float32 R,G,B with lossless ZIP compression. Deep data, mip levels, other layers and
//! the display window are not used: the data window is the image.

use std::io::Cursor;
use std::path::Path;

use exr::prelude::{
    AnyChannel, AnyChannels, Encoding, FlatSamples, Image as ExrImage, Layer, LayerAttributes,
    ReadChannels, ReadLayers, SmallVec, WritableImage,
};

use super::{Image, ImageError, check_writable, checked_size, read_bytes};
use crate::atomic::write_atomic;

const FORMAT: &str = "OpenEXR";

/// How much decompression can expand a file: deflate's limit is about 1032:1 and the
/// other EXR codecs expand less. A header whose pixels would need more than this many
/// times the file's size (plus an allowance for tiny files) misstates its size, and is
/// refused before the decoder allocates what it claims.
const MAX_EXPANSION: u128 = 1100;
const EXPANSION_ALLOWANCE: u128 = 64 << 20;

/// Checks every header's claimed pixel size against the per-side limit and the file's
/// size, reading only the headers.
fn check_claimed_size(path: &Path, bytes: &[u8]) -> Result<(), ImageError> {
    let meta = exr::meta::MetaData::read_from_buffered(Cursor::new(bytes), true).map_err(|e| {
        ImageError::Decode {
            path: path.to_path_buf(),
            format: FORMAT,
            reason: e.to_string(),
        }
    })?;
    for header in meta.headers.iter() {
        let (w, h) = (header.layer_size.0, header.layer_size.1);
        checked_size(path, w, h)?;
        let per_pixel: u128 = header
            .channels
            .list
            .iter()
            .map(|c| c.sample_type.bytes_per_sample() as u128)
            .sum();
        let claimed = w as u128 * h as u128 * per_pixel;
        let limit = bytes.len() as u128 * MAX_EXPANSION + EXPANSION_ALLOWANCE;
        if claimed > limit {
            return Err(ImageError::Decode {
                path: path.to_path_buf(),
                format: FORMAT,
                reason: format!(
                    "the header claims {w}x{h} pixels ({claimed} bytes of samples), more than a {}-byte file can hold",
                    bytes.len()
                ),
            });
        }
    }
    Ok(())
}

/// Reads an OpenEXR file as linear radiance. Channels named exactly `R`, `G`, `B` become
/// the colour; failing those, a `Y` channel is replicated to grey. Alpha and any other
/// channel are ignored. Non-finite samples are kept.
pub fn read_exr(path: &Path) -> Result<Image, ImageError> {
    let bytes = read_bytes(path)?;
    check_claimed_size(path, &bytes)?;
    let decode = |e: exr::error::Error| ImageError::Decode {
        path: path.to_path_buf(),
        format: FORMAT,
        reason: e.to_string(),
    };
    // Pedantic, as the C++ library: contradicting or missing header values and leftover
    // bytes after decompression are errors, rather than guessed around.
    let exr = exr::prelude::read()
        .no_deep_data()
        .largest_resolution_level()
        .all_channels()
        .first_valid_layer()
        .all_attributes()
        .pedantic()
        .from_buffered(Cursor::new(bytes))
        .map_err(decode)?;
    let layer = &exr.layer_data;
    let (w, h) = (layer.size.0, layer.size.1);
    let (width, height) = checked_size(path, w, h)?;
    let channels = &layer.channel_data.list;
    let find = |name: &str| channels.iter().find(|c| c.name.eq(name));

    let planes: [&AnyChannel<FlatSamples>; 3] = match (find("R"), find("G"), find("B"), find("Y")) {
        (Some(r), Some(g), Some(b), _) => [r, g, b],
        (_, _, _, Some(y)) => [y, y, y],
        _ => {
            let names: Vec<String> = channels.iter().map(|c| c.name.to_string()).collect();
            let found = if names.is_empty() {
                "none".to_owned()
            } else {
                names.join(", ")
            };
            return Err(ImageError::NoColorChannels {
                path: path.to_path_buf(),
                found,
            });
        }
    };
    let count = w * h;
    let mut values: [Vec<f32>; 3] = Default::default();
    for (plane, out) in planes.iter().zip(values.iter_mut()) {
        if plane.sampling != exr::prelude::Vec2(1, 1) {
            return Err(ImageError::Decode {
                path: path.to_path_buf(),
                format: FORMAT,
                reason: format!(
                    "channel {} is subsampled ({}x{}); Meso reads full-resolution channels only",
                    plane.name, plane.sampling.0, plane.sampling.1
                ),
            });
        }
        *out = samples_as_f32(&plane.sample_data);
        if out.len() != count {
            return Err(ImageError::Decode {
                path: path.to_path_buf(),
                format: FORMAT,
                reason: format!(
                    "channel {} holds {} samples, a {w}x{h} layer needs {count}",
                    plane.name,
                    out.len()
                ),
            });
        }
    }
    let pixels = (0..count)
        .map(|i| [values[0][i], values[1][i], values[2][i]])
        .collect();
    Ok(Image::from_pixels(width, height, pixels)
        .expect("three planes of width * height samples each"))
}

/// Every sample as f32: half widens exactly; uint converts with rounding above 2^24.
fn samples_as_f32(samples: &FlatSamples) -> Vec<f32> {
    match samples {
        FlatSamples::F16(v) => v.iter().map(|s| s.to_f32()).collect(),
        FlatSamples::F32(v) => v.clone(),
        FlatSamples::U32(v) => v.iter().map(|&s| s as f32).collect(),
    }
}

/// Writes linear float32 R,G,B (no alpha), ZIP-compressed 16-line blocks, increasing Y.
/// Lossless: reading the file back gives the same bits. Whole file or nothing.
pub fn write_exr(path: &Path, image: &Image) -> Result<(), ImageError> {
    check_writable(path, image, FORMAT)?;
    let plane = |c: usize| FlatSamples::F32(image.pixels().iter().map(|p| p[c]).collect());
    let channels = AnyChannels::sort(SmallVec::from_vec(vec![
        AnyChannel::new("R", plane(0)),
        AnyChannel::new("G", plane(1)),
        AnyChannel::new("B", plane(2)),
    ]));
    let size = (image.width() as usize, image.height() as usize);
    let layer = Layer::new(
        size,
        LayerAttributes::default(),
        Encoding::SMALL_LOSSLESS,
        channels,
    );
    let mut encoded = Cursor::new(Vec::new());
    ExrImage::from_layer(layer)
        .write()
        .to_buffered(&mut encoded)
        .map_err(|e| ImageError::Encode {
            path: path.to_path_buf(),
            format: FORMAT,
            reason: e.to_string(),
        })?;
    let bytes = encoded.into_inner();
    write_atomic(path, |w| w.write_all(&bytes))?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::image::{read_image, write_image};

    /// A test image whose pixels are all different, with negative, large and tiny values.
    fn varied(width: u32, height: u32) -> Image {
        let pixels = (0..width * height)
            .map(|i| {
                let t = i as f32;
                [t * 0.37 - 1.5, (t * 1.3).sin() * 1e4, 1e-30 * (t + 1.0)]
            })
            .collect();
        Image::from_pixels(width, height, pixels).expect("width * height pixels")
    }

    #[test]
    fn float32_round_trip_is_bit_exact_for_odd_sizes() {
        let dir = tempfile::tempdir().expect("temp dir");
        for (w, h) in [(1, 1), (3, 7), (7, 3), (65, 33)] {
            let img = varied(w, h);
            let path = dir.path().join(format!("{w}x{h}.exr"));
            write_exr(&path, &img).expect("write");
            let back = read_exr(&path).expect("read");
            assert_eq!((back.width(), back.height()), (w, h));
            for (a, b) in img.pixels().iter().zip(back.pixels()) {
                assert_eq!(a.map(f32::to_bits), b.map(f32::to_bits));
            }
        }
    }

    #[test]
    fn non_finite_samples_are_kept() {
        let dir = tempfile::tempdir().expect("temp dir");
        let img = Image::from_pixels(
            2,
            1,
            vec![
                [f32::NAN, f32::INFINITY, -f32::INFINITY],
                [f32::MAX, -0.0, 1.0],
            ],
        )
        .expect("2 pixels");
        let path = dir.path().join("odd.exr");
        write_exr(&path, &img).expect("write");
        let back = read_exr(&path).expect("read");
        assert!(back.get(0, 0)[0].is_nan());
        assert_eq!(back.get(0, 0)[1], f32::INFINITY);
        assert_eq!(back.get(1, 0)[0], f32::MAX);
        assert_eq!(back.get(1, 0)[1].to_bits(), (-0.0f32).to_bits());
    }

    /// Writes an EXR with arbitrary named channels, for the reader's channel logic.
    fn write_channels(path: &Path, width: usize, height: usize, list: Vec<(&str, FlatSamples)>) {
        let channels = AnyChannels::sort(
            list.into_iter()
                .map(|(name, samples)| AnyChannel::new(name, samples))
                .collect(),
        );
        let layer = Layer::new(
            (width, height),
            LayerAttributes::default(),
            Encoding::UNCOMPRESSED,
            channels,
        );
        ExrImage::from_layer(layer)
            .write()
            .to_file(path)
            .expect("write test EXR");
    }

    #[test]
    fn luminance_only_and_half_channels_are_read() {
        let dir = tempfile::tempdir().expect("temp dir");
        let path = dir.path().join("grey.exr");
        let y: Vec<exr::prelude::f16> = [0.0f32, 0.5, 2.0, -0.25, 1024.0, 1e-3]
            .iter()
            .map(|&v| exr::prelude::f16::from_f32(v))
            .collect();
        write_channels(
            &path,
            3,
            2,
            vec![
                ("Y", FlatSamples::F16(y.clone())),
                ("A", FlatSamples::F16(y.clone())),
            ],
        );
        let img = read_exr(&path).expect("Y-only EXR");
        assert_eq!((img.width(), img.height()), (3, 2));
        for (p, s) in img.pixels().iter().zip(&y) {
            assert_eq!(*p, [s.to_f32(); 3]);
        }
        assert_eq!(img.get(1, 0), [0.5; 3]);
        assert_eq!(img.get(0, 1), [-0.25; 3]);
    }

    #[test]
    fn rgb_wins_over_y_and_alpha_is_ignored() {
        let dir = tempfile::tempdir().expect("temp dir");
        let path = dir.path().join("rgba.exr");
        let plane = |v: f32| FlatSamples::F32(vec![v; 4]);
        write_channels(
            &path,
            2,
            2,
            vec![
                ("A", plane(0.0)),
                ("B", plane(3.0)),
                ("G", plane(2.0)),
                ("R", plane(1.0)),
                ("Y", plane(9.0)),
            ],
        );
        let img = read_exr(&path).expect("RGBA EXR");
        assert!(img.pixels().iter().all(|p| *p == [1.0, 2.0, 3.0]));
    }

    #[test]
    fn no_colour_channel_is_a_named_error() {
        let dir = tempfile::tempdir().expect("temp dir");
        let path = dir.path().join("depth.exr");
        write_channels(
            &path,
            2,
            2,
            vec![
                ("Z", FlatSamples::F32(vec![1.0; 4])),
                ("R", FlatSamples::F32(vec![1.0; 4])),
            ],
        );
        let err = read_exr(&path).expect_err("no G, B or Y");
        let msg = err.to_string();
        assert!(
            msg.contains("depth.exr")
                && msg.contains("no R,G,B or Y channel")
                && msg.contains("R, Z"),
            "{msg}"
        );
    }

    #[test]
    fn truncated_and_garbage_files_are_named_errors() {
        let dir = tempfile::tempdir().expect("temp dir");
        let path = dir.path().join("whole.exr");
        write_exr(&path, &varied(40, 30)).expect("write");
        let bytes = std::fs::read(&path).expect("read back");
        let cut = dir.path().join("cut.exr");
        // Cut inside the header, the offset table and the pixel blocks.
        for len in [0, 3, 20, 200, bytes.len() / 2, bytes.len() - 1] {
            std::fs::write(&cut, &bytes[..len]).expect("write truncated");
            let err = read_image(&cut).expect_err("truncated EXR must not decode");
            assert!(err.to_string().contains("cut.exr"), "at {len}: {err}");
        }
        let garbage = dir.path().join("garbage.exr");
        std::fs::write(&garbage, b"not an exr at all").expect("write");
        let err = read_image(&garbage).expect_err("garbage");
        assert!(
            matches!(err, ImageError::Decode { .. }) && err.to_string().contains("garbage.exr"),
            "{err}"
        );
    }

    #[test]
    fn failed_write_keeps_the_previous_file() {
        let dir = tempfile::tempdir().expect("temp dir");
        let missing = dir.path().join("no/such/folder/out.exr");
        let err = write_image(&missing, &varied(2, 2), 0.0).expect_err("missing folder");
        assert!(err.to_string().contains("no/such/folder"), "{err}");

        // A destination that cannot be replaced (a non-empty folder) fails at the rename:
        // what was there survives and no temporary is left behind.
        let blocker = dir.path().join("blocker.exr");
        std::fs::create_dir(&blocker).expect("mkdir");
        std::fs::write(blocker.join("keep.txt"), b"keep").expect("write");
        let err = write_exr(&blocker, &varied(2, 2)).expect_err("cannot replace a folder");
        assert!(err.to_string().contains("blocker.exr"), "{err}");
        assert_eq!(
            std::fs::read(blocker.join("keep.txt")).expect("kept"),
            b"keep"
        );

        let path = dir.path().join("keep.exr");
        let first = varied(3, 3);
        write_exr(&path, &first).expect("write");
        write_exr(&path, &Image::new(0, 0)).expect_err("empty image");
        assert_eq!(read_exr(&path).expect("still readable"), first);
        let names: Vec<_> = std::fs::read_dir(dir.path())
            .expect("list")
            .filter_map(|e| e.ok())
            .collect();
        assert_eq!(names.len(), 2, "left behind: {names:?}");
    }

    #[test]
    fn corrupted_bytes_never_panic() {
        // The CLI promises an error line, never a panic: damage every byte of a small
        // file in turn (header, offset table, compressed blocks) and read it.
        let dir = tempfile::tempdir().expect("temp dir");
        let path = dir.path().join("damaged.exr");
        write_exr(&path, &varied(5, 4)).expect("write");
        let bytes = std::fs::read(&path).expect("read back");
        for i in 0..bytes.len() {
            for v in [0x00, 0xff, bytes[i] ^ 0x10] {
                let mut damaged = bytes.clone();
                damaged[i] = v;
                std::fs::write(&path, &damaged).expect("write damaged");
                let outcome = std::panic::catch_unwind(|| read_exr(&path));
                assert!(outcome.is_ok(), "byte {i} set to {v:#x} panics the reader");
            }
        }
    }
}
