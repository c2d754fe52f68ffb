//! Generated video sequences for testing and measuring trackers: an object moving along a
//! smooth random 6-DoF trajectory in front of a cluttered background, optionally with a
//! passing occluder, blur and noise, with its true pose and visible mask per frame.

use crate::geometry::views::view_pose;
use crate::geometry::{Intrinsics, Pose};
use crate::mesh::procedural::Rng;
use crate::mesh::Mesh;
use crate::render::{RenderError, RenderOptions, RenderPool};
use image::{GrayImage, RgbImage};
use nalgebra::{Rotation3, Unit, Vector3};

#[derive(Clone, Debug)]
pub struct SequenceConfig {
    pub frames: usize,
    /// Camera distance of the object's centre at the start, m.
    pub distance: f64,
    /// Largest rotation and translation between consecutive frames, degrees and m.
    pub max_degrees_per_frame: f64,
    pub max_metres_per_frame: f64,
    pub seed: u64,
    /// A bar of a tenth of the image's width that crosses the view once over the
    /// sequence, hiding whatever is behind it.
    pub occluder: bool,
    /// Gaussian blur (pixels) and noise (grey levels) of every frame, after compositing.
    pub blur_sigma: f64,
    pub noise_sigma: f64,
}

impl Default for SequenceConfig {
    fn default() -> Self {
        Self { frames: 60, distance: 0.5, max_degrees_per_frame: 3.0, max_metres_per_frame: 0.01, seed: 1, occluder: false, blur_sigma: 0.0, noise_sigma: 0.0 }
    }
}

pub struct Frame {
    pub rgb: RgbImage,
    pub truth: Pose,
    /// The object's visible pixels (its silhouette less what the occluder hides).
    pub visible: GrayImage,
}

/// Coloured rectangles of many sizes on a gradient: edges and colours for the tracker to
/// be confused by, the same for every frame (a static camera).
pub fn cluttered_background(width: u32, height: u32, rng: &mut Rng) -> RgbImage {
    let mut img = RgbImage::from_fn(width, height, |x, y| image::Rgb([(60 + x * 80 / width) as u8, (70 + y * 60 / height) as u8, 90]));
    for _ in 0..60 {
        let (w, h) = ((rng.uniform() * 0.25 * width as f64) as u32 + 4, (rng.uniform() * 0.25 * height as f64) as u32 + 4);
        let (x0, y0) = ((rng.uniform() * width as f64) as u32, (rng.uniform() * height as f64) as u32);
        let c = image::Rgb([(rng.uniform() * 255.0) as u8, (rng.uniform() * 255.0) as u8, (rng.uniform() * 255.0) as u8]);
        for y in y0..(y0 + h).min(height) {
            for x in x0..(x0 + w).min(width) {
                img.put_pixel(x, y, c);
            }
        }
    }
    img
}

