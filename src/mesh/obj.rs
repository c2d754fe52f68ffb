//! Wavefront OBJ + MTL via `tobj`: one part per tobj model (object/material run), `Kd` as base
//! colour, `map_Kd` as texture, `v x y z r g b` vertex colours.

use super::assemble::{Assembler, Piece};
use super::files::{Folder, MeshFiles};
use super::texture::TextureCache;
use super::{Material, Mesh, MeshError, Units};
use std::cell::RefCell;
use std::path::{Path, PathBuf};

/// Loads an OBJ file (and the MTL libraries and textures it names) whose lengths are in `units`.
pub fn load_obj(path: &Path, units: Units) -> Result<Mesh, MeshError> {
    obj_from_bytes(path, &super::files::read_mesh_file(path)?, units, &Folder::beside(path))
}

/// An OBJ file's bytes, the files it names from `files`; `path` names it in errors.
pub(super) fn obj_from_bytes(path: &Path, bytes: &[u8], units: Units, files: &dyn MeshFiles) -> Result<Mesh, MeshError> {
    // tobj's buffer API hands over the raw mtllib name and merges all libraries' materials,
    // forgetting where each came from; the closure records each material's folder (tobj
    // appends them in load order), relative to the OBJ's, and any failure, which tobj
    // would otherwise report without the library's name.
    let material_dirs: RefCell<Vec<PathBuf>> = RefCell::default();
    let mtl_failure: RefCell<Option<String>> = RefCell::default();
    let options = tobj::LoadOptions { single_index: true, triangulate: true, ..Default::default() };
    check_obj(bytes).map_err(|e| MeshError::format(path, e))?;
    let mut reader = LineCounter { inner: std::io::BufReader::new(bytes), newlines: 0, partial: false };
    let (models, materials) = tobj::load_obj_buf(&mut reader, &options, |mtl| {
        let result = files.read(&mtl.to_string_lossy()).map_err(|e| format!("material library {e}")).and_then(|text| {
            let unreadable = |e: String| format!("material library {} unreadable ({e})", mtl.display());
            check_mtl(&text).map_err(unreadable)?;
            tobj::load_mtl_buf(&mut text.as_slice()).map_err(|e| unreadable(e.to_string()))
        });
        match result {
            Ok((mats, map)) => {
                let mtl_dir = mtl.parent().unwrap_or(Path::new("")).to_path_buf();
                material_dirs.borrow_mut().extend(std::iter::repeat_n(mtl_dir, mats.len()));
                Ok((mats, map))
            }
            Err(e) => {
                mtl_failure.borrow_mut().get_or_insert(e);
                Err(tobj::LoadError::OpenFileFailed)
            }
        }
    })
    .map_err(|e| MeshError::format(path, format!("{e} (parsing stopped at line {})", reader.line())))?;
    if let Some(message) = mtl_failure.into_inner() {
        return Err(MeshError::format(path, message));
    }
    // With no mtllib at all tobj reports an empty material list as an error; that is fine.
    let tobj_materials = materials.unwrap_or_default();

    let mut textures = TextureCache::default();
    let dirs = material_dirs.into_inner();
    let mut out: Vec<Material> = Vec::with_capacity(tobj_materials.len() + 1);
    for (m, mtl_dir) in tobj_materials.iter().zip(&dirs) {
        out.push(convert_material(path, m, mtl_dir, files, &mut textures)?);
    }
    let default_material = out.len() as u32;
    out.push(Material::default());

    let scale = units.to_metres();
    let mut assembler = Assembler::new();
    for model in &models {
        let m = &model.mesh;
        let material = m.material_id.filter(|&i| i < tobj_materials.len()).map_or(default_material, |i| i as u32);
        let piece = Piece {
            positions: triples(&m.positions).into_iter().map(|p| p.map(|c| (c as f64 * scale) as f32)).collect(),
            normals: (!m.normals.is_empty()).then(|| triples(&m.normals)),
            colors: (!m.vertex_color.is_empty()).then(|| triples(&m.vertex_color)),
            uvs: (!m.texcoords.is_empty()).then(|| m.texcoords.chunks_exact(2).map(|t| [t[0], t[1]]).collect()),
            triangles: m.indices.chunks_exact(3).map(|t| [t[0], t[1], t[2]]).collect(),
            material,
        };
        assembler.push(piece).map_err(|e| MeshError::format(path, format!("object {:?}: {e}", model.name)))?;
    }
    if assembler.is_empty() {
        return Err(MeshError::format(path, "no faces"));
    }
    Mesh::new(path.display().to_string(), units, assembler.finish(out))
}

