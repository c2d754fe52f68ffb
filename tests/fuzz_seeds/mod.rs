//! Writes the seed corpora of fuzz/seeds/<target>/ from the same kinds of inputs the tests
//! build (small ones: seeds are checked in). Run by hand after changing a format:
//! `cargo test --test fuzz_regressions -- --ignored write_seeds`.

use b2tfpose::fuzzing::SEPARATOR;
use b2tfpose::mesh::{procedural::textured_box, Material, Mesh, MeshData, Units};
use b2tfpose::service::proto as pb;
use prost::Message;
use std::path::Path;
use std::sync::Arc;

fn png(image: image::DynamicImage) -> Vec<u8> {
    let mut out = Vec::new();
    image.write_to(&mut std::io::Cursor::new(&mut out), image::ImageFormat::Png).unwrap();
    out
}

fn jpeg(image: image::DynamicImage) -> Vec<u8> {
    let mut out = Vec::new();
    image.to_rgb8().write_to(&mut std::io::Cursor::new(&mut out), image::ImageFormat::Jpeg).unwrap();
    out
}

fn checker(w: u32, h: u32) -> image::RgbImage {
    image::RgbImage::from_fn(w, h, |x, y| image::Rgb(if (x + y) % 2 == 0 { [200, 30, 30] } else { [10, 10, 90] }))
}

fn joined(files: &[&[u8]]) -> Vec<u8> {
    files.join(SEPARATOR)
}

/// The test box with an 8×8 texture instead of its large atlas.
fn small_box() -> Mesh {
    let texture = image::DynamicImage::ImageRgb8(checker(8, 8)).to_rgba8();
    let materials = vec![Material { name: "skin".into(), texture: Some(texture.into()), ..Material::default() }];
    Mesh::new("box", Units::M, MeshData { materials, ..textured_box([0.1, 0.06, 0.16], 3).data().clone() }).unwrap()
}

fn mesh_files(write: impl Fn(&Path) -> Vec<&'static str>) -> Vec<u8> {
    let dir = tempfile::tempdir().unwrap();
    let names = write(dir.path());
    let files: Vec<Vec<u8>> = names.iter().map(|n| std::fs::read(dir.path().join(n)).unwrap()).collect();
    joined(&files.iter().map(Vec::as_slice).collect::<Vec<_>>())
}

const MINIMAL_GLTF: &str = r#"{"asset":{"version":"2.0"},"scenes":[{"nodes":[0]}],"nodes":[{"mesh":0}],
"meshes":[{"primitives":[{"attributes":{"POSITION":0}}]}],
"accessors":[{"bufferView":0,"componentType":5126,"count":3,"type":"VEC3","min":[0,0,0],"max":[1,1,0]}],
"bufferViews":[{"buffer":0,"byteLength":36}],
"buffers":[{"byteLength":36,"uri":"data:application/octet-stream;base64,AAAAAAAAAAAAAAAAAACAPwAAAAAAAAAAAAAAAAAAgD8AAAAA"}]}"#;

const ESTIMATE_JSON: &str = r#"{"image":{"raw_rgb8":"AAAAAAAAAAAAAAAAAAAAAAAAAAAAAAAAAAAAAAAAAAAAAAAAAAAAAAAAAAAAAAAA","width":4,"height":4},
"intrinsics":{"fx":4,"fy":4,"cx":1.5,"cy":1.5,"width":4,"height":4},
"detections":[{"object_id":"a","mask_rle":{"counts":[5,2,2,2,5],"size":[4,4]}},{"object_id":"b","bbox":[1,1,2,2],"score":0.5}],
"options":{"k":5,"max_masks":1,"refiner":"none"}}"#;

const DETECT_JSON: &str = r#"{"image":{"raw_rgb8":"AAAAAAAAAAAAAAAAAAAAAAAAAAAAAAAAAAAAAAAAAAAAAAAAAAAAAAAAAAAAAAAA","width":4,"height":4},
"intrinsics":{"fx":4,"fy":4,"cx":1.5,"cy":1.5,"width":4,"height":4},
"objects":["a","b"],"options":{"max_detections":3,"min_score":0.5,"min_distance_m":0.2,"max_distance_m":2.0,"refine_masks":false}}"#;

const ONBOARD_JSON: &str = r#"{"object_id":"box","mesh":{"data":"diAwIDAgMAp2IDEgMCAwCnYgMCAxIDAKZiAxIDIgMwo=","format":"obj","units":"mm",
"resources":[{"name":"a.mtl","data":"bmV3bXRsIGEK"}]},"options":{"level":0,"in_plane":2,"pca":"off"},"replace":true}"#;

