//! One generated image: place objects without hiding each other too much, render each
//! alone, composite by depth over clutter, add occluders, degrade (and store as JPEG).

use super::appearance::{as_stored, degrade, drift_print, sample_lighting};
use super::background::{fill_behind, pick, Background};
use super::config::{Appearance, SceneConfig};
use super::layers::Layers;
use super::occluders::{sample_occluder, Occluder, OccluderPhoto};
use super::placement::{sample_intrinsics, sample_placement, Extent, Placement};
use super::supersample::{average_down, centre_depth, centre_samples, repeat_up};
use crate::eval::degrade::clutter_background;
use crate::geometry::{Intrinsics, Pose};
use crate::mesh::procedural::Rng;
use crate::mesh::Mesh;
use crate::render::{RenderOutput, RenderPool};
use anyhow::{bail, Result};
use image::{GrayImage, RgbImage};
use std::borrow::Cow;

/// One object instance of a generated image, with what BOP's ground truth records.
#[derive(Clone, Debug)]
pub struct SceneInstance {
    pub obj_id: u32,
    /// `T_cam_obj`, metres.
    pub pose: Pose,
    /// Full silhouette (the object rendered alone), 255 inside.
    pub mask: GrayImage,
    /// Visible part after depth compositing and occluders, 255 inside.
    pub mask_visib: GrayImage,
    pub px_count_all: usize,
    pub px_count_visib: usize,
}

impl SceneInstance {
    pub fn visib_fract(&self) -> f64 {
        self.px_count_visib as f64 / self.px_count_all.max(1) as f64
    }
}

#[derive(Clone, Debug)]
pub struct SceneImage {
    pub cam: Intrinsics,
    /// The degraded photo-like image.
    pub rgb: RgbImage,
    /// Scene depth in metres (objects and occluders), row-major; 0 where there is none.
    pub depth: Vec<f32>,
    pub instances: Vec<SceneInstance>,
}

/// Draws of a position per instance before giving up (most are rejected without rendering).
const PLACEMENT_DRAWS: usize = 300;
/// Renders per instance before giving up: each costs a few milliseconds.
const RENDERS_PER_INSTANCE: usize = 30;
/// Chance that an instance gets an occluder, and tries to place one that keeps every
/// instance visible enough.
const OCCLUDER_CHANCE: f64 = 0.7;
const OCCLUDER_TRIES: usize = 8;
/// With a least occlusion: occluders tried per instance until it hides enough, occluders
/// in one image at most (the layer owner index is a byte), and draws of the whole image.
const HEAVY_OCCLUDER_TRIES: usize = 60;
const MAX_OCCLUDERS: usize = 200;
const OCCLUSION_ATTEMPTS: usize = 8;
/// Occluders float this fraction of the nearest object's depth in front of the camera:
/// in front of everything, so they hide whatever they overlap.
const OCCLUDER_DEPTH: f32 = 0.9;

/// Image `im_id` of the dataset that `cfg` describes. Its randomness depends only on
/// `cfg.seed` and `im_id`, so images can be made in any order or alone.
pub fn generate_image(objects: &[(u32, Mesh)], cfg: &SceneConfig, pool: &RenderPool, im_id: u32) -> Result<SceneImage> {
    generate_image_over(objects, cfg, pool, im_id, &[])
}

/// [`generate_image`] drawn over one of `backgrounds` (a real frame, drawn from the image's
/// seed), or over procedural clutter where there are none.
pub fn generate_image_over(objects: &[(u32, Mesh)], cfg: &SceneConfig, pool: &RenderPool, im_id: u32, backgrounds: &[Background]) -> Result<SceneImage> {
    if objects.is_empty() {
        bail!("no objects to place in the scene");
    }
    cfg.validate().map_err(|e| anyhow::anyhow!("scene config: {e}"))?;
    let base = cfg.seed.wrapping_mul(0x0001_0000_0001).wrapping_add(im_id as u64);
    for attempt in 0..OCCLUSION_ATTEMPTS {
        // Attempt 0 draws from the image's own seed, so images without a least occlusion
        // are what they always were.
        let mut rng = Rng::new(base.wrapping_add((attempt as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15)));
        if let Some(image) = try_generate(objects, cfg, pool, im_id, backgrounds, &mut rng)? {
            return Ok(image);
        }
    }
    bail!(
        "image {im_id}: could not hide at least {:.0} % of every instance (and at most {:.0} %) in {OCCLUSION_ATTEMPTS} attempts; \
         lower min_occlusion or objects_per_image",
        cfg.min_occlusion * 100.0,
        cfg.max_occlusion * 100.0
    )
}

