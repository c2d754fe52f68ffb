//! `b2tf detect`: finds onboarded objects in an image with no mask and no box, and writes
//! the detections in the BOP default-detections JSON (as CNOS writes them), so the file can
//! replace a trained detector's anywhere the BOP tools read one.

use crate::detect::{detect, DetectOptions, DetectReport, Target};
use crate::onboard::ObjectModel;
use anyhow::{bail, Context, Result};
use serde_json::json;
use std::path::PathBuf;
use std::sync::Arc;

#[derive(clap::Args, Debug)]
pub struct DetectArgs {
    /// Object store (default: $B2TF_STORE, else sqlite://~/.local/share/b2tfpose/objects.db).
    #[arg(long)]
    pub store: Option<String>,
    /// Object to look for; repeat for several. Default: every object in the store.
    #[arg(long = "object")]
    pub objects: Vec<String>,
    /// RGB image (PNG or JPEG).
    #[arg(long)]
    pub image: PathBuf,
    /// Camera JSON ({"K", "resolution"} or BOP {"cam_K"[, "width", "height"]}).
    #[arg(long)]
    pub camera: PathBuf,
    /// RGB-D: a 16-bit depth PNG registered to the image (same size and camera); values ×
    /// --depth-scale are millimetres, 0 = no measurement. The objects are then looked for
    /// in the surfaces the depth shows (docs/detection.md, "With depth").
    #[arg(long)]
    pub depth: Option<PathBuf>,
    /// Millimetres per --depth unit (BOP's depth_scale).
    #[arg(long, default_value_t = 1.0, requires = "depth")]
    pub depth_scale: f64,
    /// Detections JSON to write (BOP default-detections format).
    #[arg(long)]
    pub out: PathBuf,
    /// Also draw the detections (outline, box, label) over the image into this PNG.
    #[arg(long)]
    pub overlay: Option<PathBuf>,
    #[command(flatten)]
    pub search: SearchArgs,
    /// scene_id and image_id written into each detection.
    #[arg(long, default_value_t = 0)]
    pub scene_id: u32,
    #[arg(long, default_value_t = 0)]
    pub image_id: u32,
}

/// The search settings, shared with the commands that detect before estimating.
#[derive(clap::Args, Debug, Clone)]
pub struct SearchArgs {
    /// At most this many detections over all objects.
    #[arg(long, default_value_t = DetectOptions::default().max_detections)]
    pub max_detections: usize,
    /// Score (0–1) a detection needs. Where a pose is estimated from the detector's
    /// candidates (estimate and track without a mask, bop run without detections), the
    /// candidates are taken from half of it and a pose is answered when its confirmation
    /// reaches 1.22 × it (docs/detection.md, "Confirmation").
    #[arg(long, default_value_t = DetectOptions::default().min_score)]
    pub min_score: f32,
    /// Nearest distance of the object from the camera to search, metres (default: the
    /// object filling the image's shorter side).
    #[arg(long)]
    pub min_distance: Option<f64>,
    /// Farthest distance to search, metres (default: the object 40 px across).
    #[arg(long)]
    pub max_distance: Option<f64>,
}

impl SearchArgs {
    pub fn options(&self) -> DetectOptions {
        DetectOptions { max_detections: self.max_detections, min_score: self.min_score, min_distance_m: self.min_distance, max_distance_m: self.max_distance, ..Default::default() }
    }
}

/// BOP `category_id` of an object id: its trailing number (`obj_000002` → 2), else its
/// 1-based place among the objects searched.
pub fn category_id(id: &str, place: usize) -> u32 {
    let digits: String = id.chars().rev().take_while(|c| c.is_ascii_digit()).collect::<Vec<_>>().into_iter().rev().collect();
    digits.parse().unwrap_or(place as u32 + 1)
}

/// The objects named, or every object of the store.
pub fn load_objects(store: &dyn crate::store::ObjectStore, ids: &[String]) -> Result<Vec<Arc<ObjectModel>>> {
    let ids: Vec<String> = if ids.is_empty() { store.list()?.into_iter().map(|o| o.id).collect() } else { ids.to_vec() };
    if ids.is_empty() {
        bail!("the store {} holds no object: onboard one first (b2tf onboard)", store.url());
    }
    if ids.len() > crate::limits::MAX_DETECT_OBJECTS {
        bail!("{} objects to detect; at most {} in one run", ids.len(), crate::limits::MAX_DETECT_OBJECTS);
    }
    ids.iter().map(|id| store.get(id).map(Arc::new).with_context(|| format!("loading object {id:?} from {}", store.url()))).collect()
}

