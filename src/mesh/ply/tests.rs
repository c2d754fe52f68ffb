//! The PLY reader's tests: each encoding, property layout and broken file it names.

use super::super::test_util::{assert_close, assert_error, write_png};
use super::*;
use std::path::PathBuf;

/// Corner `i` of a 20 mm cube centred on the origin: bit 0 is x, bit 1 y, bit 2 z.
fn corner(i: usize) -> [f64; 3] {
    [0, 1, 2].map(|b| if i >> b & 1 == 1 { 10.0 } else { -10.0 })
}
fn corner_uv(i: usize) -> [f64; 2] {
    let c = corner(i);
    [c[0] / 40.0 + 0.5, c[1] / 40.0 + 0.5]
}
const QUADS: [[u32; 4]; 6] = [[0, 2, 3, 1], [4, 5, 7, 6], [0, 1, 5, 4], [2, 6, 7, 3], [0, 4, 6, 2], [1, 3, 7, 5]];

fn write(dir: &Path, name: &str, bytes: impl AsRef<[u8]>) -> PathBuf {
    let path = dir.join(name);
    std::fs::write(&path, bytes).unwrap();
    path
}

/// An ascii PLY from header lines (between the format line and end_header) and data lines.
fn ascii(header: &[&str], body: &[String]) -> String {
    format!("ply\nformat ascii 1.0\n{}\nend_header\n{}\n", header.join("\n"), body.join("\n"))
}

/// The BOP layout: positions, normals, texture_u/v, quads, and a TextureFile comment.
fn cube_ascii(texture: &str, vertex_count: usize, face_count: usize) -> String {
    let mut body: Vec<String> = (0..8)
        .map(|i| {
            let [x, y, z] = corner(i);
            let [u, v] = corner_uv(i);
            let s = 1.0 / (10.0 * 3f64.sqrt());
            format!("{x} {y} {z} {} {} {} {u} {v}", x * s, y * s, z * s)
        })
        .collect();
    body.extend(QUADS.iter().map(|q| format!("4 {} {} {} {}", q[0], q[1], q[2], q[3])));
    let vertex = format!("element vertex {vertex_count}");
    let face = format!("element face {face_count}");
    let texture = format!("comment TextureFile {texture}");
    let header = [
        "comment made by a test",
        texture.as_str(),
        vertex.as_str(),
        "property float x",
        "property float y",
        "property float z",
        "property float nx",
        "property float ny",
        "property float nz",
        "property float texture_u",
        "property float texture_v",
        face.as_str(),
        "property list uchar int vertex_indices",
    ];
    ascii(&header, &body)
}

fn textured_cube_dir() -> (tempfile::TempDir, PathBuf) {
    let dir = tempfile::tempdir().unwrap();
    write_png(&dir.path().join("cube tex.png"), 4, 3);
    let path = write(dir.path(), "cube.ply", cube_ascii("cube tex.png", 8, 6));
    (dir, path)
}

#[test]
fn ascii_textured_cube_in_mm() {
    let (_dir, path) = textured_cube_dir();
    let mesh = load_ply(&path, Units::Mm).unwrap();
    assert_eq!(mesh.positions().len(), 8);
    assert_eq!(mesh.triangles().len(), 12);
    for i in 0..8 {
        assert_close(&mesh.positions()[i], &corner(i).map(|c| (c * 1e-3) as f32));
        assert_close(&mesh.uvs().unwrap()[i], &corner_uv(i).map(|c| c as f32));
        let n = mesh.normals()[i];
        assert!((n[0] * n[0] + n[1] * n[1] + n[2] * n[2] - 1.0).abs() < 1e-4, "normal {n:?} kept from the file");
    }
    assert!(mesh.has_texture());
    let texture = mesh.materials()[0].texture.as_ref().unwrap();
    assert_eq!(texture.dimensions(), (4, 3));
    assert_eq!(texture.pixels().unwrap().get_pixel(2, 1).0, [20, 10, 7, 255]);
    assert!((mesh.diameter() - 0.02 * 3f64.sqrt()).abs() < 1e-6);
    assert_eq!(mesh.source_units(), Units::Mm);
}

#[test]
fn units_scale_positions() {
    let (_dir, path) = textured_cube_dir();
    for (units, metres) in [(Units::Mm, 1e-3), (Units::Cm, 1e-2), (Units::M, 1.0)] {
        let mesh = load_ply(&path, units).unwrap();
        assert!((mesh.diameter() - 20.0 * metres * 3f64.sqrt()).abs() < 1e-6 * metres * 100.0, "{units:?}");
        assert_close(&mesh.positions()[7], &[(10.0 * metres) as f32; 3]);
    }
}

