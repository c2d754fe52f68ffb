//! Generated datasets (`bop::scene_dataset` writing `eval::scenes`' scenes) against their own claims: layout, units, masks, depth, round trip,
//! reproducibility. GPU tests skip without an adapter unless B2TF_REQUIRE_GPU=1.

use super::{generate_dataset, CONFIG_FILE};
use crate::bop::{load_models_info, load_scene_gt, load_split_gt, TEST_SPLIT};
use crate::eval::scenes::*;
use crate::mesh::procedural::textured_box;
use crate::mesh::Mesh;
use crate::render::RenderOptions;
use crate::render::RenderPool;
use image::{GrayImage, ImageBuffer, Luma};
use serde_json::Value;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

fn pool() -> Option<RenderPool> {
    crate::render::tests::test_pool()
}

fn objects() -> Vec<(u32, Mesh)> {
    vec![(1, textured_box([0.10, 0.06, 0.16], 3)), (2, textured_box([0.05, 0.05, 0.08], 9))]
}

/// Three objects over two meshes, so one image holds two instances of an object.
fn small_config(seed: u64) -> SceneConfig {
    SceneConfig { images: 3, objects_per_image: 3, image_size: (160, 120), seed, ..SceneConfig::default() }
}

fn read_json(path: &Path) -> Value {
    serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap()
}

fn gray(path: &Path) -> GrayImage {
    image::open(path).unwrap_or_else(|e| panic!("{}: {e}", path.display())).into_luma8()
}

fn ones(m: &GrayImage) -> usize {
    m.pixels().filter(|p| p[0] > 0).count()
}

