//! `b2tf bench detect`: the detector on generated photo-like scenes (clutter, occluders,
//! lighting, blur, noise): recall at box IoU 0.5, AP50 and AP@[.5:.95] per object, false
//! detections on images that hold none of the searched objects (only distractors), and
//! the time per image with 1, 10 and 30 objects searched.

use crate::bop::coco_ap::{summarize, Dt, Gt, ImageCategory};
use crate::detect::nms::box_iou;
use crate::detect::{detect, DetectOptions, ShapeModel, Target};
use crate::eval::scenes::{generate_image, SceneConfig};
use crate::mesh::{load_mesh, Mesh, Units};
use crate::render::RenderPool;
use anyhow::{bail, Context, Result};
use std::collections::BTreeMap;
use std::path::PathBuf;
use std::time::Instant;

#[derive(clap::Args, Debug)]
pub struct BenchDetectArgs {
    /// Mesh files: the first ones are searched for, the last --distractors only appear.
    #[arg(long = "mesh", required = true)]
    pub meshes: Vec<PathBuf>,
    #[arg(long)]
    pub units: Option<Units>,
    /// How many of the meshes (the last ones) are distractors: in the scenes, never searched.
    #[arg(long, default_value_t = 0)]
    pub distractors: usize,
    /// Images with objects; each holds 2 to --max-objects-per-image instances.
    #[arg(long, default_value_t = 20)]
    pub images: usize,
    #[arg(long, default_value_t = 6)]
    pub max_objects_per_image: usize,
    /// Images holding only distractors (none of the searched objects): false detections.
    #[arg(long, default_value_t = 10)]
    pub empty_images: usize,
    /// Scenes and templates from the meshes without their textures and colours (a stand-in
    /// for untextured parts).
    #[arg(long)]
    pub untextured: bool,
    /// Score threshold (default: the detector's).
    #[arg(long)]
    pub min_score: Option<f32>,
    /// Detections kept per image, best first (default: the detector's).
    #[arg(long)]
    pub max_detections: Option<usize>,
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Also time the search with this many objects (templates repeated when fewer meshes).
    #[arg(long = "time-objects", default_values_t = vec![1, 10, 30])]
    pub time_objects: Vec<usize>,
    /// Write an overlay PNG per image into this folder.
    #[arg(long)]
    pub overlays: Option<PathBuf>,
    /// Also print, per instance, the best template score at its true place and scale and
    /// every detection's score terms with its box IoU (to study the search and the scores).
    #[arg(long)]
    pub oracle: bool,
    /// Also run the one-call path (`Estimate` naming the object: detection, estimation and
    /// confirmation) on every image for every searched object, with the objects of this
    /// store (onboarded under the meshes' file names), and score the answered poses' boxes.
    #[arg(long)]
    pub estimate_store: Option<String>,
}

/// One detection or ground-truth instance of one object in one image.
struct Scored {
    image: usize,
    bbox: [f64; 4],
    score: f32,
}

