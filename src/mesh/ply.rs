//! PLY reader (ascii, binary little and big endian) for BOP-style models: positions, normals,
//! vertex colours, per-vertex or per-face texture coordinates, polygon faces, and a texture
//! named by a `comment TextureFile NAME` header line.
//!
//! Our own reader rather than a crate's because the errors must say where a file is broken
//! (element, index, line or byte), and the BOP conventions (TextureFile, texcoord lists) need
//! handling anyway.

use super::files::{Folder, MeshFiles};
use super::texture::load_texture;
use super::{Material, Mesh, MeshData, MeshError, Units};
use crate::limits::{MAX_MESH_TRIANGLES, MAX_MESH_VERTICES};
use std::collections::HashMap;
use std::path::Path;

/// Loads a PLY file whose lengths are in `units`.
pub fn load_ply(path: &Path, units: Units) -> Result<Mesh, MeshError> {
    ply_from_bytes(path, &super::files::read_mesh_file(path)?, units, &Folder::beside(path))
}

/// A PLY file's bytes, its texture from `files`; `path` names it in errors.
pub(super) fn ply_from_bytes(path: &Path, bytes: &[u8], units: Units, files: &dyn MeshFiles) -> Result<Mesh, MeshError> {
    let (mut data, texture) = parse_ply(bytes, units).map_err(|m| MeshError::format(path, m))?;
    if let Some(name) = texture {
        let image = load_texture(path, files, &name)?;
        data.materials = vec![Material { name, texture: Some(image.into()), ..Material::default() }];
    }
    Mesh::new(path.display().to_string(), units, data)
}

/// The vertices' x, y, z exactly as the file holds them, in file order and file units: ascii
/// text parsed as f64, binary floats widened. This is what bop_toolkit's `inout.load_ply`
/// returns as `pts` and scores poses on; a `Mesh`'s f32 metres round them by up to 6·10⁻⁸
/// relative, which now and then moves an error across a BOP threshold.
pub fn load_ply_points(path: &Path) -> Result<Vec<[f64; 3]>, MeshError> {
    let bytes = std::fs::read(path).map_err(|source| MeshError::Io { path: path.to_path_buf(), source })?;
    let (raw, _texture) = parse_raw(&bytes).map_err(|m| MeshError::format(path, m))?;
    Ok(raw.positions)
}

/// Parses a whole PLY file into mesh arrays (positions scaled to metres) and the texture file
/// name from the header, if any. Errors are messages without the file name.
fn parse_ply(bytes: &[u8], units: Units) -> Result<(MeshData, Option<String>), String> {
    let (raw, texture) = parse_raw(bytes)?;
    Ok((raw.into_mesh_data(units.to_metres()), texture))
}

/// Everything the file holds, as read, and the texture file name from the header, if any.
fn parse_raw(bytes: &[u8]) -> Result<(Raw, Option<String>), String> {
    let header = parse_header(bytes)?;
    let plan = Plan::new(&header)?;
    let body = &bytes[header.body_offset..];
    let mut raw = Raw::default();
    match header.encoding {
        Encoding::Ascii => {
            let text = std::str::from_utf8(body).map_err(|e| format!("ascii data is not text (byte {})", header.body_offset + e.valid_up_to()))?;
            let mut src = Ascii { lines: text.lines(), line: header.lines, tokens: "".split_ascii_whitespace() };
            read_body(&mut src, &header, &plan, &mut raw)?;
        }
        Encoding::Binary { big_endian } => {
            let mut src = Binary { data: body, pos: 0, start: header.body_offset, big_endian };
            read_body(&mut src, &header, &plan, &mut raw)?;
        }
    }
    Ok((raw, header.texture))
}

// ---------------------------------------------------------------------------------------------
// Header

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Scalar {
    I8,
    U8,
    I16,
    U16,
    I32,
    U32,
    F32,
    F64,
}

impl Scalar {
    fn parse(s: &str) -> Option<Self> {
        Some(match s {
            "char" | "int8" => Scalar::I8,
            "uchar" | "uint8" => Scalar::U8,
            "short" | "int16" => Scalar::I16,
            "ushort" | "uint16" => Scalar::U16,
            "int" | "int32" => Scalar::I32,
            "uint" | "uint32" => Scalar::U32,
            "float" | "float32" => Scalar::F32,
            "double" | "float64" => Scalar::F64,
            _ => return None,
        })
    }

