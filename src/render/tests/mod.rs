//! GPU tests of the renderer. They need an adapter (lavapipe is enough); without one they
//! print why and pass, unless B2TF_REQUIRE_GPU=1 makes that a failure.

mod bench;
mod culling;
mod meshes;

use nalgebra::{Point3, Rotation3, Vector3};

use super::*;
use crate::geometry::{Intrinsics, Pose};
use crate::mesh::{Material, Mesh, Units};
use meshes::*;

pub(super) fn renderer_with(config: RendererConfig) -> Option<Renderer> {
    match Renderer::with_config(config) {
        Ok(r) => Some(r),
        Err(e @ RenderError::NoAdapter { .. }) if std::env::var_os("B2TF_REQUIRE_GPU").is_none() => {
            eprintln!("SKIPPED (no GPU adapter): {e}");
            None
        }
        Err(e) => panic!("{e}"),
    }
}

/// A one-renderer pool for GPU tests elsewhere in the crate: None (after saying why)
/// without an adapter, unless B2TF_REQUIRE_GPU=1.
pub(crate) fn test_pool() -> Option<RenderPool> {
    pool_of(1)
}

fn pool_of(size: usize) -> Option<RenderPool> {
    pool_with(size, RendererConfig::default())
}

fn pool_with(size: usize, config: RendererConfig) -> Option<RenderPool> {
    match RenderPool::new(size, config) {
        Ok(p) => Some(p),
        Err(e @ RenderError::NoAdapter { .. }) if std::env::var_os("B2TF_REQUIRE_GPU").is_none() => {
            eprintln!("SKIPPED (no GPU adapter): {e}");
            None
        }
        Err(e) => panic!("{e}"),
    }
}

fn renderer() -> Option<Renderer> {
    renderer_with(RendererConfig::default())
}

/// Deliberately non-square pixels and a principal point off the image centre, so that a
/// swapped axis or a half-pixel slip shows.
fn camera() -> Intrinsics {
    Intrinsics::new(600.0, 610.0, 318.3, 241.7, 640, 480).unwrap()
}

fn pose(deg: [f64; 3], t: [f64; 3]) -> Pose {
    let [x, y, z] = deg.map(f64::to_radians);
    Pose::new(Rotation3::from_euler_angles(x, y, z), Vector3::from(t))
}

/// Output colour = albedo exactly (no lighting).
fn unlit() -> RenderOptions {
    RenderOptions { ambient: 1.0, light_intensity: 0.0, ..Default::default() }
}

fn rgb(out: &RenderOutput, x: f64, y: f64) -> [u8; 3] {
    out.rgb.get_pixel(x.round() as u32, y.round() as u32).0
}

#[test]
fn depth_at_projected_vertices_is_their_camera_z() {
    let Some(mut r) = renderer() else { return };
    let k = camera();
    let n = 11;
    let mesh = grid(0.05, n);
    // Fronto-parallel, and tilted: on a tilted plane the pixel centre nearest a vertex is
    // not on the vertex, so compare with the plane's exact depth along that pixel's ray
    // (and with the vertex z, which the rounding allows to differ by the plane's slope).
    for p in [pose([0.0; 3], [0.012, -0.007, 0.4]), pose([20.0, -35.0, 10.0], [-0.02, 0.01, 0.45])] {
        let out = r.render(&mesh, &p, &k, &unlit()).unwrap();
        let normal = p.rotation * Vector3::z();
        let mut checked = 0;
        for (i, v) in mesh.positions().iter().enumerate() {
            let (row, col) = (i as u32 / n, i as u32 % n);
            if row == 0 || col == 0 || row == n - 1 || col == n - 1 {
                continue; // border vertices' nearest pixel may lie off the surface
            }
            let c = p.transform_point(&Point3::from(v.map(|x| x as f64)));
            let uv = k.project(&c).unwrap();
            let (x, y) = (uv.x.round() as u32, uv.y.round() as u32);
            assert!(out.is_foreground(x, y), "vertex {i} at {uv:?} not in mask");
            let ray = Vector3::new((x as f64 - k.cx) / k.fx, (y as f64 - k.cy) / k.fy, 1.0);
            let exact = normal.dot(&p.translation) / normal.dot(&ray);
            let d = out.depth_at(x, y) as f64;
            assert!((d - exact).abs() < 1e-4, "vertex {i}: depth {d} vs ray {exact}");
            assert!((d - c.z).abs() < 1e-3, "vertex {i}: depth {d} vs vertex z {}", c.z);
            checked += 1;
        }
        assert_eq!(checked, (n - 2) * (n - 2));
    }
}