/// What tobj 4 overflows on (a panic with overflow checks, a wrong vertex without): an
/// index beyond ±2³², or a relative (negative) one reaching before the first position,
/// texture coordinate or normal (found by fuzzing: `f 2/-10` after four `vt`).
fn check_obj(text: &[u8]) -> Result<(), String> {
    let mut counts = [0u64; 3]; // v, vt, vn so far: what relative indices count back from
    for (i, line) in String::from_utf8_lossy(text).lines().enumerate() {
        let mut words = line.split_whitespace();
        match words.next() {
            Some("v") => counts[0] += 1,
            Some("vt") => counts[1] += 1,
            Some("vn") => counts[2] += 1,
            Some("f" | "l" | "p") => {
                for (k, index) in words.flat_map(|w| w.split('/').enumerate()) {
                    let Ok(v) = index.parse::<i128>() else { continue };
                    let before_first = v < 0 && counts.get(k).is_some_and(|&n| v.unsigned_abs() > n as u128);
                    if v.unsigned_abs() > u32::MAX as u128 || before_first {
                        return Err(format!("line {}: index {v} is out of range", i + 1));
                    }
                }
            }
            _ => {}
        }
    }
    Ok(())
}

/// What tobj 4 panics on instead of refusing: a colour line (`Ka`, `Kd`, `Ks`, `Ke`) with
/// fewer than three values (found by fuzzing: `Kd 0.8 0`).
fn check_mtl(text: &[u8]) -> Result<(), String> {
    for (i, line) in String::from_utf8_lossy(text).lines().enumerate() {
        let mut words = line.split_whitespace();
        if let Some(key @ ("Ka" | "Kd" | "Ks" | "Ke")) = words.next() {
            if words.count() < 3 {
                return Err(format!("line {}: {key} needs three numbers", i + 1));
            }
        }
    }
    Ok(())
}

fn triples(values: &[f32]) -> Vec<[f32; 3]> {
    values.chunks_exact(3).map(|v| [v[0], v[1], v[2]]).collect()
}

fn convert_material(obj: &Path, m: &tobj::Material, mtl_dir: &Path, files: &dyn MeshFiles, textures: &mut TextureCache) -> Result<Material, MeshError> {
    let [r, g, b] = m.diffuse.unwrap_or([1.0; 3]);
    let texture = match m.diffuse_texture.as_deref().map(texture_file_name) {
        // Relative to the material library's folder, as OBJ readers resolve it.
        Some(name) if !name.is_empty() => Some(textures.load(obj, files, &mtl_dir.join(name).to_string_lossy())?.into()),
        _ => None,
    };
    Ok(Material { name: m.name.clone(), base_color: [r, g, b, m.dissolve.unwrap_or(1.0)], texture })
}

/// tobj keeps the whole rest of a `map_Kd` line, so spaces in file names survive ("fuze
/// uv.jpg"), but so do texture options ("-s 1 1 1 tex.png"); this drops leading options
/// and keeps the rest as the file name.
fn texture_file_name(line: &str) -> &str {
    let mut rest = line.trim();
    while rest.starts_with('-') {
        let (option, after) = split_word(rest);
        // Number of arguments per MTL texture option; -o/-s/-t take one to three numbers.
        let (min, max) = match option {
            "-blendu" | "-blendv" | "-cc" | "-clamp" | "-imfchan" | "-texres" | "-bm" | "-boost" | "-type" => (1, 1),
            "-mm" => (2, 2),
            "-o" | "-s" | "-t" => (1, 3),
            _ => break, // Not an option we know: treat it as part of the name.
        };
        rest = after;
        for k in 0..max {
            let (arg, after) = split_word(rest);
            if k >= min && arg.parse::<f64>().is_err() {
                break;
            }
            rest = after;
        }
    }
    rest
}