    fn is_float(self) -> bool {
        matches!(self, Scalar::F32 | Scalar::F64)
    }

    /// Value of a full-intensity colour channel: integer colours span their type's range,
    /// float colours are already 0..1.
    fn colour_full_scale(self) -> f64 {
        match self {
            Scalar::I8 | Scalar::U8 => 255.0,
            Scalar::I16 | Scalar::U16 => 65535.0,
            Scalar::I32 | Scalar::U32 => u32::MAX as f64,
            Scalar::F32 | Scalar::F64 => 1.0,
        }
    }
}

#[derive(Clone, Copy, Debug)]
enum Kind {
    Scalar(Scalar),
    List { count: Scalar, item: Scalar },
}

#[derive(Debug)]
struct Property {
    name: String,
    kind: Kind,
}

#[derive(Debug)]
struct Element {
    name: String,
    count: usize,
    props: Vec<Property>,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Encoding {
    Ascii,
    Binary { big_endian: bool },
}

#[derive(Debug)]
struct Header {
    encoding: Encoding,
    elements: Vec<Element>,
    texture: Option<String>,
    /// Byte offset of the data after `end_header`.
    body_offset: usize,
    /// Number of header lines, so that ascii data lines can be numbered as in the file.
    lines: usize,
}

fn parse_header(bytes: &[u8]) -> Result<Header, String> {
    let mut encoding = None;
    let mut elements: Vec<Element> = Vec::new();
    let mut texture = None;
    let mut pos = 0;
    let mut n = 0;
    loop {
        let Some(len) = bytes[pos..].iter().position(|&b| b == b'\n') else {
            return Err(if n == 0 { "not a PLY file (empty or no line break)".into() } else { "header has no end_header line".into() });
        };
        n += 1;
        let raw = &bytes[pos..pos + len];
        pos += len + 1;
        let line = String::from_utf8_lossy(raw.strip_suffix(b"\r").unwrap_or(raw));
        let bad = |what: &str| format!("header line {n}: {what}: {line:?}");
        let mut words = line.split_ascii_whitespace();
        let keyword = words.next().unwrap_or("");
        if n == 1 {
            if keyword != "ply" {
                return Err("not a PLY file (first line is not \"ply\")".into());
            }
            continue;
        }
        match keyword {
            "format" => {
                encoding = Some(match (words.next(), words.next()) {
                    (Some("ascii"), Some("1.0")) => Encoding::Ascii,
                    (Some("binary_little_endian"), Some("1.0")) => Encoding::Binary { big_endian: false },
                    (Some("binary_big_endian"), Some("1.0")) => Encoding::Binary { big_endian: true },
                    _ => return Err(bad("unknown format")),
                })
            }
            "comment" => {
                // The name is the rest of the line: it may contain spaces ("fuze uv.jpg").
                let rest = line.trim_start()["comment".len()..].trim_start();
                let mut split = rest.splitn(2, |c: char| c.is_ascii_whitespace());
                if split.next().is_some_and(|w| w.eq_ignore_ascii_case("TextureFile")) {
                    let name = split.next().unwrap_or("").trim();
                    if name.is_empty() {
                        return Err(bad("TextureFile comment without a file name"));
                    }
                    texture = Some(name.to_string());
                }
            }
            "obj_info" | "" => {}
            "element" => {
                let (Some(name), Some(count), None) = (words.next(), words.next(), words.next()) else {
                    return Err(bad("expected \"element NAME COUNT\""));
                };
                let count = count.parse().map_err(|_| bad("element count is not a non-negative integer"))?;
                elements.push(Element { name: name.to_string(), count, props: Vec::new() });
            }
            "property" => {
                let Some(element) = elements.last_mut() else {
                    return Err(bad("property before any element"));
                };
                let words: Vec<&str> = words.collect();
                let ty = |s: &str| Scalar::parse(s).ok_or_else(|| bad(&format!("unknown type {s:?}")));
                let (kind, name) = match words[..] {
                    ["list", count, item, name] => (Kind::List { count: ty(count)?, item: ty(item)? }, name),
                    [scalar, name] if scalar != "list" => (Kind::Scalar(ty(scalar)?), name),
                    _ => return Err(bad("expected \"property TYPE NAME\" or \"property list TYPE TYPE NAME\"")),
                };
                element.props.push(Property { name: name.to_string(), kind });
            }
            "end_header" => break,
            _ => return Err(bad("unknown header keyword")),
        }
    }
    let encoding = encoding.ok_or("header has no format line")?;
    Ok(Header { encoding, elements, texture, body_offset: pos, lines: n })
}

// ---------------------------------------------------------------------------------------------
// What to do with each property

/// Slots of a vertex's values, in the order `Raw` stores them.
const POS: usize = 0;
const NORMAL: usize = 3;
const COLOUR: usize = 6;
const UV: usize = 9;
const SLOTS: usize = 11;

#[derive(Clone, Copy, Debug)]
enum Role {
    Skip,
    /// A vertex value into slot `usize`, divided by the `f64` (colour full scale, else 1).
    Vertex(usize, f64),
    FaceIndices,
    FaceTexcoords,
}

/// Per element, per property: its role; plus which vertex attributes the file has in full.
/// Only the first element named "vertex" and the first named "face" are read; any other
/// element is skipped.
struct Plan {
    roles: Vec<Vec<Role>>,
    vertex_element: usize,
    face_element: usize,
    vertex_count: usize,
    has_normals: bool,
    has_colours: bool,
    has_uvs: bool,
}

impl Plan {
    fn new(header: &Header) -> Result<Self, String> {
        let position = |name: &str| header.elements.iter().position(|e| e.name == name);
        let vertex_element = position("vertex").ok_or("header declares no vertex element")?;
        let face_element = position("face").ok_or("no faces: header declares no face element")?;
        let (vertex, face) = (&header.elements[vertex_element], &header.elements[face_element]);
        if face.count == 0 {
            return Err("no faces: element face has count 0".into());
        }
        // Refused from the header, before reading: each face gives at least one triangle.
        for (element, max) in [(vertex, MAX_MESH_VERTICES), (face, MAX_MESH_TRIANGLES)] {
            if element.count > max {
                return Err(format!("element {} has count {}, over the limit of {max}", element.name, element.count));
            }
        }
        let find = |names: &[&str]| vertex.props.iter().position(|p| names.contains(&p.name.as_str()));
        // Alternatives per slot, in slot order; an attribute counts only if all its slots exist.
        let slot_names: [&[&str]; SLOTS] = [
            &["x"],
            &["y"],
            &["z"],
            &["nx", "normal_x"],
            &["ny", "normal_y"],
            &["nz", "normal_z"],
            &["red", "r", "diffuse_red"],
            &["green", "g", "diffuse_green"],
            &["blue", "b", "diffuse_blue"],
            &["texture_u", "s", "u", "texture_s"],
            &["texture_v", "t", "v", "texture_t"],
        ];
        let found: Vec<Option<usize>> = slot_names.iter().map(|names| find(names)).collect();
        let complete = |range: std::ops::Range<usize>| found[range].iter().all(Option::is_some);
        for (slot, axis) in ["x", "y", "z"].iter().enumerate() {
            if found[slot].is_none() {
                return Err(format!("vertex element has no property {axis}"));
            }
        }
        let (has_normals, has_colours, has_uvs) = (complete(NORMAL..NORMAL + 3), complete(COLOUR..COLOUR + 3), complete(UV..UV + 2));
        let mut vertex_roles = vec![Role::Skip; vertex.props.len()];
        for (slot, prop) in found.iter().enumerate() {
            let wanted = match slot {
                POS..NORMAL => true,
                NORMAL..COLOUR => has_normals,
                COLOUR..UV => has_colours,
                _ => has_uvs,
            };
            if let (true, Some(p)) = (wanted, *prop) {
                let Kind::Scalar(ty) = vertex.props[p].kind else {
                    return Err(format!("vertex property {} is a list, expected a number", vertex.props[p].name));
                };
                let scale = if (COLOUR..UV).contains(&slot) { ty.colour_full_scale() } else { 1.0 };
                vertex_roles[p] = Role::Vertex(slot, scale);
            }
        }
        let mut face_roles = vec![Role::Skip; face.props.len()];
        let list = |names: &[&str]| face.props.iter().position(|p| names.contains(&p.name.as_str()) && matches!(p.kind, Kind::List { .. }));
        face_roles[list(&["vertex_indices", "vertex_index"]).ok_or("face element has no vertex_indices list")?] = Role::FaceIndices;
        if let Some(p) = list(&["texcoord"]) {
            face_roles[p] = Role::FaceTexcoords;
        }
        let vertex_count = vertex.count;
        let mut roles: Vec<Vec<Role>> = header.elements.iter().map(|e| vec![Role::Skip; e.props.len()]).collect();
        roles[vertex_element] = vertex_roles;
        roles[face_element] = face_roles;
        Ok(Plan { roles, vertex_element, face_element, vertex_count, has_normals, has_colours, has_uvs })
    }
}

// ---------------------------------------------------------------------------------------------
// Data sources: the same element walk reads ascii tokens or binary numbers.

trait Source {
    /// Called before each element item.
    fn begin_item(&mut self) -> Result<(), String>;
    /// Next number of type `ty`; the error says what is wrong, not where.
    fn value(&mut self, ty: Scalar) -> Result<f64, String>;
    /// Called after each element item, to catch items with more values than the header says.
    fn end_item(&mut self) -> Result<(), String>;
    /// Called after the last element, to catch data beyond what the header's counts cover.
    fn finish(&mut self) -> Result<(), String>;
    fn location(&self) -> String;
}

struct Ascii<'a> {
    lines: std::str::Lines<'a>,
    line: usize,
    tokens: std::str::SplitAsciiWhitespace<'a>,
}

