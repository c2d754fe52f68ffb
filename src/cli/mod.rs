//! The `b2tf` command line: argument parsing and one file per command.

pub mod backbone_args;
pub mod bench;
pub mod bench_backbone;
pub mod bench_catalogue;
pub mod bench_depth_fit;
pub mod bench_detect;
pub mod bench_estimate;
pub mod bench_margin;
pub mod bench_matching;
pub mod bench_one_call;
mod bench_profile;
pub mod bench_proposals;
pub mod bench_refine;
pub mod bench_scenes;
pub mod bench_serve;
pub mod bench_stability;
pub mod bench_store;
pub mod bench_symmetries;
pub mod bench_track;
pub mod bench_track_grpc;
pub mod bop_cmd;
pub mod bop_eval_cmd;
pub mod camera_file;
pub mod child_server;
pub mod demo_client;
pub mod demo_cmd;
pub mod demo_scene;
pub mod depth_file;
pub mod detect_cmd;
pub mod detect_overlay;
pub mod estimate_cmd;
pub mod object_args;
pub mod objects_cmd;
pub mod onboard_cmd;
pub mod pose_arg;
pub mod progress;
pub mod render_cmd;
pub mod serve_cmd;
pub mod serve_config;
pub mod thread_cpu;
pub mod track_cmd;
pub mod verify_args;

use clap::{Parser, Subcommand};

#[derive(Parser, Debug)]
#[command(name = "b2tf", version, about = "Training-free zero-shot 6DoF pose estimation from one RGB image and a CAD mesh")]
pub struct Cli {
    #[command(subcommand)]
    pub command: Command,
    #[command(flatten)]
    pub telemetry: crate::telemetry::TelemetryArgs,
}

#[derive(Subcommand, Debug)]
pub enum Command {
    /// Onboard a mesh: render templates, extract features and 3D points, save the object model.
    Onboard(onboard_cmd::OnboardArgs),
    /// The whole method on a generated object and scene: onboard, estimate, compare with the truth.
    Demo(demo_scene::DemoArgs),
    /// Find onboarded objects in an image (no mask, no box): BOP default-detections JSON.
    Detect(detect_cmd::DetectArgs),
    /// Estimate an object's pose in an image from one or more candidate masks.
    Estimate(estimate_cmd::EstimateArgs),
    /// Poses through a video (a folder of frames): a full estimate from the first frame's
    /// mask, then frame-to-frame tracking, re-initialised when lost; one JSON line per frame.
    Track(track_cmd::TrackArgs),
    /// Render a mesh at a pose through a camera (RGB, depth and mask PNGs) for debugging.
    Render(render_cmd::RenderArgs),
    /// Write the generated sample object (a textured box, OBJ + MTL + PNG, metres).
    Sample {
        /// Output folder.
        #[arg(long)]
        out: std::path::PathBuf,
        /// Pattern seed.
        #[arg(long, default_value_t = 3)]
        seed: u64,
    },
    /// Run the service: HTTP/JSON and gRPC (onboard and estimate over the network).
    Serve(serve_cmd::ServeArgs),
    /// List, inspect or delete the objects of an object store.
    Objects(objects_cmd::ObjectsArgs),
    /// BOP benchmark: generate a dataset, run the estimator on one, score results (AR).
    #[command(subcommand)]
    Bop(bop_cmd::BopCommand),
    /// Benchmarks that print figures (re-identification, rendering, onboarding).
    #[command(subcommand)]
    Bench(bench::BenchCommand),
}

impl Command {
    /// Log levels when B2TF_LOG / RUST_LOG say nothing: the service logs one line per
    /// request (info); one-shot commands only warnings, since their output is the result
    /// and a progress bar.
    pub fn default_log_filter(&self) -> &'static str {
        match self {
            Command::Serve(_) => "warn,b2tfpose=info",
            _ => "warn",
        }
    }
}