#[test]
fn dataset_files_agree_with_the_scene_they_describe() {
    let Some(pool) = pool() else { return };
    // The renderer's depth, to compare with renders (`depth_sensor_measures_the_scene`
    // checks the sensor's).
    let (objs, cfg) = (objects(), SceneConfig { depth_sensor: crate::depth::sensor::SensorModel::exact(), ..small_config(7) });
    let dir = tempfile::tempdir().unwrap();
    let summary = generate_dataset(&objs, &cfg, &pool, dir.path()).unwrap();
    assert_eq!((summary.images, summary.instances), (3, 9));
    let scene = dir.path().join("test/000001");
    assert_eq!(summary.scene_dir, scene);
    let gt = read_json(&scene.join("scene_gt.json"));
    let info = read_json(&scene.join("scene_gt_info.json"));
    let cams = read_json(&scene.join("scene_camera.json"));
    assert_eq!(gt.as_object().unwrap().keys().collect::<Vec<_>>(), ["0", "1", "2"]);

    for im_id in 0..3u32 {
        // The images are reproducible one by one, which gives the poses that were used.
        let img = generate_image(&objs, &cfg, &pool, im_id).unwrap();
        let key = im_id.to_string();
        let rgb = image::open(scene.join(format!("rgb/{im_id:06}.png"))).unwrap().into_rgb8();
        assert_eq!(rgb, img.rgb);
        let depth: ImageBuffer<Luma<u16>, Vec<u16>> = image::open(scene.join(format!("depth/{im_id:06}.png"))).unwrap().into_luma16();
        assert_eq!(depth.dimensions(), (160, 120));
        let cam = &cams[&key];
        let k: Vec<f64> = serde_json::from_value(cam["cam_K"].clone()).unwrap();
        assert_eq!(k, vec![img.cam.fx, 0.0, img.cam.cx, 0.0, img.cam.fy, img.cam.cy, 0.0, 0.0, 1.0]);
        let depth_scale = cam["depth_scale"].as_f64().unwrap();
        assert_eq!(depth_scale, 0.1);
        // A background behind everything: every pixel has a depth.
        assert!(depth.pixels().all(|p| p[0] > 0));

        for (i, inst) in img.instances.iter().enumerate() {
            let g = &gt[&key][i];
            assert_eq!(g["obj_id"].as_u64().unwrap() as u32, inst.obj_id);
            let t: Vec<f64> = serde_json::from_value(g["cam_t_m2c"].clone()).unwrap();
            for a in 0..3 {
                assert!((t[a] - inst.pose.translation[a] * 1000.0).abs() < 1e-9, "cam_t_m2c {t:?} is not the pose in mm");
            }
            let r: Vec<f64> = serde_json::from_value(g["cam_R_m2c"].clone()).unwrap();
            assert_eq!(r, inst.pose.rotation_row_major());

            let mask = gray(&scene.join(format!("mask/{im_id:06}_{i:06}.png")));
            let visib = gray(&scene.join(format!("mask_visib/{im_id:06}_{i:06}.png")));
            assert_eq!((mask.dimensions(), visib.dimensions()), ((160, 120), (160, 120)));
            assert!(mask.pixels().zip(visib.pixels()).all(|(m, v)| m[0] == 255 || v[0] == 0), "mask_visib ⊄ mask");
            let gi = &info[&key][i];
            let (all, vis) = (ones(&mask), ones(&visib));
            assert_eq!(gi["px_count_all"].as_u64().unwrap() as usize, all);
            assert_eq!(gi["px_count_visib"].as_u64().unwrap() as usize, vis);
            assert!((gi["visib_fract"].as_f64().unwrap() - vis as f64 / all as f64).abs() < 1e-12);
            assert!(vis as f64 / all as f64 >= 1.0 - cfg.max_occlusion, "instance {i} of image {im_id} is {vis}/{all} visible");
            // Wholly inside the frame before occlusion: every vertex projects into it.
            for v in objs[(inst.obj_id - 1) as usize].1.positions() {
                let uv = img.cam.project(&inst.pose.transform_point(&nalgebra::Point3::from(v.map(f64::from)))).unwrap();
                assert!(uv.x >= 0.0 && uv.y >= 0.0 && uv.x <= 159.0 && uv.y <= 119.0, "vertex at {uv:?}");
            }

            // The object rendered alone at the recorded pose: same silhouette, and the
            // depth PNG decodes to its depth (mm) wherever the object is visible.
            let alone = pool.render(&objs[(inst.obj_id - 1) as usize].1, &inst.pose, &img.cam, &RenderOptions::default()).unwrap();
            assert_eq!(alone.mask, mask);
            let [x0, y0, x1, y1] = alone.mask_bbox().unwrap().map(i64::from);
            assert_eq!(gi["bbox_obj"], serde_json::json!([x0, y0, x1 - x0 + 1, y1 - y0 + 1]));
            for (x, y, p) in visib.enumerate_pixels() {
                if p[0] > 0 {
                    let mm = depth.get_pixel(x, y)[0] as f64 * depth_scale;
                    let want = alone.depth_at(x, y) as f64 * 1000.0;
                    assert!((mm - want).abs() < 1.0, "depth at ({x}, {y}): {mm} mm vs rendered {want} mm");
                }
            }
        }
    }

    let targets = read_json(&dir.path().join("test_targets_bop19.json"));
    let targets = targets.as_array().unwrap();
    assert!(targets.iter().all(|t| t["scene_id"] == 1));
    assert_eq!(targets.iter().map(|t| t["inst_count"].as_u64().unwrap()).sum::<u64>(), 9);
    assert!(targets.iter().any(|t| t["inst_count"] == 2), "three slots over two objects repeat one");
    let saved: SceneConfig = serde_json::from_value(read_json(&dir.path().join(CONFIG_FILE))).unwrap();
    assert_eq!(saved, cfg);
    let models = load_models_info(dir.path()).unwrap();
    assert_eq!(models.keys().copied().collect::<Vec<_>>(), vec![1, 2]);
    assert!((models[&1].diameter - objs[0].1.diameter() * 1000.0).abs() < 1e-6);
    assert!((models[&2].size_z - 80.0).abs() < 1e-3 && (models[&2].min_x + 25.0).abs() < 1e-3);
}

#[test]
fn reader_gives_back_poses_cameras_and_paths() {
    let Some(pool) = pool() else { return };
    let (objs, cfg) = (objects(), SceneConfig { images: 2, objects_per_image: 2, ..small_config(11) });
    let dir = tempfile::tempdir().unwrap();
    generate_dataset(&objs, &cfg, &pool, dir.path()).unwrap();
    let mut warnings = Vec::new();
    let images = load_split_gt(dir.path(), TEST_SPLIT, &mut warnings).unwrap();
    assert_eq!(images, load_scene_gt(&dir.path().join("test/000001"), &mut warnings).unwrap());
    assert!(warnings.is_empty(), "{warnings:?}");
    assert_eq!(images.iter().map(|i| (i.scene_id, i.im_id)).collect::<Vec<_>>(), vec![(1, 0), (1, 1)]);
    for gt in &images {
        let img = generate_image(&objs, &cfg, &pool, gt.im_id).unwrap();
        assert_eq!(gt.cam, img.cam);
        assert_eq!(gt.depth_scale, 0.1);
        assert!(gt.rgb_path.is_file() && gt.depth_path.is_file());
        assert_eq!(gt.instances.len(), img.instances.len());
        for (g, want) in gt.instances.iter().zip(&img.instances) {
            assert_eq!(g.obj_id, want.obj_id);
            assert!((g.pose.translation - want.pose.translation).norm() < 1e-12, "{:?} vs {:?}", g.pose, want.pose);
            assert!((g.pose.rotation.matrix() - want.pose.rotation.matrix()).amax() < 1e-12);
            assert!((g.visib_fract.unwrap() - want.visib_fract()).abs() < 1e-12);
            assert_eq!(gray(&g.mask_visib_path), want.mask_visib);
            assert_eq!(gray(&g.mask_path), want.mask);
        }
    }
}

