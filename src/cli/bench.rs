//! `b2tf bench …`: commands that print the figures quoted in docs and issue notes.

use crate::eval::reid::ReidSet;
use crate::features::{EmbeddedBackbone, EmbeddedConfig};
use crate::geometry::views::{fitted_distance, view_pose};
use crate::mesh::{load_mesh, procedural::textured_box, Mesh, Units};
use crate::onboard::{onboard_profiled, OnboardConfig};
use crate::render::RenderOptions;
use anyhow::{bail, Result};
use std::path::{Path, PathBuf};
use std::time::Instant;

// One command line parsed once per run: the size of its largest variant costs nothing.
#[allow(clippy::large_enum_variant)]
#[derive(clap::Subcommand, Debug)]
pub enum BenchCommand {
    /// Patch re-identification of backbone variants, between neighbouring views and across
    /// a simulated render-to-real gap.
    Reid {
        /// Mesh to test on (default: the procedural textured box).
        #[arg(long)]
        mesh: Option<PathBuf>,
        #[arg(long)]
        units: Option<Units>,
        /// Image pairs per setting.
        #[arg(long, default_value_t = 8)]
        pairs: usize,
        #[arg(long, default_value_t = 1)]
        seed: u64,
    },
    /// Pose accuracy (MSSD < 0.1 × diameter) and per-stage median times on generated scenes,
    /// with and without RRC.
    Estimate(super::bench_estimate::BenchEstimateArgs),
    /// The detector on generated scenes: recall, AP, false detections on images without
    /// the objects, time per image against the number of objects searched.
    Detect(super::bench_detect::BenchDetectArgs),
    /// Backbone speed: ms per crop and crops/s at several batch sizes, embedded and ONNX.
    Backbone(super::bench_backbone::BenchBackboneArgs),
    /// The refiners alone, from the true pose and from known perturbations of it, by the
    /// object's apparent size.
    Refine(super::bench_refine::BenchRefineArgs),
    /// The HTTP service under concurrent estimate load: req/s, p50/p99, server memory.
    Serve(super::bench_serve::BenchServeArgs),
    /// A server with a catalogue of many objects (copies of a store's): disk, resident
    /// memory with all loaded, estimate latency of a not-yet-loaded object and a loaded one.
    Catalogue(super::bench_catalogue::BenchCatalogueArgs),
    /// Object store costs: bytes per object (f16, PCA), put time, cold and warm loads.
    Store(super::bench_store::BenchStoreArgs),
    /// What descriptor size costs: mutual-NN matching (GEMM) per query against pools of
    /// template patches, and the PCA's fit and projection.
    Matching(super::bench_matching::BenchMatchingArgs),
    /// The tracker on generated sequences: ms per frame, MSSD recall, losses.
    Track(super::bench_track::BenchTrackArgs),
    /// The depth fit (RGB-D refinement) alone on generated cases: errors after it, time;
    /// `--dump` writes the cases for a peer ICP (tools/bench/icp_peer.sh).
    DepthFit(super::bench_depth_fit::BenchDepthFitArgs),
    /// The symmetry finder on meshes: what it finds, how long it takes, and whether it
    /// agrees with a BOP models_info.json.
    Symmetries(super::bench_symmetries::BenchSymmetriesArgs),
    /// A box's mask proposals on a BOP dataset's boxes: ms per source and IoU with the
    /// true masks, the wall time of all of them per box.
    Proposals(super::bench_proposals::BenchProposalsArgs),
    /// Renders per second.
    Render {
        #[arg(long)]
        mesh: Option<PathBuf>,
        #[arg(long)]
        units: Option<Units>,
        #[arg(long, default_value_t = 512)]
        size: u32,
        #[arg(long, default_value_t = 100)]
        count: usize,
        /// Draw both sides of closed meshes too (as before back-face culling).
        #[arg(long)]
        two_sided: bool,
        /// Draw every triangle as the mesh gives it: both sides, repeated faces again.
        #[arg(long)]
        every_triangle: bool,
    },
    /// Loads and onboards every mesh under a folder; prints vertices, faces, load time,
    /// onboarding time and model size.
    Onboard {
        /// Folder searched recursively for .ply/.obj/.gltf/.glb files.
        #[arg(long)]
        data: PathBuf,
        /// Units of PLY/OBJ files outside BOP model folders (BOP models, next to a
        /// models_info.json, are mm by the BOP format).
        #[arg(long)]
        default_units: Units,
        /// Object store the models are put into (default: a temporary SQLite store,
        /// removed afterwards).
        #[arg(long)]
        store: Option<String>,
        /// Only meshes whose path contains this text.
        #[arg(long)]
        filter: Option<String>,
    },
}

