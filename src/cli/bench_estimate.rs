//! `b2tf bench estimate`: accuracy and per-stage times on generated scenes.

use crate::estimate::{Detection, EstimateConfig, EstimateResult};
use crate::eval::pose_error::{mssd, rotation_error_deg, translation_error_m};
use crate::eval::scenes::generate_image;
use crate::geometry::Pose;
use crate::mesh::Mesh;
use crate::render::RenderPool;
use anyhow::{bail, Context, Result};
use std::path::PathBuf;
use std::sync::Arc;

#[derive(clap::Args, Debug)]
pub struct BenchEstimateArgs {
    #[command(flatten)]
    pub scenes: super::bench_scenes::BenchSceneArgs,
    /// Simulate the render-to-real gap: templates from the untextured mesh, harsher scenes.
    #[arg(long)]
    pub gap: bool,
    /// Only the scene side of the gap (lighting, blur, noise, colour shift, JPEG, prints
    /// that drift from the texture) with textured templates: the case of a user with a
    /// textured CAD model and a real camera.
    #[arg(long, conflicts_with = "gap")]
    pub harsh_scenes: bool,
    /// Weight of the silhouette IoU in template retrieval (default: the library's).
    #[arg(long)]
    pub silhouette_weight: Option<f32>,
    /// Templates kept by retrieval.
    #[arg(long)]
    pub k: Option<usize>,
    /// Geodesic NMS radius in degrees (0 disables NMS).
    #[arg(long)]
    pub nms_degrees: Option<f64>,
    /// RANSAC reprojection threshold in pixels.
    #[arg(long)]
    pub pnp_threshold: Option<f64>,
    /// RRC's renders in pixels per image pixel of the object (default 2; 0: at the
    /// backbone's crop size).
    #[arg(long)]
    pub rrc_render_scale: Option<f64>,
    /// RRC's renders at most this many pixels a side, unless the object's window in the
    /// photo is wider (default 256; 512 or more: no cap below the backbone's crop).
    #[arg(long)]
    pub rrc_render_cap: Option<u32>,
    /// RRC on every instance, also where the first PnP's inliers are sure enough to skip
    /// it (the paper's method; by default RRC runs where they are under 0.15 of the
    /// query's foreground patches).
    #[arg(long)]
    pub rrc_always: bool,
    /// Refiner after PnP/RRC: none (pass-through), silhouette-depth (scales the depth to
    /// the best silhouette IoU) or contour (aligns the outline with the mask).
    #[arg(long, value_enum, default_value_t = crate::estimate::RefinerKind::default())]
    pub refiner: crate::estimate::RefinerKind,
    /// Run the contour refiner without its occlusion model (for comparison).
    #[arg(long)]
    pub no_occlusion_model: bool,
    /// Which objects' outlines the contour refiner places on the photo's edges, to a
    /// fraction of a pixel, rather than on the mask alone.
    #[arg(long, value_enum, default_value_t = crate::estimate::contour::PhotoEdges::default())]
    pub photo_edges: crate::estimate::contour::PhotoEdges,
    #[command(flatten)]
    pub verify: super::verify_args::VerifyArgs,
    /// Share of colour agreement (the rest edge agreement) in verification's appearance term.
    #[arg(long)]
    pub colour_share: Option<f64>,
    /// Verification weights of silhouette IoU, contour agreement and appearance: A,B,C.
    #[arg(long, value_parser = parse_weights)]
    pub verify_weights: Option<[f64; 3]>,
    /// Write an overlay PNG per image into this folder.
    #[arg(long)]
    pub overlays: Option<PathBuf>,
    /// Write each instance's given mask against its true visible mask into this folder
    /// (IMAGE_OBJ.png: the photo, magenta where the mask holds too much, cyan where it
    /// misses): for looking at box segmentations.
    #[arg(long)]
    pub mask_diffs: Option<PathBuf>,
    /// PCA of the patch descriptors, as `b2tf onboard --pca`: auto, off or a component count.
    #[arg(long, default_value = "auto")]
    pub pca: crate::onboard::PcaSetting,
    /// How the patch descriptors are held, as `b2tf onboard --descriptors`: f16 (the
    /// default), pq4 or pq2 (product-quantised in memory, as onboarding would).
    #[arg(long, value_enum, default_value = "f16")]
    pub descriptors: crate::onboard::DescriptorCoding,
    /// Which templates hold patch rows, as `b2tf onboard --patch-rows` (applied in memory
    /// to the models cached per template).
    #[arg(long, value_enum, default_value = "auto")]
    pub patch_rows: crate::onboard::PatchRows,
    /// Write one CSV row per instance and setting (errors, apparent size) into this file.
    #[arg(long)]
    pub per_instance: Option<PathBuf>,
    /// Write one CSV row per verified hypothesis of each instance (with RRC): its error and
    /// every verification term, to study choices of weights and candidates offline.
    #[arg(long)]
    pub per_candidate: Option<PathBuf>,
    /// Hand verification the true pose, turned by each of these angles in degrees about a
    /// random axis through the object's centre (0: the truth itself), as hint poses
    /// (`Estimator::estimate_hinted`): with `--per-candidate`, tells a right pose that is
    /// never generated from one the refiner loses or the vote turns down. A diagnostic:
    /// the figures then are no longer the estimator's own.
    #[arg(long, value_delimiter = ',')]
    pub truth_hints: Vec<f64>,
    /// Give the estimator the mask segmented inside the visible mask's box (as from a
    /// box-only detector) instead of the true visible mask; prints the masks' IoU.
    #[arg(long)]
    pub from_boxes: bool,
    /// With --from-boxes: fill the boxes instead of segmenting them (the old behaviour).
    #[arg(long, requires = "from_boxes")]
    pub fill_boxes: bool,
    /// With --from-boxes: several mask proposals per box from these sources, chosen
    /// among by their poses as `bop run`, the service and `b2tf estimate --box` do
    /// (e.g. cut,smooth-cut,wide-ring-cut,ellipse); without it, the one cut. The mask
    /// figures printed are the first proposal's (the cut's).
    #[arg(long, requires = "from_boxes", conflicts_with = "fill_boxes")]
    pub box_proposals: Option<crate::masks::ProposalConfig>,
    /// Whether a box's poses are moved back until their outline covers the box
    /// (`estimate::box_prior`): `auto`, for meshes without colours; `tight` (also the flag
    /// alone), always, for boxes drawn tight; `off`, never, for boxes drawn loose.
    #[arg(long, value_enum, default_value_t = crate::estimate::BoxPrior::default(), num_args = 0..=1, default_missing_value = "tight", requires = "box_proposals")]
    pub box_prior: crate::estimate::BoxPrior,
    /// RGB-D: each scene's depth goes to the estimator (`estimate::depth_fit`). The
    /// scenes' depth is what a Kinect-class camera measures (`depth::sensor`; the renderer's
    /// exact depth with --exact-depth).
    #[arg(long)]
    pub depth: bool,
    /// With --from-boxes: keep the graph cut's outline as it is, without settling its
    /// pixels by coverage (`masks::outline_matte`), for comparison.
    #[arg(long, requires = "from_boxes")]
    pub raw_box_outline: bool,
    /// Estimate each instance alone, as a request naming one object does: without the
    /// other instances' detections, which tell the refiner and verification where this
    /// object's mask may be cut by something in front.
    #[arg(long)]
    pub alone: bool,
    /// The refinement on the print's settings as JSON, those not named keeping their
    /// defaults (`PrintRefineConfig`), e.g. '{"point_sigma_px": 0.5, "points": {"within_mask":
    /// false}}'; `--print-rounds` overrides its rounds.
    #[arg(long, value_parser = parse_print_config)]
    pub print_config: Option<crate::estimate::contour::PrintRefineConfig>,
    /// Estimate each instance again (with RRC) on its mask less one outline pixel, and print
    /// how often that alone changes the verdict: the noise floor for comparing settings.
    #[arg(long)]
    pub stability: bool,
    /// Threads an image's instances are estimated on side by side, as the service and `bop
    /// run` do for a request's detections; 1: in turn, each instance's time its own.
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u16).range(1..=256))]
    pub instance_threads: u16,
}