/// One draw of the image; `None` when occluders could not hide `min_occlusion` of some
/// instance.
fn try_generate(objects: &[(u32, Mesh)], cfg: &SceneConfig, pool: &RenderPool, im_id: u32, backgrounds: &[Background], rng: &mut Rng) -> Result<Option<SceneImage>> {
    let cam = sample_intrinsics(cfg, rng);
    // Everything up to the painted image happens on `fine`, the camera with `s`×`s` pixels
    // for each of the image's (placements are in metres and fill shares, so they do not
    // change with it).
    let s = cfg.supersampling.max(1);
    let fine = cam.supersampled(s);
    let appearance = cfg.effective_appearance();
    let lighting = sample_lighting(&appearance, rng);
    let min_visible = 1.0 - cfg.max_occlusion;
    let extents: Vec<Extent> = objects.iter().map(|(_, m)| Extent::of(m)).collect();

    let mut layers = Layers::new(fine.width, fine.height);
    let mut placed: Vec<(usize, Placement, RenderOutput)> = Vec::new();
    let mut full: Vec<usize> = Vec::new();
    let count = cfg.objects_in_image(rng);
    for &obj in &slot_objects(objects.len(), count, rng) {
        let (mut draws, mut renders) = (0, 0);
        loop {
            if draws == PLACEMENT_DRAWS || renders == RENDERS_PER_INSTANCE {
                bail!(
                    "image {im_id}: could not place instance {} (object {}) with at least {:.0} % visible after {draws} positions \
                     and {renders} renders; lower objects_per_image or fill_range, or raise max_occlusion",
                    placed.len(),
                    objects[obj].0,
                    min_visible * 100.0
                );
            }
            draws += 1;
            let fill = rng.range(cfg.fill_range.0, cfg.fill_range.1);
            // Drawn only when clustering, so unclustered scenes stay what they were.
            let beside = match placed.len() {
                n if cfg.clustered && n > 0 => Some(&placed[(rng.next_u64() % n as u64) as usize].1),
                _ => None,
            };
            let Some(p) = sample_placement(&extents[obj], &cam, fill, beside, rng) else {
                continue;
            };
            if placed.iter().any(|(_, q, _)| p.crowds(q, min_visible)) {
                continue;
            }
            renders += 1;
            let out = pool.render(&objects[obj].1, &p.pose, &fine, &lighting)?;
            let count = out.depth.iter().filter(|&&z| z > 0.0).count();
            if count == 0 {
                continue;
            }
            let mut trial = layers.clone();
            trial.add_object(placed.len(), &out);
            full.push(count);
            if trial.min_visible_fraction(&full) >= min_visible {
                layers = trial;
                placed.push((obj, p, out));
                break;
            }
            full.pop();
        }
    }

    let mut occluders: Vec<Occluder> = Vec::new();
    if cfg.occluders {
        let z = layers.nearest() * OCCLUDER_DEPTH;
        let heavy = cfg.min_occlusion > 0.0;
        for (i, (_, _, out)) in placed.iter().enumerate() {
            if !heavy && rng.uniform() >= OCCLUDER_CHANCE {
                continue;
            }
            let [x0, y0, x1, y1] = out.mask_bbox().expect("placed objects cover pixels");
            let size = (x1 - x0).max(y1 - y0) as f64 + 1.0;
            for _ in 0..if heavy { HEAVY_OCCLUDER_TRIES } else { OCCLUDER_TRIES } {
                // Heavy occlusion anchors each occluder on what is still visible, so that it
                // hides something new.
                let anchor: Cow<GrayImage> = if heavy { Cow::Owned(layers.visible_mask(i)) } else { Cow::Borrowed(&out.mask) };
                if occluders.len() >= MAX_OCCLUDERS || (heavy && anchor.pixels().all(|p| p[0] == 0)) {
                    break;
                }
                let occ = sample_occluder(random_pixel(&anchor, rng), size, rng);
                let mut trial = layers.clone();
                trial.add_occluder(occluders.len(), &occ, z);
                if trial.min_visible_fraction(&full) >= min_visible {
                    layers = trial;
                    occluders.push(occ);
                    if !heavy || 1.0 - layers.visible_fractions(&full)[i] >= cfg.min_occlusion {
                        break;
                    }
                }
            }
        }
        if layers.visible_fractions(&full).iter().any(|v| 1.0 - v < cfg.min_occlusion) {
            return Ok(None);
        }
    }

    let (background, real_depth, occluder_photo) = if backgrounds.is_empty() {
        (clutter_background(cam.width, cam.height, rng), None, None)
    } else {
        let (photo, depth) = pick(backgrounds, rng).fitted(cam.width, cam.height);
        // Over real frames the occluders are real clutter too: pieces of another real photo.
        let pieces = repeat_up(&pick(backgrounds, rng).photo_at(cam.width, cam.height), s);
        (photo, depth, Some(OccluderPhoto::new(pieces, occluders.len(), rng)))
    };
    let print = Appearance { print_shift_px: appearance.print_shift_px * s as f64, ..appearance.clone() };
    for (_, _, out) in placed.iter_mut() {
        drift_print(&mut out.rgb, &out.mask, &print, rng);
    }
    let renders: Vec<&RenderOutput> = placed.iter().map(|(_, _, out)| out).collect();
    // At s = 1 each helper below is a copy.
    let clean = average_down(&layers.paint(&renders, &occluders, occluder_photo.as_ref(), &repeat_up(&background, s)), s);
    let rgb = as_stored(degrade(&clean, &appearance, rng), &appearance, rng)?;
    // The counts are the image-resolution masks' (a render's mask is its depth > 0).
    let count = |mask: &GrayImage| mask.pixels().filter(|p| p[0] > 0).count();
    let instances = placed
        .into_iter()
        .enumerate()
        .map(|(i, (obj, p, out))| {
            let (mask, mask_visib) = (centre_samples(&out.mask, s), centre_samples(&layers.visible_mask(i), s));
            SceneInstance { obj_id: objects[obj].0, pose: p.pose, px_count_all: count(&mask), px_count_visib: count(&mask_visib), mask, mask_visib }
        })
        .collect();
    let depth = measured_depth(centre_depth(layers.depth(), fine.width, s), &rgb, &cam, cfg, im_id, real_depth.as_deref());
    Ok(Some(SceneImage { cam, rgb, depth, instances }))
}