pub fn run(cmd: BenchCommand) -> Result<()> {
    match cmd {
        BenchCommand::Reid { mesh, units, pairs, seed } => reid(mesh_or_box(mesh, units)?, pairs, seed),
        BenchCommand::Estimate(a) => super::bench_estimate::run(a),
        BenchCommand::Refine(a) => super::bench_refine::run(a),
        BenchCommand::Detect(a) => super::bench_detect::run(a),
        BenchCommand::Backbone(a) => super::bench_backbone::run(a),
        BenchCommand::Store(a) => super::bench_store::run(a),
        BenchCommand::Catalogue(a) => super::bench_catalogue::run(a),
        BenchCommand::Matching(a) => super::bench_matching::run(a),
        BenchCommand::Track(a) => super::bench_track::run(a),
        BenchCommand::DepthFit(a) => super::bench_depth_fit::run(a),
        BenchCommand::Symmetries(a) => super::bench_symmetries::run(a),
        BenchCommand::Proposals(a) => super::bench_proposals::run(a),
        BenchCommand::Serve(a) => super::bench_serve::run(a),
        BenchCommand::Render { mesh, units, size, count, two_sided, every_triangle } => {
            let config = crate::render::RendererConfig { cull_closed_meshes: !(two_sided || every_triangle), drop_repeated_faces: !every_triangle, ..Default::default() };
            render(mesh_or_box(mesh, units)?, size, count, config)
        }
        BenchCommand::Onboard { data, default_units, store, filter } => onboard_table(&data, default_units, store, filter),
    }
}

fn mesh_or_box(path: Option<PathBuf>, units: Option<Units>) -> Result<Mesh> {
    Ok(match path {
        Some(p) => load_mesh(&p, units)?,
        None => textured_box([0.10, 0.06, 0.16], 3),
    })
}

/// Backbone variants compared in docs/backbone.md.
fn variants() -> Vec<(&'static str, EmbeddedConfig)> {
    let d = EmbeddedConfig::default();
    vec![
        ("sift-like: signed HOG + colour", EmbeddedConfig { signed_orientation: true, shape_weight: 0.0, smoothing_passes: 1, ..d.clone() }),
        ("unsigned HOG only", EmbeddedConfig { color_weight: 0.0, shape_weight: 0.0, ..d.clone() }),
        ("silhouette context only", EmbeddedConfig { hog_weight: 0.0, color_weight: 0.0, ..d.clone() }),
        ("HOG + colour + 1 silhouette", EmbeddedConfig { shape_weight: 1.0, ..d.clone() }),
        ("HOG + colour + 3 silhouette", EmbeddedConfig { shape_weight: 3.0, ..d.clone() }),
        ("HOG + 2 silhouette, 1 smoothing", EmbeddedConfig { color_weight: 0.0, smoothing_passes: 1, ..d.clone() }),
        ("HOG + colour + 2 silhouette (default)", d),
    ]
}

fn reid(mesh: Mesh, pairs: usize, seed: u64) -> Result<()> {
    let pool = super::open_renderer(1)?;
    let t = Instant::now();
    let set = ReidSet::build(&mesh, &pool, pairs, seed)?;
    println!("patch re-identification on {} ({pairs} pairs per setting, seed {seed}; built in {:.1} s)", mesh.name(), t.elapsed().as_secs_f64());
    println!("{:<38} {:>16} {:>16} {:>16}", "backbone", "neighbour views", "render-to-real", "both at once");
    for (name, cfg) in variants() {
        let bb = EmbeddedBackbone::new(cfg).map_err(anyhow::Error::msg)?;
        let s = set.score(&bb, 0.5)?;
        println!(
            "{name:<38} {:>15.1}% {:>15.1}% {:>15.1}%   ({} / {} patches)",
            100.0 * s.neighbour_views,
            100.0 * s.render_to_real,
            100.0 * s.neighbour_across_gap,
            s.patches_neighbour,
            s.patches_gap
        );
    }
    Ok(())
}

fn render(mesh: Mesh, size: u32, count: usize, config: crate::render::RendererConfig) -> Result<()> {
    if count == 0 || size == 0 {
        bail!("--count and --size must be positive");
    }
    let drawn = crate::mesh::surface::drawn_surface(&mesh, config.drop_repeated_faces);
    let pool = super::open_renderer_with(1, config.clone())?;
    let c = (size as f64 - 1.0) * 0.5;
    let k = crate::geometry::Intrinsics::new(size as f64, size as f64, c, c, size, size)?;
    let centre = nalgebra::Vector3::from(mesh.bbox_center());
    let d = fitted_distance(mesh.diameter() * 0.5, k.fx, size as f64 * 0.5, 0.9);
    let dirs = crate::geometry::icosphere(2);
    let views: Vec<_> = (0..count).map(|i| (view_pose(&dirs[i % dirs.len()], 0.0, &centre, d), k)).collect();
    pool.render(&mesh, &views[0].0, &k, &RenderOptions::default())?; // upload + warm-up
    let t = Instant::now();
    pool.render_batch(&mesh, &views, &RenderOptions::default())?;
    let s = t.elapsed().as_secs_f64();
    println!(
        "{count} renders of {} ({} triangles, {} drawn, {}) at {size}×{size} on {}: {:.1} renders/s ({:.1} ms each, RGB + depth + mask read back)",
        mesh.name(),
        mesh.triangles().len(),
        drawn.triangles.len(),
        if config.cull_closed_meshes && drawn.closed {
            "closed: one-sided"
        } else if drawn.closed {
            "closed, drawn two-sided"
        } else {
            "open: two-sided"
        },
        pool.describe(),
        count as f64 / s,
        1e3 * s / count as f64
    );
    Ok(())
}