/// `truth` turned by each of `degrees` about a random axis (seeded) through the mesh's
/// centre: the hint poses of `--truth-hints`.
fn truth_hints(truth: &Pose, mesh: &Mesh, degrees: &[f64], seed: u64) -> Vec<Pose> {
    let mut rng = crate::mesh::procedural::Rng::new(seed);
    let centre = nalgebra::Vector3::from(mesh.bbox_center());
    degrees
        .iter()
        .map(|&d| {
            let axis = nalgebra::Unit::new_normalize(nalgebra::Vector3::new(rng.normal(), rng.normal(), rng.normal()));
            crate::estimate::rrc::variant_pose(truth, &nalgebra::Rotation3::from_axis_angle(&axis, d.to_radians()), &centre)
        })
        .collect()
}

/// The photo with the pixels `mask` holds beyond `truth` in magenta and those it misses
/// in cyan.
fn mask_diff(photo: &image::RgbImage, mask: &image::GrayImage, truth: &image::GrayImage) -> image::RgbImage {
    image::RgbImage::from_fn(photo.width(), photo.height(), |x, y| match (mask.get_pixel(x, y).0[0] > 0, truth.get_pixel(x, y).0[0] > 0) {
        (true, false) => image::Rgb([255, 0, 255]),
        (false, true) => image::Rgb([0, 255, 255]),
        _ => *photo.get_pixel(x, y),
    })
}

fn parse_print_config(s: &str) -> Result<crate::estimate::contour::PrintRefineConfig, String> {
    serde_json::from_str(s).map_err(|e| format!("not a PrintRefineConfig: {e}"))
}

