//! A crafted UBO2003 zip (a small file whose entries claim a large BTF) is refused
//! before the BTF is allocated. Its own test binary: the allocator below records the
//! largest single allocation each thread makes, which would be the BTF's values.

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;
use std::io::{Cursor, Write};

use meso_materials::btf::ubo2003::{self, ZipImportErrorKind};
use meso_materials::btf::{crop, directions};

struct Largest;

thread_local! {
    static LARGEST: Cell<usize> = const { Cell::new(0) };
}

fn note(size: usize) {
    // `try_with`: nothing to record while the thread's storage is being torn down.
    let _ = LARGEST.try_with(|l| l.set(l.get().max(size)));
}

// SAFETY: every call is passed on to `System` unchanged; `note` only records the size.
unsafe impl GlobalAlloc for Largest {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        note(layout.size());
        // SAFETY: the caller's contract is `System`'s.
        unsafe { System.alloc(layout) }
    }
    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        note(layout.size());
        // SAFETY: as above.
        unsafe { System.alloc_zeroed(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        // SAFETY: as above.
        unsafe { System.dealloc(ptr, layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        note(new_size);
        // SAFETY: as above.
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

#[global_allocator]
static ALLOCATOR: Largest = Largest;

/// 81 x 81 entries on the Bonn directions: the first a real 330 x 330 JPEG (one flat
/// colour, a few KB), every other one only the start of that JPEG (its header claims
/// 330 x 330; the image data is cut off). The claims add up to 330 * 330 texels x
/// 6561 pairs x 3 = 2.14 billion values, 8.6 GB as f32, in a zip of about a MB.
/// Returns the zip and the first entry's name.
fn crafted() -> (Vec<u8>, String) {
    let mut jpeg = Vec::new();
    image::codecs::jpeg::JpegEncoder::new(&mut jpeg)
        .encode(
            &vec![90u8; 330 * 330 * 3],
            330,
            330,
            image::ExtendedColorType::Rgb8,
        )
        .expect("encode");
    // Up to just past the start of the scan: tables and size, no image data.
    let sos = jpeg
        .windows(2)
        .position(|w| w == [0xFF, 0xDA])
        .expect("a scan");
    let header = jpeg[..sos + 12].to_vec();
    let angles: Vec<(u32, u32)> = directions::bonn81()
        .into_iter()
        .map(|d| {
            let (t, p) = directions::to_angles_deg(d);
            (t.round() as u32, p.round() as u32)
        })
        .collect();
    let mut out = Cursor::new(Vec::new());
    let mut first = String::new();
    {
        let mut z = zip::ZipWriter::new(&mut out);
        let opts = zip::write::SimpleFileOptions::default()
            .compression_method(zip::CompressionMethod::Deflated);
        for (i, l) in angles.iter().enumerate() {
            for (j, v) in angles.iter().enumerate() {
                let name = format!(
                    "CRAFT/tl{:03} pl{:03} tv{:03} pv{:03}.jpg",
                    l.0, l.1, v.0, v.1
                );
                z.start_file(name.as_str(), opts).expect("start");
                let whole = i == 0 && j == 0;
                z.write_all(if whole { &jpeg } else { &header })
                    .expect("write");
                if whole {
                    first = name;
                }
            }
        }
        z.finish().expect("finish");
    }
    (out.into_inner(), first)
}

#[test]
fn a_small_zip_claiming_a_large_btf_is_refused_before_the_btf_is_allocated() {
    let (zip, first) = crafted();
    assert!(zip.len() < 4 << 20, "{} bytes", zip.len());
    // The claims are within the import's own bounds: only decoding can refuse them.
    assert!(crop::check_budget(330 * 330, 81 * 81).is_ok());
    const { assert!(330 * 330 * 6561 * 3 * 4 <= ubo2003::DEFAULT_MAX_IMPORT_BYTES) };
    LARGEST.with(|l| l.set(0));
    let e = ubo2003::read_zip(Cursor::new(zip), "x", "t", None).expect_err("refused");
    let largest = LARGEST.with(Cell::get);
    match &e {
        ZipImportErrorKind::Image { entry, .. } => {
            assert!(entry.starts_with("CRAFT/tl") && *entry != first, "{e}")
        }
        other => panic!("expected a damaged entry to be named, got {other}"),
    }
    // The zip's buffers and one decoded image (330 x 330 x 3 bytes): far below the
    // 8.6 GB the claims add up to.
    assert!(largest < 16 << 20, "largest allocation {largest} bytes");
}
