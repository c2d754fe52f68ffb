//! The small real object every check uses, and copies of it under other ids, generations
//! and sizes.

use super::*;

/// The small real object every check uses, onboarded once per process (a textured box, 24
/// templates at 128 px). `None` without a GPU adapter (the check then skips) unless
/// `B2TF_REQUIRE_GPU` is set, as in the crate's other GPU tests.
pub(crate) fn model() -> Option<&'static ObjectModel> {
    static MODEL: OnceLock<Option<ObjectModel>> = OnceLock::new();
    MODEL
        .get_or_init(|| {
            let mut m = b2tfpose::onboard::test_model::small_model()?.clone();
            assert!(m.mesh.has_texture(), "the test object should carry a texture, so that textures are stored too");
            // Symmetries of every kind, so that storing and listing them is checked (the
            // textured box itself has none).
            let flip = DiscreteSymmetry::from_row_major_4x4(&[1.0, 0.0, 0.0, 0.0, 0.0, -1.0, 0.0, 0.01, 0.0, 0.0, -1.0, 0.0, 0.0, 0.0, 0.0, 1.0]);
            let axis = ContinuousSymmetry { axis: [0.0, 0.0, 1.0], offset: [0.0, 0.005, 0.0] };
            m.symmetries = Some(KnownSymmetries { source: SymmetrySource::ModelsInfo, symmetries: ObjectSymmetries { discrete: vec![flip], continuous: vec![axis] } });
            Some(m)
        })
        .as_ref()
}

pub(crate) fn with_id(m: &ObjectModel, id: &str) -> ObjectModel {
    ObjectModel { object_id: id.to_string(), ..m.clone() }
}

/// Version `generation` of object `id`, marked in both halves of the encoded form: the
/// manifest (`config.render_size`) and the tensors (the first silhouette word). A reader
/// that combined a manifest of one version with tensors of another fails `assert_same`
/// against the version its manifest names.
pub(crate) fn generation(base: &ObjectModel, id: &str, generation: u32) -> ObjectModel {
    let mut m = with_id(base, id);
    m.config.render_size = 1000 + generation;
    m.silhouettes.to_mut()[0] = u64::from(generation);
    m
}

/// The generation a loaded object claims in its manifest.
pub(crate) fn generation_of(m: &ObjectModel) -> u32 {
    m.config.render_size.checked_sub(1000).unwrap_or_else(|| panic!("object {:?} carries no generation mark", m.object_id))
}

/// Bytes of the model's tensor arrays (what dominates its encoded size).
pub(crate) fn tensor_bytes(m: &ObjectModel) -> usize {
    m.global.len() * 4 + m.patch_descriptors.memory_bytes() + m.patch_points.len() * 12 + m.patch_cells.len() * 2 + m.silhouettes.len() * 8
}

/// Size of the big object of the kill test: large enough that its put takes a good fraction
/// of a second even where writes are fast, small enough for a debug build.
pub(crate) const BIG_OBJECT_BYTES: usize = 150 << 20;

/// How many copies of the small model make the big one.
pub(crate) fn big_copies(m: &ObjectModel) -> usize {
    BIG_OBJECT_BYTES.div_ceil(tensor_bytes(m).max(1))
}

/// A valid, honestly bigger model: the templates with their patches, descriptors and
/// silhouettes repeated `copies` times, each copy's templates pointing at its own patch rows
/// (what `ObjectModel::validate` requires to stay consistent).
pub(crate) fn enlarged(m: &ObjectModel, id: &str, copies: usize) -> ObjectModel {
    let patches = u32::try_from(m.patch_count()).expect("patch count");
    let mut big = with_id(m, id);
    big.templates = (0..copies as u32).flat_map(|k| m.templates.iter().map(move |t| Template { patch_start: t.patch_start + k * patches, ..t.clone() })).collect();
    big.global = m.global.repeat(copies);
    big.patch_descriptors = match &m.patch_descriptors {
        PatchDescriptors::Half(v) => PatchDescriptors::Half(v.repeat(copies).into()),
        PatchDescriptors::Quantized { quantizer, codes } => PatchDescriptors::Quantized { quantizer: quantizer.clone(), codes: codes.repeat(copies).into() },
        PatchDescriptors::Int8 { codes, scales } => PatchDescriptors::Int8 { codes: codes.repeat(copies).into(), scales: scales.repeat(copies).into() },
    };
    big.patch_points = match &m.patch_points {
        PatchPoints::Exact(p) => PatchPoints::Exact(p.repeat(copies).into()),
        PatchPoints::Grid { grid, steps } => PatchPoints::Grid { grid: *grid, steps: steps.repeat(copies).into() },
    };
    big.patch_cells = m.patch_cells.repeat(copies).into();
    big.silhouettes = m.silhouettes.repeat(copies).into();
    big.validate().expect("the enlarged model is consistent");
    big
}

/// Every field of a model that the store keeps, compared.
#[track_caller]
pub(crate) fn assert_same(expected: &ObjectModel, got: &ObjectModel) {
    let id = &expected.object_id;
    assert_eq!(got.object_id, *id);
    assert_eq!(got.backbone, expected.backbone, "{id}: backbone");
    assert_eq!(got.config, expected.config, "{id}: config");
    assert_eq!(got.render_intrinsics, expected.render_intrinsics, "{id}: render intrinsics");
    assert_eq!(got.grid, expected.grid, "{id}: grid");
    assert_eq!((got.global_dim, got.local_dim), (expected.global_dim, expected.local_dim), "{id}: descriptor sizes");
    assert!(got.templates == expected.templates, "{id}: templates differ");
    assert!(got.global == expected.global, "{id}: global descriptors differ");
    assert!(got.patch_descriptors == expected.patch_descriptors, "{id}: patch descriptors differ");
    assert!(got.patch_points == expected.patch_points, "{id}: patch points differ");
    assert!(got.patch_cells == expected.patch_cells, "{id}: patch cells differ");
    assert!(got.silhouettes == expected.silhouettes, "{id}: silhouettes differ");
    assert!(got.contours.get() == expected.contours.get(), "{id}: contour models differ");
    assert_eq!(got.symmetries, expected.symmetries, "{id}: symmetries");
    let (a, b) = (&expected.mesh, &got.mesh);
    assert_eq!(b.name(), a.name(), "{id}: mesh name");
    assert_eq!(b.source_units(), a.source_units(), "{id}: mesh units");
    assert!(b.positions() == a.positions() && b.normals() == a.normals() && b.triangles() == a.triangles(), "{id}: mesh geometry differs");
    assert!(b.colors() == a.colors() && b.uvs() == a.uvs() && b.parts() == a.parts(), "{id}: mesh attributes differ");
    assert_eq!(b.materials().len(), a.materials().len(), "{id}: materials");
    for (i, (ma, mb)) in a.materials().iter().zip(b.materials()).enumerate() {
        assert_eq!((&mb.name, mb.base_color), (&ma.name, ma.base_color), "{id}: material {i}");
        let pixels = |m: &b2tfpose::mesh::Material| m.texture.as_ref().map(|t| (t.dimensions(), t.pixels().unwrap().as_raw().clone()));
        assert!(pixels(mb) == pixels(ma), "{id}: texture of material {i} differs");
    }
}

pub(crate) fn now_unix_s() -> u64 {
    SystemTime::now().duration_since(UNIX_EPOCH).expect("clock after 1970").as_secs()
}
