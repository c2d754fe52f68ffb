//! What a renderer needs to draw of a mesh. Three things cut its work without changing the
//! picture. Some meshes hold every face twice (all ten HOPE meshes of `../shared/data` do:
//! the same positions, winding and texture coordinates, on duplicated vertices whose
//! normals point the other way, a back side for renderers that light one side only); the
//! second copy never shows here, where both sides are lit alike. On a closed surface, every
//! triangle that faces away from the camera lies behind one that faces it, so a renderer
//! may skip those (cull back faces), which on a software rasteriser is about half its work.
//! And CAD meshes are often wound inconsistently: where the surface is closed, the winding
//! can be mended (each triangle wound like its neighbours, each shell outward), since the
//! renderer lights both sides alike. Positions are compared by value (to a millionth of
//! the diameter), not by vertex index: a texture seam duplicates vertices without opening
//! the surface.

use super::types::{Mesh, Part};
use std::collections::HashMap;

/// The triangles worth drawing, by part, and whether they close.
#[derive(Clone, Debug)]
pub struct DrawnSurface {
    /// `mesh`'s triangles (indices into its vertex arrays) less exact repeats, part by part;
    /// where `closed`, each wound counter-clockwise seen from outside.
    pub triangles: Vec<[u32; 3]>,
    pub parts: Vec<Part>,
    /// Every shell closed (each edge between exactly two triangles, an orientable surface):
    /// back faces may be culled.
    pub closed: bool,
    /// Triangles left out as repeats.
    pub repeats: usize,
    /// Triangles whose winding was turned round.
    pub rewound: usize,
}

/// `mesh`'s triangles, where `drop_repeats`, without those that repeat an earlier one of
/// the same part exactly (same positions in the same cyclic order, the same colours and
/// texture coordinates at each corner, and the same normals or all of them turned round);
/// wound outward where they close.
pub fn drawn_surface(mesh: &Mesh, drop_repeats: bool) -> DrawnSurface {
    let welded = weld(mesh.positions(), WELD * mesh.diameter());
    let corner = |i: u32| {
        let i = i as usize;
        let colour = mesh.colors().map_or([0; 3], |c| c[i].map(f32::to_bits));
        let uv = mesh.uvs().map_or([0; 2], |t| t[i].map(f32::to_bits));
        (welded.0[i], colour, uv)
    };
    // The renderer lights both sides alike (|N·L|), so a face with all its normals turned
    // round looks the same: the normals count up to one sign for the whole face.
    let normals = |corners: [u32; 3]| {
        let mut n = [0f32; 9];
        for (k, &i) in corners.iter().enumerate() {
            n[3 * k..3 * k + 3].copy_from_slice(&mesh.normals()[i as usize]);
        }
        if n.iter().find(|x| **x != 0.0).is_some_and(|x| *x < 0.0) {
            n.iter_mut().for_each(|x| *x = -*x);
        }
        n.map(f32::to_bits)
    };
    let mut triangles = Vec::with_capacity(mesh.triangles().len());
    let mut parts = Vec::with_capacity(mesh.parts().len());
    for part in mesh.parts() {
        let first = triangles.len() as u32;
        let mut seen = std::collections::HashSet::new();
        for t in &mesh.triangles()[part.first_triangle as usize..(part.first_triangle + part.triangle_count) as usize] {
            // The same cycle read from its smallest welded corner.
            let start = (0..3).min_by_key(|&k| (welded.0[t[k] as usize], k)).expect("three corners");
            let cycle = [0, 1, 2].map(|k| t[(start + k) % 3]);
            if !drop_repeats || seen.insert((cycle.map(corner), normals(cycle))) {
                triangles.push(*t);
            }
        }
        parts.push(Part { first_triangle: first, triangle_count: triangles.len() as u32 - first, material: part.material });
    }
    let repeats = mesh.triangles().len() - triangles.len();
    let turns = outward_turns(&triangles, &welded);
    let (closed, rewound) = match &turns {
        Some(turns) => {
            for (t, _) in triangles.iter_mut().zip(turns).filter(|(_, &turn)| turn) {
                t.swap(1, 2);
            }
            (true, turns.iter().filter(|&&t| t).count())
        }
        None => (false, 0),
    };
    DrawnSurface { triangles, parts, closed, repeats, rewound }
}

/// Positions this close (a share of the diameter) are one: exporters write a seam's
/// copies from separately rounded arithmetic (a sphere's seam at 0 and 2π), a gap far below
/// any pixel.
const WELD: f64 = 1e-6;