impl Ascii<'_> {
    /// Advances to the next non-blank line; false at the end of the file.
    fn next_line(&mut self) -> bool {
        for line in self.lines.by_ref() {
            self.line += 1;
            if !line.trim_ascii().is_empty() {
                self.tokens = line.split_ascii_whitespace();
                return true;
            }
        }
        false
    }
}

/// Ascii items sit one per line (as every writer does it); holding to that turns a header
/// whose counts disagree with the data into an error at the first misfit line, instead of
/// silently shifted values.
impl Source for Ascii<'_> {
    fn begin_item(&mut self) -> Result<(), String> {
        match self.next_line() {
            true => Ok(()),
            false => Err("file ends early (truncated, or the header's counts are too large)".into()),
        }
    }
    fn value(&mut self, ty: Scalar) -> Result<f64, String> {
        let t = self.tokens.next().ok_or("line ends early (fewer values than the header's properties)")?;
        let v: f64 = t.parse().map_err(|_| format!("unparsable number {t:?}"))?;
        if !ty.is_float() && v.fract() != 0.0 {
            return Err(format!("{t:?} is not an integer"));
        }
        Ok(v)
    }
    fn end_item(&mut self) -> Result<(), String> {
        match self.tokens.next() {
            Some(t) => Err(format!("unexpected extra value {t:?} (more values than the header's properties)")),
            None => Ok(()),
        }
    }
    fn finish(&mut self) -> Result<(), String> {
        match self.next_line() {
            true => Err(format!("extra data at line {} after the last element (the header's counts are too small)", self.line)),
            false => Ok(()),
        }
    }
    fn location(&self) -> String {
        format!("line {}", self.line)
    }
}

