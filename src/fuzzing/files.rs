//! The files the CLI and the BOP runner read: camera files, BOP detections, results CSVs,
//! and the store's manifest (with its tensors and a texture, when given).

use std::path::Path;

fn text(data: &[u8]) -> Option<&str> {
    std::str::from_utf8(data).ok()
}

pub fn camera_file(data: &[u8]) {
    if let Some(text) = text(data) {
        let _ = crate::cli::camera_file::parse_camera(text);
    }
}

/// Readable detections' masks are measured from their runs (decoding them all would only
/// test the allocator).
pub fn bop_detections(data: &[u8]) {
    let Some(text) = text(data) else { return };
    for d in crate::bop::detections::parse_detections(Path::new("fuzz.json"), text).into_iter().flatten() {
        if let Some(rle) = &d.segmentation {
            let _ = (rle.area(), rle.bbox());
        }
    }
}

pub fn results_csv(data: &[u8]) {
    if let Some(text) = text(data) {
        let _ = crate::bop::results_csv::parse_results(Path::new("fuzz.csv"), text, &mut Vec::new());
    }
}

/// The manifest, then optionally the tensors and the textures in the order asked for.
pub fn store_manifest(data: &[u8]) {
    let parts = super::split(data);
    let _ = crate::store::codec::summary(parts[0]);
    if let Some(tensors) = parts.get(1) {
        let mut textures = parts[2..].iter();
        let _ = crate::store::codec::decode(parts[0], tensors, &mut |name| textures.next().map(|t| t.to_vec()).ok_or_else(|| format!("{name}: not found")));
    }
}
