//! An onboarded object: the templates (pose, global descriptor, silhouette) and, for each
//! template, its foreground patches (descriptor, 3D object-frame point, patch index).

use super::contour::ContourModel;
use super::pca_setting::PcaSetting;
use crate::detect::ShapeModel;
use crate::features::BackboneIdentity;
use crate::geometry::symmetry::KnownSymmetries;
use crate::geometry::{CropBox, Intrinsics, PatchGrid, Pose, ViewSampling};
use crate::mesh::Mesh;
use std::sync::{Arc, OnceLock};

/// Version of the model layout; bumped on any change of meaning or layout. 2: optional
/// PCA-compressed patch descriptors (version 1 models load as uncompressed). 3: the contour
/// model (older models load without it and get it computed on first use). 4: the detector's
/// shape templates (older models likewise get them on first use, or `b2tf objects upgrade`).
/// 5: the object's symmetries (older models load with them unknown). 6: product-quantised
/// patch descriptors (`patch_codes` and `pq_centroids` in place of `patch_descriptors`;
/// older models keep their f16 ones). 7: patch points as 16-bit grid steps
/// (`patch_point_steps` and `patch_point_grid` in place of `patch_points`; older models
/// keep their f32 ones) and the contour points and normals likewise compact. 8: patch rows
/// may be held per view (`config.patch_rows`), which a program of format 7 would misread.
/// Optional tensors an older program may ignore without misreading anything (the contour's
/// `contour_plain_share`) do not bump it, so that nodes of both versions can share a store.
pub const MODEL_FORMAT_VERSION: u32 = 8;

/// Side of the stored template silhouettes (crop mask downsampled, 1 bit per cell).
pub const SILHOUETTE_SIZE: usize = 64;
pub const SILHOUETTE_WORDS: usize = SILHOUETTE_SIZE * SILHOUETTE_SIZE / 64;

/// How the templates were made; recorded so that a model can be re-made or compared.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct OnboardConfig {
    pub views: ViewSampling,
    /// Side of the square base renders, pixels.
    pub render_size: u32,
    /// Share of the render's half-width the object's bounding sphere fills.
    pub render_fill: f64,
    /// Crop padding around the mask box, as a fraction of its longer side.
    pub crop_padding: f64,
    /// A patch is foreground when the object covers at least this share of it.
    pub min_coverage: f32,
    /// PCA compression of the patch descriptors as asked for (what was applied is the
    /// model's `pca`). Records before the setting had `pca_dim`: null (keep all) or a count.
    #[serde(default = "PcaSetting::off", alias = "pca_dim")]
    pub pca: PcaSetting,
    /// How the patch descriptors are stored; records before format 6 kept f16.
    #[serde(default = "DescriptorCoding::f16")]
    pub descriptors: DescriptorCoding,
    /// Whether each template holds its own patch rows or the in-plane turns of a view share
    /// the rows of its first; records before format 8 held them per template.
    #[serde(default = "PatchRows::per_template")]
    pub patch_rows: PatchRows,
}

/// Which templates hold patch rows (`b2tf onboard --patch-rows`). The in-plane turns of a
/// view show the same patches turned; per view, they are stored once and estimation turns
/// the query instead (docs/store.md, "Patch rows per view").
/// A model holds one of the first two; `Auto`, the default, asks onboarding to choose.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize, clap::ValueEnum)]
#[serde(rename_all = "kebab-case")]
pub enum PatchRows {
    /// Every template its own rows.
    PerTemplate,
    /// The rows of each view's in-plane-0 template only, shared by its turns.
    PerView,
    /// Per view where the backbone encodes the turned queries at a reduced size (the
    /// embedded one: about 20 ms of one core an estimate, docs/store.md "Per view by
    /// default"), per template where each turn would be another full pass (an ONNX
    /// ViT).
    Auto,
}

impl PatchRows {
    /// What records before format 8 held.
    pub fn per_template() -> Self {
        PatchRows::PerTemplate
    }

    /// `Auto` made per view or per template for `backbone`; the others as they are.
    pub fn resolve(self, backbone: &dyn crate::features::Backbone) -> Self {
        match self {
            PatchRows::Auto if backbone.reduced_input_size().is_some() => PatchRows::PerView,
            PatchRows::Auto => PatchRows::PerTemplate,
            rows => rows,
        }
    }
}

