//! `OnnxBackbone`: a ViT exported to ONNX (DINOv3 by tools/export_backbone.py, or the
//! random-weight test model of tools/make_test_vit.py) run through ONNX Runtime.
//!
//! The ONNX Runtime shared library is loaded at run time (the `ort` crate's
//! `load-dynamic`), from the PyPI `onnxruntime` wheel that scripts/setup.sh installs: a
//! build never downloads anything. The model comes with a JSON sidecar (`model.json` next
//! to `model.onnx`) that names its inputs, outputs, layers, normalisation and the sha256
//! of the ONNX file; the file must match it, and the session's shapes must match both.

use super::backbone::{check_sizes, l2_normalize, mean_descriptor, patch_coverage, Backbone, BackboneIdentity, FeatureError, FeatureMap};
use super::crop::CropInput;
use crate::geometry::PatchGrid;
use ort::session::Session;
use ort::value::Tensor;
use rayon::prelude::*;
use sha2::{Digest, Sha256};
use std::path::{Path, PathBuf};
use std::sync::{Mutex, OnceLock};

/// Where ONNX Runtime's library is looked for, in order, when no path is given.
pub const LIBRARY_VARIABLES: [&str; 2] = ["B2TF_ORT_LIB", "ORT_DYLIB_PATH"];

/// The sidecar of an exported backbone.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct BackboneSpec {
    pub format: String,
    pub version: u32,
    pub model: String,
    pub source: String,
    pub patch_size: u32,
    pub input_size: u32,
    pub mean: [f32; 3],
    pub std: [f32; 3],
    pub input: String,
    pub local_output: String,
    pub global_output: String,
    pub depth: u32,
    pub local_layer: u32,
    pub global_layer: u32,
    pub local_dim: u32,
    pub global_dim: u32,
    pub dtype: String,
    pub onnx_sha256: String,
}

/// Where the backbone runs.
#[derive(Clone, Debug, PartialEq, Eq, Default)]
pub enum Device {
    #[default]
    Cpu,
    Cuda(u32),
    /// TensorRT (fp16, engines cached in a folder beside the model) on GPU N.
    TensorRt(u32),
}

impl std::str::FromStr for Device {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        let (kind, index) = match s.split_once(':') {
            Some((k, i)) => (k, Some(i)),
            None => (s, None),
        };
        let index = match index {
            None => 0,
            Some(i) => i.parse::<u32>().map_err(|_| format!("device {s:?}: {i:?} is not a GPU index"))?,
        };
        match (kind, s.contains(':')) {
            ("cpu", false) => Ok(Device::Cpu),
            ("cuda", _) => Ok(Device::Cuda(index)),
            ("tensorrt", _) => Ok(Device::TensorRt(index)),
            _ => Err(format!("unknown device {s:?}: expected cpu, cuda[:N] or tensorrt[:N]")),
        }
    }
}

impl std::fmt::Display for Device {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Device::Cpu => write!(f, "cpu"),
            Device::Cuda(i) => write!(f, "cuda:{i}"),
            Device::TensorRt(i) => write!(f, "tensorrt:{i}"),
        }
    }
}

#[derive(Debug, thiserror::Error)]
pub enum OnnxError {
    #[error("no ONNX Runtime library: set B2TF_ORT_LIB (or ORT_DYLIB_PATH) to libonnxruntime.so (scripts/setup.sh installs the PyPI onnxruntime wheel and scripts/env.sh sets it)")]
    NoLibrary,
    #[error("ONNX Runtime library {path}: {reason}")]
    Library { path: PathBuf, reason: String },
    #[error("backbone model {path}: {reason}")]
    Model { path: PathBuf, reason: String },
    #[error("backbone sidecar {path}: {reason}")]
    Sidecar { path: PathBuf, reason: String },
    #[error("device {device}: {reason}")]
    Provider { device: Device, reason: String },
    #[error("ONNX Runtime run failed: {0}")]
    Run(String),
}

/// The library path: `explicit`, else the first of `LIBRARY_VARIABLES` that is set.
pub fn library_path(explicit: Option<&Path>) -> Result<PathBuf, OnnxError> {
    if let Some(p) = explicit {
        return Ok(p.to_path_buf());
    }
    LIBRARY_VARIABLES.iter().find_map(|v| std::env::var_os(v).filter(|s| !s.is_empty())).map(PathBuf::from).ok_or(OnnxError::NoLibrary)
}