pub fn run(a: BenchDetectArgs) -> Result<()> {
    if a.distractors >= a.meshes.len() {
        bail!("--distractors {} leaves none of the {} meshes to search for", a.distractors, a.meshes.len());
    }
    let mut meshes: Vec<Mesh> = a.meshes.iter().map(|p| load_mesh(p, a.units).with_context(|| format!("loading {}", p.display()))).collect::<Result<_>>()?;
    if a.untextured {
        meshes = meshes.iter().map(|m| m.without_appearance()).collect();
    }
    let names: Vec<String> = a.meshes.iter().map(|p| p.file_stem().map_or("mesh".into(), |s| s.to_string_lossy().into_owned())).collect();
    let searched = meshes.len() - a.distractors;
    let d = DetectOptions::default();
    let opts = DetectOptions { min_score: a.min_score.unwrap_or(d.min_score), max_detections: a.max_detections.unwrap_or(d.max_detections), ..d };
    // The store is checked before the templates are built: a wrong one fails at once.
    if a.estimate_store.is_some() && a.untextured {
        bail!("--estimate-store runs the onboarded (textured) objects; leave out --untextured");
    }
    let mut one_call = a.estimate_store.as_deref().map(|url| super::bench_one_call::OneCall::open(url, &names[..searched], opts.clone())).transpose()?;
    let pool = super::open_renderer_for(RenderPool::DEFAULT_SIZE, meshes.len())?;
    let t = Instant::now();
    let shapes: Vec<ShapeModel> = meshes[..searched].iter().map(|m| ShapeModel::build(m, &pool, &Default::default())).collect::<Result<_, _>>()?;
    println!("templates: {} objects × {} in {:.1} s ({:.2} s per object)", searched, shapes[0].template_count(), t.elapsed().as_secs_f64(), t.elapsed().as_secs_f64() / searched as f64);
    let targets: Vec<Target> = (0..searched).map(|i| Target { id: &names[i], shape: &shapes[i], mesh: &meshes[i] }).collect();
    let all: Vec<(u32, Mesh)> = meshes.iter().enumerate().map(|(i, m)| (i as u32 + 1, m.clone())).collect();
    if let Some(dir) = &a.overlays {
        std::fs::create_dir_all(dir)?;
    }

    let mut truth: BTreeMap<usize, Vec<Scored>> = BTreeMap::new();
    // Whole silhouettes' boxes, as an answered pose's render gives them (occluded parts too).
    let mut truth_whole: BTreeMap<usize, Vec<Scored>> = BTreeMap::new();
    let mut found: BTreeMap<usize, Vec<Scored>> = BTreeMap::new();
    let mut answered: BTreeMap<usize, Vec<Scored>> = BTreeMap::new();
    let mut ms = Vec::new();
    for im in 0..a.images {
        let n = 2 + im % (a.max_objects_per_image.max(2) - 1);
        let cfg = SceneConfig { images: 1, objects_per_image: n, max_occlusion: 0.5, seed: a.seed, ..Default::default() };
        let scene = generate_image(&all, &cfg, &pool, im as u32)?;
        for inst in &scene.instances {
            let obj = inst.obj_id as usize - 1;
            if obj < searched {
                if let Some(b) = crate::detect::detector::bbox_of(&inst.mask_visib) {
                    truth.entry(obj).or_default().push(Scored { image: im, bbox: b, score: 1.0 });
                }
                if let Some(b) = crate::detect::detector::bbox_of(&inst.mask) {
                    truth_whole.entry(obj).or_default().push(Scored { image: im, bbox: b, score: 1.0 });
                }
            }
        }
        if a.oracle {
            oracle(&scene, &targets, searched);
        }
        let report = detect(&scene.rgb, None, &scene.cam, &targets, &opts, &pool)?;
        ms.push(report.timings.total_ms);
        for d in &report.detections {
            let obj = names.iter().position(|n| *n == d.object_id).expect("a searched object");
            if a.oracle {
                let best =
                    scene.instances.iter().filter(|i| i.obj_id as usize - 1 == obj).filter_map(|i| crate::detect::detector::bbox_of(&i.mask_visib)).map(|b| box_iou(&b, &d.bbox)).fold(0.0, f64::max);
                println!(
                    "image {im} {}: score {:.3}, box IoU {:.2}, shape {:.3}, outline {:.3}, colour {}, texture {}",
                    d.object_id,
                    d.score,
                    best,
                    d.shape_score,
                    d.evidence.outline,
                    d.evidence.colour.map_or("-".into(), |c| format!("{c:.3}")),
                    d.evidence.texture.map_or("-".into(), |c| format!("{c:.3}"))
                );
            }
            found.entry(obj).or_default().push(Scored { image: im, bbox: d.bbox, score: d.score });
        }
        if let Some(dir) = &a.overlays {
            super::detect_overlay::draw(&scene.rgb, &report).save(dir.join(format!("{im:04}.png")))?;
        }
        if let Some(one) = one_call.as_mut() {
            for obj in 0..searched {
                let held = scene.instances.iter().filter(|i| i.obj_id as usize - 1 == obj).count();
                for (bbox, score) in one.answer(&scene.rgb, &scene.cam, &names[obj], &meshes[obj], held.max(1), &pool)? {
                    if a.oracle {
                        let best = truth_whole.get(&obj).into_iter().flatten().filter(|t| t.image == im).map(|t| box_iou(&t.bbox, &bbox)).fold(0.0, f64::max);
                        println!("one-call image {im} {}: confirmation {score:.3}, box IoU {best:.2}", names[obj]);
                    }
                    answered.entry(obj).or_default().push(Scored { image: im, bbox, score });
                }
            }
        }
    }
    table(&names[..searched], &truth, &found, a.images, "detections", &mut ms);
    if let Some(one) = &one_call {
        let mut ms = one.ms.clone();
        table(&names[..searched], &truth_whole, &answered, a.images, "one-call estimates (box of the answered pose's whole silhouette against the truth's, confirmation score)", &mut ms);
    }

    if a.distractors > 0 && a.empty_images > 0 {
        let distractors: Vec<(u32, Mesh)> = all[searched..].to_vec();
        let (mut false_dets, mut false_answers) = (0, 0);
        for im in 0..a.empty_images {
            let cfg = SceneConfig { images: 1, objects_per_image: 2 + im % 3, max_occlusion: 0.5, seed: a.seed + 1000, ..Default::default() };
            let scene = generate_image(&distractors, &cfg, &pool, im as u32)?;
            let report = detect(&scene.rgb, None, &scene.cam, &targets, &opts, &pool)?;
            false_dets += report.detections.len();
            if let Some(dir) = &a.overlays {
                super::detect_overlay::draw(&scene.rgb, &report).save(dir.join(format!("empty-{im:04}.png")))?;
            }
            if let Some(one) = one_call.as_mut() {
                for obj in 0..searched {
                    let wrong = one.answer(&scene.rgb, &scene.cam, &names[obj], &meshes[obj], 1, &pool)?;
                    if a.oracle {
                        for (_, score) in &wrong {
                            println!("one-call empty image {im} {}: confirmation {score:.3}", names[obj]);
                        }
                    }
                    false_answers += wrong.len();
                }
            }
        }
        println!("images without searched objects: {false_dets} false detections in {} images ({:.3} per image)", a.empty_images, false_dets as f64 / a.empty_images as f64);
        if one_call.is_some() {
            println!(
                "images without searched objects, one call per object: {false_answers} poses answered in {} images × {searched} objects ({:.3} per image, {:.3} per call)",
                a.empty_images,
                false_answers as f64 / a.empty_images as f64,
                false_answers as f64 / (a.empty_images * searched) as f64
            );
        }
    }
    if let Some(one) = &one_call {
        println!("one call: {} instances answered in {} calls", one.answered, one.ms.len());
    }

    // Time against the number of objects searched, on one scene.
    let cfg = SceneConfig { images: 1, objects_per_image: 3, seed: a.seed, ..Default::default() };
    let scene = generate_image(&all, &cfg, &pool, 0)?;
    for &n in &a.time_objects {
        let many: Vec<Target> = (0..n).map(|i| Target { id: &names[i % searched], shape: &shapes[i % searched], mesh: &meshes[i % searched] }).collect();
        let r = detect(&scene.rgb, None, &scene.cam, &many, &opts, &pool)?;
        let t = &r.timings;
        println!(
            "{n} objects: {:.0} ms (responses {:.0}, search {:.0}, verification {:.0}, masks {:.0}) on {}×{}",
            t.total_ms,
            t.responses_ms,
            t.search_ms,
            t.verify_ms,
            t.masks_ms,
            scene.rgb.width(),
            scene.rgb.height()
        );
    }
    Ok(())
}

