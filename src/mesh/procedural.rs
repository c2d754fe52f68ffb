//! Meshes the project makes itself (tests, demos, benchmarks need no downloads): a
//! textured box whose faces carry distinct procedural patterns, so that its pose is
//! unambiguous from any side, and a plain cylinder.

use super::types::{Material, Mesh, MeshData, Units};

/// Small deterministic generator (xorshift64*), so procedural assets are reproducible.
#[derive(Clone, Debug)]
pub struct Rng(u64);

impl Rng {
    pub fn new(seed: u64) -> Self {
        Self(seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1)
    }
    pub fn next_u64(&mut self) -> u64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        self.0.wrapping_mul(0x2545_F491_4F6C_DD1D)
    }
    /// Uniform in [0, 1).
    pub fn uniform(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 / (1u64 << 53) as f64
    }
    pub fn range(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * self.uniform()
    }
    /// Standard normal (Box–Muller).
    pub fn normal(&mut self) -> f64 {
        let (u1, u2) = (self.uniform().max(1e-12), self.uniform());
        (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
    }
}

/// A texture tile of random coloured discs and stripes on a base colour.
fn pattern_tile(rng: &mut Rng, size: u32) -> image::RgbaImage {
    let base = [rng.range(40.0, 220.0), rng.range(40.0, 220.0), rng.range(40.0, 220.0)];
    let mut img = image::RgbaImage::from_pixel(size, size, image::Rgba([base[0] as u8, base[1] as u8, base[2] as u8, 255]));
    let stripes = 2 + (rng.next_u64() % 4) as u32;
    let stripe_col = [rng.range(0.0, 255.0) as u8, rng.range(0.0, 255.0) as u8, rng.range(0.0, 255.0) as u8, 255];
    let angle = rng.range(0.0, std::f64::consts::PI);
    let (sa, ca) = angle.sin_cos();
    for (x, y, p) in img.enumerate_pixels_mut() {
        let t = (x as f64 * ca + y as f64 * sa) / size as f64 * stripes as f64;
        if t.fract() < 0.25 {
            *p = image::Rgba(stripe_col);
        }
    }
    for _ in 0..6 {
        let (cx, cy, r) = (rng.range(0.0, size as f64), rng.range(0.0, size as f64), rng.range(0.05, 0.18) * size as f64);
        let col = image::Rgba([rng.range(0.0, 255.0) as u8, rng.range(0.0, 255.0) as u8, rng.range(0.0, 255.0) as u8, 255]);
        for (x, y, p) in img.enumerate_pixels_mut() {
            if (x as f64 - cx).powi(2) + (y as f64 - cy).powi(2) < r * r {
                *p = col;
            }
        }
    }
    img
}

/// Random small discs over a tile: a fine print with corners everywhere, as a label's
/// text and pictures have, rather than the few broad shapes of `pattern_tile`.
fn sprinkle(rng: &mut Rng, tile: &mut image::RgbaImage, discs: usize) {
    let size = tile.width() as f64;
    for _ in 0..discs {
        let (cx, cy, r) = (rng.range(0.0, size), rng.range(0.0, size), rng.range(0.015, 0.045) * size);
        let col = image::Rgba([rng.range(0.0, 255.0) as u8, rng.range(0.0, 255.0) as u8, rng.range(0.0, 255.0) as u8, 255]);
        let (x0, x1) = ((cx - r).max(0.0) as u32, ((cx + r).ceil() as u32).min(tile.width()));
        let (y0, y1) = ((cy - r).max(0.0) as u32, ((cy + r).ceil() as u32).min(tile.height()));
        for y in y0..y1 {
            for x in x0..x1 {
                if (x as f64 - cx).powi(2) + (y as f64 - cy).powi(2) < r * r {
                    tile.put_pixel(x, y, col);
                }
            }
        }
    }
}

/// A box of `size` metres (x, y, z) centred on the origin, each face textured with its
/// own pattern from a 3×2 atlas. Four vertices per face, so UVs and normals are per face.
pub fn textured_box(size: [f32; 3], seed: u64) -> Mesh {
    printed_box(size, seed, 0)
}