/// Box segmentation against the truth, over the instances of a `--from-boxes` run.
#[derive(Default)]
struct BoxTally {
    segment: crate::masks::SegmentConfig,
    iou: Vec<f64>,
    /// Pixels of the box's mask outside the true visible mask, and of that mask missed.
    extra: Vec<f64>,
    missed: Vec<f64>,
    filled_iou: Vec<f64>,
    ms: Vec<f64>,
    fallbacks: usize,
}

impl BoxTally {
    /// The detection a box-only detector would give for `truth`: its tight box, segmented
    /// (and, with `proposals`, that cut's fellow proposals after it, each carrying the box).
    fn detection(&mut self, image: &image::RgbImage, truth: &image::GrayImage, how: crate::masks::BoxMask, proposals: Option<&crate::masks::ProposalConfig>) -> Result<Vec<Detection>> {
        let (x0, y0, x1, y1) = crate::features::mask_bbox(truth).ok_or_else(|| anyhow::anyhow!("empty visible mask"))?;
        let bbox = [x0 as f64, y0 as f64, (x1 - x0 + 1) as f64, (y1 - y0 + 1) as f64];
        let s = crate::masks::box_to_mask_with(image, bbox, how, &self.segment)?;
        let filled = crate::masks::box_to_mask(image, bbox, crate::masks::BoxMask::Fill)?;
        self.iou.push(crate::masks::mask_iou(&s.mask, truth));
        let (ours, true_px) = (s.mask.as_raw(), truth.as_raw());
        self.extra.push(ours.iter().zip(true_px).filter(|&(&a, &b)| a > 0 && b == 0).count() as f64);
        self.missed.push(ours.iter().zip(true_px).filter(|&(&a, &b)| a == 0 && b > 0).count() as f64);
        self.filled_iou.push(crate::masks::mask_iou(&filled.mask, truth));
        self.ms.push(s.ms);
        self.fallbacks += (s.method == crate::masks::Method::EllipseFallback) as usize;
        Ok(match proposals {
            Some(p) => Detection::from_box_masks(crate::masks::box_masks(image, bbox, crate::masks::BoxMask::Propose, p)?, 1.0),
            None => vec![Detection::new(s.mask, 1.0)],
        })
    }

    fn report(&mut self) {
        let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len().max(1) as f64;
        println!(
            "masks from boxes: mean IoU with the true visible mask {:.3} (filled box {:.3}), median {:.0} pixels too many and {:.0} missed per mask, {} of {} fell back to the ellipse, median {:.0} ms per box",
            mean(&self.iou),
            mean(&self.filled_iou),
            median(&mut self.extra),
            median(&mut self.missed),
            self.fallbacks,
            self.iou.len(),
            median(&mut self.ms)
        );
    }
}

/// One configuration's outcomes over all instances.
#[derive(Default)]
struct Tally {
    name: &'static str,
    correct: usize,
    found: usize,
    rot: Vec<f64>,
    trans_mm: Vec<f64>,
    /// |Δz|/z of the instances whose rotation is within 10°.
    depth_rel: Vec<f64>,
    stages: Vec<[f64; 9]>,
    /// (instances, correct) by apparent object size: < 100, 100–200, ≥ 200 px mask box side.
    by_size: [(usize, usize); 3],
    /// Each image's instances and the time their estimates took, start to end (ms): what a
    /// request naming every instance of the image costs (`--instance-threads`).
    per_image: Vec<(usize, f64)>,
    /// Instances whose RRC was skipped, their first matches being sure enough.
    rrc_skipped: usize,
}

impl Tally {
    /// The images' time in all: median and p90, with the median instances per image.
    fn per_image_report(&self) -> String {
        let (mut counts, mut ms): (Vec<f64>, Vec<f64>) = self.per_image.iter().map(|&(n, t)| (n as f64, t)).unzip();
        if ms.is_empty() {
            return "no images".into();
        }
        let (n, med) = (median(&mut counts), median(&mut ms));
        format!("median {med:.0} ms / p90 {:.0} ms an image of {n:.0} instances ({:.0} ms an instance)", quantile(&mut ms, 0.9), med / n.max(1.0))
    }
}

pub(super) fn size_bucket(mask: &image::GrayImage) -> usize {
    let side = crate::features::mask_bbox(mask).map(|(a, b, c, d)| (c - a).max(d - b) + 1).unwrap_or(0);
    match side {
        0..100 => 0,
        100..200 => 1,
        _ => 2,
    }
}

fn parse_weights(s: &str) -> Result<[f64; 3], String> {
    let v: Vec<f64> = s.split(',').map(|x| x.trim().parse::<f64>().map_err(|e| format!("{x:?}: {e}"))).collect::<Result<_, _>>()?;
    match v[..] {
        [a, b, c] if v.iter().all(|x| x.is_finite() && *x >= 0.0) => Ok([a, b, c]),
        _ => Err(format!("expected three non-negative weights A,B,C, got {s:?}")),
    }
}

pub(super) fn share((n, ok): (usize, usize)) -> String {
    if n == 0 {
        "–".into()
    } else {
        format!("{:.0} % of {n}", 100.0 * ok as f64 / n as f64)
    }
}