/// Exact depth of the first hit of pixel (x, y)'s ray on the cube of half-size `h`.
fn ray_cast_cube(k: &Intrinsics, p: &Pose, h: f64, x: u32, y: u32) -> Option<f64> {
    let d_cam = Vector3::new((x as f64 - k.cx) / k.fx, (y as f64 - k.cy) / k.fy, 1.0);
    let inv = p.inverse();
    let (o, d) = (inv.translation, inv.rotation * d_cam);
    let (mut t0, mut t1) = (f64::NEG_INFINITY, f64::INFINITY);
    for i in 0..3 {
        let (a, b) = ((-h - o[i]) / d[i], (h - o[i]) / d[i]);
        t0 = t0.max(a.min(b));
        t1 = t1.min(a.max(b));
    }
    // The camera-frame ray has unit z, so the ray parameter is the camera z.
    (t0 <= t1 && t0 > 0.0).then_some(t0)
}

#[test]
fn every_pixel_matches_a_ray_cast() {
    let Some(mut r) = renderer() else { return };
    let k = camera();
    let h = 0.04;
    let p = pose([25.0, 40.0, -15.0], [0.03, -0.02, 0.35]);
    let out = r.render(&cube(h as f32, None), &p, &k, &unlit()).unwrap();
    let (mut coverage_mismatch, mut worst, mut covered) = (0, 0f64, 0);
    for y in 0..k.height {
        for x in 0..k.width {
            match (ray_cast_cube(&k, &p, h, x, y), out.is_foreground(x, y)) {
                (Some(z), true) => {
                    worst = worst.max((out.depth_at(x, y) as f64 - z).abs());
                    covered += 1;
                }
                (None, false) => {}
                _ => coverage_mismatch += 1,
            }
        }
    }
    eprintln!("covered {covered} px, coverage mismatches {coverage_mismatch}, worst depth error {worst:e} m");
    assert!(covered > 10_000);
    // Only pixel centres within rasteriser precision (1/256 px) of an edge may disagree; a
    // half-pixel slip would flip hundreds along the silhouette.
    assert!(coverage_mismatch <= 4, "{coverage_mismatch} pixels disagree with the ray cast");
    assert!(worst < 1e-4, "worst depth error {worst} m");
}

#[test]
fn mask_extent_matches_projected_vertices() {
    let Some(mut r) = renderer() else { return };
    let k = camera();
    let mesh = uv_sphere(0.05, 32, 64);
    for p in [pose([10.0, 20.0, 30.0], [0.05, 0.03, 0.5]), pose([0.0; 3], [-0.1, -0.05, 0.7])] {
        let out = r.render(&mesh, &p, &k, &RenderOptions::grey()).unwrap();
        let (mut lo, mut hi) = ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]);
        for v in mesh.positions() {
            let uv = k.project(&p.transform_point(&Point3::from(v.map(|x| x as f64)))).unwrap();
            lo = [lo[0].min(uv.x), lo[1].min(uv.y)];
            hi = [hi[0].max(uv.x), hi[1].max(uv.y)];
        }
        let b = out.mask_bbox().unwrap().map(|c| c as f64);
        let expected = [lo[0], lo[1], hi[0], hi[1]];
        for i in 0..4 {
            assert!((b[i] - expected[i]).abs() <= 1.0, "mask bbox {b:?} vs projected {expected:?}");
        }
    }
}