/// How an object's patch descriptors are stored (`b2tf onboard --descriptors`).
/// Measured in docs/store.md ("Compact descriptors"): the product-quantised codings cost
/// accuracy with the embedded backbone, so f16 stays the default.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize, clap::ValueEnum)]
#[serde(rename_all = "snake_case")]
pub enum DescriptorCoding {
    /// f16 values: exact, 2 bytes per value.
    #[default]
    F16,
    /// Product-quantised, one byte per 4 values (an eighth of f16's bytes).
    Pq4,
    /// Product-quantised, one byte per 2 values (a quarter of f16's bytes).
    Pq2,
    /// int8 values with a scale per row (about half of f16's bytes).
    I8,
}

impl DescriptorCoding {
    pub fn f16() -> Self {
        DescriptorCoding::F16
    }
}

// The names are clap's (`--descriptors pq4`), so the CLI, the API and the docs agree.
impl std::fmt::Display for DescriptorCoding {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let name = clap::ValueEnum::to_possible_value(self).expect("no variant is skipped");
        f.write_str(name.get_name())
    }
}

impl std::str::FromStr for DescriptorCoding {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, String> {
        <Self as clap::ValueEnum>::from_str(s.trim(), true).map_err(|_| format!("unknown descriptor coding {s:?} (expected f16, i8, pq2 or pq4)"))
    }
}

// The names are clap's (`--patch-rows per-view`), as for the descriptor codings.
impl std::fmt::Display for PatchRows {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let name = clap::ValueEnum::to_possible_value(self).expect("no variant is skipped");
        f.write_str(name.get_name())
    }
}

impl std::str::FromStr for PatchRows {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, String> {
        <Self as clap::ValueEnum>::from_str(s.trim(), true).map_err(|_| format!("unknown patch rows {s:?} (expected per-template, per-view or auto)"))
    }
}

impl Default for OnboardConfig {
    fn default() -> Self {
        Self {
            views: ViewSampling::default(),
            render_size: 512,
            render_fill: 0.9,
            crop_padding: 0.1,
            min_coverage: 0.5,
            pca: PcaSetting::Auto,
            descriptors: DescriptorCoding::F16,
            patch_rows: PatchRows::Auto,
        }
    }
}

/// One template: a view of the object and where its patches sit in the model's arrays.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Template {
    pub pose: Pose,
    /// Index of the icosphere viewpoint and of the in-plane rotation.
    pub view: u32,
    pub in_plane: u32,
    /// Crop window in the (in-plane rotated) template image.
    pub crop: CropBox,
    /// First patch row in the model's patch arrays, and how many.
    pub patch_start: u32,
    pub patch_count: u32,
}

/// Everything estimation needs about one object.
#[derive(Clone, Debug)]
pub struct ObjectModel {
    pub object_id: String,
    pub backbone: BackboneIdentity,
    pub config: OnboardConfig,
    /// Intrinsics of the base renders (templates share them; in-plane rotations are exact
    /// because fx = fy and the object centre is on the principal point).
    pub render_intrinsics: Intrinsics,
    pub grid: PatchGrid,
    pub mesh: Mesh,
    pub templates: Vec<Template>,
    /// `templates × global_dim`, L2-normalised rows.
    pub global: Vec<f32>,
    pub global_dim: usize,
    /// `patches × local_dim`, L2-normalised rows (after `pca` when there is one), f16 or
    /// product-quantised.
    pub patch_descriptors: super::PatchDescriptors,
    pub local_dim: usize,
    /// The projection applied to the backbone's patch descriptors, if compressed.
    pub pca: Option<super::pca::Pca>,
    /// Object-frame point (metres) behind each patch centre.
    pub patch_points: super::PatchPoints,
    /// Patch index `i·n + j` in its template's crop grid.
    pub patch_cells: super::stored_rows::StoredRows<u16>,
    /// `templates × SILHOUETTE_WORDS` bit-packed crop masks, row-major, LSB first.
    pub silhouettes: super::stored_rows::StoredRows<u64>,
    /// Silhouette contour points per viewpoint, for the contour refiner. Set by onboarding
    /// and loading; objects stored before format 3 get it on first use
    /// (`contour_model_or_build`), once per loaded copy.
    pub contours: OnceLock<Arc<ContourModel>>,
    /// The detector's shape templates. Set by onboarding and loading; objects stored
    /// before format 4 get them on first use (`shape_model_or_build`).
    pub detector: OnceLock<Arc<ShapeModel>>,
    /// The object's symmetries (metres), found by onboarding from the mesh or given by the
    /// user; `None` for objects stored before format 5 (unknown, not "none").
    pub symmetries: Option<KnownSymmetries>,
}