struct Binary<'a> {
    data: &'a [u8],
    pos: usize,
    /// File offset of `data`, so that locations are file offsets.
    start: usize,
    big_endian: bool,
}

impl Binary<'_> {
    fn take<const N: usize>(&mut self) -> Result<[u8; N], String> {
        let bytes =
            self.data.get(self.pos..self.pos + N).ok_or_else(|| format!("binary data ends early at byte {} (truncated, or the header's counts are too large)", self.start + self.data.len()))?;
        self.pos += N;
        Ok(bytes.try_into().expect("slice of length N"))
    }
}

impl Source for Binary<'_> {
    fn begin_item(&mut self) -> Result<(), String> {
        Ok(())
    }
    fn value(&mut self, ty: Scalar) -> Result<f64, String> {
        macro_rules! num {
            ($t:ty) => {{
                let b = self.take::<{ std::mem::size_of::<$t>() }>()?;
                (if self.big_endian { <$t>::from_be_bytes(b) } else { <$t>::from_le_bytes(b) }) as f64
            }};
        }
        Ok(match ty {
            Scalar::I8 => num!(i8),
            Scalar::U8 => num!(u8),
            Scalar::I16 => num!(i16),
            Scalar::U16 => num!(u16),
            Scalar::I32 => num!(i32),
            Scalar::U32 => num!(u32),
            Scalar::F32 => num!(f32),
            Scalar::F64 => num!(f64),
        })
    }
    fn end_item(&mut self) -> Result<(), String> {
        Ok(())
    }
    fn finish(&mut self) -> Result<(), String> {
        match self.data.len() - self.pos {
            0 => Ok(()),
            extra => Err(format!("{extra} bytes of extra data after the last element (the header's counts are too small)")),
        }
    }
    fn location(&self) -> String {
        format!("byte {}", self.start + self.pos)
    }
}

