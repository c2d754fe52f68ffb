//! Closed meshes are drawn one-sided and repeated faces once (`mesh::surface`): the images
//! must be those of drawing every triangle on both sides.

use super::*;
use crate::mesh::surface::drawn_surface;
use crate::mesh::MeshData;

/// `mesh` with every face again on vertices of its own whose normals point the other way
/// (as the HOPE meshes come).
fn doubled(mesh: &Mesh) -> Mesh {
    let mut d = mesh.data().clone();
    let n = d.positions.len() as u32;
    d.positions.extend(mesh.positions().to_vec());
    d.normals.extend(mesh.normals().iter().map(|v| v.map(|c| -c)));
    d.colors.extend(mesh.colors().unwrap_or_default().to_vec());
    d.uvs.extend(mesh.uvs().unwrap_or_default().to_vec());
    d.triangles.extend(mesh.triangles().iter().map(|t| t.map(|i| i + n)));
    d.parts = vec![];
    Mesh::new("doubled", Units::M, d).unwrap()
}

/// `mesh` with every face wound the other way round.
fn turned_inside_out(mesh: &Mesh) -> Mesh {
    let d = MeshData { triangles: mesh.triangles().iter().map(|t| [t[0], t[2], t[1]]).collect(), ..mesh.data().clone() };
    Mesh::new("wound inward", Units::M, d).unwrap()
}

#[test]
fn closed_and_repeated_meshes_render_as_when_every_triangle_is_drawn_on_both_sides() {
    let Some(mut one_sided) = renderer() else { return };
    let Some(mut two_sided) = renderer_with(RendererConfig { cull_closed_meshes: false, drop_repeated_faces: false, ..Default::default() }) else { return };
    let printed = crate::mesh::procedural::textured_box([0.1, 0.06, 0.16], 3);
    let mut holed = printed.data().clone();
    holed.triangles.pop();
    holed.parts = vec![];
    let holed = Mesh::new("box without a triangle", Units::M, holed).unwrap();
    let cases = [(printed.clone(), true), (doubled(&printed), true), (turned_inside_out(&printed), true), (textured_sphere(), true), (cube(0.05, Some([0.9, 0.5, 0.1])), true), (holed, false)];
    let k = camera();
    for (mesh, closed) in &cases {
        assert_eq!(drawn_surface(mesh, true).closed, *closed, "{}", mesh.name());
        for (i, deg) in [[0.0, 0.0, 0.0], [30.0, -40.0, 10.0], [170.0, 20.0, -60.0], [-75.0, 95.0, 140.0]].into_iter().enumerate() {
            let p = pose(deg, [0.01, -0.02, 0.45]);
            let a = one_sided.render(mesh, &p, &k, &RenderOptions::default()).unwrap();
            let b = two_sided.render(mesh, &p, &k, &RenderOptions::default()).unwrap();
            assert!(a.mask.pixels().filter(|m| m[0] > 0).count() > 1000, "{} pose {i}: on screen", mesh.name());
            // Where two faces meet at a crease, a back face can win a pixel by the last bit
            // of depth: a few such pixels at most, and never a change of outline.
            let covered = a.mask.pixels().filter(|m| m[0] > 0).count();
            let differing = (0..a.depth.len()).filter(|&n| a.rgb.as_raw()[3 * n..3 * n + 3] != b.rgb.as_raw()[3 * n..3 * n + 3] || a.depth[n] != b.depth[n]).collect::<Vec<_>>();
            assert_eq!(a.mask, b.mask, "{} pose {i}: outline changed", mesh.name());
            assert!(differing.len() <= 2 + covered / 1000, "{} pose {i}: {} of {covered} pixels differ", mesh.name(), differing.len());
            assert!(differing.iter().all(|&n| (a.depth[n] - b.depth[n]).abs() < 1e-5), "{} pose {i}: depth moved", mesh.name());
        }
    }
    // The repeats drawn once look like the original drawn once.
    let p = pose([30.0, -40.0, 10.0], [0.0, 0.0, 0.45]);
    let (a, b) = (two_sided.render(&doubled(&printed), &p, &k, &RenderOptions::default()).unwrap(), two_sided.render(&printed, &p, &k, &RenderOptions::default()).unwrap());
    assert!(a.rgb == b.rgb && a.depth == b.depth);
}

/// The one image where culling shows: from inside a closed mesh, every face faces away. A
/// renderer that stopped culling closed meshes (or culled the wrong side) fails here.
#[test]
fn from_inside_a_closed_mesh_one_sided_drawing_shows_nothing() {
    let Some(mut one_sided) = renderer() else { return };
    let Some(mut two_sided) = renderer_with(RendererConfig { cull_closed_meshes: false, ..Default::default() }) else { return };
    let sphere = textured_sphere();
    let k = camera();
    let inside = pose([10.0, 20.0, 30.0], [0.0, 0.0, 0.01]);
    let covered = |r: &RenderOutput| r.mask.pixels().filter(|m| m[0] > 0).count();
    assert_eq!(covered(&one_sided.render(&sphere, &inside, &k, &RenderOptions::default()).unwrap()), 0);
    assert!(covered(&two_sided.render(&sphere, &inside, &k, &RenderOptions::default()).unwrap()) > 100_000);
    // From outside, the near side shows: culling the front faces instead would show the far
    // side's depth.
    let outside = pose([10.0, 20.0, 30.0], [0.0, 0.0, 0.4]);
    let (a, b) = (one_sided.render(&sphere, &outside, &k, &RenderOptions::default()).unwrap(), two_sided.render(&sphere, &outside, &k, &RenderOptions::default()).unwrap());
    let centre = (k.cy as usize) * k.width as usize + k.cx as usize;
    assert!(a.depth[centre] > 0.0 && (a.depth[centre] - b.depth[centre]).abs() < 1e-4, "{} {}", a.depth[centre], b.depth[centre]);
}
