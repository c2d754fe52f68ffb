use crate::geometry::views::{fitted_distance, view_pose};
use crate::mesh::{load_mesh, Units};
use crate::render::RenderOptions;
use anyhow::{Context, Result};
use std::path::PathBuf;

#[derive(clap::Args, Debug)]
pub struct RenderArgs {
    /// Mesh file: .ply, .obj, .gltf or .glb.
    #[arg(long)]
    pub mesh: PathBuf,
    /// Length unit of a PLY or OBJ file (mm, cm, m).
    #[arg(long)]
    pub units: Option<Units>,
    /// T_cam_obj: 12 comma-separated numbers (R row-major, t in metres) or a JSON file with
    /// "R" (9) and "t" (3, metres). Default: the object centred, filling most of the image.
    #[arg(long, allow_hyphen_values = true)]
    pub pose: Option<String>,
    /// Camera JSON: {"K": 3×3, "resolution": [h, w]} or BOP {"cam_K", "width", "height"}.
    #[arg(long)]
    pub camera: PathBuf,
    /// Output folder for rgb.png, depth.png (16-bit, 0.1 mm units), mask.png.
    #[arg(long)]
    pub out: PathBuf,
    /// Render in uniform grey, ignoring textures and vertex colours.
    #[arg(long)]
    pub grey: bool,
}

/// Depth PNG unit: 0.1 mm per level, as BOP's depth_scale 0.1 (max 6.5 m).
pub const DEPTH_PNG_SCALE_M: f64 = 1e-4;

pub fn run(a: RenderArgs) -> Result<()> {
    let mesh = load_mesh(&a.mesh, a.units)?;
    let k = super::camera_file::load_camera(&a.camera)?;
    let pose = match &a.pose {
        Some(p) => super::pose_arg::parse_pose(p)?,
        None => {
            let centre = nalgebra::Vector3::from(mesh.bbox_center());
            let d = fitted_distance(mesh.diameter() * 0.5, k.fx.max(k.fy), 0.5 * k.width.min(k.height) as f64, 0.8);
            // Object centre on the principal point, seen from the +x+y+z octant.
            view_pose(&nalgebra::Vector3::new(1.0, -1.0, 1.0).normalize(), 0.0, &centre, d)
        }
    };
    let pool = super::open_renderer(1)?;
    let opts = if a.grey { RenderOptions::grey() } else { RenderOptions::default() };
    let r = pool.render(&mesh, &pose, &k, &opts)?;
    std::fs::create_dir_all(&a.out).with_context(|| format!("cannot create {}", a.out.display()))?;
    r.rgb.save(a.out.join("rgb.png")).context("writing rgb.png")?;
    r.mask.save(a.out.join("mask.png")).context("writing mask.png")?;
    let depth = image::ImageBuffer::<image::Luma<u16>, Vec<u16>>::from_fn(k.width, k.height, |x, y| image::Luma([(r.depth_at(x, y) as f64 / DEPTH_PNG_SCALE_M).round().min(65535.0) as u16]));
    depth.save(a.out.join("depth.png")).context("writing depth.png")?;
    let visible = r.mask.pixels().filter(|p| p[0] > 0).count();
    println!(
        "rendered {} at t = [{:.4}, {:.4}, {:.4}] m: {visible} object pixels; wrote rgb.png, depth.png (0.1 mm units), mask.png to {}",
        mesh.name(),
        pose.translation.x,
        pose.translation.y,
        pose.translation.z,
        a.out.display()
    );
    Ok(())
}