pub(super) fn median(v: &mut [f64]) -> f64 {
    quantile(v, 0.5)
}

/// The value below which share `q` of `v` lies (nearest rank; NaN when empty).
pub(super) fn quantile(v: &mut [f64], q: f64) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    v.sort_by(|a, b| a.total_cmp(b));
    v[((v.len() as f64 * q) as usize).min(v.len() - 1)]
}

/// The id a benchmark caches object `name` under: objects of an ONNX backbone (whose
/// weights hash is given) get their own ids instead of overwriting the embedded ones.
pub(super) fn cached_object_id(name: &str, onnx_weights_hash: Option<&str>) -> String {
    match onnx_weights_hash {
        Some(h) => format!("{name}.{}", &h[..h.len().min(12)]),
        None => name.to_string(),
    }
}

/// `cached_object_id` for a model of `identity`.
pub(super) fn cached_id_for(name: &str, identity: &crate::features::BackboneIdentity) -> String {
    cached_object_id(name, identity.name.starts_with("onnx:").then_some(identity.weights_hash.as_str()))
}

/// The onboarded models of `meshes`, cached in `store`. Across the gap, templates come
/// from the bare geometry while scenes stay textured.
pub(super) fn bench_models(meshes: &[(String, Mesh)], gap: bool, store: &str, backbone: &dyn crate::features::Backbone, pool: &RenderPool) -> Result<Vec<crate::onboard::ObjectModel>> {
    let store = crate::store::open(store)?;
    meshes
        .iter()
        .map(|(name, mesh)| {
            let (id, template_mesh) = if gap { (format!("{name}-untextured"), mesh.without_appearance()) } else { (name.clone(), mesh.clone()) };
            let id = cached_id_for(&id, &backbone.identity());
            super::cached_model(&id, &template_mesh, store.as_ref(), backbone, pool, super::bench_cache_config())
        })
        .collect()
}