/// The per-object table and the summary line of `found` (detections, or answered poses'
/// boxes) against the truth.
fn table(names: &[String], truth: &BTreeMap<usize, Vec<Scored>>, found: &BTreeMap<usize, Vec<Scored>>, images: usize, what: &str, ms: &mut [f64]) {
    println!("{what}:");
    println!("| object | instances | recall@0.5 | AP50 | AP@[.5:.95] |");
    println!("|---|---:|---:|---:|---:|");
    let (mut hits, mut total) = (0, 0);
    let mut every: BTreeMap<u32, Vec<ImageCategory>> = BTreeMap::new();
    for (obj, name) in names.iter().enumerate() {
        let gt = truth.get(&obj).map_or(&[][..], |v| v.as_slice());
        let dets = found.get(&obj).map_or(&[][..], |v| v.as_slice());
        if gt.is_empty() {
            continue;
        }
        let one = BTreeMap::from([(obj as u32, coco_images(gt, dets, images))]);
        let s = summarize(&one);
        let h = recalled(gt, dets, 0.5);
        println!("| {} | {} | {:.2} | {:.2} | {:.2} |", name, gt.len(), h as f64 / gt.len() as f64, s.ap50, s.ap);
        every.extend(one);
        hits += h;
        total += gt.len();
    }
    let s = summarize(&every);
    println!(
        "all: recall@0.5 {:.3} ({hits}/{total}), AP50 {:.3}, AP@[.5:.95] {:.3} (COCO, as bop eval --detections); median {:.0} ms per call",
        hits as f64 / total.max(1) as f64,
        s.ap50,
        s.ap,
        super::bench_estimate::median(ms)
    );
}