fn split_word(s: &str) -> (&str, &str) {
    let s = s.trim_start();
    let end = s.find(|c: char| c.is_ascii_whitespace()).unwrap_or(s.len());
    (&s[..end], s[end..].trim_start())
}

/// Counts the lines tobj has consumed, so that its errors (which carry no position) can be
/// reported at the line where parsing stopped.
struct LineCounter<R> {
    inner: std::io::BufReader<R>,
    newlines: usize,
    /// Whether bytes of an unterminated line have been consumed.
    partial: bool,
}

impl<R> LineCounter<R> {
    /// The line tobj read last (1-based).
    fn line(&self) -> usize {
        self.newlines + self.partial as usize
    }
}

impl<R: std::io::Read> std::io::Read for LineCounter<R> {
    fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        use std::io::BufRead;
        let n = self.fill_buf()?.len().min(buf.len());
        buf[..n].copy_from_slice(&self.inner.buffer()[..n]);
        self.consume(n);
        Ok(n)
    }
}

impl<R: std::io::Read> std::io::BufRead for LineCounter<R> {
    fn fill_buf(&mut self) -> std::io::Result<&[u8]> {
        self.inner.fill_buf()
    }
    fn consume(&mut self, amt: usize) {
        let consumed = &self.inner.buffer()[..amt];
        self.newlines += consumed.iter().filter(|&&b| b == b'\n').count();
        if let Some(&last) = consumed.last() {
            self.partial = last != b'\n';
        }
        self.inner.consume(amt);
    }
}

#[cfg(test)]
mod tests {
    use super::super::test_util::{assert_close, assert_error, write_png};
    use super::*;

    fn write(dir: &Path, name: &str, text: &str) -> PathBuf {
        let path = dir.join(name);
        std::fs::write(&path, text).unwrap();
        path
    }

    /// A unit square (two quads' worth: one quad) with uvs and a normal.
    const SQUARE: &str = "v 0 0 0\nv 2 0 0\nv 2 2 0\nv 0 2 0\nvt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\nvn 0 0 1\n";

    #[test]
    fn texture_name_with_space_and_cm_units() {
        let dir = tempfile::tempdir().unwrap();
        write_png(&dir.path().join("my tex.png"), 5, 2);
        write(dir.path(), "sq.obj.mtl", "newmtl\tskin \nKd 0.8 0.7 0.6\nmap_Kd my tex.png \n");
        let obj = format!("mtllib sq.obj.mtl\n{SQUARE}usemtl skin\nf 1/1/1 2/2/1 3/3/1 4/4/1\n");
        let path = write(dir.path(), "sq.obj", &obj);
        let mesh = load_obj(&path, Units::Cm).unwrap();
        assert_eq!(mesh.triangles().len(), 2);
        assert_eq!(mesh.positions().len(), 4);
        assert_close(&mesh.positions()[2], &[0.02, 0.02, 0.0]);
        assert_close(&mesh.uvs().unwrap()[2], &[1.0, 1.0]);
        assert!(mesh.has_texture());
        let material = &mesh.materials()[mesh.parts()[0].material as usize];
        assert_eq!(material.texture.as_ref().unwrap().dimensions(), (5, 2));
        assert_close(&material.base_color, &[0.8, 0.7, 0.6, 1.0]);
        assert_close(&mesh.normals()[0], &[0.0, 0.0, 1.0]);
    }

