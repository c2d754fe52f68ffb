//! The ONNX backbone on ONNX Runtime's CPU provider, with the random-weight ViT that
//! tools/make_test_vit.py builds (no download): outputs equal onnxruntime-python's,
//! onboarding and estimation run end to end with it, and every bad input is a clear error.
//! Needs B2TF_ORT_LIB and the tools' Python packages (scripts/setup.sh, scripts/env.sh).

use b2tfpose::estimate::{Detection, EstimateConfig, EstimateError, Estimator};
use b2tfpose::eval::scenes::{generate_image, SceneConfig};
use b2tfpose::features::onnx::{sidecar_path, OnnxError};
use b2tfpose::features::{Backbone, CropInput, Device, EmbeddedBackbone, EmbeddedConfig, OnnxBackbone};
use b2tfpose::geometry::ViewSampling;
use b2tfpose::mesh::procedural::textured_box;
use b2tfpose::onboard::{onboard, OnboardConfig};
use b2tfpose::render::{RenderPool, RendererConfig};
use std::path::{Path, PathBuf};
use std::sync::{Arc, OnceLock};

/// The test model, built once per test binary into a folder that lives as long as it.
fn model_dir() -> &'static Path {
    static DIR: OnceLock<tempfile::TempDir> = OnceLock::new();
    DIR.get_or_init(|| {
        let dir = tempfile::tempdir().unwrap();
        let out =
            std::process::Command::new("python3").args(["tools/make_test_vit.py", "--reference", "--out"]).arg(dir.path()).current_dir(env!("CARGO_MANIFEST_DIR")).output().expect("python3 runs");
        assert!(out.status.success(), "make_test_vit.py failed (run scripts/setup.sh; source scripts/env.sh): {}", String::from_utf8_lossy(&out.stderr));
        dir
    })
    .path()
}

fn model_path() -> PathBuf {
    model_dir().join("model.onnx")
}

fn backbone() -> &'static Arc<OnnxBackbone> {
    static B: OnceLock<Arc<OnnxBackbone>> = OnceLock::new();
    B.get_or_init(|| Arc::new(OnnxBackbone::open(&model_path(), &Device::Cpu, None).expect("B2TF_ORT_LIB names ONNX Runtime's library (source scripts/env.sh)")))
}

fn read_f32(path: &Path) -> Vec<f32> {
    std::fs::read(path).unwrap().chunks_exact(4).map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]])).collect()
}

#[test]
fn outputs_equal_onnxruntime_python() {
    let b = backbone();
    let input = read_f32(&model_dir().join("reference_input.f32"));
    let (local, global) = b.run(input, 2).unwrap();
    for (name, ours) in [("local", &local), ("global", &global)] {
        let theirs = read_f32(&model_dir().join(format!("reference_{name}.f32")));
        assert_eq!(ours.len(), theirs.len(), "{name}");
        let worst = ours.iter().zip(&theirs).map(|(a, b)| (a - b).abs()).fold(0f32, f32::max);
        let scale = theirs.iter().map(|x| x.abs()).fold(0f32, f32::max);
        assert!(worst <= 1e-5 * scale.max(1.0), "{name}: largest difference {worst} (values up to {scale})");
    }
}

