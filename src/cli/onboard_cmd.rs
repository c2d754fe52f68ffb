use crate::geometry::symmetry::{parse_models_info, KnownSymmetries, SymmetrySource};
use crate::geometry::ViewSampling;
use crate::mesh::{load_mesh, Units};
use crate::onboard::{onboard, OnboardConfig};
use anyhow::{Context, Result};
use std::path::PathBuf;
use std::time::Instant;

#[derive(clap::Args, Debug)]
pub struct OnboardArgs {
    /// Mesh file: .ply, .obj, .gltf or .glb.
    #[arg(long)]
    pub mesh: PathBuf,
    /// Length unit of a PLY or OBJ file (mm, cm, m); glTF is metres by specification.
    #[arg(long)]
    pub units: Option<Units>,
    /// Object id (1–64 of A–Z a–z 0–9 - _ .).
    #[arg(long)]
    pub id: String,
    /// Object store: sqlite://PATH.db, dir://PATH or s3://BUCKET/PREFIX (default: $B2TF_STORE, else
    /// sqlite://~/.local/share/b2tfpose/objects.db).
    #[arg(long)]
    pub store: Option<String>,
    /// Icosphere subdivision level (0–3: 12, 42, 162, 642 viewpoints).
    #[arg(long, default_value_t = 2)]
    pub level: u32,
    /// In-plane rotations per viewpoint.
    #[arg(long, default_value_t = 12)]
    pub in_plane: u32,
    /// PCA compression of the patch descriptors: `auto` keeps descriptors of up to 256
    /// dims (the embedded backbone's) and compresses wider ones (DINOv3) to at most 256
    /// components within a 360 MB budget; `off` keeps all (f16); or a component count.
    #[arg(long, default_value = "auto")]
    pub pca: crate::onboard::PcaSetting,
    /// How the patch descriptors are stored: `f16`, or product-quantised on the object's
    /// own patches, `pq4` (one byte per four values: an eighth of f16's bytes) or `pq2`
    /// (a quarter); the quantised ones cost accuracy (docs/store.md).
    #[arg(long, value_enum, default_value = "f16")]
    pub descriptors: crate::onboard::DescriptorCoding,
    /// Which templates keep patch rows: `per-view` (each view's in-plane turns share its
    /// unturned template's rows, about a twelfth of the bytes at 12 turns; estimation then
    /// encodes the query once per turn it needs), `per-template` (every template its own
    /// rows), or `auto`: per view with the embedded backbone (whose turned queries cost
    /// about 20 ms of one core an estimate), per template with an ONNX one (docs/store.md).
    #[arg(long, value_enum, default_value = "auto")]
    pub patch_rows: crate::onboard::PatchRows,
    /// Replace an existing object with the same id.
    #[arg(long)]
    pub replace: bool,
    /// The object's symmetries from a BOP `models_info.json`, as FILE:OBJ_ID (translations
    /// in the mesh's units), instead of those onboarding finds from the mesh.
    #[arg(long, value_name = "FILE:OBJ_ID")]
    pub symmetries: Option<String>,
    /// Number of render contexts.
    #[arg(long, default_value_t = crate::render::RenderPool::DEFAULT_SIZE)]
    pub render_pool: usize,
    #[command(flatten)]
    pub backbone: super::backbone_args::BackboneArgs,
}