impl ObjectModel {
    pub fn diameter(&self) -> f64 {
        self.mesh.diameter()
    }

    pub fn template_count(&self) -> usize {
        self.templates.len()
    }

    pub fn patch_count(&self) -> usize {
        self.patch_points.len()
    }

    pub fn global_descriptor(&self, t: usize) -> &[f32] {
        &self.global[t * self.global_dim..(t + 1) * self.global_dim]
    }

    /// Template silhouette, bit-packed (`SILHOUETTE_WORDS` words).
    pub fn silhouette_words(&self, t: usize) -> &[u64] {
        &self.silhouettes[t * SILHOUETTE_WORDS..(t + 1) * SILHOUETTE_WORDS]
    }

    /// The contour model, computed now (silhouette renders of the mesh) if the object was
    /// stored without one.
    pub fn contour_model_or_build(&self, renderer: &crate::render::RenderPool) -> Result<Arc<ContourModel>, crate::render::RenderError> {
        self.built_on_first_use(&self.contours, "a contour model (format < 3)", || ContourModel::build(&self.mesh, renderer, &Default::default()))
    }

    /// Whether the contour model was stored before plain runs were kept for objects with
    /// colours (such an object reads no photo edges under `PhotoEdges::Plain`).
    pub fn contour_lacks_plain_runs(&self) -> bool {
        self.mesh.has_colours() && self.contours.get().is_some_and(|c| c.plain_share.is_empty())
    }

    /// Adds what an object stored by an older version lacks and first use does not make:
    /// its symmetries (found from the mesh), grid-coded patch points and, for a printed
    /// object, the contour model's plain runs. `objects upgrade` and the benchmarks' model
    /// cache both use it; true where it changed anything.
    pub fn add_what_older_versions_lacked(&mut self, renderer: &crate::render::RenderPool) -> Result<bool, crate::render::RenderError> {
        let mut changed = !self.patch_points.is_grid();
        self.patch_points.to_grid();
        if self.symmetries.is_none() {
            self.symmetries = Some(super::mesh_symmetries(&self.mesh));
            changed = true;
        }
        if let Some(config) = self.contours.get().filter(|_| self.contour_lacks_plain_runs()).map(|c| c.config) {
            self.contours = OnceLock::from(Arc::new(ContourModel::build(&self.mesh, renderer, &config)?));
            changed = true;
        }
        Ok(changed)
    }

    /// The detector's templates, computed now (renders of the mesh) if the object was stored
    /// without them.
    pub fn shape_model_or_build(&self, renderer: &crate::render::RenderPool) -> Result<Arc<ShapeModel>, crate::render::RenderError> {
        self.built_on_first_use(&self.detector, "detector templates (format < 4)", || ShapeModel::build(&self.mesh, renderer, &Default::default()))
    }

    /// What `cell` holds, or `build`'s result kept there, with a warning saying what an
    /// older object lacked and how to store it.
    fn built_on_first_use<T>(&self, cell: &OnceLock<Arc<T>>, what: &str, build: impl FnOnce() -> Result<T, crate::render::RenderError>) -> Result<Arc<T>, crate::render::RenderError> {
        if let Some(c) = cell.get() {
            return Ok(c.clone());
        }
        let t = std::time::Instant::now();
        let built = Arc::new(build()?);
        tracing::warn!("object {:?} was stored without {what}: computed it in {:.1} s for this session; `b2tf objects upgrade` stores it", self.object_id, t.elapsed().as_secs_f64());
        // Two threads may race here; both results are equal, the first one stays.
        let _ = cell.set(built);
        Ok(cell.get().expect("just set").clone())
    }

    /// Approximate heap bytes held: the arrays, the mesh and its textures (for cache budgets).
    pub fn memory_bytes(&self) -> usize {
        let d = self.mesh.data();
        let mesh = d.positions.len() * 12 + d.normals.len() * 12 + d.colors.len() * 12 + d.uvs.len() * 8 + d.triangles.len() * 12;
        let textures: usize = self.mesh.materials().iter().filter_map(|m| m.texture.as_ref()).map(|t| t.heap_bytes()).sum();
        self.global.len() * 4
            + self.patch_descriptors.memory_bytes()
            + self.patch_points.heap_bytes()
            + self.patch_cells.heap_bytes()
            + self.silhouettes.heap_bytes()
            + self.templates.len() * std::mem::size_of::<Template>()
            + mesh
            + textures
            + self.contours.get().map_or(0, |c| c.memory_bytes())
            + self.detector.get().map_or(0, |d| d.memory_bytes())
    }

