//! The fuzz corpora as ordinary tests: every seed (fuzz/seeds/<target>/) and every input a
//! fuzzer ever found a failure with (fuzz/regressions/<target>/) goes through the same entry
//! function the libFuzzer target calls (b2tfpose::fuzzing), which must return normally.

mod fuzz_seeds;

use b2tfpose::fuzzing::TARGETS;
use std::path::{Path, PathBuf};

fn fuzz_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("fuzz")
}

/// The files of `fuzz/<kind>/<target>/`, sorted; none when the folder is absent.
fn inputs(kind: &str, target: &str) -> Vec<PathBuf> {
    let mut files: Vec<PathBuf> = std::fs::read_dir(fuzz_dir().join(kind).join(target)).into_iter().flatten().map(|e| e.unwrap().path()).collect();
    files.sort();
    files
}

#[test]
fn every_seed_and_regression_runs_through_its_target() {
    let mut failed = Vec::new();
    for &(target, entry) in TARGETS {
        let seeds = inputs("seeds", target);
        assert!(!seeds.is_empty(), "fuzz/seeds/{target}/ has no seed");
        for file in seeds.iter().chain(&inputs("regressions", target)) {
            let data = std::fs::read(file).unwrap();
            if std::panic::catch_unwind(|| entry(&data)).is_err() {
                failed.push(file.display().to_string());
            }
        }
    }
    assert!(failed.is_empty(), "inputs whose target panicked: {failed:#?}");
}

/// The `store_manifest` seed with tensors is a whole object that loads, so fuzzing starts
/// from inputs that get through the manifest into the tensors, the mesh and the texture.
#[test]
fn the_store_seed_with_tensors_decodes() {
    let data = std::fs::read(fuzz_dir().join("seeds/store_manifest/tiny_object")).unwrap();
    let parts = b2tfpose::fuzzing::split(&data);
    assert_eq!(parts.len(), 3, "manifest, tensors, texture");
    let mut texture = Some(parts[2].to_vec());
    let model = b2tfpose::store::codec::decode(parts[0], parts[1], &mut |_| texture.take().ok_or_else(|| "asked twice".to_string())).unwrap();
    assert_eq!((model.template_count(), model.patch_count(), model.mesh.data().triangles.len()), (1, 2, 4));
    assert!(model.contours.get().is_some() && model.mesh.materials()[0].texture.is_some());
    assert!(!model.patch_points.is_grid(), "tiny_object is the format 6 seed");
    // The format 7 seed: patch points as grid steps, the contour compact.
    let data = std::fs::read(fuzz_dir().join("seeds/store_manifest/tiny_object_v7")).unwrap();
    let parts = b2tfpose::fuzzing::split(&data);
    let mut texture = Some(parts[2].to_vec());
    let model = b2tfpose::store::codec::decode(parts[0], parts[1], &mut |_| texture.take().ok_or_else(|| "asked twice".to_string())).unwrap();
    assert!(model.patch_points.is_grid() && model.contours.get().is_some());
    // The generator still writes an object that decodes (it is not byte-identical: each
    // write gets a fresh generation and timestamp).
    let fresh = fuzz_seeds::tiny_stored_object();
    let parts = b2tfpose::fuzzing::split(&fresh);
    let mut texture = Some(parts[2].to_vec());
    b2tfpose::store::codec::decode(parts[0], parts[1], &mut |_| texture.take().ok_or_else(|| "asked twice".to_string())).unwrap();
}

/// A folder under seeds/ or regressions/ that names no target would never be replayed.
#[test]
fn corpus_folders_name_targets() {
    for kind in ["seeds", "regressions"] {
        for entry in std::fs::read_dir(fuzz_dir().join(kind)).into_iter().flatten() {
            let name = entry.unwrap().file_name().to_string_lossy().to_string();
            assert!(TARGETS.iter().any(|(t, _)| *t == name), "fuzz/{kind}/{name} is not a target");
        }
    }
}

/// Every target has its file in fuzz/fuzz_targets/ and its entry in fuzz/Cargo.toml.
#[test]
fn every_target_is_built_by_cargo_fuzz() {
    let manifest = std::fs::read_to_string(fuzz_dir().join("Cargo.toml")).unwrap();
    for (target, _) in TARGETS {
        let source = std::fs::read_to_string(fuzz_dir().join(format!("fuzz_targets/{target}.rs"))).unwrap();
        assert!(source.contains(&format!("b2tfpose::fuzzing::{target}(")), "fuzz_targets/{target}.rs calls another entry");
        assert!(manifest.contains(&format!("name = \"{target}\"")), "fuzz/Cargo.toml lacks {target}");
    }
}

#[test]
#[ignore = "writes fuzz/seeds: run by hand after changing a format"]
fn write_seeds() {
    fuzz_seeds::write_all(&fuzz_dir().join("seeds"));
}
