//! Small meshes built in code for the renderer tests.

use crate::mesh::{Material, Mesh, MeshData, Units};

/// Axis-aligned cube of half-size `h` centred at the origin, 24 vertices (flat faces), with
/// an optional uniform vertex colour (sRGB).
pub fn cube(h: f32, color: Option<[f32; 3]>) -> Mesh {
    let mut d = MeshData::default();
    for axis in 0..3 {
        for sign in [-1.0f32, 1.0] {
            let (a, b) = ((axis + 1) % 3, (axis + 2) % 3);
            let base = d.positions.len() as u32;
            for (s, t) in [(-1.0, -1.0), (1.0, -1.0), (1.0, 1.0), (-1.0, 1.0)] {
                let mut p = [0.0; 3];
                p[axis] = sign * h;
                p[a] = s * h;
                p[b] = t * h;
                d.positions.push(p);
                let mut n = [0.0; 3];
                n[axis] = sign;
                d.normals.push(n);
            }
            d.triangles.extend([[base, base + 1, base + 2], [base, base + 2, base + 3]]);
        }
    }
    if let Some(c) = color {
        d.colors = vec![c; d.positions.len()];
    }
    Mesh::new("cube", Units::M, d).unwrap()
}

/// Latitude–longitude sphere: `2·slices·(stacks−1)` triangles, UVs (u around, v up).
pub fn uv_sphere(r: f32, stacks: u32, slices: u32) -> Mesh {
    let mut d = MeshData::default();
    for i in 0..=stacks {
        let theta = std::f32::consts::PI * i as f32 / stacks as f32;
        for j in 0..=slices {
            let phi = 2.0 * std::f32::consts::PI * j as f32 / slices as f32;
            let n = [theta.sin() * phi.cos(), theta.sin() * phi.sin(), theta.cos()];
            d.positions.push(n.map(|c| c * r));
            d.normals.push(n);
            d.uvs.push([j as f32 / slices as f32, 1.0 - i as f32 / stacks as f32]);
        }
    }
    let row = slices + 1;
    for i in 0..stacks {
        for j in 0..slices {
            let (a, b, c, e) = (i * row + j, i * row + j + 1, (i + 1) * row + j, (i + 1) * row + j + 1);
            if i > 0 {
                d.triangles.push([a, c, b]);
            }
            if i + 1 < stacks {
                d.triangles.push([b, c, e]);
            }
        }
    }
    Mesh::new("sphere", Units::M, d).unwrap()
}

/// `cells × cells` checkerboard image: cell (0, 0) — the top-left of the image — is `a`.
pub fn checkerboard(cells: u32, cell_px: u32, a: [u8; 3], b: [u8; 3]) -> image::RgbaImage {
    image::RgbaImage::from_fn(cells * cell_px, cells * cell_px, |x, y| {
        let c = if (x / cell_px + y / cell_px).is_multiple_of(2) { a } else { b };
        image::Rgba([c[0], c[1], c[2], 255])
    })
}

/// Square of half-size `h` in the object plane z = 0, textured with `texture` so that the
/// image's top-left corner maps to object (−h, −h): with an identity rotation (camera y
/// down) the texture appears upright. `flip_winding` reverses the triangles (back face
/// towards the camera).
pub fn textured_quad(h: f32, texture: image::RgbaImage, flip_winding: bool) -> Mesh {
    let mut triangles = vec![[0, 1, 2], [0, 2, 3]];
    if flip_winding {
        triangles.iter_mut().for_each(|t| t.swap(1, 2));
    }
    let d = MeshData {
        positions: vec![[-h, -h, 0.0], [h, -h, 0.0], [h, h, 0.0], [-h, h, 0.0]],
        // OBJ convention, v up: the top of the image is v = 1.
        uvs: vec![[0.0, 1.0], [1.0, 1.0], [1.0, 0.0], [0.0, 0.0]],
        triangles,
        materials: vec![Material { name: "checker".into(), base_color: [1.0; 4], texture: Some(texture.into()) }],
        ..Default::default()
    };
    Mesh::new("quad", Units::M, d).unwrap()
}

/// `n × n` vertex grid of half-size `h` in the plane z = 0 (many interior vertices).
pub fn grid(h: f32, n: u32) -> Mesh {
    let mut d = MeshData::default();
    for i in 0..n {
        for j in 0..n {
            let s = |k: u32| -h + 2.0 * h * k as f32 / (n - 1) as f32;
            d.positions.push([s(j), s(i), 0.0]);
        }
    }
    for i in 0..n - 1 {
        for j in 0..n - 1 {
            let a = i * n + j;
            d.triangles.extend([[a, a + 1, a + n + 1], [a, a + n + 1, a + n]]);
        }
    }
    Mesh::new("grid", Units::M, d).unwrap()
}
