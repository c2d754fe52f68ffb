//! The bodies of the libFuzzer targets in `fuzz/` (one function each, same name), compiled
//! normally so that `tests/fuzz_regressions.rs` replays the seed corpora and every input a
//! fuzzer ever crashed on as ordinary tests. Each takes arbitrary bytes and must return
//! without panicking, hanging or allocating without bound, whatever they are; an `Err`
//! from the code under test is a fine outcome.
//!
//! Inputs made of several files (a mesh and what it refers to, a manifest and its tensors)
//! are the files joined by [`SEPARATOR`].

mod files;
mod images;
mod mesh;
mod service;

pub use files::{bop_detections, camera_file, results_csv, store_manifest};
pub use images::{image_input, mask_png, mask_rle};
pub use mesh::{mesh_gltf, mesh_obj, mesh_ply};
pub use service::{grpc_request, http_json, multipart};

/// A target's body: takes any bytes, returns normally.
pub type Entry = fn(&[u8]);

/// Every target's name, as `fuzz/fuzz_targets/<name>.rs` and the corpora folders use it,
/// with its entry function.
pub const TARGETS: &[(&str, Entry)] = &[
    ("mesh_ply", mesh_ply),
    ("mesh_obj", mesh_obj),
    ("mesh_gltf", mesh_gltf),
    ("image_input", image_input),
    ("mask_png", mask_png),
    ("mask_rle", mask_rle),
    ("http_json", http_json),
    ("multipart", multipart),
    ("grpc_request", grpc_request),
    ("camera_file", camera_file),
    ("bop_detections", bop_detections),
    ("results_csv", results_csv),
    ("store_manifest", store_manifest),
];

/// Between the files of a multi-file input.
pub const SEPARATOR: &[u8] = b"\n=====FILE=====\n";

/// The files of a multi-file input, in order.
pub fn split(data: &[u8]) -> Vec<&[u8]> {
    let mut parts = Vec::new();
    let mut rest = data;
    while let Some(at) = rest.windows(SEPARATOR.len()).position(|w| w == SEPARATOR) {
        parts.push(&rest[..at]);
        rest = &rest[at + SEPARATOR.len()..];
    }
    parts.push(rest);
    parts
}

/// The first `N` bytes as a header and the rest, or `None` when the input is shorter.
fn header<const N: usize>(data: &[u8]) -> Option<([u8; N], &[u8])> {
    let (head, rest) = data.split_first_chunk::<N>()?;
    Some((*head, rest))
}

#[cfg(test)]
mod tests {
    #[test]
    fn split_and_join_agree() {
        let joined = [b"a".as_slice(), super::SEPARATOR, b"", super::SEPARATOR, b"c"].concat();
        assert_eq!(super::split(&joined), vec![b"a".as_slice(), b"", b"c"]);
        assert_eq!(super::split(b"plain"), vec![b"plain".as_slice()]);
    }
}
