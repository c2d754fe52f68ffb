//! Onboarding end to end on lavapipe: templates, 3D points, directory-store round trip.

use b2tfpose::features::{EmbeddedBackbone, EmbeddedConfig};
use b2tfpose::geometry::{Pose, ViewSampling};
use b2tfpose::mesh::procedural::textured_box;
use b2tfpose::onboard::{onboard, ObjectModel, OnboardConfig};
use b2tfpose::render::{RenderPool, RendererConfig};
use b2tfpose::store::{dir::DirStore, ObjectStore};
use nalgebra::Point3;
use std::sync::Mutex;

fn small_model() -> ObjectModel {
    let mesh = textured_box([0.10, 0.06, 0.16], 3);
    // Every template its own rows: each row's point must project onto its own template's
    // patch (rows shared per view are checked in `onboard::per_view_rows`).
    let cfg = OnboardConfig { views: ViewSampling { level: 0, in_plane_steps: 3 }, render_size: 256, patch_rows: b2tfpose::onboard::PatchRows::PerTemplate, ..Default::default() };
    let bb = EmbeddedBackbone::new(EmbeddedConfig::default()).unwrap();
    let pool = RenderPool::new(1, RendererConfig::default()).unwrap();
    let seen = Mutex::new(vec![]);
    let m = onboard("box-1", &mesh, &cfg, &bb, &pool, &|p| seen.lock().unwrap().push(p.templates_done)).unwrap();
    let seen = seen.into_inner().unwrap();
    assert_eq!(*seen.last().unwrap(), 36, "progress reaches the template count: {seen:?}");
    m
}

#[test]
fn templates_have_consistent_points_and_round_trip() {
    let m = small_model();
    assert_eq!(m.template_count(), 12 * 3);
    m.validate().unwrap();
    let k = m.render_intrinsics;
    let half = [0.05f32, 0.03, 0.08];
    let mut worst_px: f64 = 0.0;
    for t in &m.templates {
        assert!(t.patch_count > 20, "template {t:?} has few patches");
        for p in t.patch_start as usize..(t.patch_start + t.patch_count) as usize {
            let x = m.patch_points.point(p);
            // On the box surface: one coordinate at ± half its size (1 mm tolerance).
            let on_face = (0..3).any(|a| (x[a].abs() - half[a]).abs() < 1e-3);
            assert!(on_face && (0..3).all(|a| x[a].abs() <= half[a] + 1e-3), "point {x:?} is not on the box");
            // Projects back onto its own patch centre through the template pose and crop.
            let cam = t.pose.transform_point(&Point3::new(x[0] as f64, x[1] as f64, x[2] as f64));
            let uv = k.project(&cam).unwrap();
            let (cu, cv) = t.crop.to_crop(uv.x, uv.y);
            let (pu, pv) = m.grid.centre_of(m.patch_cells[p] as usize);
            worst_px = worst_px.max(((cu - pu).powi(2) + (cv - pv).powi(2)).sqrt());
        }
    }
    assert!(worst_px < 1.0, "3D points reproject {worst_px:.2} crop px from their patch centres");

    // The box's faces differ, so it has no symmetry, and onboarding says it looked.
    let found = m.symmetries.as_ref().expect("onboarding finds the symmetries");
    assert_eq!(found.source, b2tfpose::geometry::symmetry::SymmetrySource::Mesh);
    assert!(found.symmetries.is_empty(), "{found:?}");

    let dir = tempfile::tempdir().unwrap();
    let store = DirStore::open(dir.path()).unwrap();
    store.put(&m, false).unwrap();
    let path = dir.path().join(&m.object_id);
    let back = store.get(&m.object_id).unwrap();
    assert_eq!(back.templates, m.templates);
    assert_eq!(back.patch_points, m.patch_points);
    assert_eq!(back.patch_descriptors, m.patch_descriptors);
    assert_eq!(back.silhouettes, m.silhouettes);
    assert_eq!(back.backbone, m.backbone);
    assert_eq!(back.mesh.positions(), m.mesh.positions());
    assert!(back.mesh.has_texture());
    assert!((back.diameter() - m.diameter()).abs() < 1e-12);
    assert_eq!(back.symmetries, m.symmetries);
    // Saving again without `replace` refuses; with it, succeeds.
    assert!(store.put(&m, false).is_err());
    store.put(&m, true).unwrap();

    // Broken manifests and tensors give errors naming the file.
    let manifest = path.join("manifest.json");
    let good = std::fs::read_to_string(&manifest).unwrap();
    // An object stored before format 5 loads with its symmetries unknown.
    let mut old: serde_json::Value = serde_json::from_str(&good).unwrap();
    old.as_object_mut().unwrap().remove("symmetries").expect("format 5 stores the symmetries");
    old["format_version"] = serde_json::json!(4);
    std::fs::write(&manifest, serde_json::to_string(&old).unwrap()).unwrap();
    assert_eq!(store.get(&m.object_id).unwrap().symmetries, None);
    assert_eq!(store.info(&m.object_id).unwrap().symmetries, None);
    std::fs::write(&manifest, good.replace(&format!("\"format_version\": {}", b2tfpose::onboard::MODEL_FORMAT_VERSION), "\"format_version\": 99")).unwrap();
    let e = store.get(&m.object_id).unwrap_err().to_string();
    assert!(e.contains("box-1") && e.contains("newer"), "{e}");
    std::fs::write(&manifest, &good[..good.len() / 2]).unwrap();
    let e = store.get(&m.object_id).unwrap_err().to_string();
    assert!(e.contains("box-1") && e.contains("invalid JSON"), "{e}");
    std::fs::write(&manifest, &good).unwrap();
    let tensors = path.join("tensors.safetensors");
    let bytes = std::fs::read(&tensors).unwrap();
    std::fs::write(&tensors, &bytes[..bytes.len() / 2]).unwrap();
    let e = store.get(&m.object_id).unwrap_err().to_string();
    assert!(e.contains("box-1") && e.contains("tensors"), "{e}");
}

#[test]
fn bad_object_ids_are_refused() {
    let mesh = textured_box([0.1, 0.1, 0.1], 1);
    let bb = EmbeddedBackbone::new(EmbeddedConfig::default()).unwrap();
    let pool = RenderPool::new(1, RendererConfig::default()).unwrap();
    for id in ["", "../etc", "a/b", ".hidden", &"x".repeat(65)] {
        let e = onboard(id, &mesh, &OnboardConfig::default(), &bb, &pool, &|_| {}).unwrap_err();
        assert!(e.to_string().contains("invalid"), "{id}: {e}");
    }
    let bad = OnboardConfig { views: ViewSampling { level: 5, in_plane_steps: 12 }, ..Default::default() };
    let e = onboard("ok", &mesh, &bad, &bb, &pool, &|_| {}).unwrap_err();
    assert!(e.to_string().contains("level"), "{e}");
    let _ = Pose::identity();
}