/// ONNX Runtime's process-wide environment, loaded from `library` the first time. A
/// process holds one library: later calls reuse it whatever path they name.
fn environment(library: &Path) -> Result<&'static ort::environment::Environment, OnnxError> {
    static ENV: OnceLock<ort::environment::Environment> = OnceLock::new();
    // Checked first so that the error names the path rather than a dlopen message, and
    // so that a wrong path is an error even in a process that loaded the library before.
    if !library.is_file() {
        return Err(OnnxError::Library { path: library.to_path_buf(), reason: "no such file".into() });
    }
    if let Some(env) = ENV.get() {
        return Ok(env);
    }
    let lib_err = |reason: String| OnnxError::Library { path: library.to_path_buf(), reason };
    let builder = ort::init_from(library).map_err(|e| lib_err(e.to_string()))?;
    let env = builder.with_name("b2tfpose").build().map_err(|e| lib_err(e.to_string()))?;
    Ok(ENV.get_or_init(|| env))
}

/// The sidecar of `model`: `model` with the extension `.json`.
pub fn sidecar_path(model: &Path) -> PathBuf {
    model.with_extension("json")
}

/// The sidecar of `model`, parsed but not yet checked against the file.
pub fn read_sidecar(model: &Path) -> Result<BackboneSpec, OnnxError> {
    let path = sidecar_path(model);
    let bad = |reason: String| OnnxError::Sidecar { path: path.clone(), reason };
    let text = std::fs::read(&path).map_err(|e| bad(e.to_string()))?;
    serde_json::from_slice(&text).map_err(|e| bad(e.to_string()))
}

/// Reads and checks the sidecar against the ONNX file's bytes.
pub fn read_spec(model: &Path, onnx: &[u8]) -> Result<BackboneSpec, OnnxError> {
    let path = sidecar_path(model);
    let bad = |reason: String| OnnxError::Sidecar { path: path.clone(), reason };
    let spec = read_sidecar(model)?;
    if spec.format != "b2tfpose-backbone" || spec.version != 1 {
        return Err(bad(format!("format {:?} version {}, expected \"b2tfpose-backbone\" version 1", spec.format, spec.version)));
    }
    let hash = hex(&Sha256::digest(onnx));
    if hash != spec.onnx_sha256 {
        return Err(bad(format!("the ONNX file's sha256 is {hash}, the sidecar says {} (a different or damaged export)", spec.onnx_sha256)));
    }
    if spec.patch_size == 0 || spec.input_size == 0 || !spec.input_size.is_multiple_of(spec.patch_size) {
        return Err(bad(format!("input size {} is not a positive multiple of the patch size {}", spec.input_size, spec.patch_size)));
    }
    if spec.local_dim == 0 || spec.global_dim == 0 || !spec.std.iter().all(|s| *s > 0.0) {
        return Err(bad("descriptor dimensions and std must be positive".into()));
    }
    if spec.dtype != "float32" {
        return Err(bad(format!("input dtype {:?}: only float32 inputs are supported (an fp16 export keeps float32 inputs)", spec.dtype)));
    }
    Ok(spec)
}

fn hex(bytes: &[u8]) -> String {
    bytes.iter().map(|b| format!("{b:02x}")).collect()
}

pub struct OnnxBackbone {
    spec: BackboneSpec,
    device: Device,
    grid: PatchGrid,
    session: Mutex<Session>,
    /// Crops per run: bounds the activations one call holds.
    max_batch: usize,
    /// Patch coverage a patch needs to enter the global descriptor's masked mean.
    min_coverage: f32,
}

impl OnnxBackbone {
    /// Opens `model` (with its sidecar) on `device`, loading ONNX Runtime from `library`
    /// (or the variables of `LIBRARY_VARIABLES`). Every mismatch is an error: a provider
    /// that cannot load never falls back to the CPU.
    pub fn open(model: &Path, device: &Device, library: Option<&Path>) -> Result<Self, OnnxError> {
        let model_err = |reason: String| OnnxError::Model { path: model.to_path_buf(), reason };
        let onnx = std::fs::read(model).map_err(|e| model_err(e.to_string()))?;
        let spec = read_spec(model, &onnx)?;
        let env = environment(&library_path(library)?)?;
        // The PyPI `onnxruntime` wheel is CPU-only: CUDA and TensorRT need onnxruntime-gpu's library.
        let provider_err = |e: ort::Error| OnnxError::Provider { device: device.clone(), reason: format!("{e} (GPU providers need the library of the onnxruntime-gpu wheel in B2TF_ORT_LIB)") };
        let mut builder = Session::builder(env).map_err(|e| model_err(e.to_string()))?;
        builder = match device {
            Device::Cpu => builder,
            Device::Cuda(i) => builder.with_execution_providers([ort::ep::CUDA::default().with_device_id(*i as i32).build().error_on_failure()]).map_err(|e| provider_err(e.into()))?,
            Device::TensorRt(i) => {
                let cache = model.with_extension("trt-cache");
                let trt = ort::ep::TensorRT::default().with_device_id(*i as i32).with_fp16(true).with_engine_cache(true).with_engine_cache_path(cache.display());
                builder.with_execution_providers([trt.build().error_on_failure()]).map_err(|e| provider_err(e.into()))?
            }
        };
        let session = builder.commit_from_memory(&onnx).map_err(|e| model_err(format!("ONNX Runtime cannot load it: {e}")))?;
        let grid = PatchGrid::for_crop(spec.input_size, spec.patch_size).map_err(model_err)?;
        check_interface(&session, &spec, grid.len()).map_err(model_err)?;
        Ok(Self { spec, device: device.clone(), grid, session: Mutex::new(session), max_batch: 16, min_coverage: 0.5 })
    }