/// One id per position (positions within `tolerance` of an earlier one, each coordinate,
/// take its id), per vertex; and each id's position.
fn weld(positions: &[[f32; 3]], tolerance: f64) -> (Vec<u32>, Vec<[f64; 3]>) {
    let tolerance = tolerance.max(f64::MIN_POSITIVE);
    let cell = |p: &[f64; 3]| p.map(|c| (c / tolerance).floor() as i64);
    let mut grid: HashMap<[i64; 3], Vec<u32>> = HashMap::with_capacity(positions.len());
    let mut unique: Vec<[f64; 3]> = Vec::new();
    let welded = positions
        .iter()
        .map(|p| {
            let p = p.map(|c| c as f64);
            let [x, y, z] = cell(&p);
            let near = (-1..=1).flat_map(|dx| (-1..=1).flat_map(move |dy| (-1..=1).map(move |dz| [x + dx, y + dy, z + dz])));
            let found = near.filter_map(|c| grid.get(&c)).flatten().copied().find(|&id| (0..3).all(|k| (unique[id as usize][k] - p[k]).abs() <= tolerance));
            found.unwrap_or_else(|| {
                unique.push(p);
                let id = unique.len() as u32 - 1;
                grid.entry(cell(&p)).or_default().push(id);
                id
            })
        })
        .collect();
    (welded, unique)
}

/// An edge (lower welded id first), a triangle on it, and whether the triangle runs along
/// it from the lower id.
type Side = ((u32, u32), usize, bool);