/// Little-endian or big-endian writer for binary bodies.
struct Bin {
    bytes: Vec<u8>,
    big: bool,
}
impl Bin {
    fn put<const N: usize>(&mut self, le: [u8; N], be: [u8; N]) {
        self.bytes.extend(if self.big { be } else { le });
    }
    fn f64(&mut self, v: f64) {
        self.put(v.to_le_bytes(), v.to_be_bytes());
    }
    fn f32(&mut self, v: f32) {
        self.put(v.to_le_bytes(), v.to_be_bytes());
    }
    fn i32(&mut self, v: i32) {
        self.put(v.to_le_bytes(), v.to_be_bytes());
    }
    fn u16(&mut self, v: u16) {
        self.put(v.to_le_bytes(), v.to_be_bytes());
    }
    fn u8(&mut self, v: u8) {
        self.bytes.push(v);
    }
}

/// The cube in binary with other types (double positions, uchar colours with alpha, s/t
/// uvs, ushort index lists), plus properties and an element the reader must skip.
fn cube_binary(big: bool, vertex_coord: impl Fn(usize, usize) -> f64) -> Vec<u8> {
    let format = if big { "binary_big_endian" } else { "binary_little_endian" };
    let header = format!(
        "ply\r\nformat {format} 1.0\r\ncomment TextureFile cube tex.png\r\nelement vertex 8\r\nproperty double x\r\n\
         property double y\r\nproperty double z\r\nproperty list uchar float junk\r\nproperty uchar red\r\n\
         property uchar green\r\nproperty uchar blue\r\nproperty uchar alpha\r\nproperty float s\r\nproperty float t\r\n\
         element edge 2\r\nproperty int a\r\nproperty list uchar int b\r\n\
         element face 6\r\nproperty uchar flags\r\nproperty list uchar ushort vertex_index\r\nend_header\r\n"
    );
    let mut b = Bin { bytes: header.into_bytes(), big };
    for i in 0..8 {
        (0..3).for_each(|k| b.f64(vertex_coord(i, k)));
        b.u8(i as u8 % 3);
        (0..i % 3).for_each(|k| b.f32(k as f32));
        [30 * i as u8, 255 - 30 * i as u8, 100, 255].into_iter().for_each(|c| b.u8(c));
        corner_uv(i).into_iter().for_each(|c| b.f32(c as f32));
    }
    for e in 0..2 {
        b.i32(e);
        b.u8(2);
        b.i32(7);
        b.i32(8);
    }
    for q in QUADS {
        b.u8(0xEE);
        b.u8(4);
        q.into_iter().for_each(|i| b.u16(i as u16));
    }
    b.bytes
}

#[test]
fn binary_cube_both_endians_matches_ascii() {
    let (dir, ascii_path) = textured_cube_dir();
    let reference = load_ply(&ascii_path, Units::Mm).unwrap();
    for big in [false, true] {
        let path = write(dir.path(), "cube_bin.ply", cube_binary(big, |i, k| corner(i)[k]));
        let mesh = load_ply(&path, Units::Mm).unwrap();
        assert_eq!(mesh.positions(), reference.positions(), "big endian: {big}");
        assert_eq!(mesh.triangles(), reference.triangles());
        assert_eq!(mesh.uvs(), reference.uvs());
        assert!(mesh.has_texture());
        let colours = mesh.colors().unwrap();
        assert_close(&colours[2], &[60.0 / 255.0, 195.0 / 255.0, 100.0 / 255.0]);
    }
}

#[test]
fn points_are_the_file_values_unrounded() {
    // As the BOP toolkit reads them: ascii text as f64 whatever the declared type, binary
    // floats widened exactly. Through a Mesh's f32 metres 2.5 mm comes back as 2.4999999441.
    let dir = tempfile::tempdir().unwrap();
    let header = |format: &str| {
        format!("ply\nformat {format} 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n")
    };
    let ascii = write(dir.path(), "a.ply", header("ascii") + "2.5 0 0\n0 4.3674882 0\n0 0 0.1\n3 0 1 2\n");
    assert_eq!(load_ply_points(&ascii).unwrap(), vec![[2.5, 0.0, 0.0], [0.0, 4.3674882, 0.0], [0.0, 0.0, 0.1]]);
    let via_mesh = load_ply(&ascii, Units::Mm).unwrap().positions()[0][0] as f64 * 1000.0;
    assert_eq!(via_mesh, 2.4999999441206455);

    let mut b = Bin { bytes: header("binary_little_endian").into_bytes(), big: false };
    [2.5f32, 0.0, 0.0, 0.0, 4.3674882, 0.0, 0.0, 0.0, 0.1].into_iter().for_each(|v| b.f32(v));
    b.u8(3);
    (0..3).for_each(|i| b.i32(i));
    let binary = write(dir.path(), "b.ply", b.bytes);
    let f = |v: f32| v as f64;
    assert_eq!(load_ply_points(&binary).unwrap(), vec![[2.5, 0.0, 0.0], [0.0, f(4.3674882), 0.0], [0.0, 0.0, f(0.1)]]);
}