#[test]
fn vertex_colours_override_and_lighting() {
    let Some(mut r) = renderer() else { return };
    let k = camera();
    let red = cube(0.05, Some([1.0, 0.0, 0.0]));
    let facing = pose([0.0; 3], [0.0, 0.0, 0.4]);
    let centre = |out: &RenderOutput| rgb(out, k.cx, k.cy);
    assert_eq!(centre(&r.render(&red, &facing, &k, &unlit()).unwrap()), [255, 0, 0]);
    let no_vc = RenderOptions { use_vertex_colors: false, ..unlit() };
    assert_eq!(centre(&r.render(&red, &facing, &k, &no_vc).unwrap()), [255, 255, 255]);
    let grey = RenderOptions { override_color: Some([0.5; 3]), ..unlit() };
    let g = centre(&r.render(&red, &facing, &k, &grey).unwrap());
    assert!(g.iter().all(|&c| (127..=128).contains(&c)), "grey renders as {g:?}");
    // Headlight: a face square to the camera gets the full light, a tilted one less.
    let lit = RenderOptions::default();
    assert_eq!(centre(&r.render(&red, &facing, &k, &lit).unwrap()), [255, 0, 0]);
    let tilted = centre(&r.render(&red, &pose([0.0, 50.0, 0.0], [0.0, 0.0, 0.4]), &k, &lit).unwrap());
    assert!(tilted[0] > 100 && tilted[0] < 250 && tilted[1] == 0, "{tilted:?}");
    // Background is written exactly.
    let bg = RenderOptions { background: [10, 20, 30], ..unlit() };
    assert_eq!(r.render(&red, &facing, &k, &bg).unwrap().rgb.get_pixel(0, 0).0, [10, 20, 30]);
}

#[test]
fn checkerboard_texture_appears_upright_on_both_sides() {
    let Some(mut r) = renderer() else { return };
    let k = camera();
    let (red, green) = ([255, 0, 0], [0, 255, 0]);
    let z = 0.3;
    let p = pose([0.0; 3], [0.0, 0.0, z]);
    // The quad spans ±h; quadrant centres sit at ±h/2.
    let q = 0.025 * k.fx / z;
    for flip in [false, true] {
        let mesh = textured_quad(0.05, checkerboard(2, 4, red, green), flip);
        let out = r.render(&mesh, &p, &k, &unlit()).unwrap();
        assert_eq!(rgb(&out, k.cx - q, k.cy - q), red, "top-left (flip {flip})");
        assert_eq!(rgb(&out, k.cx + q, k.cy - q), green, "top-right (flip {flip})");
        assert_eq!(rgb(&out, k.cx - q, k.cy + q), green, "bottom-left (flip {flip})");
        assert_eq!(rgb(&out, k.cx + q, k.cy + q), red, "bottom-right (flip {flip})");
        let plain = r.render(&mesh, &p, &k, &RenderOptions { use_texture: false, ..unlit() }).unwrap();
        assert_eq!(rgb(&plain, k.cx - q, k.cy - q), [255, 255, 255]);
        // Two-sided lighting: the back face is lit like the front.
        let lit = r.render(&mesh, &p, &k, &RenderOptions::default()).unwrap();
        assert_eq!(rgb(&lit, k.cx - q, k.cy - q), red);
    }
}

#[test]
fn second_render_of_a_mesh_does_not_upload_again() {
    let Some(mut r) = renderer() else { return };
    let (k, p, o) = (camera(), pose([10.0, 0.0, 0.0], [0.0, 0.0, 0.4]), RenderOptions::default());
    let a = cube(0.05, None);
    r.render(&a, &p, &k, &o).unwrap();
    r.render(&a, &pose([0.0, 30.0, 0.0], [0.0, 0.0, 0.5]), &k, &o).unwrap();
    r.render(&a.clone(), &p, &k, &o).unwrap();
    assert_eq!(r.mesh_uploads(), 1);
    r.render(&cube(0.05, None), &p, &k, &o).unwrap();
    assert_eq!(r.mesh_uploads(), 2);

    let Some(mut small) = renderer_with(RendererConfig { max_cached_meshes: 1, ..Default::default() }) else { return };
    let b = uv_sphere(0.05, 8, 16);
    for m in [&a, &b, &a] {
        small.render(m, &p, &k, &o).unwrap();
    }
    assert_eq!((small.mesh_uploads(), small.cached_meshes()), (3, 1));
}

#[test]
fn prepare_uploads_to_every_renderer_once_and_renders_reuse_it() {
    let Some(pool) = pool_of(2) else { return };
    let mesh = textured_sphere();
    pool.prepare(&mesh).unwrap();
    assert_eq!(pool.mesh_uploads(), 2);
    let (k, p, o) = (camera(), pose([10.0, 0.0, 0.0], [0.0, 0.0, 0.4]), RenderOptions::default());
    let views = vec![(p, k); 4];
    assert_eq!(pool.render_batch(&mesh, &views, &o).unwrap().len(), 4);
    pool.prepare(&mesh).unwrap();
    assert_eq!(pool.mesh_uploads(), 2, "already uploaded everywhere");
}

