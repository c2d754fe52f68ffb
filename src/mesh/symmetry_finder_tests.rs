use super::*;
use crate::mesh::procedural::{cylinder, textured_box};
use crate::mesh::{MeshData, Units};

/// Every found symmetry maps the mesh's vertices onto its surface (checked on the vertices
/// of the mesh itself, within 2 % of the diameter: corners have few samples near them).
fn assert_maps_onto_itself(mesh: &Mesh, found: &ObjectSymmetries) {
    let surface = Surface::sample(mesh, 20_000);
    let config = FinderConfig::default();
    let tester = Tester::new(&surface, Vector3::zeros(), mesh.diameter() * 0.02, &config);
    for pose in symmetry_poses(found, 8) {
        for p in mesh.positions() {
            let q = pose.rotation * Vector3::from(p.map(f64::from)) + pose.translation;
            assert!(tester.nearest(&q).is_some(), "{:?} moves {p:?} off the surface", pose);
        }
    }
}

fn half_turn_axes(found: &ObjectSymmetries) -> Vec<Vector3<f64>> {
    found
        .discrete
        .iter()
        .map(|d| {
            let r = Rotation3::from_matrix_unchecked(d.rotation);
            assert!((r.angle() - std::f64::consts::PI).abs() < 1e-3, "not a half-turn: {} rad", r.angle());
            r.axis().expect("a half-turn has an axis").into_inner()
        })
        .collect()
}

#[test]
fn a_cylinder_turns_freely_about_its_axis_and_flips() {
    let mesh = cylinder(0.03, 0.12, 64);
    let found = find_symmetries(&mesh, &FinderConfig::default());
    assert_eq!(found.continuous.len(), 1, "{found:?}");
    let axis = Vector3::from(found.continuous[0].axis);
    assert!(axis.normalize().z.abs() > 0.999, "axis {axis:?}");
    assert!(Vector3::from(found.continuous[0].offset).norm() < 1e-3, "offset {:?}", found.continuous[0].offset);
    let flips = half_turn_axes(&found);
    assert_eq!(flips.len(), 1, "{found:?}");
    assert!(flips[0].z.abs() < 0.05, "the flip's axis {:?} is across the cylinder", flips[0]);
    assert_maps_onto_itself(&mesh, &found);
}

#[test]
fn a_plain_box_has_three_half_turns() {
    let mesh = textured_box([0.10, 0.06, 0.16], 3).without_appearance();
    let found = find_symmetries(&mesh, &FinderConfig::default());
    assert!(found.continuous.is_empty(), "{found:?}");
    let mut axes: Vec<usize> = half_turn_axes(&found).iter().map(|a| a.iamax()).collect();
    axes.sort();
    assert_eq!(axes, vec![0, 1, 2], "{found:?}");
    for d in &found.discrete {
        assert!(d.translation.norm() < 1e-3, "about the centre: {:?}", d.translation);
    }
    assert_maps_onto_itself(&mesh, &found);
}

#[test]
fn a_cube_has_the_rotations_of_a_cube() {
    let mesh = textured_box([0.08, 0.08, 0.08], 3).without_appearance();
    let found = find_symmetries(&mesh, &FinderConfig::default());
    assert!(found.continuous.is_empty(), "{found:?}");
    assert_eq!(found.discrete.len(), 23, "the 24 rotations of a cube, less the identity");
    assert_maps_onto_itself(&mesh, &found);
}

#[test]
fn a_box_with_different_textures_on_its_faces_has_none() {
    let found = find_symmetries(&textured_box([0.10, 0.06, 0.16], 3), &FinderConfig::default());
    assert!(found.is_empty(), "{found:?}");
}

#[test]
fn an_irregular_mesh_has_none() {
    // A box with a bump off every axis: no rotation maps it onto itself.
    let body = textured_box([0.10, 0.06, 0.16], 3).without_appearance();
    let bump = textured_box([0.03, 0.03, 0.03], 4).without_appearance();
    let mut d = MeshData { positions: body.positions().to_vec(), triangles: body.triangles().to_vec(), ..Default::default() };
    let offset = d.positions.len() as u32;
    d.positions.extend(bump.positions().iter().map(|p| [p[0] + 0.05, p[1] + 0.02, p[2] + 0.06]));
    d.triangles.extend(bump.triangles().iter().map(|t| t.map(|i| i + offset)));
    let mesh = Mesh::new("box with a bump", Units::M, d).unwrap();
    let found = find_symmetries(&mesh, &FinderConfig::default());
    assert!(found.is_empty(), "{found:?}");
}

#[test]
fn an_off_centre_cylinder_keeps_its_axis_through_its_centre() {
    let c = cylinder(0.02, 0.10, 48);
    let d = MeshData { positions: c.positions().iter().map(|p| [p[0] + 0.5, p[1] - 0.2, p[2] + 0.1]).collect(), triangles: c.triangles().to_vec(), ..Default::default() };
    let mesh = Mesh::new("moved cylinder", Units::M, d).unwrap();
    let found = find_symmetries(&mesh, &FinderConfig::default());
    assert_eq!(found.continuous.len(), 1, "{found:?}");
    let o = Vector3::from(found.continuous[0].offset);
    assert!((o - Vector3::new(0.5, -0.2, 0.1)).norm() < 2e-3, "offset {o:?}");
    let flip = &found.discrete[0];
    // The flip keeps the centre where it is: t = c − R·c.
    let centre = Vector3::new(0.5, -0.2, 0.1);
    assert!((flip.rotation * centre + flip.translation - centre).norm() < 2e-3);
}