/// One object's detections in an image (for the commands that detect when no mask is
/// given); an error naming the object and the detector's reason when there is none.
pub fn detect_object(
    model: &ObjectModel,
    (image, depth): (&image::RgbImage, Option<&crate::depth::DepthImage>),
    k: &crate::geometry::Intrinsics,
    options: &DetectOptions,
    renderer: &crate::render::RenderPool,
) -> Result<Vec<crate::detect::Detection>> {
    let shape = model.shape_model_or_build(renderer)?;
    let targets = [Target { id: &model.object_id, shape: &shape, mesh: &model.mesh }];
    let report = detect(image, depth, k, &targets, options, renderer)?;
    if report.detections.is_empty() {
        bail!("the detector did not find {} ({}); give a --mask (or a --box), or lower --min-score", model.object_id, report.reason.unwrap_or_default());
    }
    for d in &report.detections {
        println!("{} detected at [{:.0}, {:.0}, {:.0}, {:.0}], score {:.3}", d.object_id, d.bbox[0], d.bbox[1], d.bbox[2], d.bbox[3], d.score);
    }
    Ok(report.detections)
}

pub fn run(a: DetectArgs) -> Result<()> {
    let store = crate::store::open(&a.store.clone().unwrap_or_else(crate::store::default_url))?;
    let models = load_objects(store.as_ref(), &a.objects)?;
    let image = image::open(&a.image).with_context(|| format!("cannot read image {}", a.image.display()))?.to_rgb8();
    let k = super::camera_file::load_camera_for(&a.camera, Some(image.dimensions()))?;
    let renderer = super::open_renderer(crate::render::RenderPool::DEFAULT_SIZE)?;
    let shapes = models.iter().map(|m| m.shape_model_or_build(&renderer)).collect::<Result<Vec<_>, _>>()?;
    let targets: Vec<Target> = models.iter().zip(&shapes).map(|(m, s)| Target { id: &m.object_id, shape: s, mesh: &m.mesh }).collect();
    let depth = a.depth.as_deref().map(|p| super::depth_file::load_depth(p, a.depth_scale, image.dimensions())).transpose()?;
    let report = detect(&image, depth.as_ref(), &k, &targets, &a.search.options(), &renderer)?;
    let places: std::collections::HashMap<&str, usize> = models.iter().enumerate().map(|(i, m)| (m.object_id.as_str(), i)).collect();
    let doc = bop_json(&report, a.scene_id, a.image_id, &|id| category_id(id, places[id]));
    std::fs::write(&a.out, serde_json::to_vec_pretty(&doc)?).with_context(|| format!("writing {}", a.out.display()))?;
    for d in &report.detections {
        println!("{}: box [{:.0}, {:.0}, {:.0}, {:.0}], score {:.3}, mask from {:?}", d.object_id, d.bbox[0], d.bbox[1], d.bbox[2], d.bbox[3], d.score, d.mask_source);
    }
    if let Some(r) = &report.reason {
        println!("no detection: {r}");
    }
    let t = &report.timings;
    println!(
        "{} detections in {:.0} ms (responses {:.0}, search {:.0}, verification {:.0}, masks {:.0}); wrote {}",
        report.detections.len(),
        t.total_ms,
        t.responses_ms,
        t.search_ms,
        t.verify_ms,
        t.masks_ms,
        a.out.display()
    );
    if let Some(path) = &a.overlay {
        super::detect_overlay::draw(&image, &report).save(path).with_context(|| format!("writing {}", path.display()))?;
        println!("overlay: {}", path.display());
    }
    Ok(())
}

/// The BOP default-detections list (plus each detection's object id and coarse pose, which
/// BOP readers ignore).
pub fn bop_json(report: &DetectReport, scene_id: u32, image_id: u32, category: &dyn Fn(&str) -> u32) -> serde_json::Value {
    let seconds = report.timings.total_ms / 1e3;
    let list: Vec<serde_json::Value> = report
        .detections
        .iter()
        .map(|d| {
            let rle = crate::masks::Rle::encode(&d.mask);
            json!({
                "scene_id": scene_id,
                "image_id": image_id,
                "category_id": category(&d.object_id),
                "bbox": d.bbox,
                "score": d.score,
                "time": seconds,
                "segmentation": rle.to_json_uncompressed(),
                "object": d.object_id,
                "R": d.pose.rotation_row_major(),
                "t": [d.pose.translation.x, d.pose.translation.y, d.pose.translation.z],
            })
        })
        .collect();
    serde_json::Value::Array(list)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn category_ids_come_from_trailing_numbers() {
        assert_eq!(category_id("obj_000002", 5), 2);
        assert_eq!(category_id("17", 0), 17);
        assert_eq!(category_id("bracket", 2), 3);
    }
}