pub fn run(cli: Cli) -> anyhow::Result<()> {
    match cli.command {
        Command::Onboard(a) => onboard_cmd::run(a),
        Command::Demo(a) => demo_cmd::run(a),
        Command::Detect(a) => detect_cmd::run(a),
        Command::Estimate(a) => estimate_cmd::run(a),
        Command::Track(a) => track_cmd::run(a),
        Command::Render(a) => render_cmd::run(a),
        Command::Sample { out, seed } => {
            let mesh = crate::mesh::procedural::textured_box([0.10, 0.06, 0.16], seed);
            let path = crate::mesh::write_obj::write_obj(&mesh, &out, "sample_box")?;
            println!("wrote {} (a 10 × 6 × 16 cm textured box, units m)", path.display());
            Ok(())
        }
        Command::Bench(b) => bench::run(b),
        Command::Bop(b) => bop_cmd::run(b),
        Command::Objects(a) => objects_cmd::run(a),
        Command::Serve(a) => serve_cmd::run(a),
    }
}

/// Renderer pool shared by the commands, with a message that says what to install when
/// no adapter can be found.
/// The depth camera generated scenes and sequences are measured with: Kinect-class, or
/// the renderer's exact depth with `--exact-depth`.
pub fn depth_sensor(exact: bool) -> crate::depth::sensor::SensorModel {
    if exact {
        crate::depth::sensor::SensorModel::exact()
    } else {
        crate::depth::sensor::SensorModel::default()
    }
}

pub fn open_renderer(size: usize) -> anyhow::Result<crate::render::RenderPool> {
    open_renderer_with(size, crate::render::RendererConfig::default())
}

/// `open_renderer` whose renderers keep `objects` meshes uploaded (`RendererConfig::keeping`).
pub fn open_renderer_for(size: usize, objects: usize) -> anyhow::Result<crate::render::RenderPool> {
    open_renderer_with(size, crate::render::RendererConfig::keeping(objects))
}

/// `open_renderer` with other renderer settings.
pub fn open_renderer_with(size: usize, config: crate::render::RendererConfig) -> anyhow::Result<crate::render::RenderPool> {
    Ok(crate::render::RenderPool::new(size, config)?)
}

/// The object `id` from `store` when it was made from this mesh (geometry and appearance)
/// by this backbone with `config` (its `patch_rows` resolved for the backbone); otherwise
/// onboards it (with a progress bar) and puts it there. Benchmarks and the demo reuse
/// models across runs this way.
/// What the benches cache: uncompressed descriptors with every template's own rows, from
/// which any PCA, coding and patch rows are made in memory (as onboarding with them would)
/// without onboarding again.
pub fn bench_cache_config() -> crate::onboard::OnboardConfig {
    use crate::onboard::{DescriptorCoding, OnboardConfig, PatchRows, PcaSetting};
    OnboardConfig { pca: PcaSetting::Off, descriptors: DescriptorCoding::F16, patch_rows: PatchRows::PerTemplate, ..Default::default() }
}

pub fn cached_model(
    id: &str,
    mesh: &crate::mesh::Mesh,
    store: &dyn crate::store::ObjectStore,
    backbone: &dyn crate::features::Backbone,
    pool: &crate::render::RenderPool,
    config: crate::onboard::OnboardConfig,
) -> anyhow::Result<crate::onboard::ObjectModel> {
    use crate::onboard::onboard;
    let config = crate::onboard::OnboardConfig { patch_rows: config.patch_rows.resolve(backbone), ..config };
    if let Ok(mut m) = store.get(id) {
        if m.backbone == backbone.identity() && m.config == config && m.mesh.positions() == mesh.positions() && m.mesh.has_texture() == mesh.has_texture() {
            // Cached by an older version: what it lacks is made as `objects upgrade` makes
            // it, so benchmarks measure what onboarding makes now.
            if m.add_what_older_versions_lacked(pool)? {
                store.put(&m, true)?;
            }
            return Ok(m);
        }
    }
    let total = (crate::geometry::icosphere(config.views.level).len() as u32 * config.views.in_plane_steps) as u64;
    let pb = progress::bar(total, &format!("onboarding {id}"));
    let m = onboard(id, mesh, &config, backbone, pool, &|p| pb.set_position(p.templates_done as u64))?;
    pb.finish_and_clear();
    store.put(&m, true)?;
    Ok(m)
}
