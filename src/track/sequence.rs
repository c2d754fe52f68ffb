//! Generated video sequences for testing and measuring trackers: an object moving along a
//! smooth random 6-DoF trajectory in front of a cluttered background, optionally with a
//! passing occluder, blur and noise, with its true pose, visible mask and what a depth
//! camera measures per frame (a wall behind, the occluder in front, `depth::sensor`).

use crate::depth::sensor::{fill_with_plane, SensorModel};
use crate::geometry::views::view_pose;
use crate::geometry::{Intrinsics, Pose};
use crate::mesh::procedural::Rng;
use crate::mesh::Mesh;
use crate::render::{RenderError, RenderOptions, RenderPool};
use image::{GrayImage, RgbImage};
use nalgebra::{Rotation3, Vector3};

#[derive(Clone, Debug, serde::Serialize)]
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
    /// What the depth camera measures (`SensorModel::exact()`: the renderer's depth).
    pub depth_sensor: SensorModel,
}

impl Default for SequenceConfig {
    fn default() -> Self {
        Self { frames: 60, distance: 0.5, max_degrees_per_frame: 3.0, max_metres_per_frame: 0.01, seed: 1, occluder: false, blur_sigma: 0.0, noise_sigma: 0.0, depth_sensor: SensorModel::default() }
    }
}

/// The wall behind the scene and the occluding bar, as multiples of the start distance.
const WALL_DISTANCE: f64 = 1.6;
const OCCLUDER_DISTANCE: f64 = 0.6;

pub struct Frame {
    pub rgb: RgbImage,
    pub truth: Pose,
    /// The object's visible pixels (its silhouette less what the occluder hides).
    pub visible: GrayImage,
    /// Metres as the depth camera measures them (0 = no measurement).
    pub depth: Vec<f32>,
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

/// A smooth random signal within [-1, 1]: three sinusoids of random frequency (0.5–1.5 per
/// unit time) and phase, with weights that sum to 1.
struct Wave([(f64, f64, f64); 3]);

impl Wave {
    fn new(rng: &mut Rng) -> Self {
        let w: [f64; 3] = [0.2 + rng.uniform(), 0.2 + rng.uniform(), 0.2 + rng.uniform()];
        let sum: f64 = w.iter().sum();
        Self(w.map(|wi| (wi / sum, rng.range(0.5, 1.5), rng.uniform() * std::f64::consts::TAU)))
    }

    fn at(&self, t: f64) -> f64 {
        self.0.iter().map(|(w, f, phase)| w * (f * t + phase).sin()).sum()
    }

    /// A bound on |d/dt| of the signal.
    fn speed_bound(&self) -> f64 {
        self.0.iter().map(|(w, f, _)| w * f).sum()
    }
}

/// Half-sides of the box the object's centre moves in, as shares of the start distance
/// (sideways, up-down, depth): the object stays in a 4:3 view at the start distance.
const TRAVEL: [f64; 3] = [0.2, 0.12, 0.2];

/// Angular velocity's own rate of change, radians of wave phase per frame: the spin turns
/// over tens of frames, as a thrown or carried part's does.
const SPIN_CHANGE: f64 = 0.08;

/// The object's poses: its centre moves smoothly through a box around the start (each axis
/// a [`Wave`], time-scaled so that the fastest frame moves `max_metres_per_frame`) and it
/// spins with a smoothly changing angular velocity whose fastest frame turns
/// `max_degrees_per_frame`. Smooth, not a random walk: a real part's velocity does not jump,
/// so a tracker's motion prior is tested on the accelerations the box forces, not on noise.
pub fn trajectory(mesh: &Mesh, cfg: &SequenceConfig) -> Vec<Pose> {
    let mut rng = Rng::new(cfg.seed);
    let centre = Vector3::from(mesh.bbox_center());
    let dir = Vector3::new(rng.normal(), rng.normal(), rng.normal().abs() + 0.5).normalize();
    let start = view_pose(&dir, rng.uniform() * std::f64::consts::TAU, &centre, cfg.distance);
    let n = cfg.frames;
    let travel: [(f64, Wave); 3] = TRAVEL.map(|share| (share * cfg.distance, Wave::new(&mut rng)));
    // Starts at the start pose: each wave is measured from its value at t = 0.
    let offset_at = |t: f64| Vector3::from_fn(|i, _| travel[i].0 * (travel[i].1.at(t) - travel[i].1.at(0.0)) / 2.0);
    let largest_step = |rate: f64| (1..n).map(|i| (offset_at(rate * i as f64) - offset_at(rate * (i - 1) as f64)).norm()).fold(0.0, f64::max);
    // The bound's rate never exceeds the limit; the measured one is tried as well so the
    // fastest frame reaches it, and kept only where it stays within.
    let bound = travel.iter().map(|(l, w)| (l * w.speed_bound() / 2.0).powi(2)).sum::<f64>().sqrt();
    let mut rate = cfg.max_metres_per_frame / bound.max(1e-12);
    let reached = largest_step(rate);
    if reached > 0.0 && largest_step(rate * cfg.max_metres_per_frame / reached) <= cfg.max_metres_per_frame * (1.0 + 1e-9) {
        rate *= cfg.max_metres_per_frame / reached;
    }
    let spin: [Wave; 3] = std::array::from_fn(|_| Wave::new(&mut rng));
    let spin_at = |i: usize| Vector3::from_fn(|a, _| spin[a].at(SPIN_CHANGE * i as f64));
    let peak_spin = (0..n).map(|i| spin_at(i).norm()).fold(0.0, f64::max).max(1e-12);
    let start_centre = start.rotation * centre + start.translation;
    let mut rotation = start.rotation;
    let mut poses = Vec::with_capacity(n);
    for i in 0..n {
        let c = start_centre + offset_at(rate * i as f64);
        poses.push(Pose::new(rotation, c - rotation * centre));
        // Turn about the object's centre.
        let turn = spin_at(i) * (cfg.max_degrees_per_frame.to_radians() / peak_spin);
        rotation = Rotation3::new(turn) * rotation;
    }
    poses
}

/// A sequence ready to render frame by frame: its trajectory and its static background.
pub struct Sequence<'a> {
    mesh: &'a Mesh,
    k: Intrinsics,
    cfg: SequenceConfig,
    poses: Vec<Pose>,
    background: RgbImage,
    occluder_colour: image::Rgb<u8>,
}