pub fn run(a: OnboardArgs) -> Result<()> {
    let t0 = Instant::now();
    let mesh = load_mesh(&a.mesh, a.units)?;
    let load_s = t0.elapsed().as_secs_f64();
    let given = a.symmetries.as_deref().map(|s| symmetries_from_models_info(s, mesh.source_units())).transpose()?;
    let config = OnboardConfig { views: ViewSampling { level: a.level, in_plane_steps: a.in_plane }, pca: a.pca, descriptors: a.descriptors, patch_rows: a.patch_rows, ..Default::default() };
    config.views.validate().map_err(anyhow::Error::msg)?;
    crate::onboard::validate_object_id(&a.id)?;
    let store = crate::store::open(&a.store.clone().unwrap_or_else(crate::store::default_url))?;
    if store.exists(&a.id)? && !a.replace {
        anyhow::bail!("object {:?} already exists in {}; pass --replace to overwrite it", a.id, store.url());
    }
    let backbone = a.backbone.open()?;
    a.pca.check(backbone.identity().local_dim as usize).map_err(anyhow::Error::msg)?;
    let pool = super::open_renderer(a.render_pool)?;
    let total = (crate::geometry::icosphere(a.level).len() as u32 * a.in_plane) as u64;
    let pb = super::progress::bar(total, "onboarding");
    let t1 = Instant::now();
    let mut model = onboard(&a.id, &mesh, &config, backbone.as_ref(), &pool, &|p| pb.set_position(p.templates_done as u64))?;
    pb.finish_and_clear();
    if given.is_some() {
        model.symmetries = given;
    }
    let onboard_s = t1.elapsed().as_secs_f64();
    let t2 = Instant::now();
    let info = store.put(&model, a.replace).context("saving the object model")?;
    let store_s = t2.elapsed().as_secs_f64();
    println!(
        "onboarded {:?}: {} templates, {} patches, diameter {:.1} mm, backbone {} ({})",
        a.id,
        model.template_count(),
        model.patch_count(),
        model.diameter() * 1e3,
        backbone.identity().name,
        backbone.identity().weights_hash
    );
    if let Some(s) = &model.symmetries {
        println!("symmetries: {}", s.describe());
    }
    let stored = match &model.patch_descriptors {
        crate::onboard::PatchDescriptors::Half(_) => "f16".to_string(),
        crate::onboard::PatchDescriptors::Quantized { quantizer, .. } => format!("{} code bytes each", quantizer.subspaces),
        crate::onboard::PatchDescriptors::Int8 { .. } => "int8 with a scale each".to_string(),
    };
    match &model.pca {
        Some(p) => println!("patch descriptors: {} PCA components of {} (--pca {}), {stored}", p.output_dim, p.input_dim, a.pca),
        None => println!("patch descriptors: all {} dimensions (--pca {}), {stored}", model.local_dim, a.pca),
    }
    if model.rows_per_view() {
        println!("patch rows: per view, shared by its {} in-plane turns", model.config.views.in_plane_steps);
    }
    println!("mesh load {load_s:.2} s, onboarding {onboard_s:.1} s, storing {store_s:.2} s; {:.1} MB in {}", info.bytes as f64 / 1e6, store.url());
    Ok(())
}

/// `FILE:OBJ_ID` of a BOP `models_info.json`: that object's symmetries, in metres.
pub fn symmetries_from_models_info(arg: &str, units: Units) -> Result<KnownSymmetries> {
    let (file, id) = arg.rsplit_once(':').ok_or_else(|| anyhow::anyhow!("--symmetries {arg:?}: expected FILE:OBJ_ID (a BOP models_info.json and the object's number in it)"))?;
    let id: u32 = id.trim().parse().map_err(|_| anyhow::anyhow!("--symmetries {arg:?}: object id {id:?} is not a number"))?;
    let text = std::fs::read_to_string(file).with_context(|| format!("--symmetries: reading {file}"))?;
    let all = parse_models_info(&text).with_context(|| format!("--symmetries: {file}"))?;
    let found = all.get(&id).ok_or_else(|| anyhow::anyhow!("--symmetries: {file} has no object {id} (it has {})", all.keys().map(|k| k.to_string()).collect::<Vec<_>>().join(", ")))?;
    Ok(KnownSymmetries { source: SymmetrySource::ModelsInfo, symmetries: found.scaled(units.to_metres()) })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn symmetries_come_from_models_info_in_metres_and_bad_arguments_are_named() {
        let dir = tempfile::tempdir().unwrap();
        let file = dir.path().join("models_info.json");
        std::fs::write(&file, r#"{"3": {"diameter": 80, "symmetries_continuous": [{"axis": [0, 0, 1], "offset": [0, 0, 20]}]}, "4": {"diameter": 50}}"#).unwrap();
        let f = file.display();
        let got = symmetries_from_models_info(&format!("{f}:3"), Units::Mm).unwrap();
        assert_eq!(got.source, SymmetrySource::ModelsInfo);
        assert_eq!(got.symmetries.continuous[0].offset, [0.0, 0.0, 0.02], "millimetres become metres");
        assert!(symmetries_from_models_info(&format!("{f}:4"), Units::Mm).unwrap().symmetries.is_empty());
        for (arg, needle) in [
            (format!("{f}"), "FILE:OBJ_ID"),
            (format!("{f}:x"), "not a number"),
            (format!("{f}:9"), "has no object 9 (it has 3, 4)"),
            ("/nonexistent/info.json:1".to_string(), "/nonexistent/info.json"),
        ] {
            let e = format!("{:#}", symmetries_from_models_info(&arg, Units::Mm).unwrap_err());
            assert!(e.contains(needle), "{arg}: {e}");
        }
        std::fs::write(&file, r#"{"1": {"symmetries_discrete": [[1, 0, 0]]}}"#).unwrap();
        let e = format!("{:#}", symmetries_from_models_info(&format!("{f}:1"), Units::Mm).unwrap_err());
        assert!(e.contains("16"), "{e}");
    }
}