const MULTIPART: &str = "--BOUNDARY\r\nContent-Disposition: form-data; name=\"object_id\"\r\n\r\nbox\r\n\
--BOUNDARY\r\nContent-Disposition: form-data; name=\"units\"\r\n\r\nmm\r\n\
--BOUNDARY\r\nContent-Disposition: form-data; name=\"level\"\r\n\r\n1\r\n\
--BOUNDARY\r\nContent-Disposition: form-data; name=\"mesh\"; filename=\"box.obj\"\r\n\r\nmtllib a.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n\r\n\
--BOUNDARY\r\nContent-Disposition: form-data; name=\"resource\"; filename=\"a.mtl\"\r\n\r\nnewmtl a\nKd 1 0 0\n\r\n--BOUNDARY--\r\n";

const DETECTIONS: &str = r#"[{"scene_id":1,"image_id":2,"category_id":3,"bbox":[1,1,2,2],"score":0.9,"time":0.1,"segmentation":{"counts":[5,2,2,2,5],"size":[4,4]}},
{"scene_id":1,"image_id":2,"category_id":4,"bbox":[0,0,8,8],"score":0.5,"segmentation":{"counts":"b04400000>","size":[8,8]}},
{"scene_id":1,"image_id":3,"category_id":4,"bbox":[0,0,1,1],"score":0.2}]"#;

const RESULTS: &str = "scene_id,im_id,obj_id,score,R,t,time\n\
1,2,3,0.9,1 0 0 0 1 0 0 0 1,10 20 300,0.5\r\n1,2,4,0.1,0 -1 0 1 0 0 0 0 1,-5 0 250.5,-1";

fn grpc_estimate() -> Vec<u8> {
    let rle = pb::Rle { counts: vec![5, 2, 2, 2, 5], height: 4, width: 4 };
    let detections = vec![
        pb::Detection { object_id: "a".into(), mask: Some(pb::detection::Mask::MaskRle(rle)), bbox: None, score: None },
        pb::Detection { object_id: "b".into(), mask: Some(pb::detection::Mask::MaskPng(png(image::DynamicImage::ImageRgb8(checker(4, 4))))), bbox: None, score: Some(0.4) },
        pb::Detection { object_id: "c".into(), mask: None, bbox: Some(pb::BBox { x: 0.5, y: 0.5, width: 2.0, height: 3.0 }), score: None },
    ];
    let image = pb::Image { data: Some(pb::image::Data::RawRgb8(checker(4, 4).into_raw())), width: 4, height: 4 };
    let intrinsics = pb::Intrinsics { fx: 4.0, fy: 4.0, cx: 1.5, cy: 1.5, width: 4, height: 4 };
    let options = pb::EstimateOptions { k: 3, refiner: "none".into(), ..Default::default() };
    pb::EstimateRequest { image: Some(image), intrinsics: Some(intrinsics), detections, options: Some(options), ..Default::default() }.encode_to_vec()
}

fn grpc_detect() -> Vec<u8> {
    let image = pb::Image { data: Some(pb::image::Data::Encoded(png(image::DynamicImage::ImageRgb8(checker(4, 4))))), width: 0, height: 0 };
    let intrinsics = pb::Intrinsics { fx: 4.0, fy: 4.0, cx: 1.5, cy: 1.5, width: 4, height: 4 };
    let options = pb::DetectOptions { max_detections: 2, min_score: Some(0.3), min_distance_m: Some(0.1), max_distance_m: Some(1.0), refine_masks: Some(true) };
    pb::DetectRequest { image: Some(image), intrinsics: Some(intrinsics), objects: vec!["a".into()], options: Some(options), depth: None }.encode_to_vec()
}

fn grpc_onboard() -> Vec<u8> {
    let resources = vec![pb::Resource { name: "a.mtl".into(), data: b"newmtl a\n".to_vec() }];
    let mesh = pb::Mesh { data: b"mtllib a.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n".to_vec(), format: "obj".into(), units: "mm".into(), resources };
    let options = pb::OnboardOptions { level: Some(1), in_plane: 4, pca: 16, full_descriptors: false, descriptors: "pq4".into(), patch_rows: "per-view".into() };
    pb::OnboardRequest { object_id: "box".into(), mesh: Some(mesh), options: Some(options), replace: false }.encode_to_vec()
}

