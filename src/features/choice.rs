//! Which backbone a command or the service runs: the embedded one, or an ONNX export on a
//! device. Parsed from `--backbone embedded | onnx:PATH` and `--device cpu | cuda[:N] |
//! tensorrt[:N]` (and their `B2TF_BACKBONE` / `B2TF_DEVICE` variables and config keys).

use super::onnx::{Device, OnnxBackbone};
use super::{Backbone, EmbeddedBackbone, EmbeddedConfig};
use std::path::PathBuf;
use std::sync::Arc;

#[derive(Clone, Debug, PartialEq, Eq, Default)]
pub enum BackboneChoice {
    /// The weight-free descriptor built into the binary.
    #[default]
    Embedded,
    /// An exported ViT (`PATH` with its `.json` sidecar beside it).
    Onnx(PathBuf),
}

impl std::str::FromStr for BackboneChoice {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s.trim() {
            "embedded" => Ok(Self::Embedded),
            other => match other.strip_prefix("onnx:") {
                Some(path) if !path.is_empty() => Ok(Self::Onnx(PathBuf::from(path))),
                _ => Err(format!("unknown backbone {s:?}: expected \"embedded\" or \"onnx:PATH\" (an export of tools/export_backbone.py)")),
            },
        }
    }
}

impl std::fmt::Display for BackboneChoice {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::Embedded => write!(f, "embedded"),
            Self::Onnx(p) => write!(f, "onnx:{}", p.display()),
        }
    }
}

/// Opens the chosen backbone on `device`. The embedded backbone runs on the CPU only: asking
/// for a GPU with it is an error rather than a silent CPU run.
pub fn open_backbone(choice: &BackboneChoice, device: &Device) -> Result<Arc<dyn Backbone>, String> {
    match choice {
        BackboneChoice::Embedded if *device != Device::Cpu => Err(format!("the embedded backbone runs on the CPU; device {device} needs an ONNX backbone (--backbone onnx:PATH)")),
        BackboneChoice::Embedded => Ok(Arc::new(EmbeddedBackbone::new(EmbeddedConfig::default())?)),
        BackboneChoice::Onnx(path) => Ok(Arc::new(OnnxBackbone::open(path, device, None).map_err(|e| e.to_string())?)),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn choices_parse_and_bad_ones_are_named() {
        assert_eq!("embedded".parse::<BackboneChoice>(), Ok(BackboneChoice::Embedded));
        assert_eq!("onnx:/m/dino.onnx".parse::<BackboneChoice>(), Ok(BackboneChoice::Onnx("/m/dino.onnx".into())));
        assert_eq!(BackboneChoice::Onnx("a.onnx".into()).to_string(), "onnx:a.onnx");
        for bad in ["dinov3", "onnx:", ""] {
            let e = bad.parse::<BackboneChoice>().unwrap_err();
            assert!(e.contains(&format!("{bad:?}")), "{e}");
        }
    }

    #[test]
    fn the_embedded_backbone_refuses_a_gpu() {
        let e = open_backbone(&BackboneChoice::Embedded, &Device::Cuda(0)).err().unwrap();
        assert!(e.contains("cuda:0") && e.contains("onnx:PATH"), "{e}");
        assert!(open_backbone(&BackboneChoice::Embedded, &Device::Cpu).is_ok());
    }
}