pub fn run(a: BenchEstimateArgs) -> Result<()> {
    let scene_cfg = a.scenes.scene_config(a.gap || a.harsh_scenes)?;
    let backbone = a.scenes.backbone.open()?;
    let pool = Arc::new(super::open_renderer(RenderPool::DEFAULT_SIZE)?);
    let meshes = a.scenes.load_meshes()?;
    let mut models = bench_models(&meshes, a.gap, &a.scenes.store, backbone.as_ref(), &pool)?;
    for model in &mut models {
        if a.patch_rows.resolve(backbone.as_ref()) == crate::onboard::PatchRows::PerView {
            crate::onboard::share_rows_per_view(model).map_err(anyhow::Error::msg)?;
        }
        crate::onboard::apply_pca(model, a.pca)?;
        let (t, before) = (std::time::Instant::now(), model.patch_descriptors.memory_bytes());
        crate::onboard::apply_coding(model, a.descriptors)?;
        if a.descriptors != crate::onboard::DescriptorCoding::F16 {
            eprintln!(
                "{}: {:?} descriptors of {} patches in {:.1} s: {:.1} → {:.1} MB",
                model.object_id,
                a.descriptors,
                model.patch_count(),
                t.elapsed().as_secs_f64(),
                before as f64 / 1e6,
                model.patch_descriptors.memory_bytes() as f64 / 1e6
            );
        }
    }
    let objects: Vec<(u32, Mesh)> = meshes.iter().enumerate().map(|(i, (_, m))| (i as u32 + 1, m.clone())).collect();
    // Symmetric objects are scored against the truth turned by their symmetry nearest to
    // each pose (BOP's MSSD), the identity alone for the others; per model, the symmetry
    // poses and the surface sample that picks among them.
    let scoring: Vec<(Vec<Pose>, Vec<[f32; 3]>)> = models
        .iter()
        .map(|m| {
            let symmetries = m.symmetries.as_ref().map_or_else(|| vec![Pose::identity()], |s| crate::mesh::symmetry_finder::symmetry_poses(&s.symmetries, 36));
            (symmetries, crate::eval::pose_error::sample_points(m.mesh.positions(), 500))
        })
        .collect();
    let mut contour = crate::estimate::contour::ContourRefiner::new(pool.clone());
    contour.config.occlusion_model = !a.no_occlusion_model;
    contour.config.photo_edges = a.photo_edges;
    let estimator = crate::estimate::Estimator::new(backbone, pool.clone()).with_contour(Arc::new(contour));
    let mut base = EstimateConfig { refiner: a.refiner, box_prior: a.box_prior, ..Default::default() };
    if let Some(w) = a.silhouette_weight {
        base.retrieval.silhouette_weight = w;
    }
    if let Some(k) = a.k {
        base.retrieval.k = k;
    }
    if let Some(t) = a.pnp_threshold {
        base.pnp.reprojection_threshold_px = t;
    }
    if let Some(d) = a.nms_degrees {
        base.retrieval.nms_degrees = d;
    }
    if let Some(s) = a.rrc_render_scale {
        base.rrc_render_scale = s;
    }
    if let Some(c) = a.rrc_render_cap {
        base.rrc_render_cap = c;
    }
    base = base.with_rrc_always(a.rrc_always);
    base.verify = a.verify.config();
    base.print = a.print_config.unwrap_or_default();
    if let Some(rounds) = a.verify.print_rounds {
        base.print.rounds = rounds;
    }
    if let Some(c) = a.colour_share {
        base.verify.colour_share = c;
    }
    if let Some(w) = a.verify_weights {
        base.verify.weights = w;
    }
    let configs = [("with RRC", base.clone()), ("without RRC", EstimateConfig { rrc: false, ..base.clone() })];
    let mut tallies: Vec<Tally> = configs.iter().map(|(n, _)| Tally { name: n, ..Default::default() }).collect();
    let mut instances = 0;
    let mut stability = super::bench_stability::Stability::default();
    let mut margins = super::bench_margin::MarginTally::default();
    let mut boxes = BoxTally { segment: crate::masks::SegmentConfig { settle_outline: !a.raw_box_outline, ..Default::default() }, ..Default::default() };
    for dir in [&a.overlays, &a.mask_diffs].into_iter().flatten() {
        std::fs::create_dir_all(dir).with_context(|| format!("cannot create the folder {}", dir.display()))?;
    }
    let mut candidate_rows = String::from("image,obj_id,size_px,mask,source,mssd_over_diameter,rot_err_deg,contour,iou,edges,colour,features,score,lines,lines_with_edge\n");
    let mut rows = String::from("image,obj_id,setting,size_px,visible,found,rot_err_deg,trans_err_mm,depth_err_mm,mssd_over_diameter,inliers,best_candidate_mssd_over_diameter,best_candidate_rank,print_points,runner_up_margin,runner_up_distance\n");
    let mut uploads_ms: Vec<f64> = Vec::new();
    let pb = super::progress::bar(a.scenes.images as u64, "estimating");
    for im in 0..a.scenes.images as u32 {
        let scene = generate_image(&objects, &scene_cfg, &pool, im)?;
        let mut overlay = scene.rgb.clone();
        // Every instance's detection first: each is estimated among the others, as in a
        // request that names every object in the picture.
        // Each instance's candidates: its one mask, or its box's proposals; the first stands
        // for the instance where other instances are concerned.
        let how = if a.fill_boxes { crate::masks::BoxMask::Fill } else { crate::masks::BoxMask::Segment };
        let depth = if a.depth { Some(crate::depth::DepthImage::from_metres(scene.rgb.width(), scene.rgb.height(), scene.depth.clone())?) } else { None };
        let dets: Vec<Vec<Detection>> = scene
            .instances
            .iter()
            .map(|inst| if a.from_boxes { boxes.detection(&scene.rgb, &inst.mask_visib, how, a.box_proposals.as_ref()) } else { Ok(vec![Detection::new(inst.mask_visib.clone(), 1.0)]) })
            .collect::<Result<_>>()?;
        // Every instance's estimate first, side by side as a request's would be, timed as
        // the image's; then each is scored, in the instances' order.
        let others: Vec<Option<image::GrayImage>> = (0..dets.len())
            .map(|n| if a.alone { None } else { crate::masks::union(dets.iter().enumerate().filter(|&(o, _)| o != n).map(|(_, d)| &d[0].mask), scene.rgb.width(), scene.rgb.height()) })
            .collect();
        let hints: Vec<Vec<Pose>> =
            scene.instances.iter().enumerate().map(|(n, inst)| truth_hints(&inst.pose, &models[inst.obj_id as usize - 1].mesh, &a.truth_hints, im as u64 * 1000 + n as u64)).collect();
        // The image's objects are on the renderers before the clock starts, as the service
        // puts an object there when it loads it: the scenes' own renders (other copies of the
        // meshes) and the other images' objects may have pushed them out, and a first render's
        // upload (a texture's decode) is a load's cost, not an estimate's.
        let upload = std::time::Instant::now();
        for inst in &scene.instances {
            pool.prepare(&models[inst.obj_id as usize - 1].mesh)?;
        }
        uploads_ms.push(upload.elapsed().as_secs_f64() * 1e3);
        let mut results: Vec<std::vec::IntoIter<EstimateResult>> = Vec::new();
        for (t, (_, cfg)) in tallies.iter_mut().zip(&configs) {
            let (started, setting) = (std::time::Instant::now(), t.name);
            let estimated = crate::parallel::ordered_map((0..scene.instances.len()).collect(), a.instance_threads.into(), |n| {
                let inst = &scene.instances[n];
                tracing::debug!(image = im, obj_id = inst.obj_id, setting, "bench instance");
                estimator.estimate_hinted(&models[inst.obj_id as usize - 1], (&scene.rgb, depth.as_ref()), &scene.cam, &dets[n], others[n].as_ref(), &hints[n], cfg)
            })?;
            t.per_image.push((scene.instances.len(), started.elapsed().as_secs_f64() * 1e3));
            results.push(estimated.into_iter());
        }
        for (n, inst) in scene.instances.iter().enumerate() {
            instances += 1;
            if let Some(dir) = &a.mask_diffs {
                let path = dir.join(format!("{im:04}_{}.png", inst.obj_id));
                mask_diff(&scene.rgb, &dets[n][0].mask, &inst.mask_visib).save(&path).with_context(|| format!("cannot write {}", path.display()))?;
            }
            let model = &models[inst.obj_id as usize - 1];
            let (det, others, hints) = (&dets[n], &others[n], &hints[n]);
            let (symmetries, sample) = &scoring[inst.obj_id as usize - 1];
            let truth = |p: &Pose| crate::eval::pose_error::closest_symmetric(p, &inst.pose, symmetries, sample);
            for ((t, (_, cfg)), estimated) in tallies.iter_mut().zip(&configs).zip(&mut results) {
                let r = estimated.next().context("an instance without its estimate")?;
                // The answer's error (MSSD over the diameter, against the truth turned by its
                // nearest symmetry), one pass over the mesh for the row, the tallies and the
                // stability check.
                let gt = r.pose.as_ref().map_or(inst.pose, &truth);
                let error = r.pose.as_ref().map(|p| mssd(p, &gt, model.mesh.positions()) / model.diameter());
                if a.stability && cfg.rrc {
                    let less: Vec<Detection> = det.iter().map(|d| Detection { mask: super::bench_stability::less_one_pixel(&d.mask), ..d.clone() }).collect();
                    let again = estimator.estimate_hinted(model, (&scene.rgb, depth.as_ref()), &scene.cam, &less, others.as_ref(), hints, cfg)?;
                    stability.push(error, again.pose.as_ref().map(|p| mssd(p, &truth(p), model.mesh.positions()) / model.diameter()));
                }
                t.rrc_skipped += usize::from(r.hypotheses.iter().any(|h| h.rrc_skipped));
                let tm = &r.timings;
                t.stages.push([tm.crop, tm.features, tm.retrieval, tm.matching, tm.pnp, tm.rrc, tm.refine, tm.selection, tm.total]);
                let bucket = size_bucket(&inst.mask);
                t.by_size[bucket].0 += 1;
                let size_px = crate::features::mask_bbox(&inst.mask).map_or(0, |b| (b.2 - b.0).max(b.3 - b.1));
                let inliers = r.hypotheses.iter().map(|h| h.inliers.max(h.rrc_inliers)).max().unwrap_or(0);
                // How good verification's best candidate was, and where verification ranked
                // it: tells a candidate that never existed from one that lost the vote. MSSD
                // to four decimals, as the candidates' rows: at three, 0.0996 read as 0.100
                // and a count of `< 0.1` from the file missed it.
                let oracle = r
                    .hypotheses
                    .iter()
                    .flat_map(|h| h.verified.iter().enumerate())
                    .map(|(rank, v)| (mssd(&v.pose, &truth(&v.pose), model.mesh.positions()) / model.diameter(), rank))
                    .min_by(|a, b| a.0.total_cmp(&b.0));
                let oracle = oracle.map_or(",".to_string(), |(m, rank)| format!("{m:.4},{rank}"));
                // Every candidate's MSSD costs a pass over the mesh: only when asked for.
                if a.per_candidate.is_some() && t.name == "with RRC" {
                    for (mask, h) in r.hypotheses.iter().enumerate() {
                        for v in &h.verified {
                            let gt = truth(&v.pose);
                            candidate_rows.push_str(&format!(
                                "{im},{},{size_px},{mask},{},{:.4},{:.2},{:.4},{:.4},{:.4},{:.4},{:.4},{:.4},{},{}\n",
                                inst.obj_id,
                                v.source,
                                mssd(&v.pose, &gt, model.mesh.positions()) / model.diameter(),
                                rotation_error_deg(&v.pose, &gt),
                                v.contour,
                                v.iou,
                                v.edges,
                                v.colour,
                                v.features,
                                v.score,
                                v.refinement.lines,
                                v.refinement.lines_with_edge,
                            ));
                        }
                    }
                }
                // The print points before and after the kept pose was refined on its print
                // ("before/after"), empty where it was not.
                let print = r.hypotheses.iter().find(|h| Some(h.mask_index) == r.mask_index).and_then(|h| h.refinement.as_ref()?.print_points).map_or(String::new(), |[b, a]| format!("{b}/{a}"));
                let runner_up = r.runner_up.map_or(",".to_string(), |u| format!("{:.4},{:.3}", u.margin, u.distance));
                match &r.pose {
                    Some(p) => rows.push_str(&format!(
                        "{im},{},{},{size_px},{:.3},1,{:.2},{:.1},{:.1},{:.4},{inliers},{oracle},{print},{runner_up}\n",
                        inst.obj_id,
                        t.name,
                        inst.visib_fract(),
                        rotation_error_deg(p, &gt),
                        translation_error_m(p, &gt) * 1e3,
                        (p.translation.z - gt.translation.z) * 1e3,
                        error.unwrap_or(f64::NAN),
                    )),
                    None => rows.push_str(&format!("{im},{},{},{size_px},{:.3},0,,,,,{inliers},{oracle},,,\n", inst.obj_id, t.name, inst.visib_fract())),
                }
                if let Some(p) = r.pose {
                    t.found += 1;
                    t.rot.push(rotation_error_deg(&p, &gt));
                    t.trans_mm.push(translation_error_m(&p, &gt) * 1e3);
                    if rotation_error_deg(&p, &gt) < 10.0 {
                        t.depth_rel.push((p.translation.z - gt.translation.z).abs() / gt.translation.z);
                    }
                    let right = error.is_some_and(|e| e < 0.1);
                    if right {
                        t.correct += 1;
                        t.by_size[bucket].1 += 1;
                    }
                    if cfg.rrc {
                        margins.push(r.runner_up.map(|u| u.margin), right);
                    }
                    if cfg.rrc && a.overlays.is_some() {
                        overlay = crate::render::overlay::draw_overlay(&overlay, &pool, &model.mesh, &p, &scene.cam, [0, 255, 0])?;
                    }
                }
            }
        }
        if let Some(dir) = &a.overlays {
            overlay.save(dir.join(format!("{im:04}.png")))?;
        }
        pb.inc(1);
    }
    pb.finish_and_clear();
    if instances == 0 {
        bail!("no instances generated");
    }
    if let Some(path) = &a.per_candidate {
        std::fs::write(path, &candidate_rows).with_context(|| format!("writing {}", path.display()))?;
    }
    if let Some(path) = &a.per_instance {
        std::fs::write(path, rows)?;
    }
    if a.from_boxes {
        boxes.report();
    }
    println!("{}", margins.report());
    if a.stability {
        println!("{}", stability.report());
    }
    println!(
        "retrieval: k {}, NMS {}°, silhouette weight {}; PnP threshold {} px; refiner {}; verification {}",
        base.retrieval.k,
        base.retrieval.nms_degrees,
        base.retrieval.silhouette_weight,
        base.pnp.reprojection_threshold_px,
        base.refiner.name(),
        if base.verify.enabled {
            format!(
                "{} templates, {} matched, {} rendered, weights {:?}, second look {}",
                base.verify.templates,
                base.verify.matched_templates,
                base.verify.rendered,
                base.verify.weights,
                if base.verify.second_look { "on" } else { "off" }
            )
        } else {
            "off".into()
        }
    );
    println!(
        "{} instances in {} generated images ({} objects/image, diameter {:.2}–{:.2} of the image height, {:.0}–{:.0} % occluded, seed {}){}; objects: {}",
        instances,
        a.scenes.images,
        a.scenes.objects_per_image,
        a.scenes.fill.0,
        a.scenes.fill.1,
        a.scenes.min_occlusion * 100.0,
        a.scenes.max_occlusion * 100.0,
        a.scenes.seed,
        if a.gap {
            ", render-to-real gap: untextured templates, harsher scenes"
        } else if a.harsh_scenes {
            ", harsher scenes (lighting, blur, noise, JPEG, print drift), textured templates"
        } else {
            ""
        },
        meshes.iter().map(|(n, _)| n.as_str()).collect::<Vec<_>>().join(", ")
    );
    println!(
        "rendering: {}; the image's meshes put on the renderers before each image's timing (as the service does when it loads an object): median {:.0} ms, at most {:.0} ms an image",
        pool.describe(),
        median(&mut uploads_ms.clone()),
        uploads_ms.iter().cloned().fold(0.0, f64::max)
    );
    println!("| setting | MSSD < 0.1·d | < 100 px | 100–200 px | ≥ 200 px | pose found | median rot. err (°) | median trans. err (mm) | median / p90 Δz/z (rot. < 10°) | median ms: crop | features | retrieval | matching | pnp | rrc | refine | selection | total | p90 ms total |");
    println!("|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|");
    for t in &mut tallies {
        let med: Vec<f64> = (0..9).map(|s| median(&mut t.stages.iter().map(|x| x[s]).collect::<Vec<_>>())).collect();
        println!(
            "| {} | {:.1} % | {} | {} | {} | {:.1} % | {:.1} | {:.1} | {:.2} % / {:.2} % | {:.0} | {:.0} | {:.0} | {:.0} | {:.0} | {:.0} | {:.0} | {:.0} | {:.0} | {:.0} |",
            t.name,
            100.0 * t.correct as f64 / instances as f64,
            share(t.by_size[0]),
            share(t.by_size[1]),
            share(t.by_size[2]),
            100.0 * t.found as f64 / instances as f64,
            median(&mut t.rot),
            median(&mut t.trans_mm),
            100.0 * median(&mut t.depth_rel),
            100.0 * quantile(&mut t.depth_rel, 0.9),
            med[0],
            med[1],
            med[2],
            med[3],
            med[4],
            med[5],
            med[6],
            med[7],
            med[8],
            quantile(&mut t.stages.iter().map(|x| x[8]).collect::<Vec<_>>(), 0.9)
        );
    }
    for t in &tallies {
        println!("profile, {}: {}", t.name, profile(&t.stages));
    }
    for (t, (_, cfg)) in tallies.iter().zip(&configs).filter(|(_, (_, cfg))| cfg.rrc && cfg.rrc_sure_share > 0.0) {
        println!("RRC skipped on {} of {} instances, {}: the first PnP's inliers at least {} of the query's foreground patches", t.rrc_skipped, t.stages.len(), t.name, cfg.rrc_sure_share);
    }
    for t in &tallies {
        println!("per image, {}: {}", t.name, t.per_image_report());
    }
    Ok(())
}