    /// Whether the in-plane turns of a view share its first template's patch rows.
    pub fn rows_per_view(&self) -> bool {
        self.config.patch_rows == PatchRows::PerView
    }

    /// The in-plane angle of template `t` (radians): the turn a query needs to meet its
    /// rows when they are shared per view.
    pub fn in_plane_angle(&self, t: usize) -> f64 {
        self.templates[t].in_plane as f64 * std::f64::consts::TAU / self.config.views.in_plane_steps.max(1) as f64
    }

    /// Crop pixel coordinates, in template `t`'s own crop, of the patch `cell` of its rows:
    /// the grid cell's centre, or where the shared row's cell lands once turned.
    pub fn patch_centre_in_template(&self, t: usize, cell: u16) -> (f64, f64) {
        let (cu, cv) = self.grid.centre_of(cell as usize);
        let tp = &self.templates[t];
        if !self.rows_per_view() || tp.in_plane == 0 {
            return (cu, cv);
        }
        let owner = &self.templates[t - tp.in_plane as usize];
        let (bu, bv) = owner.crop.to_image(cu, cv);
        let (u, v) = super::template_camera::in_plane_turn(&self.render_intrinsics, self.in_plane_angle(t)).apply(bu, bv);
        tp.crop.to_crop(u, v)
    }

    /// Query patch descriptors (`n × backbone local_dim`) in the space of the stored ones.
    pub fn to_stored_space<'a>(&self, descriptors: &'a [f32]) -> std::borrow::Cow<'a, [f32]> {
        match &self.pca {
            Some(p) => std::borrow::Cow::Owned(p.project(descriptors)),
            None => std::borrow::Cow::Borrowed(descriptors),
        }
    }

    /// Checks the arrays agree with each other (used after loading).
    pub fn validate(&self) -> Result<(), String> {
        let t = self.templates.len();
        let p = self.patch_points.len();
        let checks = [
            (self.global.len() == t * self.global_dim, "global descriptors"),
            (self.patch_descriptors.shape_ok(self.local_dim) && self.patch_descriptors.rows(self.local_dim) == p, "patch descriptors"),
            (self.patch_cells.len() == p, "patch cells"),
            (self.silhouettes.len() == t * SILHOUETTE_WORDS, "silhouettes"),
            (self.local_dim == self.pca.as_ref().map_or(self.backbone.local_dim as usize, |p| p.output_dim), "local descriptor size vs backbone and PCA"),
            (self.pca.as_ref().is_none_or(|p| p.input_dim == self.backbone.local_dim as usize && p.validate().is_ok()), "PCA arrays"),
        ];
        if let Some((_, what)) = checks.iter().find(|(ok, _)| !ok) {
            return Err(format!("object {:?}: {what} do not match the template/patch counts", self.object_id));
        }
        // Estimation sizes its crops from the grid (`n · patch`): it must be the one the
        // backbone's input and patch sizes give, as onboarding made it.
        if PatchGrid::for_crop(self.backbone.input_size, self.backbone.patch_size).ok() != Some(self.grid) {
            return Err(format!(
                "object {:?}: its {}² grid of {} px patches is not the backbone's ({} px input, {} px patches)",
                self.object_id, self.grid.n, self.grid.patch, self.backbone.input_size, self.backbone.patch_size
            ));
        }
        for (i, tp) in self.templates.iter().enumerate() {
            if tp.patch_start as usize + tp.patch_count as usize > p {
                return Err(format!("object {:?}: template {i} points past the patch arrays", self.object_id));
            }
            if self.rows_per_view() {
                let owner = i.checked_sub(tp.in_plane as usize).map(|o| &self.templates[o]);
                if !owner.is_some_and(|o| o.view == tp.view && o.in_plane == 0 && (o.patch_start, o.patch_count) == (tp.patch_start, tp.patch_count)) {
                    return Err(format!("object {:?}: template {i} does not share its view's patch rows", self.object_id));
                }
            }
        }
        if self.patch_cells.iter().any(|&c| c as usize >= self.grid.len()) {
            return Err(format!("object {:?}: a patch index lies outside the {}² grid", self.object_id, self.grid.n));
        }
        if let Some(c) = self.contours.get() {
            c.validate().map_err(|e| format!("object {:?}: {e}", self.object_id))?;
        }
        if let Some(s) = &self.symmetries {
            s.symmetries.validate().map_err(|e| format!("object {:?}: {e}", self.object_id))?;
        }
        if let Some(d) = self.detector.get() {
            d.validate().map_err(|e| format!("object {:?}: {e}", self.object_id))?;
        }
        Ok(())
    }
}