#[test]
fn fixed_seed_gives_identical_files() {
    let Some(pool) = pool() else { return };
    let objs = objects();
    let cfg = SceneConfig { images: 2, ..small_config(5) };
    let dirs: Vec<_> = (0..4).map(|_| tempfile::tempdir().unwrap()).collect();
    for (d, (seed, gap)) in dirs.iter().zip([(5, true), (5, true), (6, true), (5, false)]) {
        generate_dataset(&objs, &SceneConfig { seed, render_to_real_gap: gap, ..cfg.clone() }, &pool, d.path()).unwrap();
    }
    let files = |root: &Path| -> BTreeMap<PathBuf, Vec<u8>> {
        let mut out = BTreeMap::new();
        let mut stack = vec![root.to_path_buf()];
        while let Some(d) = stack.pop() {
            for e in std::fs::read_dir(&d).unwrap() {
                let p = e.unwrap().path();
                if p.is_dir() {
                    stack.push(p);
                } else {
                    out.insert(p.strip_prefix(root).unwrap().to_path_buf(), std::fs::read(&p).unwrap());
                }
            }
        }
        out
    };
    let (a, b, c) = (files(dirs[0].path()), files(dirs[1].path()), files(dirs[2].path()));
    assert_eq!(a.len(), 6 + 2 * 2 + 2 * 3 * 2, "json files, rgb + depth per image, two masks per instance");
    assert!(a == b, "same seed, different files");
    let rgb = PathBuf::from("test/000001/rgb/000000.png");
    assert_ne!(a[&rgb], c[&rgb], "another seed gives another image");
    // Without the gap: other pixels, same geometry.
    let d = files(dirs[3].path());
    assert_ne!(a[&rgb], d[&rgb]);
    for (path, bytes) in &a {
        let p = path.to_string_lossy();
        if p.contains("mask") || p.ends_with("scene_gt.json") || p.ends_with("scene_camera.json") || p.contains("depth/") {
            assert!(d[path] == *bytes, "{p} differs without the gap");
        }
    }
}

#[test]
fn crowded_config_fails_with_advice() {
    let Some(pool) = pool() else { return };
    let cfg = SceneConfig { objects_per_image: 4, fill_range: (0.8, 0.9), max_occlusion: 0.0, ..small_config(1) };
    let err = generate_image(&objects(), &cfg, &pool, 0).unwrap_err().to_string();
    assert!(err.contains("image 0: could not place instance") && err.contains("max_occlusion"), "{err}");
}

/// With a least occlusion every instance hides at least that much, and no more than the
/// most.
#[test]
fn least_occlusion_is_reached() {
    let Some(pool) = pool() else { return };
    let cfg = SceneConfig { objects_per_image: 2, min_occlusion: 0.5, max_occlusion: 0.8, ..small_config(4) };
    for im_id in 0..2 {
        let image = generate_image(&objects(), &cfg, &pool, im_id).unwrap();
        for inst in &image.instances {
            let hidden = 1.0 - inst.visib_fract();
            assert!((0.5..=0.8).contains(&hidden), "image {im_id}: object {} hides {hidden:.2}", inst.obj_id);
            assert_eq!(ones(&inst.mask_visib), inst.px_count_visib);
        }
    }
}