/// What the service asks before a request renders: whether an object's mesh must be put on
/// the renderers again, having been pushed out by others (more objects in turn than each
/// keeps).
#[test]
fn a_pool_says_when_it_lacks_a_mesh_that_others_pushed_out() {
    let Some(pool) = pool_with(2, RendererConfig { max_cached_meshes: 1, ..Default::default() }) else { return };
    let (a, b) = (textured_sphere(), cube(0.05, None));
    assert!(pool.lacks(&a), "nothing uploaded yet");
    pool.prepare(&a).unwrap();
    assert!(!pool.lacks(&a) && pool.lacks(&b));
    pool.render(&b, &pose([0.0; 3], [0.0, 0.0, 0.4]), &camera(), &RenderOptions::default()).unwrap();
    assert!(pool.lacks(&a), "one renderer drew the cube in the sphere's place");
    pool.prepare(&a).unwrap();
    assert!(!pool.lacks(&a));
    assert_eq!(pool.mesh_uploads(), 4, "the sphere on both, the cube on one, the sphere again where the cube had replaced it");
}

#[test]
fn bad_inputs_are_errors_and_leave_the_renderer_usable() {
    let Some(mut r) = renderer() else { return };
    let (mesh, p, o) = (cube(0.05, None), pose([0.0; 3], [0.0, 0.0, 0.4]), RenderOptions::default());
    let mut k = camera();
    k.width = 0;
    assert!(matches!(r.render(&mesh, &p, &k, &o), Err(RenderError::InvalidIntrinsics(_))));
    let mut k = camera();
    k.height = 0;
    assert!(r.render(&mesh, &p, &k, &o).is_err());
    let mut k = camera();
    k.width = 1 << 20;
    assert!(matches!(r.render(&mesh, &p, &k, &o), Err(RenderError::TooLarge { .. })));
    let mut k = camera();
    k.fx = -1.0;
    assert!(r.render(&mesh, &p, &k, &o).is_err());
    let nan_pose = pose([0.0; 3], [0.0, f64::NAN, 0.4]);
    assert!(matches!(r.render(&mesh, &nan_pose, &camera(), &o), Err(RenderError::InvalidPose(_))));
    let bad_clip = RenderOptions { clip_range: Some((1.0, 0.5)), ..Default::default() };
    assert!(matches!(r.render(&mesh, &p, &camera(), &bad_clip), Err(RenderError::InvalidOptions(_))));
    assert!(r.render(&mesh, &p, &camera(), &o).unwrap().mask_bbox().is_some());
}

#[test]
fn changing_image_size_between_renders() {
    let Some(mut r) = renderer() else { return };
    let (mesh, p, o) = (uv_sphere(0.05, 16, 32), pose([0.0; 3], [0.0, 0.0, 0.4]), RenderOptions::default());
    let big = r.render(&mesh, &p, &camera(), &o).unwrap();
    let small_k = Intrinsics::new(300.0, 305.0, 159.0, 120.5, 321, 241).unwrap();
    let small = r.render(&mesh, &p, &small_k, &o).unwrap();
    assert_eq!((small.width(), small.height(), small.depth.len()), (321, 241, 321 * 241));
    assert_eq!(r.render(&mesh, &p, &camera(), &o).unwrap(), big);
}

/// A render drawn into the corner of targets kept from a larger one (`Targets::serves`) is
/// the render made in targets of its own size, pixel for pixel: sizes a few pixels apart,
/// as a tracker's window gives, odd sides, and the larger size again after them.
#[test]
fn renders_into_reused_larger_targets_match_renders_of_their_own_size() {
    let (Some(mut reusing), Some(mut fresh_each)) = (renderer(), renderer()) else { return };
    let (mesh, o) = (textured_sphere(), RenderOptions::default());
    let p = pose([20.0, 35.0, 0.0], [0.004, -0.003, 0.3]);
    let sized = |w: u32, h: u32| Intrinsics::new(0.9 * w as f64, 0.9 * w as f64, (w as f64 - 1.0) / 2.0 + 3.3, (h as f64 - 1.0) / 2.0 - 2.1, w, h).unwrap();
    // Sides that are multiples of the allocation step get targets of exactly their size.
    for (w, h) in [(320, 256), (256, 192), (250, 233), (193, 240), (255, 199), (320, 256), (192, 128), (161, 130)] {
        let k = sized(w, h);
        let reused = reusing.render(&mesh, &p, &k, &o).unwrap();
        // A renderer whose targets were last made for another size makes new ones.
        let own = fresh_each.render(&mesh, &p, &sized(w + 300, h + 300), &o).and_then(|_| fresh_each.render(&mesh, &p, &k, &o)).unwrap();
        assert!(reused.mask_bbox().is_some(), "{w}×{h}: the sphere is in view");
        assert!(reused == own, "{w}×{h} differs from a render in targets of its own size");
    }
}