// ---------------------------------------------------------------------------------------------
// Reading the elements

/// Everything read from the body, before scaling and texture-coordinate unsharing.
#[derive(Default)]
struct Raw {
    positions: Vec<[f64; 3]>,
    normals: Vec<[f32; 3]>,
    colours: Vec<[f32; 3]>,
    uvs: Vec<[f32; 2]>,
    triangles: Vec<[u32; 3]>,
    /// Per triangle corner, when the faces carry `texcoord` lists.
    corner_uvs: Vec<[f32; 2]>,
}

fn read_body<S: Source>(src: &mut S, header: &Header, plan: &Plan, raw: &mut Raw) -> Result<(), String> {
    let mut indices = Vec::new();
    let mut texcoords = Vec::new();
    for (e, (element, roles)) in header.elements.iter().zip(&plan.roles).enumerate() {
        // Binary items without properties take no bytes: nothing to read, however many
        // the header claims (looping over a count of 10^18 would never end).
        if element.props.is_empty() && header.encoding != Encoding::Ascii {
            continue;
        }
        for item in 0..element.count {
            let at = |src: &S, what: String| format!("{} {item} of {} ({}): {what}", element.name, element.count, src.location());
            src.begin_item().map_err(|e| at(src, e))?;
            let mut slots = [0f64; SLOTS];
            let mut has_texcoords = false;
            indices.clear();
            texcoords.clear();
            for (prop, &role) in element.props.iter().zip(roles) {
                let with_name = |e: String| format!("property {}: {e}", prop.name);
                match (prop.kind, role) {
                    (Kind::Scalar(ty), Role::Vertex(slot, scale)) => slots[slot] = src.value(ty).map_err(|e| at(src, with_name(e)))? / scale,
                    (Kind::Scalar(ty), _) => {
                        src.value(ty).map_err(|e| at(src, with_name(e)))?;
                    }
                    (Kind::List { count, item: ty }, role) => {
                        let n = src.value(count).map_err(|e| at(src, with_name(e)))?;
                        if n < 0.0 {
                            return Err(at(src, with_name(format!("negative list length {n}"))));
                        }
                        let mut out = match role {
                            Role::FaceIndices => Some(&mut indices),
                            Role::FaceTexcoords => {
                                has_texcoords = true;
                                Some(&mut texcoords)
                            }
                            _ => None,
                        };
                        // One value at a time, so that a corrupt huge count cannot allocate:
                        // the data runs out first.
                        for _ in 0..n as u64 {
                            let v = src.value(ty).map_err(|e| at(src, with_name(e)))?;
                            if let Some(out) = out.as_mut() {
                                out.push(v);
                            }
                        }
                    }
                }
            }
            src.end_item().map_err(|e| at(src, e))?;
            if e == plan.vertex_element {
                raw.push_vertex(&slots, plan).map_err(|e| at(src, e))?;
            } else if e == plan.face_element {
                let texcoords = has_texcoords.then_some(&texcoords[..]);
                raw.push_face(&indices, texcoords, plan.vertex_count).map_err(|e| at(src, e))?;
            }
        }
    }
    src.finish()
}