/// A frame with what only a dataset on disk needs: the object's full silhouette.
pub struct FrameWithSilhouette {
    pub frame: Frame,
    pub silhouette: GrayImage,
}

impl<'a> Sequence<'a> {
    pub fn new(mesh: &'a Mesh, k: &Intrinsics, cfg: &SequenceConfig) -> Self {
        let mut rng = Rng::new(cfg.seed ^ 0x5eed);
        let background = cluttered_background(k.width, k.height, &mut rng);
        let occluder_colour = image::Rgb([(rng.uniform() * 255.0) as u8, (rng.uniform() * 255.0) as u8, (rng.uniform() * 255.0) as u8]);
        Self { mesh, k: *k, cfg: cfg.clone(), poses: trajectory(mesh, cfg), background, occluder_colour }
    }

    pub fn len(&self) -> usize {
        self.poses.len()
    }

    pub fn is_empty(&self) -> bool {
        self.poses.is_empty()
    }

    /// Frame `i`: the object over the background, lit from a fixed direction, then the
    /// occluder, blur and noise as configured. Each frame's noise has its own seed, so
    /// frames can be made in any order.
    pub fn frame(&self, i: usize, pool: &RenderPool) -> Result<FrameWithSilhouette, RenderError> {
        let (k, cfg) = (&self.k, &self.cfg);
        let truth = self.poses[i];
        let r = pool.render(self.mesh, &truth, k, &RenderOptions::default())?;
        let mut rgb = crate::eval::degrade::composite(&r.rgb, &r.mask, &self.background);
        let mut visible = r.mask.clone();
        let mut depth = r.depth.clone();
        fill_with_plane(&mut depth, k, WALL_DISTANCE * cfg.distance, (0.0, 0.0));
        if cfg.occluder {
            // From just off the left edge to just off the right one.
            let bar = (k.width / 10).max(1);
            let x0 = ((i as f64 / self.len().max(1) as f64) * (k.width + bar) as f64) as i64 - bar as i64;
            for x in x0.max(0) as u32..((x0 + bar as i64).max(0) as u32).min(k.width) {
                for y in 0..k.height {
                    rgb.put_pixel(x, y, self.occluder_colour);
                    visible.put_pixel(x, y, image::Luma([0]));
                    depth[(y * k.width + x) as usize] = (OCCLUDER_DISTANCE * cfg.distance) as f32;
                }
            }
        }
        if cfg.blur_sigma > 0.0 {
            rgb = crate::eval::degrade::gaussian_blur(&rgb, cfg.blur_sigma);
        }
        if cfg.noise_sigma > 0.0 {
            let mut rng = Rng::new(cfg.seed ^ 0x5eed ^ (i as u64 + 1).wrapping_mul(0x9e37_79b9_7f4a_7c15));
            rgb = crate::eval::degrade::add_noise(&rgb, cfg.noise_sigma, &mut rng);
        }
        let depth = cfg.depth_sensor.measure(&depth, Some(&rgb), k, cfg.seed ^ 0xde97_0000 ^ (i as u64 + 1).wrapping_mul(0x9e37_79b9_7f4a_7c15));
        Ok(FrameWithSilhouette { frame: Frame { rgb, truth, visible, depth }, silhouette: r.mask })
    }
}

/// Renders the whole sequence (see [`Sequence::frame`]).
pub fn generate(mesh: &Mesh, k: &Intrinsics, cfg: &SequenceConfig, pool: &RenderPool) -> Result<Vec<Frame>, RenderError> {
    let seq = Sequence::new(mesh, k, cfg);
    (0..seq.len()).map(|i| seq.frame(i, pool).map(|f| f.frame)).collect()
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
        let centre = Vector3::from(mesh.bbox_center());
        let centre_of = |p: &Pose| p.rotation * centre + p.translation;
        let (mut fastest_turn, mut fastest_move) = (0.0f64, 0.0f64);
        for w in poses.windows(2) {
            let turn = crate::geometry::geodesic_distance(&w[0].rotation, &w[1].rotation).to_degrees();
            let moved = (centre_of(&w[1]) - centre_of(&w[0])).norm();
            assert!(turn <= 10.0 + 1e-9 && moved <= 0.05 + 1e-9, "{turn}° {moved} m");
            (fastest_turn, fastest_move) = (fastest_turn.max(turn), fastest_move.max(moved));
        }
        // "Up to" the limits: the fastest frames come near them.
        assert!(fastest_turn > 9.0 && fastest_move > 0.04, "{fastest_turn}° {fastest_move} m");
        for p in &poses {
            let offset = centre_of(p) - centre_of(&poses[0]);
            assert!((0..3).all(|i| offset[i].abs() <= 2.0 * TRAVEL[i] * cfg.distance + 1e-9), "{offset:?}");
        }
    }
}