#[test]
fn pool_from_many_threads_matches_a_single_renderer() {
    let Some(mut single) = renderer() else { return };
    let pool = RenderPool::new(2, RendererConfig::default()).unwrap();
    let (k, o) = (camera(), RenderOptions::default());
    let mesh = textured_sphere();
    let views: Vec<(Pose, Intrinsics)> = (0..6).map(|i| (pose([i as f64 * 25.0, i as f64 * 40.0, 0.0], [0.0, 0.01, 0.3 + 0.02 * i as f64]), k)).collect();
    let expected = single.render_batch(&mesh, &views, &o).unwrap();
    std::thread::scope(|s| {
        for t in 0..4 {
            let (pool, mesh, views, expected, o) = (&pool, &mesh, &views, &expected, &o);
            s.spawn(move || {
                for i in 0..views.len() {
                    let j = (i + t) % views.len();
                    let out = pool.render(mesh, &views[j].0, &views[j].1, o).unwrap();
                    assert!(out == expected[j], "thread {t}, view {j} differs");
                }
            });
        }
    });
    assert!(pool.render_batch(&mesh, &views, &o).unwrap() == expected);
    assert!(pool.mesh_uploads() <= 2, "one upload per renderer at most");
}

fn textured_sphere() -> Mesh {
    let s = uv_sphere(0.05, 16, 32);
    let mut d = s.data().clone();
    d.colors = d.positions.iter().map(|p| [0.5 + 5.0 * p[0], 0.5 + 5.0 * p[1], 0.8]).collect();
    d.materials = vec![Material { name: "checker".into(), base_color: [1.0, 0.9, 0.8, 1.0], texture: Some(checkerboard(8, 8, [250, 200, 40], [30, 60, 200]).into()) }];
    Mesh::new("textured sphere", Units::M, d).unwrap()
}

/// `textured_sphere` with its texture as an object store holds it: a PNG, or damaged bytes.
fn sphere_with_texture(texture: crate::mesh::Texture) -> Mesh {
    let mut d = textured_sphere().data().clone();
    d.materials[0].texture = Some(texture);
    Mesh::new("textured sphere, stored", Units::M, d).unwrap()
}

#[test]
fn a_texture_held_as_png_renders_as_its_pixels_and_a_damaged_one_as_the_base_colour() {
    let Some(mut r) = renderer() else { return };
    let (p, k, o) = (pose([30.0, 20.0, 0.0], [0.0, 0.0, 0.3]), camera(), RenderOptions::default());
    let mut png = Vec::new();
    checkerboard(8, 8, [250, 200, 40], [30, 60, 200]).write_to(&mut std::io::Cursor::new(&mut png), image::ImageFormat::Png).unwrap();
    let decoded = r.render(&textured_sphere(), &p, &k, &o).unwrap();
    let stored = r.render(&sphere_with_texture(crate::mesh::Texture::from_png(png.clone()).unwrap()), &p, &k, &o).unwrap();
    assert!(stored == decoded, "the PNG's pixels are the decoded image's");
    // The body cut short after a valid header: drawn untextured, not an error per render.
    png.truncate(png.len() - 60);
    let damaged = r.render(&sphere_with_texture(crate::mesh::Texture::from_png(png).unwrap()), &p, &k, &o).unwrap();
    let mut untextured = textured_sphere().data().clone();
    untextured.materials[0].texture = None;
    let plain = r.render(&Mesh::new("untextured sphere", Units::M, untextured).unwrap(), &p, &k, &o).unwrap();
    assert!(damaged.rgb == plain.rgb && damaged.rgb != decoded.rgb);
}

#[test]
fn a_run_over_many_objects_keeps_them_all_and_never_fewer_than_the_default() {
    let default = RendererConfig::default().max_cached_meshes;
    assert_eq!(RendererConfig::keeping(0).max_cached_meshes, default);
    assert_eq!(RendererConfig::keeping(default + 9).max_cached_meshes, default + 9);
}