    pub fn spec(&self) -> &BackboneSpec {
        &self.spec
    }

    pub fn device(&self) -> &Device {
        &self.device
    }

    /// The normalised NCHW input of `crops`, exactly as the export expects it:
    /// (RGB/255 − mean)/std per channel, background black as in every crop.
    pub fn preprocess(&self, crops: &[CropInput]) -> Vec<f32> {
        let s = self.spec.input_size as usize;
        let plane = s * s;
        let mut out = vec![0f32; crops.len() * 3 * plane];
        out.par_chunks_mut(3 * plane).zip(crops).for_each(|(planes, crop)| {
            for (i, px) in crop.rgb.pixels().enumerate() {
                for c in 0..3 {
                    planes[c * plane + i] = (px[c] as f32 / 255.0 - self.spec.mean[c]) / self.spec.std[c];
                }
            }
        });
        out
    }

    /// Runs `batch` normalised inputs (NCHW, `batch × 3 × S × S`); returns the local and
    /// global patch tokens, `batch × P × dim` each (copies: for tests and tools).
    pub fn run(&self, pixels: Vec<f32>, batch: usize) -> Result<(Vec<f32>, Vec<f32>), OnnxError> {
        self.run_with(pixels, batch, |local, global| (local.to_vec(), global.to_vec()))
    }

    /// Runs `batch` normalised inputs and hands `use_tokens` the local and global patch
    /// tokens in ONNX Runtime's own output buffers. Why not copies: at ViT-L's width a batch
    /// of 16 gives 128 MB of tokens, and copying them cost about as much as the GPU pass.
    fn run_with<R>(&self, pixels: Vec<f32>, batch: usize, use_tokens: impl FnOnce(&[f32], &[f32]) -> R) -> Result<R, OnnxError> {
        let s = self.spec.input_size as usize;
        if pixels.len() != batch * 3 * s * s {
            return Err(OnnxError::Run(format!("{} input values for {batch} crops of 3×{s}×{s}", pixels.len())));
        }
        let run_err = |e: ort::Error| OnnxError::Run(e.to_string());
        let input = Tensor::from_array(([batch, 3, s, s], pixels)).map_err(run_err)?;
        let mut session = self.session.lock().unwrap_or_else(|p| p.into_inner());
        let outputs = session.run(ort::inputs![self.spec.input.as_str() => input]).map_err(run_err)?;
        let tokens = |name: &str, dim: u32| -> Result<&[f32], OnnxError> {
            let (shape, data) = outputs[name].try_extract_tensor::<f32>().map_err(run_err)?;
            let want = [batch as i64, self.grid.len() as i64, dim as i64];
            if shape[..] != want[..] {
                return Err(OnnxError::Run(format!("output {name} has shape {:?}, expected {want:?}", &shape[..])));
            }
            Ok(data)
        };
        Ok(use_tokens(tokens(&self.spec.local_output, self.spec.local_dim)?, tokens(&self.spec.global_output, self.spec.global_dim)?))
    }

    fn feature_map(&self, crop: &CropInput, local: &[f32], global: &[f32]) -> FeatureMap {
        let (ld, gd) = (self.spec.local_dim as usize, self.spec.global_dim as usize);
        let mut local = local.to_vec();
        local.chunks_exact_mut(ld).for_each(l2_normalize);
        let coverage = patch_coverage(&crop.mask, &self.grid);
        // Masked mean pooling of the last layer's patch tokens (as the embedded backbone
        // pools); a crop with no patch that reaches the coverage threshold pools every patch
        // it touches instead, weighted by coverage.
        let pooled = if coverage.iter().any(|&c| c >= self.min_coverage) {
            mean_descriptor(global, gd, &coverage, self.min_coverage)
        } else {
            let mut pooled = vec![0f32; gd];
            for (k, &c) in coverage.iter().enumerate().filter(|(_, &c)| c > 0.0) {
                pooled.iter_mut().zip(&global[k * gd..(k + 1) * gd]).for_each(|(p, g)| *p += c * g);
            }
            l2_normalize(&mut pooled);
            pooled
        };
        FeatureMap { grid: self.grid, local_dim: ld, local, global: pooled, coverage }
    }
}