/// Intersection over union of two bit-packed silhouettes (0 when both are empty).
pub fn silhouette_iou(a: &[u64], b: &[u64]) -> f32 {
    let (mut inter, mut union) = (0u32, 0u32);
    for (x, y) in a.iter().zip(b) {
        inter += (x & y).count_ones();
        union += (x | y).count_ones();
    }
    if union == 0 {
        0.0
    } else {
        inter as f32 / union as f32
    }
}

/// Packs a crop mask into `SILHOUETTE_SIZE²` bits: a cell is set when at least half of it is object.
pub fn pack_silhouette(mask: &image::GrayImage) -> Vec<u64> {
    let s = mask.width() as usize;
    let cell = (s / SILHOUETTE_SIZE).max(1);
    let mut words = vec![0u64; SILHOUETTE_WORDS];
    for ci in 0..SILHOUETTE_SIZE {
        for cj in 0..SILHOUETTE_SIZE {
            let mut sum = 0u32;
            for y in ci * cell..((ci + 1) * cell).min(s) {
                for x in cj * cell..((cj + 1) * cell).min(s) {
                    sum += mask.get_pixel(x as u32, y as u32)[0] as u32;
                }
            }
            if sum * 2 >= 255 * (cell * cell) as u32 {
                let k = ci * SILHOUETTE_SIZE + cj;
                words[k / 64] |= 1 << (k % 64);
            }
        }
    }
    words
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn records_from_before_the_pca_setting_still_read() {
        let current = serde_json::to_value(OnboardConfig::default()).unwrap();
        assert_eq!(current["pca"], "auto");
        let with = |pca_dim: Option<serde_json::Value>| {
            let mut v = current.clone();
            v.as_object_mut().unwrap().remove("pca");
            if let Some(p) = pca_dim {
                v["pca_dim"] = p;
            }
            serde_json::from_value::<OnboardConfig>(v).unwrap().pca
        };
        // Older records: no field or null meant every dimension kept, a number a PCA.
        assert_eq!(with(None), PcaSetting::Off);
        assert_eq!(with(Some(serde_json::Value::Null)), PcaSetting::Off);
        assert_eq!(with(Some(serde_json::json!(16))), PcaSetting::Components(16));
    }

    #[test]
    fn records_from_before_format_8_hold_rows_per_template_and_auto_resolves_by_backbone() {
        let mut v = serde_json::to_value(OnboardConfig::default()).unwrap();
        assert_eq!(v["patch_rows"], "auto");
        v.as_object_mut().unwrap().remove("patch_rows");
        assert_eq!(serde_json::from_value::<OnboardConfig>(v).unwrap().patch_rows, PatchRows::PerTemplate);
        use crate::features::{Backbone, EmbeddedBackbone, EmbeddedConfig};
        let embedded = EmbeddedBackbone::new(EmbeddedConfig::default()).unwrap();
        // Patches of 2 px have no half-width patches: no reduced size, as an ONNX ViT.
        let full_only = EmbeddedBackbone::new(EmbeddedConfig { patch_size: 2, input_size: 64, ..Default::default() }).unwrap();
        assert!(embedded.reduced_input_size().is_some() && full_only.reduced_input_size().is_none());
        assert_eq!(PatchRows::Auto.resolve(&embedded), PatchRows::PerView);
        assert_eq!(PatchRows::Auto.resolve(&full_only), PatchRows::PerTemplate);
        for rows in [PatchRows::PerView, PatchRows::PerTemplate] {
            assert_eq!((rows.resolve(&embedded), rows.resolve(&full_only)), (rows, rows));
        }
        assert_eq!("AUTO".parse::<PatchRows>(), Ok(PatchRows::Auto));
        assert!("per-face".parse::<PatchRows>().unwrap_err().contains("per-template, per-view or auto"));
    }
}