#[test]
fn float_colours_and_st_uvs() {
    let dir = tempfile::tempdir().unwrap();
    let header = [
        "element vertex 3",
        "property float x",
        "property float y",
        "property float z",
        "property float red",
        "property float green",
        "property float blue",
        "property float s",
        "property float t",
        "element face 1",
        "property list uchar uint vertex_indices",
    ];
    let body = ["0 0 0 1 0.5 0 0.1 0.2", "1 0 0 0 0 0 0.3 0.4", "0 1 0 0.25 0.25 0.25 0.5 0.6", "3 0 1 2"].map(String::from);
    let path = write(dir.path(), "tri.ply", ascii(&header, &body));
    let mesh = load_ply(&path, Units::M).unwrap();
    assert_close(&mesh.colors().unwrap()[0], &[1.0, 0.5, 0.0]);
    assert_close(&mesh.colors().unwrap()[2], &[0.25; 3]);
    assert_close(&mesh.uvs().unwrap()[1], &[0.3, 0.4]);
    assert!(!mesh.has_texture());
}

#[test]
fn polygons_are_fan_triangulated() {
    let dir = tempfile::tempdir().unwrap();
    let header = ["element vertex 5", "property float x", "property float y", "property float z", "element face 1", "property list uchar int vertex_indices"];
    let body = ["1 0 0", "0.3 0.95 0", "-0.8 0.6 0", "-0.8 -0.6 0", "0.3 -0.95 0", "5 0 1 2 3 4"].map(String::from);
    let mesh = load_ply(&write(dir.path(), "pentagon.ply", ascii(&header, &body)), Units::M).unwrap();
    assert_eq!(mesh.triangles(), &[[0, 1, 2], [0, 2, 3], [0, 3, 4]]);
}

/// A square as a quad plus a triangle over a fifth vertex, with per-face texcoords that
/// agree on vertex 1 but disagree on vertex 2: only vertex 2 is duplicated.
#[test]
fn per_face_texcoords_become_per_vertex() {
    let dir = tempfile::tempdir().unwrap();
    let header = ["element vertex 5", "property float x", "property float y", "property float z", "element face 2", "property list uchar int vertex_indices", "property list uchar float texcoord"];
    let body = ["0 0 0", "1 0 0", "1 1 0", "0 1 0", "2 0 0", "4 0 1 2 3 8 0 0 0.5 0 0.5 1 0 1", "3 1 4 2 6 0.5 0 1 0 0.9 0.9"].map(String::from);
    let mesh = load_ply(&write(dir.path(), "seam.ply", ascii(&header, &body)), Units::M).unwrap();
    assert_eq!(mesh.triangles().len(), 3);
    assert_eq!(mesh.positions().len(), 6);
    let uvs = mesh.uvs().unwrap();
    let expected = [[[0.0, 0.0], [0.5, 0.0], [0.5, 1.0]], [[0.0, 0.0], [0.5, 1.0], [0.0, 1.0]], [[0.5, 0.0], [1.0, 0.0], [0.9, 0.9]]];
    for (t, want) in mesh.triangles().iter().zip(expected) {
        for c in 0..3 {
            assert_close(&uvs[t[c] as usize], &want[c]);
        }
    }
    assert_eq!(mesh.triangles()[0][1], mesh.triangles()[2][0], "vertex 1 shared: same uv in both faces");
    assert_ne!(mesh.triangles()[0][2], mesh.triangles()[2][2], "vertex 2 split: different uvs");
}

// ---- errors: each names the file and what and where

fn bad_ascii(name: &str, text: String, needles: &[&str]) -> String {
    let (dir, _) = textured_cube_dir();
    let path = write(dir.path(), name, text);
    assert_error(load_ply(&path, Units::Mm), &path, needles)
}

#[test]
fn truncated_ascii() {
    let text = cube_ascii("cube tex.png", 8, 6);
    let cut = text.trim_end().rsplitn(3, '\n').last().unwrap().to_string();
    bad_ascii("cut.ply", cut, &["face 4 of 6", "line 28", "file ends early"]);
}

#[test]
fn truncated_binary() {
    let mut bytes = cube_binary(false, |i, k| corner(i)[k]);
    bytes.truncate(bytes.len() - 3);
    let dir = tempfile::tempdir().unwrap();
    write_png(&dir.path().join("cube tex.png"), 2, 2);
    let path = write(dir.path(), "cut.ply", bytes);
    assert_error(load_ply(&path, Units::Mm), &path, &["face 5 of 6", "binary data ends early"]);
}