/// The session takes one float input of `[batch, 3, S, S]` and gives both outputs as
/// `[batch, P, dim]`, as the sidecar says.
fn check_interface(session: &Session, spec: &BackboneSpec, patches: usize) -> Result<(), String> {
    let input = session.inputs().iter().find(|i| i.name() == spec.input).ok_or_else(|| format!("the model has no input {:?} (the sidecar's)", spec.input))?;
    let s = spec.input_size as i64;
    match input.dtype().tensor_shape() {
        Some(shape) if shape.len() == 4 && shape[1..] == [3, s, s] => {}
        other => return Err(format!("input {:?} has shape {}; the sidecar says [batch, 3, {s}, {s}]", spec.input, shape_text(other))),
    }
    for (name, dim) in [(&spec.local_output, spec.local_dim), (&spec.global_output, spec.global_dim)] {
        let out = session.outputs().iter().find(|o| o.name() == name).ok_or_else(|| format!("the model has no output {name:?} (the sidecar's)"))?;
        match out.dtype().tensor_shape() {
            Some(shape) if shape.len() == 3 && (shape[1] == patches as i64 || shape[1] < 0) && shape[2] == dim as i64 => {}
            other => return Err(format!("output {name:?} has shape {}; the sidecar says [batch, {patches}, {dim}]", shape_text(other))),
        }
    }
    Ok(())
}

/// A tensor shape as `[batch, 3, 512, 512]` (−1 = any), or what it is when not a tensor.
fn shape_text(shape: Option<&ort::value::Shape>) -> String {
    match shape {
        Some(s) => format!("[{}]", s.iter().map(|d| if *d < 0 { "batch".to_string() } else { d.to_string() }).collect::<Vec<_>>().join(", ")),
        None => "(not a tensor)".into(),
    }
}

impl Backbone for OnnxBackbone {
    fn identity(&self) -> BackboneIdentity {
        BackboneIdentity {
            name: format!("onnx:{}", self.spec.model),
            weights_hash: self.spec.onnx_sha256.clone(),
            layers: format!("local block {} / global block {} of {}, masked mean", self.spec.local_layer, self.spec.global_layer, self.spec.depth),
            input_size: self.spec.input_size,
            patch_size: self.spec.patch_size,
            local_dim: self.spec.local_dim,
            global_dim: self.spec.global_dim,
        }
    }

    fn extract(&self, crops: &[CropInput]) -> Result<Vec<FeatureMap>, FeatureError> {
        check_sizes(crops, self.spec.input_size, None)?;
        let (ld, gd, p) = (self.spec.local_dim as usize, self.spec.global_dim as usize, self.grid.len());
        let mut maps = Vec::with_capacity(crops.len());
        for chunk in crops.chunks(self.max_batch) {
            let chunk_maps = self
                .run_with(self.preprocess(chunk), chunk.len(), |local, global| {
                    // Per crop on all cores: normalising a ViT-L batch's tokens on one core
                    // took longer than the GPU pass.
                    chunk.par_iter().enumerate().map(|(i, crop)| self.feature_map(crop, &local[i * p * ld..(i + 1) * p * ld], &global[i * p * gd..(i + 1) * p * gd])).collect::<Vec<_>>()
                })
                .map_err(|e| FeatureError::Backend(e.to_string()))?;
            maps.extend(chunk_maps);
        }
        Ok(maps)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn devices_parse_and_unknown_ones_are_named() {
        assert_eq!("cpu".parse::<Device>(), Ok(Device::Cpu));
        assert_eq!("cuda".parse::<Device>(), Ok(Device::Cuda(0)));
        assert_eq!("cuda:1".parse::<Device>(), Ok(Device::Cuda(1)));
        assert_eq!("tensorrt:2".parse::<Device>(), Ok(Device::TensorRt(2)));
        assert_eq!(Device::Cuda(3).to_string(), "cuda:3");
        for bad in ["gpu", "cpu:0", "cuda:x", "cuda:-1", ""] {
            let e = bad.parse::<Device>().unwrap_err();
            assert!(e.contains(&format!("{bad:?}")), "{e}");
        }
    }

    #[test]
    fn a_missing_library_is_an_error_naming_its_path() {
        let e = environment(Path::new("/nonexistent/libonnxruntime.so")).expect_err("a missing file is an error");
        assert!(e.to_string().contains("/nonexistent/libonnxruntime.so"), "{e}");
    }
}
