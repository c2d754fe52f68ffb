//! Helpers shared by the loaders' tests.

use super::{Mesh, MeshError};
use std::path::Path;

/// A `w`×`h` RGBA image whose pixel (x, y) is (10x, 10y, 7, 255), written as PNG to `path`.
pub(super) fn write_png(path: &Path, w: u32, h: u32) {
    image::RgbaImage::from_fn(w, h, |x, y| image::Rgba([10 * x as u8, 10 * y as u8, 7, 255])).save(path).unwrap();
}

/// Asserts that loading failed with a message naming `file` and containing every `needle`
/// (case-insensitively); returns the message.
#[track_caller]
pub(super) fn assert_error(result: Result<Mesh, MeshError>, file: &Path, needles: &[&str]) -> String {
    let message = match result {
        Ok(_) => panic!("expected an error loading {}", file.display()),
        Err(e) => e.to_string(),
    };
    println!("{message}");
    let name = file.file_name().unwrap().to_string_lossy();
    assert!(message.contains(&*name), "message does not name {name}: {message}");
    for needle in needles {
        assert!(message.to_lowercase().contains(&needle.to_lowercase()), "message lacks {needle:?}: {message}");
    }
    message
}

#[track_caller]
pub(super) fn assert_close(a: &[f32], b: &[f32]) {
    assert_eq!(a.len(), b.len(), "{a:?} vs {b:?}");
    assert!(a.iter().zip(b).all(|(x, y)| (x - y).abs() <= 1e-5 * (1.0 + y.abs())), "{a:?} vs {b:?}");
}