#[test]
fn config_is_validated_and_the_gap_is_harsher() {
    assert!(SceneConfig::default().validate().is_ok());
    assert!(SceneConfig { objects_per_image: 2, objects_per_image_max: 6, ..Default::default() }.validate().is_ok());
    let bad = [
        SceneConfig { objects_per_image: 0, ..Default::default() },
        SceneConfig { objects_per_image: 3, objects_per_image_max: 2, ..Default::default() },
        SceneConfig { objects_per_image: 2, objects_per_image_max: 9, ..Default::default() },
        SceneConfig { max_occlusion: 0.95, ..Default::default() },
        SceneConfig { min_occlusion: 0.5, max_occlusion: 0.3, ..Default::default() },
        SceneConfig { min_occlusion: -0.1, ..Default::default() },
        SceneConfig { min_occlusion: 0.2, occluders: false, ..Default::default() },
        SceneConfig { fill_range: (0.4, 0.1), ..Default::default() },
        SceneConfig { image_size: (8, 480), ..Default::default() },
        SceneConfig { appearance: Appearance { jpeg_quality: Some((0, 80)), ..Default::default() }, ..Default::default() },
        SceneConfig { appearance: Appearance { jpeg_quality: Some((90, 60)), ..Default::default() }, ..Default::default() },
        SceneConfig { appearance: Appearance { print_gain: 0.8, ..Default::default() }, ..Default::default() },
        SceneConfig { appearance: Appearance { print_shift_px: f64::NAN, ..Default::default() }, ..Default::default() },
    ];
    for c in bad {
        assert!(c.validate().is_err(), "{c:?} passed");
    }
    let a = Appearance::default();
    let h = SceneConfig { render_to_real_gap: true, ..Default::default() }.effective_appearance();
    assert_eq!(h, a.harsher());
    assert!(h.light_angle_deg > a.light_angle_deg && h.ambient.1 < a.ambient.1);
    assert!(h.blur_sigma.0 > a.blur_sigma.0 && h.noise_sigma.1 > a.noise_sigma.1 && h.color_gain > a.color_gain);
    assert!(a.jpeg_quality.is_none() && h.jpeg_quality == Some((50, 85)) && h.print_gain > a.print_gain && h.print_shift_px >= 1.0);
    // A config written before these fields existed still reads, with none of them.
    let mut old = serde_json::to_value(a).unwrap();
    for key in ["jpeg_quality", "print_gain", "print_shift_px"] {
        old.as_object_mut().unwrap().remove(key);
    }
    assert_eq!(serde_json::from_value::<Appearance>(old).unwrap(), Appearance::default());
}

/// `cargo test --release -- --ignored scene_generation_speed --nocapture`
#[test]
#[ignore]
fn scene_generation_speed() {
    let Some(pool) = pool() else { return };
    let objs = objects();
    let cfg = SceneConfig { images: 10, objects_per_image: 3, ..SceneConfig::default() };
    let dir = tempfile::tempdir().unwrap();
    let t = std::time::Instant::now();
    for im_id in 0..cfg.images as u32 {
        generate_image(&objs, &cfg, &pool, im_id).unwrap();
    }
    let gen = t.elapsed().as_secs_f64() / cfg.images as f64;
    let t = std::time::Instant::now();
    generate_dataset(&objs, &cfg, &pool, dir.path()).unwrap();
    let all = t.elapsed().as_secs_f64() / cfg.images as f64;
    println!("640x480, 3 objects: {:.0} ms per image generated, {:.0} ms with writing ({})", gen * 1e3, all * 1e3, pool.describe());
}

/// With supersampling the poses are the same draws, the masks and depth stay at the
/// image's resolution (each pixel's centre sample), and the outline blends into what is
/// behind it: pixels on the outline take colours between the object's and the ground's.
#[test]
fn supersampled_scenes_blend_outlines_and_keep_centre_sample_masks() {
    let Some(pool) = pool() else { return };
    // Bare meshes: a texture sampled at 3× and averaged differs from one sampled once
    // inside the outline too, which would hide what this test looks for.
    let objs: Vec<(u32, Mesh)> = objects().into_iter().map(|(id, m)| (id, m.without_appearance())).collect();
    let plain = Appearance { blur_sigma: (0.0, 0.0), noise_sigma: (0.0, 0.0), color_gain: 0.0, color_offset: 0.0, ..Appearance::default() };
    let cfg = |s: u32| SceneConfig { images: 1, objects_per_image: 2, image_size: (160, 120), occluders: false, appearance: plain.clone(), supersampling: s, seed: 3, ..SceneConfig::default() };
    assert!(cfg(2).validate().unwrap_err().contains("supersampling"));
    assert!(cfg(7).validate().is_err() && cfg(0).validate().is_err() && cfg(5).validate().is_ok());
    let (one, three) = (generate_image(&objs, &cfg(1), &pool, 0).unwrap(), generate_image(&objs, &cfg(3), &pool, 0).unwrap());
    assert_eq!((three.rgb.dimensions(), three.depth.len()), ((160, 120), 160 * 120));
    let (mut outline_changed, mut outline, mut inside_changed, mut inside) = (0, 0, 0, 0);
    for (a, b) in one.instances.iter().zip(&three.instances) {
        assert_eq!(a.pose, b.pose);
        assert_eq!((b.mask.dimensions(), b.px_count_all, b.px_count_visib), ((160, 120), ones(&b.mask), ones(&b.mask_visib)));
        let common = a.mask.pixels().zip(b.mask.pixels()).filter(|(p, q)| p[0] > 0 && q[0] > 0).count();
        assert!(common as f64 > 0.9 * ones(&a.mask).max(ones(&b.mask)) as f64, "masks agree: {common} of {} / {}", ones(&a.mask), ones(&b.mask));
        for (x, y, p) in b.mask_visib.enumerate_pixels().filter(|(x, y, _)| *x > 0 && *y > 0 && *x < 159 && *y < 119) {
            let on_outline = [(0i32, 1i32), (1, 0), (0, -1), (-1, 0)].iter().any(|(dx, dy)| b.mask_visib.get_pixel((x as i32 + dx) as u32, (y as i32 + dy) as u32)[0] != p[0]);
            let changed = one.rgb.get_pixel(x, y).0.iter().zip(three.rgb.get_pixel(x, y).0).any(|(u, v)| u.abs_diff(v) > 12);
            if on_outline {
                (outline, outline_changed) = (outline + 1, outline_changed + changed as usize);
            } else if p[0] > 0 {
                (inside, inside_changed) = (inside + 1, inside_changed + changed as usize);
            }
        }
    }
    let (o, i) = (outline_changed as f64 / outline as f64, inside_changed as f64 / inside.max(1) as f64);
    assert!(o > 0.3 && o > 3.0 * i, "outline pixels changed: {o:.2}, inside: {i:.2}");
}

