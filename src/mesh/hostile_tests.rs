//! Hostile inputs to every loader, in memory: counts over the limits refused from the
//! header, names of devices and of files outside an upload, glTF hierarchies that would
//! multiply the work, accessors the gltf crate would panic on.

use super::files::{Folder, InMemory, MeshFiles};
use super::{load_mesh_bytes, Units};
use crate::limits::{MAX_MESH_TRIANGLES, MAX_MESH_VERTICES};
use std::collections::HashMap;
use std::path::Path;

fn load(name: &str, bytes: &[u8], files: &dyn MeshFiles) -> String {
    let units = (!name.ends_with(".glb")).then_some(Units::Mm);
    load_mesh_bytes(Path::new(name), bytes, units, files).map(|_| "loaded".to_string()).unwrap_or_else(|e| e.to_string())
}

fn none() -> InMemory {
    InMemory::default()
}

const PLY_HEAD: &str = "ply\nformat binary_little_endian 1.0\n";
const XYZ_FACES: &str = "property float x\nproperty float y\nproperty float z\nelement face 1\nproperty list uchar int vertex_indices\n";

#[test]
fn ply_counts_over_the_limits_are_refused_from_the_header() {
    let vertices = format!("{PLY_HEAD}element vertex {}\n{XYZ_FACES}end_header\n", MAX_MESH_VERTICES + 1);
    assert!(load("a.ply", vertices.as_bytes(), &none()).contains(&format!("element vertex has count {}, over the limit", MAX_MESH_VERTICES + 1)));
    let faces = format!("{PLY_HEAD}element vertex 3\n{}end_header\n", XYZ_FACES.replace("face 1", &format!("face {}", MAX_MESH_TRIANGLES + 1)));
    assert!(load("a.ply", faces.as_bytes(), &none()).contains("element face has count 20000001, over the limit"));
}

#[test]
fn ply_elements_without_properties_are_skipped_whatever_their_count() {
    let mut ply = format!("{PLY_HEAD}element junk 18446744073709551615\nelement vertex 3\n{XYZ_FACES}end_header\n").into_bytes();
    for v in [[0f32, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]] {
        ply.extend(v.iter().flat_map(|c| c.to_le_bytes()));
    }
    ply.push(3);
    ply.extend([0i32, 1, 2].iter().flat_map(|i| i.to_le_bytes()));
    assert_eq!(load("a.ply", &ply, &none()), "loaded");
}

#[test]
fn textures_over_the_limits_are_refused_from_their_header() {
    let ply = "ply\nformat ascii 1.0\ncomment TextureFile t.png\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n";
    let huge = InMemory(HashMap::from([("t.png".to_string(), crate::limits::tests::png_header_only(9000, 10))]));
    assert!(load("a.ply", ply.as_bytes(), &huge).contains("cannot decode: 9000×10 is over the limit of 8192 pixels a side"));
}

#[test]
fn devices_and_files_outside_an_upload_are_not_read() {
    let dir = tempfile::tempdir().unwrap();
    let obj = |mtl: &str| format!("mtllib {mtl}\nv 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n");
    let local = Folder::beside(&dir.path().join("m.obj"));
    assert!(load("m.obj", obj("/dev/zero").as_bytes(), &local).contains("material library /dev/zero: not a regular file"));
    let upload = Folder::confined(dir.path());
    assert!(load("m.obj", obj("../../etc/passwd").as_bytes(), &upload).contains("only names inside the upload"));
    let gltf = r#"{"asset":{"version":"2.0"},"buffers":[{"byteLength":4,"uri":"file:///dev/zero"}]}"#;
    assert!(load("m.glb", gltf.as_bytes(), &local).contains("/dev/zero: not a regular file"));
}

/// A triangle glTF with `extra` merged into its document.
fn gltf(extra: serde_json::Value) -> Vec<u8> {
    let mut doc = serde_json::json!({"asset": {"version": "2.0"}, "scenes": [{"nodes": [0]}], "nodes": [{"mesh": 0}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0}}]}],
        "accessors": [{"bufferView": 0, "componentType": 5126, "count": 3, "type": "VEC3", "min": [0, 0, 0], "max": [1, 1, 0]}],
        "bufferViews": [{"buffer": 0, "byteLength": 36}],
        "buffers": [{"byteLength": 36, "uri": "data:application/octet-stream;base64,AAAAAAAAAAAAAAAAAACAPwAAAAAAAAAAAAAAAAAAgD8AAAAA"}]});
    for (k, v) in extra.as_object().unwrap() {
        doc[k] = v.clone();
    }
    serde_json::to_vec(&doc).unwrap()
}

#[test]
fn gltf_nodes_reached_twice_are_refused() {
    assert_eq!(load("a.glb", &gltf(serde_json::json!({})), &none()), "loaded");
    // 40 levels of two children that are the same node: 2^40 visits without the check. The
    // deepest node is the first one reached again.
    let mut nodes: Vec<serde_json::Value> = (0..40).map(|i| serde_json::json!({"children": [i + 1, i + 1], "mesh": 0})).collect();
    nodes.push(serde_json::json!({"mesh": 0}));
    let e = load("a.glb", &gltf(serde_json::json!({"nodes": nodes})), &none());
    assert!(e.contains("node 40 is reached twice: the node hierarchy must be a tree"), "{e}");
    let cycle = serde_json::json!({"nodes": [{"children": [1], "mesh": 0}, {"children": [0]}]});
    assert!(load("a.glb", &gltf(cycle), &none()).contains("node 0 is reached twice"));
}