/// `textured_box` with `discs` small discs sprinkled over each face's pattern (a fine
/// print: `sprinkle`); 0 gives `textured_box` itself.
pub fn printed_box(size: [f32; 3], seed: u64, discs: usize) -> Mesh {
    let tile = 128u32;
    let mut rng = Rng::new(seed);
    let mut atlas = image::RgbaImage::new(tile * 3, tile * 2);
    for f in 0..6u32 {
        let mut t = pattern_tile(&mut rng, tile);
        sprinkle(&mut rng, &mut t, discs);
        image::imageops::replace(&mut atlas, &t, ((f % 3) * tile) as i64, ((f / 3) * tile) as i64);
    }
    let h = size.map(|s| s * 0.5);
    // (normal axis, sign): faces +x, -x, +y, -y, +z, -z.
    let faces: [(usize, f32); 6] = [(0, 1.0), (0, -1.0), (1, 1.0), (1, -1.0), (2, 1.0), (2, -1.0)];
    let mut d = MeshData::default();
    for (f, &(axis, sign)) in faces.iter().enumerate() {
        let (a, b) = ((axis + 1) % 3, (axis + 2) % 3);
        let base = d.positions.len() as u32;
        for (i, (sa, sb)) in [(-1.0f32, -1.0f32), (1.0, -1.0), (1.0, 1.0), (-1.0, 1.0)].iter().enumerate() {
            let mut p = [0f32; 3];
            p[axis] = sign * h[axis];
            p[a] = sa * h[a];
            p[b] = sb * h[b];
            d.positions.push(p);
            let mut n = [0f32; 3];
            n[axis] = sign;
            d.normals.push(n);
            let (tu, tv) = ((f % 3) as f32, (f / 3) as f32);
            let (cu, cv) = ([0.02, 0.98, 0.98, 0.02][i], [0.02, 0.02, 0.98, 0.98][i]);
            // Atlas row 0 is the image top; our UV convention has v up.
            d.uvs.push([(tu + cu) / 3.0, 1.0 - (tv + cv) / 2.0]);
        }
        d.triangles.push([base, base + 1, base + 2]);
        d.triangles.push([base, base + 2, base + 3]);
    }
    d.materials.push(Material { name: "box".into(), base_color: [1.0; 4], texture: Some(atlas.into()) });
    Mesh::new(format!("textured_box(seed {seed})"), Units::M, d).expect("procedural box is valid")
}

/// An untextured closed cylinder about z, centred on the origin, with `segments` sides.
pub fn cylinder(radius: f32, height: f32, segments: u32) -> Mesh {
    let mut d = MeshData::default();
    let h = height * 0.5;
    for &z in &[-h, h] {
        for i in 0..segments {
            let a = std::f32::consts::TAU * i as f32 / segments as f32;
            d.positions.push([radius * a.cos(), radius * a.sin(), z]);
        }
    }
    let (bottom, top) = (d.positions.len() as u32, d.positions.len() as u32 + 1);
    d.positions.push([0.0, 0.0, -h]);
    d.positions.push([0.0, 0.0, h]);
    for i in 0..segments {
        let j = (i + 1) % segments;
        let (a, b, c, e) = (i, j, segments + j, segments + i);
        d.triangles.push([a, b, c]);
        d.triangles.push([a, c, e]);
        d.triangles.push([bottom, b, a]);
        d.triangles.push([top, e, c]);
    }
    Mesh::new(format!("cylinder(r {radius}, h {height}, {segments} sides)"), Units::M, d).expect("procedural cylinder is valid")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn box_is_valid_and_deterministic() {
        let a = textured_box([0.1, 0.06, 0.16], 7);
        let b = textured_box([0.1, 0.06, 0.16], 7);
        assert_eq!(a.positions(), b.positions());
        assert!(a.has_texture());
        assert!((a.diameter() - (0.01f64 + 0.0036 + 0.0256).sqrt()).abs() < 1e-6);
        assert_eq!(a.triangles().len(), 12);
    }
}