/// Largest tilt of the background plane, as the tangent of its slope along each axis.
const BACKGROUND_TILT: f64 = 0.25;

/// The scene's exact depth with a flat background behind everything (a wall or bench
/// 15–50 % beyond the farthest surface, tilted a little), or the real frame's depth behind
/// it where the background is a real frame with depth, as the depth camera measures it.
/// Its randomness has its own seed, so the colour images are what they were before depth.
fn measured_depth(mut depth: Vec<f32>, rgb: &RgbImage, cam: &Intrinsics, cfg: &SceneConfig, im_id: u32, real: Option<&[f32]>) -> Vec<f32> {
    let seed = cfg.seed.wrapping_mul(0x0001_0000_0001).wrapping_add(im_id as u64) ^ 0xdec0_de0f_de97_4000;
    let mut rng = Rng::new(seed);
    let farthest = depth.iter().copied().fold(0f32, f32::max) as f64;
    if let Some(real) = real {
        fill_behind(&mut depth, farthest, real);
    } else if farthest > 0.0 {
        let tilt = (rng.range(-BACKGROUND_TILT, BACKGROUND_TILT), rng.range(-BACKGROUND_TILT, BACKGROUND_TILT));
        // Behind the farthest surface at every pixel: at the image's corners (|u|, |v| <
        // 0.6) the tilt brings the plane at most 1/1.3 as near.
        crate::depth::sensor::fill_with_plane(&mut depth, cam, farthest * rng.range(1.4, 1.8), tilt);
    }
    cfg.depth_sensor.measure(&depth, Some(rgb), cam, rng.next_u64())
}

/// Which object fills each slot: a random order of all objects, repeated when there are
/// more slots than objects, so that every object appears as evenly as the slots allow.
fn slot_objects(objects: usize, slots: usize, rng: &mut Rng) -> Vec<usize> {
    let mut order: Vec<usize> = (0..objects).collect();
    for i in (1..order.len()).rev() {
        order.swap(i, (rng.next_u64() % (i as u64 + 1)) as usize);
    }
    (0..slots).map(|s| order[s % objects]).collect()
}

/// A uniformly drawn pixel of a non-empty mask.
fn random_pixel(mask: &GrayImage, rng: &mut Rng) -> (f64, f64) {
    let n = mask.pixels().filter(|p| p[0] > 0).count();
    let k = (rng.next_u64() % n as u64) as usize;
    let (x, y, _) = mask.enumerate_pixels().filter(|(_, _, p)| p[0] > 0).nth(k).expect("k < count");
    (x as f64, y as f64)
}