/// Detections of one object matched greedily, best score first, to unmatched truths of
/// the same image with box IoU ≥ `iou`: how many truths were found.
fn recalled(gt: &[Scored], dets: &[Scored], iou: f64) -> usize {
    let mut order: Vec<&Scored> = dets.iter().collect();
    order.sort_by(|a, b| b.score.total_cmp(&a.score));
    let mut used = vec![false; gt.len()];
    for d in order {
        let best = gt.iter().enumerate().filter(|(i, g)| !used[*i] && g.image == d.image).map(|(i, g)| (i, box_iou(&g.bbox, &d.bbox))).filter(|(_, v)| *v >= iou).max_by(|a, b| a.1.total_cmp(&b.1));
        if let Some((i, _)) = best {
            used[i] = true;
        }
    }
    used.iter().filter(|&&u| u).count()
}

/// One object's truths and detections per image, for COCO's AP (box IoU; no instance
/// ignored: the scenes keep every instance at least half visible).
fn coco_images(gt: &[Scored], dets: &[Scored], images: usize) -> Vec<ImageCategory> {
    (0..images)
        .map(|im| {
            let g: Vec<&Scored> = gt.iter().filter(|s| s.image == im).collect();
            let d: Vec<&Scored> = dets.iter().filter(|s| s.image == im).collect();
            let area = |b: &[f64; 4]| b[2] * b[3];
            ImageCategory::new(g.iter().map(|s| Gt { area: area(&s.bbox), ignore: false }).collect(), d.iter().map(|s| Dt { score: s.score as f64, area: area(&s.bbox) }).collect(), |di, gi| {
                box_iou(&d[di].bbox, &g[gi].bbox)
            })
        })
        .collect()
}

/// Each searched instance's best template score near its true centre (±3 px) at the rung
/// nearest its true size: whether the search could have found it at all.
fn oracle(scene: &crate::eval::scenes::SceneImage, targets: &[Target], searched: usize) {
    use crate::detect::detector::{SPREAD_PX, STRIDE_PX};
    use crate::detect::scales::{rung_scale, scale_for_distance, RUNGS};
    use crate::detect::search::{score_at, specific_score_at};
    let k = &scene.cam;
    let f = (k.fx * k.fy).sqrt();
    for inst in &scene.instances {
        let obj = inst.obj_id as usize - 1;
        if obj >= searched {
            continue;
        }
        let t = &targets[obj];
        let centre = inst.pose.transform_point(&nalgebra::Point3::from(nalgebra::Vector3::from(t.mesh.bbox_center())));
        let (u, v) = (k.fx * centre.x / centre.z + k.cx, k.fy * centre.y / centre.z + k.cy);
        let rho = scale_for_distance(t.shape.config.canonical_px as f64, f, t.mesh.bounding_radius(), centre.coords.norm());
        let nearest = (0..RUNGS).min_by(|&a, &b| (rung_scale(a).ln() - rho.ln()).abs().total_cmp(&(rung_scale(b).ln() - rho.ln()).abs())).unwrap_or(0);
        let r = rung_scale(nearest);
        let (small, rx, ry) = crate::detect::detector::resampled(&scene.rgb, r);
        let maps = crate::detect::responses::ResponseMaps::compute(&small, t.shape.config.min_magnitude, SPREAD_PX, STRIDE_PX);
        let (x, y) = (((u + 0.5) * rx - 0.5).round() as i32, ((v + 0.5) * ry - 0.5).round() as i32);
        let (mut best, mut spec) = ((0.0f32, 0usize), 0.0f32);
        for tt in 0..t.shape.template_count() {
            for dy in -3..=3 {
                for dx in -3..=3 {
                    let s = score_at(t.shape, &maps, tt, x + dx, y + dy);
                    if s > best.0 {
                        best = (s, tt);
                    }
                    spec = spec.max(specific_score_at(t.shape, &maps, tt, x + dx, y + dy));
                }
            }
        }
        println!("oracle {}: visible {:.2}, scale {:.3} (searched at {:.3}), best template {} scores {:.3} raw, {:.3} above chance", t.id, inst.visib_fract(), rho, r, best.1, best.0, spec);
    }
}