/// The stages' shares of all the instances' time together (`bench_profile`).
fn profile(stages: &[[f64; 9]]) -> String {
    const NAMES: [&str; 8] = ["crop", "features", "retrieval", "matching", "pnp", "rrc", "refine", "selection"];
    super::bench_profile::stage_shares(&NAMES, stages, "instances")
}

#[cfg(test)]
mod tests {
    /// The truth itself at 0°, turned by the angle asked about the mesh's centre otherwise.
    #[test]
    fn truth_hints_are_the_truth_turned_by_the_angles_asked() {
        use crate::geometry::Pose;
        use nalgebra::{Rotation3, Vector3};
        let mesh = crate::mesh::procedural::textured_box([0.08, 0.04, 0.02], 3);
        let truth = Pose::new(Rotation3::from_euler_angles(0.4, -0.3, 0.8), Vector3::new(0.05, -0.02, 0.4));
        let hints = super::truth_hints(&truth, &mesh, &[0.0, 10.0, 25.0], 7);
        assert_eq!(hints.len(), 3);
        let centre = Vector3::from(mesh.bbox_center());
        for (h, degrees) in hints.iter().zip([0.0, 10.0, 25.0]) {
            assert!((truth.rotation.rotation_to(&h.rotation).angle().to_degrees() - degrees).abs() < 1e-6);
            assert!(((h.rotation * centre + h.translation) - (truth.rotation * centre + truth.translation)).norm() < 1e-12);
        }
    }