#[test]
fn counts_disagreeing_with_data() {
    bad_ascii("more_vertices.ply", cube_ascii("cube tex.png", 9, 6), &["vertex 8 of 9", "line 25", "line ends early"]);
    bad_ascii("fewer_faces.ply", cube_ascii("cube tex.png", 8, 5), &["extra data at line 30", "counts are too small"]);
    let text = cube_ascii("cube tex.png", 8, 6).replace("4 0 2 3 1", "3 0 2 3 1");
    bad_ascii("list_count.ply", text, &["face 0 of 6", "line 25", "extra value \"1\""]);
    let dir = tempfile::tempdir().unwrap();
    write_png(&dir.path().join("cube tex.png"), 2, 2);
    let mut bytes = cube_binary(false, |i, k| corner(i)[k]);
    bytes.push(0);
    let path = write(dir.path(), "long.ply", bytes);
    assert_error(load_ply(&path, Units::Mm), &path, &["1 bytes of extra data"]);
}

#[test]
fn non_finite_coordinates() {
    let text = cube_ascii("cube tex.png", 8, 6).replacen("-10 10 -10", "-10 nan -10", 1);
    bad_ascii("nan.ply", text, &["vertex 2 of 8", "line 19", "non-finite"]);
    let dir = tempfile::tempdir().unwrap();
    write_png(&dir.path().join("cube tex.png"), 2, 2);
    let bytes = cube_binary(true, |i, k| if i == 5 && k == 1 { f64::INFINITY } else { corner(i)[k] });
    let path = write(dir.path(), "inf.ply", bytes);
    assert_error(load_ply(&path, Units::Mm), &path, &["vertex 5 of 8", "non-finite"]);
}

#[test]
fn out_of_range_and_degenerate_faces() {
    let text = cube_ascii("cube tex.png", 8, 6).replace("4 4 5 7 6", "4 4 5 8 6");
    bad_ascii("range.ply", text, &["face 1 of 6", "line 26", "vertex index 8 out of range", "8 vertices"]);
    let text = cube_ascii("cube tex.png", 8, 6).replace("4 4 5 7 6", "2 4 5");
    bad_ascii("two.ply", text, &["face 1 of 6", "2 vertices"]);
    let text = cube_ascii("cube tex.png", 8, 6).replace("4 4 5 7 6", "4 4 5 -1 6");
    bad_ascii("negative.ply", text, &["face 1", "vertex index -1 out of range"]);
}

#[test]
fn no_faces() {
    let text = cube_ascii("cube tex.png", 8, 0);
    let no_face_lines = text.lines().filter(|l| !l.starts_with("4 ")).collect::<Vec<_>>().join("\n");
    bad_ascii("zero.ply", no_face_lines.clone(), &["no faces", "count 0"]);
    let no_element = no_face_lines.replace("element face 0\nproperty list uchar int vertex_indices\n", "");
    bad_ascii("points.ply", no_element, &["no faces", "no face element"]);
}

#[test]
fn bad_headers_and_numbers() {
    bad_ascii("magic.ply", "plx\n".into(), &["not a PLY file"]);
    bad_ascii("no_end.ply", "ply\nformat ascii 1.0\nelement vertex 1\n".into(), &["no end_header"]);
    let text = cube_ascii("cube tex.png", 8, 6);
    bad_ascii("type.ply", text.replace("property float nz", "property flot nz"), &["header line 11", "unknown type \"flot\""]);
    bad_ascii("format.ply", text.replace("format ascii 1.0", "format ascii 2.0"), &["header line 2", "unknown format"]);
    bad_ascii("word.ply", text.replacen("10 -10", "10 1o", 1), &["vertex", "property", "unparsable number \"1o\""]);
    bad_ascii("int.ply", text.replace("4 4 5 7 6", "4 4 5 7.5 6"), &["face 1", "\"7.5\" is not an integer"]);
    bad_ascii("no_z.ply", text.replace("property float z\n", ""), &["no property z"]);
}

#[test]
fn missing_texture() {
    let dir = tempfile::tempdir().unwrap();
    let path = write(dir.path(), "cube.ply", cube_ascii("absent file.png", 8, 6));
    let message = assert_error(load_ply(&path, Units::Mm), &path, &["absent file.png"]);
    assert!(matches!(load_ply(&path, Units::Mm), Err(MeshError::Texture { .. })), "{message}");
}

#[test]
fn missing_file_is_io_error() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("nothing.ply");
    assert!(matches!(load_ply(&path, Units::Mm), Err(MeshError::Io { .. })));
    assert_error(load_ply(&path, Units::Mm), &path, &[]);
}