/// The object's poses: a smoothly turning rotation axis and a velocity that wanders
/// within the per-frame limits, kept in the middle half of the view.
pub fn trajectory(mesh: &Mesh, cfg: &SequenceConfig) -> Vec<Pose> {
    let mut rng = Rng::new(cfg.seed);
    let centre = Vector3::from(mesh.bbox_center());
    let dir = Vector3::new(rng.normal(), rng.normal(), rng.normal().abs() + 0.5).normalize();
    let mut pose = view_pose(&dir, rng.uniform() * std::f64::consts::TAU, &centre, cfg.distance);
    let mut axis = Vector3::new(rng.normal(), rng.normal(), rng.normal()).normalize();
    let mut velocity = Vector3::zeros();
    let mut poses = Vec::with_capacity(cfg.frames);
    for _ in 0..cfg.frames {
        poses.push(pose);
        axis = (axis + 0.2 * Vector3::new(rng.normal(), rng.normal(), rng.normal())).normalize();
        let turn = Rotation3::from_axis_angle(&Unit::new_normalize(axis), cfg.max_degrees_per_frame.to_radians() * (0.5 + 0.5 * rng.uniform()));
        velocity += 0.3 * cfg.max_metres_per_frame * Vector3::new(rng.normal(), rng.normal(), 0.5 * rng.normal());
        // Pulled back towards the start so the object stays in view.
        let c = pose.rotation * centre + pose.translation;
        velocity -= 0.05 * (c - Vector3::new(0.0, 0.0, cfg.distance));
        if velocity.norm() > cfg.max_metres_per_frame {
            velocity *= cfg.max_metres_per_frame / velocity.norm();
        }
        // Bounced back at the edges of a box around the start (±15 % of the distance
        // sideways, ±20 % in depth), so fast motions stay in view too.
        let offset = c + velocity - Vector3::new(0.0, 0.0, cfg.distance);
        for (i, limit) in [0.15, 0.15, 0.2].into_iter().enumerate() {
            if offset[i].abs() > limit * cfg.distance && offset[i] * velocity[i] > 0.0 {
                velocity[i] = -velocity[i];
            }
        }
        // Turn about the object's centre, then move.
        let rotation = turn * pose.rotation;
        let translation = c + velocity - rotation * centre;
        pose = Pose::new(rotation, translation);
    }
    poses
}

/// Renders the sequence: each frame the object over the background, lit from a fixed
/// direction, then the occluder, blur and noise as configured.
pub fn generate(mesh: &Mesh, k: &Intrinsics, cfg: &SequenceConfig, pool: &RenderPool) -> Result<Vec<Frame>, RenderError> {
    let mut rng = Rng::new(cfg.seed ^ 0x5eed);
    let background = cluttered_background(k.width, k.height, &mut rng);
    let occluder_colour = image::Rgb([(rng.uniform() * 255.0) as u8, (rng.uniform() * 255.0) as u8, (rng.uniform() * 255.0) as u8]);
    let frames = cfg.frames.max(1);
    trajectory(mesh, cfg)
        .into_iter()
        .enumerate()
        .map(|(i, truth)| {
            let r = pool.render(mesh, &truth, k, &RenderOptions::default())?;
            let mut rgb = crate::eval::degrade::composite(&r.rgb, &r.mask, &background);
            let mut visible = r.mask;
            if cfg.occluder {
                // From just off the left edge to just off the right one.
                let bar = (k.width / 10).max(1);
                let x0 = ((i as f64 / frames as f64) * (k.width + bar) as f64) as i64 - bar as i64;
                for x in x0.max(0) as u32..((x0 + bar as i64).max(0) as u32).min(k.width) {
                    for y in 0..k.height {
                        rgb.put_pixel(x, y, occluder_colour);
                        visible.put_pixel(x, y, image::Luma([0]));
                    }
                }
            }
            if cfg.blur_sigma > 0.0 {
                rgb = crate::eval::degrade::gaussian_blur(&rgb, cfg.blur_sigma);
            }
            if cfg.noise_sigma > 0.0 {
                rgb = crate::eval::degrade::add_noise(&rgb, cfg.noise_sigma, &mut rng);
            }
            Ok(Frame { rgb, truth, visible })
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn trajectory_keeps_within_its_limits() {
        let mesh = crate::mesh::procedural::textured_box([0.1, 0.06, 0.16], 3);
        let cfg = SequenceConfig { frames: 50, max_degrees_per_frame: 10.0, max_metres_per_frame: 0.05, seed: 4, ..Default::default() };
        let poses = trajectory(&mesh, &cfg);
        assert_eq!(poses.len(), 50);
        for w in poses.windows(2) {
            let turn = crate::geometry::geodesic_distance(&w[0].rotation, &w[1].rotation).to_degrees();
            let centre = Vector3::from(mesh.bbox_center());
            let moved = ((w[1].rotation * centre + w[1].translation) - (w[0].rotation * centre + w[0].translation)).norm();
            assert!(turn <= 10.0 + 1e-9 && moved <= 0.05 + 1e-9, "{turn}° {moved} m");
        }
    }
}