    /// An image's time is its instances' together; the line gives its median, p90 and the
    /// median per instance.
    #[test]
    fn per_image_report_gives_median_p90_and_the_share_an_instance() {
        let t = super::Tally { per_image: vec![(2, 100.0), (2, 300.0), (2, 200.0)], ..Default::default() };
        assert_eq!(t.per_image_report(), "median 200 ms / p90 300 ms an image of 2 instances (100 ms an instance)");
        assert_eq!(super::Tally::default().per_image_report(), "no images");
    }

    /// Settings not named keep their defaults; a wrong type or a setting that does not
    /// exist is refused with what is wrong.
    #[test]
    fn print_settings_are_read_as_json() {
        let c = super::parse_print_config(r#"{"point_sigma_px": 0.5, "points": {"within_mask": false}}"#).unwrap();
        let d = crate::estimate::contour::PrintRefineConfig::default();
        assert_eq!((c.point_sigma_px, c.points.within_mask, c.rounds, c.points.search_px), (0.5, false, d.rounds, d.points.search_px));
        assert!(super::parse_print_config(r#"{"rounds": "three"}"#).unwrap_err().contains("not a PrintRefineConfig"));
        assert!(super::parse_print_config(r#"{"round": 3}"#).unwrap_err().contains("unknown field"));
    }

    /// Shares of the summed time, with what the stages leave of the total as `other`.
    #[test]
    fn the_profile_gives_each_stage_its_share_of_the_summed_time() {
        let stages = [[0.0, 10.0, 0.0, 20.0, 0.0, 0.0, 50.0, 0.0, 100.0], [0.0, 10.0, 0.0, 20.0, 0.0, 0.0, 30.0, 0.0, 100.0]];
        let p = super::profile(&stages);
        assert!(p.starts_with("crop 0 %, features 10 %, retrieval 0 %, matching 20 %, pnp 0 %, rrc 0 %, refine 40 %, selection 0 %, other 30 %"), "{p}");
        assert!(p.ends_with("(of 200 ms over 2 instances)"), "{p}");
        assert_eq!(super::profile(&[]), "no time measured");
    }

    /// Too many in magenta, missed in cyan, the photo where mask and truth agree.
    #[test]
    fn mask_diffs_colour_what_the_mask_gets_wrong() {
        let photo = image::RgbImage::from_pixel(2, 2, image::Rgb([10, 20, 30]));
        let mask = image::GrayImage::from_raw(2, 2, vec![255, 255, 0, 0]).unwrap();
        let truth = image::GrayImage::from_raw(2, 2, vec![255, 0, 255, 0]).unwrap();
        let d = super::mask_diff(&photo, &mask, &truth);
        assert_eq!(d.pixels().map(|p| p.0).collect::<Vec<_>>(), vec![[10, 20, 30], [255, 0, 255], [0, 255, 255], [10, 20, 30]]);
    }
}