fn find_meshes(dir: &Path, out: &mut Vec<PathBuf>) {
    let Ok(rd) = std::fs::read_dir(dir) else { return };
    let mut entries: Vec<PathBuf> = rd.flatten().map(|e| e.path()).collect();
    entries.sort();
    for p in entries {
        if p.is_dir() {
            find_meshes(&p, out);
        } else if matches!(p.extension().and_then(|e| e.to_str()).map(|e| e.to_ascii_lowercase()).as_deref(), Some("ply" | "obj" | "gltf" | "glb")) {
            out.push(p);
        }
    }
}

fn units_for(path: &Path, default_units: Units) -> Option<Units> {
    let ext = path.extension().and_then(|e| e.to_str()).unwrap_or("").to_ascii_lowercase();
    if ext == "gltf" || ext == "glb" {
        None
    } else if path.parent().is_some_and(|d| d.join("models_info.json").is_file()) {
        Some(Units::Mm)
    } else {
        Some(default_units)
    }
}

fn onboard_table(data: &Path, default_units: Units, store: Option<String>, filter: Option<String>) -> Result<()> {
    let mut meshes = Vec::new();
    find_meshes(data, &mut meshes);
    meshes.retain(|p| filter.as_ref().is_none_or(|f| p.to_string_lossy().contains(f.as_str())));
    if meshes.is_empty() {
        bail!("no meshes under {}", data.display());
    }
    let temporary = match store {
        Some(_) => None,
        None => Some(tempfile_dir()?),
    };
    let url = store.unwrap_or_else(|| format!("sqlite://{}", temporary.as_ref().expect("set").join("objects.db").display()));
    let result = crate::store::open(&url).map_err(anyhow::Error::from).and_then(|store| onboard_rows(data, default_units, &meshes, store.as_ref()));
    if let Some(t) = temporary {
        let _ = std::fs::remove_dir_all(&t);
    }
    result
}

fn onboard_rows(data: &Path, default_units: Units, meshes: &[PathBuf], store: &dyn crate::store::ObjectStore) -> Result<()> {
    let backbone = EmbeddedBackbone::new(EmbeddedConfig::default()).map_err(anyhow::Error::msg)?;
    let pool = super::open_renderer(crate::render::RenderPool::DEFAULT_SIZE)?;
    let config = OnboardConfig::default();
    println!("{}", store.url());
    println!(
        "| mesh | units | vertices | faces | diameter (mm) | load (s) | onboarding (s) | renders (s) | views (s; crops / features / points, % of thread time) | contour model (s) | detector (s) | symmetries (s) | store put (s) | templates | patches | model (MB) | of which contour model (MB) |"
    );
    println!("|---|---|---:|---:|---:|---:|---:|---:|---|---:|---:|---:|---:|---:|---:|---:|---:|");
    for path in meshes {
        let units = units_for(path, default_units);
        let t = Instant::now();
        let mesh = match load_mesh(path, units) {
            Ok(m) => m,
            Err(e) => {
                println!("| {} | | | | | | failed: {e} | | | | | | | | | | |", path.display());
                continue;
            }
        };
        let load_s = t.elapsed().as_secs_f64();
        let id: String = path.file_stem().and_then(|s| s.to_str()).unwrap_or("mesh").chars().map(|c| if c.is_ascii_alphanumeric() { c } else { '_' }).collect();
        let t = Instant::now();
        let (model, profile) = onboard_profiled(&id, &mesh, &config, &backbone, &pool, &|_| {}, &Default::default())?;
        let onboard_s = t.elapsed().as_secs_f64();
        let contour_mb = model.contours.get().map_or(0.0, |c| c.memory_bytes() as f64 / 1e6);
        let shares = profile.view_shares;
        let views = format!("{:.1} ({:.0} / {:.0} / {:.0} %)", profile.views_s, 100.0 * shares.crops, 100.0 * shares.features, 100.0 * shares.points);
        let t = Instant::now();
        let info = store.put(&model, true)?;
        let put_s = t.elapsed().as_secs_f64();
        let mb = info.bytes as f64 / 1e6;
        println!(
            "| {} | {} | {} | {} | {:.1} | {load_s:.2} | {onboard_s:.1} | {:.1} | {views} | {:.1} | {:.1} | {:.1} | {put_s:.2} | {} | {} | {mb:.1} | {contour_mb:.1} |",
            path.strip_prefix(data).unwrap_or(path).display(),
            units.map(|u| u.as_str()).unwrap_or("m (glTF)"),
            mesh.positions().len(),
            mesh.triangles().len(),
            mesh.diameter() * 1e3,
            profile.renders_s,
            profile.contours_s,
            profile.detector_s,
            profile.symmetries_s,
            model.template_count(),
            model.patch_count()
        );
    }
    Ok(())
}

fn tempfile_dir() -> Result<PathBuf> {
    let p = std::env::temp_dir().join(format!("b2tf-bench-{}", std::process::id()));
    std::fs::create_dir_all(&p)?;
    Ok(p)
}