    #[test]
    fn kd_only_materials_make_parts() {
        let dir = tempfile::tempdir().unwrap();
        write(dir.path(), "m.mtl", "newmtl red\nKd 1 0 0\nd 0.5\nnewmtl blue\nKd 0 0 1\n");
        let obj = format!("mtllib m.mtl\n{SQUARE}o a\nusemtl red\nf 1 2 3\no b\nusemtl blue\nf 1 3 4\n");
        let mesh = load_obj(&write(dir.path(), "two.obj", &obj), Units::M).unwrap();
        assert_eq!(mesh.parts().len(), 2);
        let colour = |p: usize| mesh.materials()[mesh.parts()[p].material as usize].base_color;
        assert_close(&colour(0), &[1.0, 0.0, 0.0, 0.5]);
        assert_close(&colour(1), &[0.0, 0.0, 1.0, 1.0]);
        assert!(!mesh.has_texture());
        assert!(mesh.uvs().is_none());
    }

    #[test]
    fn vertex_colours_and_no_mtl() {
        let dir = tempfile::tempdir().unwrap();
        let obj = "v 0 0 0 1 0 0\nv 1 0 0 0 1 0\nv 0 1 0 0 0 1\nf 1 2 3\n";
        let mesh = load_obj(&write(dir.path(), "vc.obj", obj), Units::M).unwrap();
        assert_close(&mesh.colors().unwrap()[1], &[0.0, 1.0, 0.0]);
        assert_eq!(mesh.materials().len(), 1);
    }

    #[test]
    fn map_kd_options_are_dropped() {
        assert_eq!(texture_file_name("fuze uv.jpg"), "fuze uv.jpg");
        assert_eq!(texture_file_name(" -s 1 1 1 -o 0.5 -bm 0.2 my tex.png "), "my tex.png");
        assert_eq!(texture_file_name("-s 2 -clamp on 3d.png"), "3d.png");
        assert_eq!(texture_file_name("-blendu off -mm 0 1 a b.jpg"), "a b.jpg");
    }

    fn bad(name: &str, obj: &str, needles: &[&str]) -> String {
        let dir = tempfile::tempdir().unwrap();
        write(dir.path(), "ok.mtl", "newmtl skin\nKd 1 1 1\n");
        write(dir.path(), "tex.mtl", "newmtl skin\nmap_Kd gone away.png\n");
        let path = write(dir.path(), name, obj);
        assert_error(load_obj(&path, Units::Mm), &path, needles)
    }

    #[test]
    fn missing_mtl() {
        bad("a.obj", &format!("mtllib missing.mtl\n{SQUARE}f 1 2 3\n"), &["material library", "missing.mtl", "not found"]);
    }

    #[test]
    fn missing_texture() {
        let dir = tempfile::tempdir().unwrap();
        write(dir.path(), "tex.mtl", "newmtl skin\nmap_Kd gone away.png\n");
        let path = write(dir.path(), "t.obj", &format!("mtllib tex.mtl\n{SQUARE}usemtl skin\nf 1 2 3\n"));
        assert!(matches!(load_obj(&path, Units::Mm), Err(MeshError::Texture { .. })));
        assert_error(load_obj(&path, Units::Mm), &path, &["gone away.png", "not found"]);
    }

    #[test]
    fn malformed_objs() {
        bad("nan.obj", &format!("mtllib ok.mtl\n{SQUARE}v nan 0 0\nf 1 2 5\n"), &["non-finite"]);
        bad("range.obj", &format!("{SQUARE}f 1 2 3\nf 1 2 9\nf 1 2 3\n"), &["out of bounds", "line 12"]);
        bad("cut.obj", &format!("{SQUARE}f 1 2 3\nv 1 2"), &["line 11", "position parse error"]);
        bad("empty.obj", SQUARE, &["no faces"]);
    }

    #[test]
    fn missing_file_is_io_error() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("none.obj");
        assert!(matches!(load_obj(&path, Units::Mm), Err(MeshError::Io { .. })));
    }
}