#[test]
fn feature_maps_are_normalised_and_batches_agree_with_single_crops() {
    let b = backbone();
    let size = b.spec().input_size;
    let crop = |shade: u8| {
        let mut mask = image::GrayImage::new(size, size);
        for y in size / 4..3 * size / 4 {
            for x in size / 3..2 * size / 3 {
                mask.put_pixel(x, y, image::Luma([255]));
            }
        }
        let rgb = image::RgbImage::from_fn(size, size, |x, y| if mask.get_pixel(x, y)[0] > 0 { image::Rgb([shade, (x % 200) as u8, (y % 150) as u8]) } else { image::Rgb([0, 0, 0]) });
        CropInput { rgb, mask }
    };
    let crops = [crop(40), crop(200)];
    let both = b.extract(&crops).unwrap();
    for (i, c) in crops.iter().enumerate() {
        let one = b.extract(std::slice::from_ref(c)).unwrap().remove(0);
        let worst = one.local.iter().zip(&both[i].local).map(|(a, b)| (a - b).abs()).fold(0f32, f32::max);
        assert!(worst < 1e-4, "crop {i}: batched and single differ by {worst}");
        let norm: f32 = one.global.iter().map(|x| x * x).sum::<f32>().sqrt();
        assert!((norm - 1.0).abs() < 1e-4, "global descriptor norm {norm}");
        assert_eq!(one.local.len(), one.grid.len() * one.local_dim);
        assert!(one.foreground(0.5).len() > 50);
    }
    // A sliver of a mask that covers no patch by half still gets a unit global descriptor.
    let mut sliver = crop(90);
    sliver.mask = image::GrayImage::from_fn(size, size, |x, y| image::Luma([if (100..104).contains(&x) && (100..104).contains(&y) { 255 } else { 0 }]));
    let g = b.extract(&[sliver]).unwrap().remove(0).global;
    assert!((g.iter().map(|x| x * x).sum::<f32>().sqrt() - 1.0).abs() < 1e-4, "sliver's global descriptor is not unit length");
    // A crop of the wrong size is refused, naming the size expected.
    let small = CropInput { rgb: image::RgbImage::new(64, 64), mask: image::GrayImage::new(64, 64) };
    let e = b.extract(&[small]).unwrap_err().to_string();
    assert!(e.contains("64×64") && e.contains(&size.to_string()), "{e}");
}

#[test]
fn onboards_and_estimates_end_to_end() {
    let b: Arc<dyn Backbone> = backbone().clone();
    let pool = Arc::new(RenderPool::new(1, RendererConfig::default()).unwrap());
    let cfg = OnboardConfig { views: ViewSampling { level: 0, in_plane_steps: 2 }, render_size: 128, ..Default::default() };
    let model = onboard("box", &textured_box([0.10, 0.06, 0.16], 3), &cfg, b.as_ref(), &pool, &|_| {}).unwrap();
    assert_eq!(model.backbone, b.identity());
    assert_eq!(model.backbone.weights_hash, backbone().spec().onnx_sha256);
    // Stored and loaded with its backbone identity.
    let dir = tempfile::tempdir().unwrap();
    let store = b2tfpose::store::open(&format!("dir://{}", dir.path().display())).unwrap();
    store.put(&model, false).unwrap();
    let model = store.get("box").unwrap();
    assert_eq!(model.backbone, b.identity());

    let scene_cfg = SceneConfig { images: 1, objects_per_image: 1, image_size: (320, 240), fill_range: (0.45, 0.6), max_occlusion: 0.1, seed: 3, ..Default::default() };
    let scene = generate_image(&[(1, model.mesh.clone())], &scene_cfg, &pool, 0).unwrap();
    let det = [Detection::new(scene.instances[0].mask_visib.clone(), 1.0)];
    let estimator = Estimator::new(b.clone(), pool.clone());
    let r = estimator.estimate(&model, &scene.rgb, &scene.cam, &det, &EstimateConfig::default()).unwrap();
    // Random weights say nothing about the object, so only that the pipeline ran through.
    assert_eq!(r.hypotheses.len(), 1);
    assert!(r.hypotheses[0].matches > 0, "{:?}", r.hypotheses[0]);
    assert!(r.timings.features > 0.0);

    // The embedded backbone cannot estimate an object onboarded with this one.
    let embedded = Estimator::new(Arc::new(EmbeddedBackbone::new(EmbeddedConfig::default()).unwrap()), pool);
    match embedded.estimate(&model, &scene.rgb, &scene.cam, &det, &EstimateConfig::default()) {
        Err(e @ EstimateError::BackboneMismatch { .. }) => assert!(e.to_string().contains("onnx:"), "{e}"),
        other => panic!("expected a backbone mismatch, got {:?}", other.map(|r| r.pose)),
    }
}

