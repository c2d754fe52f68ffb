//! `--backbone` and `--device`, shared by every command that runs a backbone.

use crate::features::{open_backbone, Backbone, BackboneChoice, Device};
use std::sync::Arc;

#[derive(clap::Args, Debug, Clone)]
pub struct BackboneArgs {
    /// Backbone: embedded (weight-free, built in) or onnx:PATH (an ONNX export with its
    /// .json sidecar beside it; ONNX Runtime's library from $B2TF_ORT_LIB).
    #[arg(long, env = "B2TF_BACKBONE", default_value = "embedded")]
    pub backbone: BackboneChoice,
    /// Where an ONNX backbone runs: cpu, cuda[:N] or tensorrt[:N] (fp16).
    #[arg(long, env = "B2TF_DEVICE", default_value = "cpu")]
    pub device: Device,
}

impl BackboneArgs {
    pub fn open(&self) -> anyhow::Result<Arc<dyn Backbone>> {
        open_backbone(&self.backbone, &self.device).map_err(anyhow::Error::msg)
    }
}