#[test]
fn depth_sensor_measures_the_scene() {
    let Some(pool) = pool() else { return };
    let objs = objects();
    let exact = generate_image(&objs, &SceneConfig { depth_sensor: crate::depth::sensor::SensorModel::exact(), ..small_config(3) }, &pool, 0).unwrap();
    let sensed = generate_image(&objs, &small_config(3), &pool, 0).unwrap();
    assert_eq!(exact.rgb, sensed.rgb, "the sensor has its own randomness");
    let (mut holes, mut errors) = (0usize, Vec::new());
    for (&e, &m) in exact.depth.iter().zip(&sensed.depth) {
        if m == 0.0 {
            holes += 1;
        } else {
            errors.push((m - e).abs() as f64);
        }
    }
    errors.sort_by(f64::total_cmp);
    let median = errors[errors.len() / 2];
    // Some holes (shadows, grazing, speckle), millimetre noise, no wholesale change.
    assert!(holes > 20 && holes < exact.depth.len() / 5, "{holes} holes");
    assert!(median > 0.0002 && median < 0.005, "median error {median} m");
}

/// Clustered scenes put every instance beside another: the instances' visible boxes,
/// grown by a few pixels, each meet another's (unclustered ones, as drawn with this seed,
/// leave some instance standing alone, so the check can fail).
#[test]
fn clustered_objects_stand_beside_each_other() {
    let Some(pool) = pool() else { return };
    let boxes_meet = |cfg: &SceneConfig| {
        (0..cfg.images as u32).all(|im| {
            let img = generate_image(&objects(), cfg, &pool, im).unwrap();
            let boxes: Vec<[i64; 4]> = img
                .instances
                .iter()
                .map(|i| {
                    let pts: Vec<(u32, u32)> = i.mask_visib.enumerate_pixels().filter(|p| p.2[0] > 0).map(|p| (p.0, p.1)).collect();
                    let (x0, y0) = pts.iter().fold((u32::MAX, u32::MAX), |a, p| (a.0.min(p.0), a.1.min(p.1)));
                    let (x1, y1) = pts.iter().fold((0, 0), |a, p| (a.0.max(p.0), a.1.max(p.1)));
                    [x0 as i64 - 3, y0 as i64 - 3, x1 as i64 + 3, y1 as i64 + 3]
                })
                .collect();
            let meet = |a: &[i64; 4], b: &[i64; 4]| a[0] <= b[2] && b[0] <= a[2] && a[1] <= b[3] && b[1] <= a[3];
            boxes.iter().enumerate().all(|(i, a)| boxes.iter().enumerate().any(|(j, b)| i != j && meet(a, b)))
        })
    };
    let cfg = SceneConfig { images: 4, objects_per_image: 3, image_size: (320, 240), fill_range: (0.15, 0.25), occluders: false, seed: 5, ..SceneConfig::default() };
    assert!(boxes_meet(&SceneConfig { clustered: true, ..cfg.clone() }), "a clustered instance stands alone");
    assert!(!boxes_meet(&cfg), "unclustered scenes happened to cluster: pick another seed for the check to mean something");
}