/// A stored object's manifest (the test box onboarded at 12 templates of 64 px; its
/// tensors, megabytes, are too large for a seed: `tiny_stored_object` is the seed with
/// tensors). None without a GPU adapter.
fn stored_manifest() -> Vec<(&'static str, &'static str, Vec<u8>)> {
    use b2tfpose::features::{EmbeddedBackbone, EmbeddedConfig};
    use b2tfpose::onboard::{onboard, OnboardConfig};
    let Ok(pool) = b2tfpose::render::RenderPool::new(1, Default::default()) else { return vec![] };
    let backbone = EmbeddedBackbone::new(EmbeddedConfig::default()).unwrap();
    let config = OnboardConfig { views: b2tfpose::geometry::ViewSampling { level: 0, in_plane_steps: 1 }, render_size: 64, ..Default::default() };
    let model = onboard("box", &small_box(), &config, &backbone, &pool, &|_| {}).unwrap();
    vec![("store_manifest", "manifest.json", b2tfpose::store::codec::encode(&model).unwrap().manifest)]
}

/// A whole stored object small enough for a seed, built by hand (no GPU): a textured
/// tetrahedron, one template with two patches on a 2×2 grid, 4-wide descriptors, one
/// contour view of 8 points. Encoded by the store's own writer (`store::codec::encode`) and
/// joined as the target reads it: manifest, tensors (safetensors), texture PNG. It decodes
/// without error (`tests/fuzz_regressions.rs`), so the fuzzer starts inside the tensors.
pub fn tiny_stored_object() -> Vec<u8> {
    use b2tfpose::features::BackboneIdentity;
    use b2tfpose::geometry::{CropBox, Intrinsics, PatchGrid, Pose, ViewSampling};
    use b2tfpose::onboard::{ContourConfig, ContourModel, ObjectModel, OnboardConfig, PcaSetting, Template};
    let texture = image::DynamicImage::ImageRgb8(checker(2, 2)).to_rgba8();
    let data = MeshData {
        positions: vec![[0.0, 0.0, 0.0], [0.05, 0.0, 0.0], [0.0, 0.05, 0.0], [0.0, 0.0, 0.05]],
        colors: vec![[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [0.5, 0.5, 0.5]],
        uvs: vec![[0.0, 0.0], [1.0, 0.0], [0.0, 1.0], [1.0, 1.0]],
        triangles: vec![[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]],
        materials: vec![Material { name: "skin".into(), texture: Some(texture.into()), ..Material::default() }],
        ..MeshData::default()
    };
    let mesh = Mesh::new("tetra", Units::M, data).unwrap();
    let (dim, points_per_view) = (4, 8);
    let backbone = BackboneIdentity { name: "tiny".into(), weights_hash: "0".into(), layers: "-".into(), input_size: 16, patch_size: 8, local_dim: dim as u32, global_dim: dim as u32 };
    let config = OnboardConfig { views: ViewSampling { level: 0, in_plane_steps: 1 }, render_size: 64, pca: PcaSetting::off(), ..Default::default() };
    let crop = CropBox { origin_u: 16.0, origin_v: 16.0, side: 32.0, size: 16 };
    let template = Template { pose: Pose::identity(), view: 0, in_plane: 0, crop, patch_start: 0, patch_count: 2 };
    let contour = ContourModel {
        config: ContourConfig { level: 0, render_size: 64, points_per_view },
        directions: vec![[0.0, 0.0, 1.0]],
        points: (0..points_per_view).map(|i| [0.01 * i as f32, 0.0, 0.0]).collect(),
        normals: vec![[1.0, 0.0, 0.0]; points_per_view],
        foreground_m: vec![0.01; points_per_view],
        background_m: vec![0.02; points_per_view],
        plain_share: vec![128; points_per_view],
    };
    let model = ObjectModel {
        object_id: "tetra".into(),
        backbone,
        config,
        render_intrinsics: Intrinsics { fx: 80.0, fy: 80.0, cx: 32.0, cy: 32.0, width: 64, height: 64 },
        grid: PatchGrid { n: 2, patch: 8 },
        mesh,
        templates: vec![template],
        global: vec![0.5; dim],
        global_dim: dim,
        patch_descriptors: b2tfpose::onboard::PatchDescriptors::Half(vec![half::f16::from_f32(0.5); 2 * dim].into()),
        local_dim: dim,
        pca: None,
        patch_points: {
            let mut p = b2tfpose::onboard::PatchPoints::Exact(vec![[0.01, 0.01, 0.0], [0.0, 0.01, 0.01]].into());
            p.to_grid();
            p
        },
        patch_cells: vec![0, 3].into(),
        silhouettes: (0..b2tfpose::onboard::model::SILHOUETTE_WORDS as u64).map(|w| w * 0x0101).collect::<Vec<u64>>().into(),
        contours: std::sync::OnceLock::from(Arc::new(contour)),
        detector: std::sync::OnceLock::new(),
        symmetries: None,
    };
    model.validate().unwrap();
    let encoded = b2tfpose::store::codec::encode(&model).unwrap();
    let texture_files: Vec<&[u8]> = encoded.textures.iter().map(|(_, png)| png.as_slice()).collect();
    joined(&[&[encoded.manifest.as_slice(), &encoded.tensors][..], &texture_files].concat())
}

/// (target, file name, bytes) of every seed.
fn seeds() -> Vec<(&'static str, &'static str, Vec<u8>)> {
    let mask = png(image::DynamicImage::ImageLuma8(image::GrayImage::from_fn(6, 5, |x, y| image::Luma([((x + y) % 3 == 0) as u8 * 255]))));
    let size = |w: u16, h: u16| [w.to_le_bytes(), h.to_le_bytes()].concat();
    let mut out = vec![
        ("mesh_ply", "box.ply", mesh_files(|d| {
            b2tfpose::mesh::write_ply::write_bop_ply(&small_box(), d, "box").unwrap();
            vec!["box.ply", "box.png"]
        })),
        ("mesh_ply", "binary.ply", b"ply\nformat binary_little_endian 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n\0\0\0\0\0\0\0\0\0\0\0\0\0\0\x80\x3f\0\0\0\0\0\0\0\0\0\0\0\0\0\0\x80\x3f\0\0\0\0\x03\0\0\0\0\x01\0\0\0\x02\0\0\0".to_vec()),
        ("mesh_obj", "box.obj", mesh_files(|d| {
            b2tfpose::mesh::write_obj::write_obj(&small_box(), d, "box").unwrap();
            vec!["box.obj", "box.mtl", "box_m0.png"]
        })),
        ("mesh_gltf", "triangle.gltf", MINIMAL_GLTF.as_bytes().to_vec()),
        ("image_input", "png", [&[0u8, 0, 0, 0, 0][..], &png(image::DynamicImage::ImageRgb8(checker(5, 3)))].concat()),
        ("image_input", "jpeg", [&[0u8, 0, 0, 0, 0][..], &jpeg(image::DynamicImage::ImageRgb8(checker(9, 7)))].concat()),
        ("image_input", "raw", [&[1u8][..], &size(2, 2), &checker(2, 2).into_raw()].concat()),
        ("mask_png", "mask", [&size(6, 5)[..], &mask].concat()),
        ("mask_rle", "coco_string", [&[0u8][..], &size(8, 8), b"b04400000>"].concat()),
        ("mask_rle", "request", [&[1u8][..], br#"{"counts":[5,2,2,2,5],"size":[4,4]}"#].concat()),
        ("mask_rle", "bop", [&[2u8][..], br#"{"counts":"2S11oN","size":[40,1]}"#].concat()),
        ("http_json", "estimate", [&[0u8][..], ESTIMATE_JSON.as_bytes()].concat()),
        ("http_json", "onboard", [&[1u8][..], ONBOARD_JSON.as_bytes()].concat()),
        ("http_json", "detect", [&[2u8][..], DETECT_JSON.as_bytes()].concat()),
        ("multipart", "onboard", MULTIPART.as_bytes().to_vec()),
        ("grpc_request", "estimate", [&[0u8][..], &grpc_estimate()].concat()),
        ("grpc_request", "onboard", [&[1u8][..], &grpc_onboard()].concat()),
        ("grpc_request", "detect", [&[2u8][..], &grpc_detect()].concat()),
        ("camera_file", "megapose.json", br#"{"K": [[600.0, 0.0, 320.0], [0.0, 610.0, 240.0], [0.0, 0.0, 1.0]], "resolution": [480, 640]}"#.to_vec()),
        ("camera_file", "bop.json", br#"{"cam_K": [600, 0, 320, 0, 610, 240, 0, 0, 1], "width": 640, "height": 480, "depth_scale": 0.1}"#.to_vec()),
        ("bop_detections", "detections.json", DETECTIONS.as_bytes().to_vec()),
        ("results_csv", "results.csv", RESULTS.as_bytes().to_vec()),
    ];
    out.extend(stored_manifest());
    // The current format; `tiny_object` beside it is kept as written in format 6 (f32
    // patch and contour points), so the older layout stays in the corpus and loads.
    out.push(("store_manifest", "tiny_object_v7", tiny_stored_object()));
    // Real files, when the shared data is there: a vertex-coloured GLB.
    let glb = Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/data/meshes/cubevc.glb");
    if let Ok(bytes) = std::fs::read(glb) {
        out.push(("mesh_gltf", "cubevc.glb", bytes));
    }
    out
}

pub fn write_all(root: &Path) {
    for (target, name, bytes) in seeds() {
        let dir = root.join(target);
        std::fs::create_dir_all(&dir).unwrap();
        std::fs::write(dir.join(name), bytes).unwrap();
    }
}