impl Raw {
    fn push_vertex(&mut self, s: &[f64; SLOTS], plan: &Plan) -> Result<(), String> {
        let p = [s[POS], s[POS + 1], s[POS + 2]];
        if p.iter().any(|c| !c.is_finite()) {
            return Err(format!("non-finite coordinate {p:?}"));
        }
        self.positions.push(p);
        let f = |i: usize| s[i] as f32;
        if plan.has_normals {
            self.normals.push([f(NORMAL), f(NORMAL + 1), f(NORMAL + 2)]);
        }
        if plan.has_colours {
            self.colours.push([f(COLOUR), f(COLOUR + 1), f(COLOUR + 2)]);
        }
        if plan.has_uvs {
            self.uvs.push([f(UV), f(UV + 1)]);
        }
        Ok(())
    }

    /// Fan-triangulates a polygon; with texcoords, records each triangle corner's uv.
    fn push_face(&mut self, indices: &[f64], texcoords: Option<&[f64]>, vertex_count: usize) -> Result<(), String> {
        let n = indices.len();
        if n < 3 {
            return Err(format!("face has {n} vertices, at least 3 are needed"));
        }
        if let Some(&bad) = indices.iter().find(|&&i| !(0.0..vertex_count as f64).contains(&i)) {
            return Err(format!("vertex index {bad} out of range (the file has {vertex_count} vertices)"));
        }
        if let Some(tc) = texcoords {
            if tc.len() != 2 * n {
                return Err(format!("texcoord list has {} values for a {n}-vertex face (expected {})", tc.len(), 2 * n));
            }
        }
        if self.triangles.len() + n - 2 > MAX_MESH_TRIANGLES {
            return Err(format!("more than {MAX_MESH_TRIANGLES} triangles, over the limit"));
        }
        let uv = |k: usize| texcoords.map(|tc| [tc[2 * k] as f32, tc[2 * k + 1] as f32]);
        for k in 1..n - 1 {
            self.triangles.push([indices[0] as u32, indices[k] as u32, indices[k + 1] as u32]);
            if let (Some(a), Some(b), Some(c)) = (uv(0), uv(k), uv(k + 1)) {
                self.corner_uvs.extend([a, b, c]);
            }
        }
        Ok(())
    }

    fn into_mesh_data(self, metres_per_unit: f64) -> MeshData {
        let mut data = MeshData {
            positions: self.positions.iter().map(|p| p.map(|c| (c * metres_per_unit) as f32)).collect(),
            normals: self.normals,
            colors: self.colours,
            uvs: self.uvs,
            triangles: self.triangles,
            ..MeshData::default()
        };
        if !self.corner_uvs.is_empty() {
            unshare_corner_uvs(&mut data, &self.corner_uvs);
        }
        data
    }
}

/// Makes per-corner uvs per-vertex: one vertex per distinct (vertex, uv) pair, so vertices are
/// duplicated only along texture seams and smooth shading survives elsewhere. Per-face
/// texcoords win over per-vertex ones when a file has both.
fn unshare_corner_uvs(data: &mut MeshData, corner_uvs: &[[f32; 2]]) {
    let mut map: HashMap<(u32, [u32; 2]), u32> = HashMap::with_capacity(corner_uvs.len());
    let mut out = MeshData { triangles: Vec::with_capacity(data.triangles.len()), ..MeshData::default() };
    for (t, tri) in data.triangles.iter().enumerate() {
        let new = std::array::from_fn(|c| {
            let (v, uv) = (tri[c], corner_uvs[3 * t + c]);
            *map.entry((v, uv.map(f32::to_bits))).or_insert_with(|| {
                let i = v as usize;
                out.positions.push(data.positions[i]);
                if let Some(n) = data.normals.get(i) {
                    out.normals.push(*n);
                }
                if let Some(c) = data.colors.get(i) {
                    out.colors.push(*c);
                }
                out.uvs.push(uv);
                out.positions.len() as u32 - 1
            })
        });
        out.triangles.push(new);
    }
    *data = out;
}

#[cfg(test)]
mod tests;