/// Which of `triangles` (vertex indices; `welded` as from `weld`) to turn round so that
/// every shell is wound consistently and outward (positive volume); `None` where the
/// surface is not closed: an edge of one triangle (a hole) or of three or more, or a
/// surface that cannot be wound consistently (a Möbius strip). Degenerate triangles
/// (corners welded together) show nothing and are left as they are.
fn outward_turns(triangles: &[[u32; 3]], (welded, positions): &(Vec<u32>, Vec<[f64; 3]>)) -> Option<Vec<bool>> {
    let corners: Vec<Option<[u32; 3]>> = triangles.iter().map(|t| Some(t.map(|i| welded[i as usize])).filter(|w| w[0] != w[1] && w[1] != w[2] && w[0] != w[2])).collect();
    // Sorted, an edge's triangles sit together.
    let mut sides: Vec<Side> = Vec::with_capacity(3 * triangles.len());
    for (i, c) in corners.iter().enumerate() {
        let Some(c) = c else { continue };
        for (a, b) in [(c[0], c[1]), (c[1], c[2]), (c[2], c[0])] {
            sides.push(((a.min(b), a.max(b)), i, a < b));
        }
    }
    sides.sort_unstable_by_key(|s| s.0);
    let edges: Vec<&[Side]> = sides.chunk_by(|a, b| a.0 == b.0).collect();
    if edges.is_empty() || edges.iter().any(|on| on.len() != 2) {
        return None;
    }
    let mut neighbours: Vec<Vec<(usize, bool)>> = vec![Vec::with_capacity(3); triangles.len()];
    for on in &edges {
        let ((_, i, fi), (_, j, fj)) = (on[0], on[1]);
        // Wound alike, two neighbours run along their edge in opposite directions.
        neighbours[i].push((j, fi == fj));
        neighbours[j].push((i, fi == fj));
    }
    // Turns within each shell, spreading from its first triangle; each shell's volume.
    let mut turn: Vec<Option<bool>> = vec![None; triangles.len()];
    let mut shell_of = vec![usize::MAX; triangles.len()];
    let mut volumes = Vec::new();
    for seed in 0..triangles.len() {
        if corners[seed].is_none() || turn[seed].is_some() {
            continue;
        }
        let shell = volumes.len();
        volumes.push(0.0f64);
        turn[seed] = Some(false);
        let mut stack = vec![seed];
        while let Some(i) = stack.pop() {
            shell_of[i] = shell;
            let mine = turn[i].expect("set before pushed");
            let c = corners[i].expect("only proper triangles are pushed");
            let [a, b, d] = if mine { [c[0], c[2], c[1]] } else { c }.map(|k| positions[k as usize]);
            volumes[shell] += (a[0] * (b[1] * d[2] - b[2] * d[1]) - a[1] * (b[0] * d[2] - b[2] * d[0]) + a[2] * (b[0] * d[1] - b[1] * d[0])) / 6.0;
            for &(j, flip) in &neighbours[i] {
                let wanted = mine ^ flip;
                match turn[j] {
                    None => {
                        turn[j] = Some(wanted);
                        stack.push(j);
                    }
                    Some(t) if t != wanted => return None,
                    Some(_) => {}
                }
            }
        }
    }
    Some((0..triangles.len()).map(|i| turn[i].is_some_and(|t| t ^ (volumes[shell_of[i]] < 0.0))).collect())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::{MeshData, Units};

    /// A unit tetrahedron wound outward, with one vertex duplicated as a texture seam would.
    fn tetrahedron() -> MeshData {
        MeshData {
            positions: vec![[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0]],
            triangles: vec![[0, 2, 1], [0, 1, 3], [0, 3, 2], [4, 2, 3]],
            ..Default::default()
        }
    }

    fn drawn(data: MeshData) -> DrawnSurface {
        drawn_surface(&Mesh::new("test", Units::M, data).unwrap(), true)
    }

    fn outward() -> Vec<[u32; 3]> {
        tetrahedron().triangles
    }

    #[test]
    fn closed_meshes_are_wound_outward_and_open_ones_left_alone() {
        let d = drawn(tetrahedron());
        assert_eq!((d.closed, d.rewound, d.triangles), (true, 0, outward()));
        // Wound inward: every triangle turned round.
        let inward: Vec<[u32; 3]> = outward().iter().map(|t| [t[0], t[2], t[1]]).collect();
        let d = drawn(MeshData { triangles: inward, ..tetrahedron() });
        assert_eq!((d.closed, d.rewound, d.triangles), (true, 4, outward()));
        // One face wound against the others (as CAD files come): that one turned round.
        let mut mixed = tetrahedron();
        mixed.triangles[3] = [4, 3, 2];
        let d = drawn(mixed);
        assert_eq!((d.closed, d.rewound, d.triangles), (true, 1, outward()));
        // Two shells, one wound each way: each outward.
        let mut two = tetrahedron();
        let shifted: Vec<[f32; 3]> = two.positions.iter().map(|p| [p[0] + 5.0, p[1], p[2]]).collect();
        two.positions.extend(shifted);
        two.triangles.extend(outward().iter().map(|t| [t[0] + 5, t[2] + 5, t[1] + 5]));
        let d = drawn(two);
        assert_eq!((d.closed, d.rewound), (true, 4));
        assert_eq!(d.triangles[4..], outward().iter().map(|t| t.map(|i| i + 5)).collect::<Vec<_>>()[..]);
        // A face missing: a hole, drawn as it comes.
        let d = drawn(MeshData { triangles: outward()[..3].to_vec(), ..tetrahedron() });
        assert_eq!((d.closed, d.rewound), (false, 0));
        // A face shared by a third triangle: not a surface.
        let mut fin = tetrahedron();
        fin.positions.push([1.0, 1.0, 1.0]);
        fin.triangles.push([0, 1, 5]);
        assert!(!drawn(fin).closed);
    }

    /// Every face twice over, on vertices of its own whose normals point the other way (as
    /// in the HOPE meshes): the repeats go, and what is left is closed; a repeat that
    /// differs in appearance or winding stays.
    #[test]
    fn repeated_faces_are_drawn_once() {
        let mut twice = tetrahedron();
        twice.uvs = vec![[0.0, 0.0], [1.0, 0.0], [0.0, 1.0], [1.0, 1.0], [1.0, 0.0]];
        // Normals as a file gives them (computed ones could differ in the last bit between
        // copies read from another corner).
        twice.normals = twice.positions.iter().map(|p| [p[0] - 0.25, p[1] - 0.25, p[2] - 0.25]).collect();
        let n = twice.positions.len() as u32;
        twice.positions.extend(tetrahedron().positions);
        twice.uvs.extend(twice.uvs.clone());
        twice.normals.extend(twice.normals.clone().iter().map(|v| v.map(|c| -c)));
        // The copies start at another corner of the same cycle.
        twice.triangles.extend(outward().iter().map(|t| [t[1] + n, t[2] + n, t[0] + n]));
        let d = drawn(twice.clone());
        assert_eq!((d.triangles.len(), d.repeats, d.closed), (4, 4, true));
        assert_eq!(d.parts, vec![Part { first_triangle: 0, triangle_count: 4, material: 0 }]);
        // Kept, they make every edge an edge of four triangles: not a surface.
        let d = drawn_surface(&Mesh::new("test", Units::M, twice.clone()).unwrap(), false);
        assert_eq!((d.triangles.len(), d.repeats, d.closed), (8, 0, false));
        // A copy printed differently shows where it wins the depth test: it stays.
        let mut printed = twice;
        printed.uvs[(n + 3) as usize] = [0.5, 0.5];
        let d = drawn(printed);
        assert_eq!(d.repeats, 1, "the three copies touching the changed vertex stay");
        assert!(!d.closed);
        // A sheet drawn with both windings is no repeat, and each side shows where it faces.
        let sheet = MeshData { positions: vec![[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]], triangles: vec![[0, 1, 2], [0, 2, 1]], ..Default::default() };
        let d = drawn(sheet);
        assert_eq!((d.repeats, d.closed, d.rewound), (0, true, 0));
    }

    /// The procedural box comes with half its faces wound inward (its renders never
    /// cared): all six outward once mended.
    #[test]
    fn the_procedural_box_is_mended() {
        let mesh = crate::mesh::procedural::textured_box([0.1, 0.06, 0.16], 3);
        let d = drawn_surface(&mesh, true);
        assert_eq!((d.closed, d.rewound, d.repeats), (true, 6, 0));
        for t in &d.triangles {
            let [a, b, c] = t.map(|i| nalgebra::Vector3::from(mesh.positions()[i as usize]));
            let normal = nalgebra::Vector3::from(mesh.normals()[t[0] as usize]);
            assert!((b - a).cross(&(c - a)).dot(&normal) > 0.0, "{t:?} wound inward");
        }
    }
}
