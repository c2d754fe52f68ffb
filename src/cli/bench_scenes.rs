//! What `bench estimate` and `bench refine` share: the backbone, the meshes and the
//! generated scenes they are measured on, and the store that caches the onboarded models.

use crate::mesh::Units;
use std::path::PathBuf;

#[derive(clap::Args, Debug)]
pub struct BenchSceneArgs {
    #[command(flatten)]
    pub backbone: super::backbone_args::BackboneArgs,
    /// Mesh files to place in the scenes (default: the generated sample box).
    #[arg(long = "mesh")]
    pub meshes: Vec<PathBuf>,
    /// Length unit of the PLY/OBJ meshes.
    #[arg(long)]
    pub units: Option<Units>,
    /// Generated images; each holds --objects-per-image instances.
    #[arg(long, default_value_t = 25)]
    pub images: usize,
    #[arg(long, default_value_t = 2)]
    pub objects_per_image: usize,
    /// Largest hidden share of an instance's silhouette.
    #[arg(long, default_value_t = 0.3)]
    pub max_occlusion: f64,
    /// Smallest hidden share of every instance (occluders are added until it is reached):
    /// for measuring heavily occluded objects, e.g. 0.5 with --max-occlusion 0.8.
    #[arg(long, default_value_t = 0.0)]
    pub min_occlusion: f64,
    /// Object diameter as a share of the image height, drawn per instance: MIN,MAX.
    #[arg(long, value_parser = parse_range, default_value = "0.10,0.40")]
    pub fill: (f64, f64),
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Strip the meshes' textures and colours, in the scenes and the templates alike: the
    /// case of an untextured part (a grey casting, a plain bottle).
    #[arg(long)]
    pub untextured: bool,
    /// Render the scenes at this many times the resolution and average down (1, 3 or 5):
    /// outlines blend into the background as a camera's pixels integrate them, where at 1
    /// they move in whole-pixel steps, as the masks do.
    #[arg(long, default_value_t = 1)]
    pub supersample: u32,
    /// The scenes' depth as the renderer gives it, exact, instead of what a Kinect-class
    /// depth camera measures (noise, shadows, holes, steps: `depth::sensor`).
    #[arg(long)]
    pub exact_depth: bool,
    /// Object store that caches onboarded objects between runs.
    #[arg(long, default_value = "dir://out/bench-models")]
    pub store: String,
}

impl BenchSceneArgs {
    /// The meshes to place, named by file stem; bare and named `…-untextured` with
    /// `--untextured` (the name the gap's untextured templates are cached under).
    pub fn load_meshes(&self) -> anyhow::Result<Vec<(String, crate::mesh::Mesh)>> {
        let meshes = bench_meshes(&self.meshes, self.units)?;
        Ok(if self.untextured { meshes.into_iter().map(|(n, m)| (format!("{n}-untextured"), m.without_appearance())).collect() } else { meshes })
    }

    /// The scene generator's settings; `harsh`: the scene side of the render-to-real gap.
    /// Checked here, before any object is onboarded, so that a bad flag fails at once.
    pub fn scene_config(&self, harsh: bool) -> anyhow::Result<crate::eval::scenes::SceneConfig> {
        let cfg = crate::eval::scenes::SceneConfig {
            images: self.images,
            objects_per_image: self.objects_per_image,
            max_occlusion: self.max_occlusion,
            min_occlusion: self.min_occlusion,
            fill_range: self.fill,
            render_to_real_gap: harsh,
            seed: self.seed,
            supersampling: self.supersample,
            depth_sensor: super::depth_sensor(self.exact_depth),
            ..Default::default()
        };
        cfg.validate().map_err(|e| anyhow::anyhow!("scene config: {e}"))?;
        Ok(cfg)
    }
}

/// `MIN,MAX` shares, 0 < MIN ≤ MAX ≤ 1 (occlusion ranges).
pub(super) fn parse_range(s: &str) -> Result<(f64, f64), String> {
    let (a, b) = s.split_once(',').ok_or_else(|| format!("expected MIN,MAX, got {s:?}"))?;
    let (a, b) = (a.trim().parse::<f64>().map_err(|e| e.to_string())?, b.trim().parse::<f64>().map_err(|e| e.to_string())?);
    if !(0.0 < a && a <= b && b <= 1.0) {
        return Err(format!("need 0 < MIN ≤ MAX ≤ 1, got {a},{b}"));
    }
    Ok((a, b))
}

/// The benchmark's meshes, named by file stem (the procedural sample box without any).
pub(super) fn bench_meshes(paths: &[std::path::PathBuf], units: Option<crate::mesh::Units>) -> anyhow::Result<Vec<(String, crate::mesh::Mesh)>> {
    if paths.is_empty() {
        return Ok(vec![("box".into(), crate::mesh::procedural::textured_box([0.10, 0.06, 0.16], 3))]);
    }
    paths.iter().map(|p| Ok((p.file_stem().and_then(|s| s.to_str()).unwrap_or("mesh").replace(' ', "_"), crate::mesh::load_mesh(p, units)?))).collect()
}
