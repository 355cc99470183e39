use std::time::{Duration, Instant};

use super::*;

fn wait(lib: &mut Library) {
    let deadline = Instant::now() + Duration::from_secs(120);
    while lib.pending() > 0 {
        lib.poll();
        assert!(Instant::now() < deadline, "thumbnails did not finish");
        std::thread::sleep(Duration::from_millis(5));
    }
}

#[test]
fn files_are_listed_by_kind_and_name() {
    let dir = tempfile::tempdir().expect("temp dir");
    for f in ["b.spmm", "a.BINARY", "c.btf", "notes.txt", "d.toml"] {
        std::fs::write(dir.path().join(f), b"x").expect("write");
    }
    std::fs::create_dir(dir.path().join("sub.spmm")).expect("a folder named like a pack");
    let got: Vec<(String, EntryKind)> = scan(dir.path())
        .into_iter()
        .map(|e| (e.name, e.kind))
        .collect();
    assert_eq!(
        got,
        vec![
            ("a".to_string(), EntryKind::Merl),
            ("b".to_string(), EntryKind::Pack),
            ("c".to_string(), EntryKind::Btf),
        ]
    );
    let shipped: Vec<String> = scan(&shipped_dir()).into_iter().map(|e| e.name).collect();
    assert!(shipped.contains(&"leather".to_string()), "{shipped:?}");
    assert!(scan(&dir.path().join("missing")).is_empty());
}

#[test]
fn the_key_follows_the_content_and_a_damaged_cache_file_is_not_trusted() {
    assert_eq!(content_key(b"abc"), content_key(b"abc"));
    assert_ne!(content_key(b"abc"), content_key(b"abd"));
    assert_ne!(content_key(b""), content_key(b"\0"));
    let dir = tempfile::tempdir().expect("temp dir");
    let cache = ThumbnailCache::new(dir.path().join("cache"));
    let t = Thumbnail {
        width: 2,
        height: 1,
        rgb: vec![1, 2, 3, 4, 5, 6],
    };
    cache.store(7, &t).expect("store");
    assert_eq!(cache.load(7), Some(t));
    let mut bytes = std::fs::read(cache.path_of(7)).expect("read");
    bytes.pop();
    std::fs::write(cache.path_of(7), &bytes).expect("truncate");
    assert_eq!(cache.load(7), None, "a short file is refused");
    assert_eq!(cache.load(8), None);
}

/// The first library renders the thumbnail (core's spmm mode, the same image as a
/// direct render) and stores it; a second library over the same cache reads it
/// without rendering; a changed file gets a new thumbnail.
#[test]
fn thumbnails_are_rendered_once_and_read_from_the_cache_on_the_second_open() {
    let dir = tempfile::tempdir().expect("temp dir");
    let folder = dir.path().join("packs");
    std::fs::create_dir(&folder).expect("folder");
    let pack = folder.join("mine.spmm");
    std::fs::copy(shipped_dir().join("leather.spmm"), &pack).expect("copy");
    let cache_dir = dir.path().join("cache");
    let only_mine = |lib: &Library| lib.entries().filter(|e| e.path == pack).count();

    let mut first = Library::open(
        std::slice::from_ref(&folder),
        ThumbnailCache::new(cache_dir.clone()),
        None,
    );
    assert_eq!(only_mine(&first), 1);
    wait(&mut first);
    let shown = first.thumbnail(&pack).expect("a thumbnail").clone();
    assert_eq!((shown.width, shown.height), (THUMB_SIZE, THUMB_SIZE));
    assert!(first.rendered >= 1);
    let bytes = std::fs::read(&pack).expect("read");
    let key = content_key(&bytes);
    assert!(
        ThumbnailCache::new(cache_dir.clone())
            .path_of(key)
            .is_file()
    );
    // It is core's render of the pack on the thumbnail sphere.
    let (material, _) = material_from(EntryKind::Pack, &pack, &bytes, None).expect("pack");
    let direct = Thumbnail::from_image(&render_thumbnail(material).expect("render"));
    assert_eq!(shown, direct);
    // The sphere is lit: not every pixel is the background.
    let background = shown.rgb[0..3].to_vec();
    assert!(
        shown
            .rgb
            .chunks(3)
            .filter(|p| *p != background.as_slice())
            .count()
            > 1000
    );
    let rendered_first = first.rendered;
    drop(first);

    let mut second = Library::open(
        std::slice::from_ref(&folder),
        ThumbnailCache::new(cache_dir.clone()),
        None,
    );
    wait(&mut second);
    assert_eq!(second.rendered, 0, "everything came from the cache");
    assert_eq!(second.from_cache, rendered_first);
    assert_eq!(second.thumbnail(&pack), Some(&shown));
    drop(second);

    // Another content, another key: rendered again.
    std::fs::copy(shipped_dir().join("brushed_metal.spmm"), &pack).expect("copy");
    let mut third = Library::open(&[folder], ThumbnailCache::new(cache_dir), None);
    wait(&mut third);
    assert_eq!(third.rendered, 1);
    assert_ne!(third.thumbnail(&pack), Some(&shown));
}