#[test]
fn gltf_accessors_the_reader_would_panic_on_are_refused() {
    let accessor = |fields: serde_json::Value| {
        let mut a = serde_json::json!({"bufferView": 0, "componentType": 5126, "count": 3, "type": "VEC3", "min": [0, 0, 0], "max": [1, 1, 0]});
        for (k, v) in fields.as_object().unwrap() {
            a[k] = v.clone();
        }
        gltf(serde_json::json!({"accessors": [a]}))
    };
    assert!(load("a.glb", &accessor(serde_json::json!({"count": 0})), &none()).contains("count 0 is outside 1..=10000000"));
    let no_view = serde_json::json!({"bufferView": null, "count": 4_000_000_000u64, "sparse": {"count": 1, "indices": {"bufferView": 0, "componentType": 5125}, "values": {"bufferView": 0}}});
    assert!(load("a.glb", &accessor(no_view), &none()).contains("count 4000000000 is outside"));
    let strided = gltf(serde_json::json!({"bufferViews": [{"buffer": 0, "byteLength": 36, "byteStride": 4}]}));
    assert!(load("a.glb", &strided, &none()).contains("stride is shorter than an item"));
    let beyond = gltf(serde_json::json!({"bufferViews": [{"buffer": 0, "byteOffset": 8, "byteLength": 36}]}));
    assert!(load("a.glb", &beyond, &none()).contains("beyond its buffer"));
}

#[test]
fn gltf_uris_that_are_not_utf8_once_decoded_are_refused() {
    let e = load("a.glb", &gltf(serde_json::json!({"buffers": [{"byteLength": 36, "uri": "%FF.bin"}]})), &none());
    assert!(e.contains("\"%FF.bin\" is not UTF-8 once percent-decoded"), "{e}");
    let e = load("a.glb", &gltf(serde_json::json!({"buffers": [{"byteLength": 36, "uri": "geo%20data.bin"}]})), &none());
    assert!(e.contains("\"geo data.bin\": not found"), "{e}");
}

#[test]
fn gltf_attributes_of_another_type_are_refused() {
    let colours = serde_json::json!({"meshes": [{"primitives": [{"attributes": {"POSITION": 0, "COLOR_0": 1}}]}],
        "accessors": [{"bufferView": 0, "componentType": 5126, "count": 3, "type": "VEC3", "min": [0, 0, 0], "max": [1, 1, 0]},
                      {"bufferView": 0, "componentType": 5126, "count": 3, "type": "VEC2"}]});
    let e = load("a.glb", &gltf(colours), &none());
    assert!(e.contains("Colors(0) accessor 1: Vec2 of F32 is not a type this attribute may have"), "{e}");
    let indices = serde_json::json!({"meshes": [{"primitives": [{"attributes": {"POSITION": 0}, "indices": 1}]}],
        "accessors": [{"bufferView": 0, "componentType": 5126, "count": 3, "type": "VEC3", "min": [0, 0, 0], "max": [1, 1, 0]},
                      {"bufferView": 0, "componentType": 5126, "count": 3, "type": "SCALAR"}]});
    assert!(load("a.glb", &gltf(indices), &none()).contains("index accessor 1: Scalar of F32"));
}

/// Found by fuzzing (fuzz/regressions/mesh_obj): tobj panicked on a colour with two values.
#[test]
fn mtl_colours_with_fewer_than_three_values_are_refused() {
    let obj = "mtllib a.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nusemtl skin\nf 1 2 3\n";
    let mtl = |kd: &str| InMemory(HashMap::from([("a.mtl".to_string(), format!("newmtl skin\n{kd}\n").into_bytes())]));
    assert_eq!(load("m.obj", obj.as_bytes(), &mtl("Kd 0.8 0 0.5")), "loaded");
    let e = load("m.obj", obj.as_bytes(), &mtl("Kd 0.8 0"));
    assert!(e.contains("material library a.mtl unreadable (line 2: Kd needs three numbers)"), "{e}");
}

/// Found by fuzzing (fuzz/regressions/mesh_gltf): a GLB header declaring fewer bytes than
/// the header overflowed the gltf crate's subtraction.
#[test]
fn glb_headers_shorter_than_themselves_are_refused() {
    let mut glb = b"glTF".to_vec();
    glb.extend(2u32.to_le_bytes());
    glb.extend(6u32.to_le_bytes());
    assert!(load("a.glb", &glb, &none()).contains("invalid glTF: GLB header declares fewer than its own 12 bytes"));
}

/// Found by fuzzing (fuzz/regressions/mesh_obj): tobj turned a relative texture index
/// reaching before the first one into a huge one and multiplied it unchecked.
#[test]
fn obj_indices_out_of_range_are_refused() {
    let obj = |f: &str| format!("v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\n{f}\n");
    assert_eq!(load("m.obj", obj("f 1/1 2/-1 -1/1").as_bytes(), &none()), "loaded");
    for f in ["f 2/-10 -1 -2", "f 1/9223372036854775807 2/1 3/1", "f -4 1 2"] {
        let e = load("m.obj", obj(f).as_bytes(), &none());
        assert!(e.contains("line 5: index") && e.contains("is out of range"), "{f}: {e}");
    }
}

/// Found by fuzzing (fuzz/regressions/mesh_gltf): gltf-json's validation indexed the
/// accessors with a POSITION that names none.
#[test]
fn gltf_positions_naming_no_accessor_are_refused() {
    let e = load("a.glb", &gltf(serde_json::json!({"accessors": []})), &none());
    assert!(e.contains("invalid glTF: mesh 0 primitive 0: POSITION accessor 0 does not exist"), "{e}");
}
