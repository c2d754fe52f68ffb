//! A request's instances estimated side by side answer as they do in turn.

use crate::geometry::{views, Intrinsics, Pose};
use crate::render::RenderOptions;
use crate::service::core::{Core, CoreConfig};
use crate::service::requests::{EstimateRequest, EstimateResponse};
use base64::Engine as _;
use nalgebra::Vector3;

fn b64_png(image: image::DynamicImage) -> String {
    let mut bytes = std::io::Cursor::new(Vec::new());
    image.write_to(&mut bytes, image::ImageFormat::Png).unwrap();
    base64::engine::general_purpose::STANDARD.encode(bytes.into_inner())
}

/// Three boxes side by side (two of object "a", one of "b", the same mesh), each with
/// its true mask, as one request.
fn three_boxes(core: &Core, mesh: &crate::mesh::Mesh) -> (EstimateRequest, Vec<Pose>) {
    let k = Intrinsics::new(300.0, 300.0, 160.0, 120.0, 320, 240).unwrap();
    let centre = Vector3::from(mesh.bbox_center());
    let poses: Vec<Pose> = [(-0.19, [1.0, -1.3, 0.9]), (0.0, [-0.6, 0.4, 1.0]), (0.19, [0.2, 1.0, 0.7])]
        .iter()
        .map(|&(x, dir)| {
            let p = views::view_pose(&Vector3::from(dir), 0.4, &centre, 0.8);
            Pose::new(p.rotation, p.translation + Vector3::new(x, 0.0, 0.0))
        })
        .collect();
    let mut rgb = image::RgbImage::from_pixel(320, 240, image::Rgb([90, 96, 104]));
    let mut detections = Vec::new();
    for (i, pose) in poses.iter().enumerate() {
        let r = core.pool.render(mesh, pose, &k, &RenderOptions::default()).unwrap();
        for (x, y, m) in r.mask.enumerate_pixels() {
            if m.0[0] > 0 {
                rgb.put_pixel(x, y, *r.rgb.get_pixel(x, y));
            }
        }
        let id = if i == 1 { "b" } else { "a" };
        detections.push(serde_json::json!({"object_id": id, "mask_png": b64_png(r.mask.into())}));
    }
    let request = serde_json::json!({
        "image": {"encoded": b64_png(rgb.into())},
        "intrinsics": {"fx": k.fx, "fy": k.fy, "cx": k.cx, "cy": k.cy, "width": k.width, "height": k.height},
        "detections": detections,
        "options": {"rrc": false, "instances_per_object": 2},
    });
    (serde_json::from_value(request).unwrap(), poses)
}

#[test]
fn instances_side_by_side_answer_as_in_turn() {
    let Some(model) = crate::onboard::test_model::small_model() else { return };
    let dir = tempfile::tempdir().unwrap();
    let core = |instance_threads| Core::new(CoreConfig { store_url: format!("dir://{}", dir.path().display()), instance_threads, ..Default::default() }).unwrap();
    let (in_turn, side_by_side) = (core(1), core(3));
    for id in ["a", "b"] {
        in_turn.store.put(&crate::onboard::ObjectModel { object_id: id.into(), ..model.clone() }, false).unwrap();
    }
    let (request, truth) = three_boxes(&in_turn, &model.mesh);
    let (one, three) = (in_turn.estimate(&request, None).unwrap(), side_by_side.estimate(&request, None).unwrap());
    let answers = |r: &EstimateResponse| r.results.iter().map(|i| (i.object_id.clone(), i.instance, i.detection_index, i.pose.as_ref().map(|p| (p.r, p.t)))).collect::<Vec<_>>();
    assert_eq!(answers(&one), answers(&three), "the same answers in the same order");
    // Objects in their order, each object's instances in its detections' order.
    let owners: Vec<(String, usize, Option<usize>)> = one.results.iter().map(|i| (i.object_id.clone(), i.instance, i.detection_index)).collect();
    assert_eq!(owners, [("a".into(), 0, Some(0)), ("a".into(), 1, Some(2)), ("b".into(), 0, Some(1))]);
    // And they are answers: each within a tenth of the box's size of its truth.
    for r in &one.results {
        let p = r.pose.as_ref().expect("a pose for every box");
        let truth = &truth[r.detection_index.unwrap()];
        let shift = (Vector3::from(p.t) - truth.translation).norm() / model.diameter();
        assert!(shift < 0.1, "{} instance {}: {shift:.3}·d from the truth", r.object_id, r.instance);
    }
}