/// An entry takes the same room while its thumbnail is being made, once it is
/// ready and when it failed: a thumbnail landing never moves the entry under the
/// pointer (a click at that moment went to the old place and was lost).
#[test]
fn an_entry_keeps_its_place_and_size_whatever_its_thumbnail_state() {
    let dir = tempfile::tempdir().expect("temp dir");
    let btf = dir.path().join("cloth.btf");
    std::fs::write(&btf, b"not read").expect("write");
    let lib = Library::open(
        &[dir.path().to_path_buf()],
        ThumbnailCache::new(dir.path().join("cache")),
        None,
    );
    use egui_kittest::kittest::Queryable as _;
    let mut h = egui_kittest::Harness::new_ui_state(
        |ui, lib: &mut Library| {
            lib.show(ui, "the floor");
        },
        lib,
    );
    h.run();
    let failed = h.get_by_label("cloth").rect();
    h.state_mut().thumbs.insert(btf.clone(), Thumb::Pending);
    h.step();
    h.step();
    assert_eq!(h.get_by_label("cloth").rect(), failed, "pending");
    let t = Thumbnail {
        width: THUMB_SIZE,
        height: THUMB_SIZE,
        rgb: vec![200; (THUMB_SIZE * THUMB_SIZE * 3) as usize],
    };
    h.state_mut()
        .thumbs
        .insert(btf.clone(), Thumb::Ready(t, None));
    h.run();
    assert_eq!(h.get_by_label("cloth").rect(), failed, "ready");
    assert!(failed.width() > THUMB_SIZE as f32 * 0.75);
}

#[test]
fn a_btf_is_listed_but_not_assignable_and_a_bad_pack_names_its_file() {
    let dir = tempfile::tempdir().expect("temp dir");
    let btf = dir.path().join("cloth.btf");
    std::fs::write(&btf, b"not read").expect("write");
    let e = material_from(EntryKind::Btf, &btf, b"", None).unwrap_err();
    assert!(e.contains("cloth.btf") && e.contains("meso fit"), "{e}");
    let bad = dir.path().join("bad.spmm");
    std::fs::write(&bad, b"garbage").expect("write");
    let cache = ThumbnailCache::new(dir.path().join("cache"));
    let e = thumbnail_of(&cache, EntryKind::Pack, &bad).unwrap_err();
    assert!(e.contains("bad.spmm"), "{e}");
    let mut lib = Library::open(&[dir.path().to_path_buf()], cache, None);
    wait(&mut lib);
    assert!(lib.failure(&btf).is_some() && lib.failure(&bad).is_some());
    assert!(lib.thumbnail(&btf).is_none());
}