/// A copy of the test model in a fresh folder, for breaking.
fn copy_model() -> (tempfile::TempDir, PathBuf) {
    let dir = tempfile::tempdir().unwrap();
    let onnx = dir.path().join("model.onnx");
    std::fs::copy(model_path(), &onnx).unwrap();
    std::fs::copy(sidecar_path(&model_path()), sidecar_path(&onnx)).unwrap();
    (dir, onnx)
}

fn edit_sidecar(onnx: &Path, edit: impl FnOnce(&mut serde_json::Value)) {
    let path = sidecar_path(onnx);
    let mut v: serde_json::Value = serde_json::from_slice(&std::fs::read(&path).unwrap()).unwrap();
    edit(&mut v);
    std::fs::write(path, serde_json::to_vec(&v).unwrap()).unwrap();
}

fn open_err(onnx: &Path, device: &Device, library: Option<&Path>) -> String {
    backbone(); // the library is loaded (as it would be by a first, good model)
    match OnnxBackbone::open(onnx, device, library) {
        Ok(_) => panic!("{} opened", onnx.display()),
        Err(e) => {
            eprintln!("{}: {e}", onnx.display());
            e.to_string()
        }
    }
}

fn sha256_hex(bytes: &[u8]) -> String {
    use sha2::Digest;
    sha2::Sha256::digest(bytes).iter().map(|b| format!("{b:02x}")).collect()
}

#[test]
fn bad_models_sidecars_libraries_and_devices_are_clear_errors() {
    // Missing ONNX file.
    let e = open_err(Path::new("/nonexistent/dino.onnx"), &Device::Cpu, None);
    assert!(e.contains("/nonexistent/dino.onnx"), "{e}");

    // Missing sidecar.
    let (dir, onnx) = copy_model();
    std::fs::remove_file(sidecar_path(&onnx)).unwrap();
    let e = open_err(&onnx, &Device::Cpu, None);
    assert!(e.contains("model.json"), "{e}");
    drop(dir);

    // A sidecar for another file (hash mismatch).
    let (_dir, onnx) = copy_model();
    edit_sidecar(&onnx, |v| v["onnx_sha256"] = "00".repeat(32).into());
    let e = open_err(&onnx, &Device::Cpu, None);
    assert!(e.contains("sha256"), "{e}");

    // A corrupt ONNX file whose sidecar matches its bytes: ONNX Runtime refuses it.
    let (_dir, onnx) = copy_model();
    let mut bytes = std::fs::read(&onnx).unwrap();
    bytes.truncate(bytes.len() / 3);
    std::fs::write(&onnx, &bytes).unwrap();
    edit_sidecar(&onnx, |v| v["onnx_sha256"] = sha256_hex(&bytes).into());
    let e = open_err(&onnx, &Device::Cpu, None);
    assert!(e.contains("cannot load"), "{e}");

    // A sidecar that disagrees with the model: input size, descriptor size, output name.
    for (field, value, expect) in [("input_size", serde_json::json!(448), "448"), ("local_dim", serde_json::json!(64), "64"), ("global_output", serde_json::json!("cls"), "\"cls\"")] {
        let (_dir, onnx) = copy_model();
        edit_sidecar(&onnx, |v| v[field] = value.clone());
        let e = open_err(&onnx, &Device::Cpu, None);
        assert!(e.contains(expect) && e.contains("sidecar"), "{field}: {e}");
    }

    // A library path that does not exist is named.
    let e = open_err(&model_path(), &Device::Cpu, Some(Path::new("/nowhere/libonnxruntime.so")));
    assert!(e.contains("/nowhere/libonnxruntime.so"), "{e}");

    // CUDA with the CPU build of ONNX Runtime: an error, never a silent fall-back to the CPU.
    match OnnxBackbone::open(&model_path(), &Device::Cuda(0), None) {
        Err(e @ OnnxError::Provider { .. }) => {
            eprintln!("{e}");
            assert!(e.to_string().contains("cuda:0"), "{e}")
        }
        Err(e) => panic!("expected a provider error, got {e}"),
        Ok(_) => panic!("CUDA opened on the CPU build of ONNX Runtime"),
    }
}
