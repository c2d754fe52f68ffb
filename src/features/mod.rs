//! Backbones: the `Backbone` trait, the embedded weight-free backbone, ONNX models run by
//! ONNX Runtime, and the crop
//! resampling shared by templates and queries.

pub mod backbone;
pub mod batch_queue;
pub mod choice;
pub mod crop;
pub mod embedded;
pub mod onnx;

pub use backbone::{Backbone, BackboneIdentity, FeatureError, FeatureMap};
pub use batch_queue::BatchingBackbone;
pub use choice::{open_backbone, BackboneChoice};
pub use crop::{crop_query, grey, mask_bbox, mask_row_ends, sample_crop, CropInput, ToSource};
pub use embedded::{EmbeddedBackbone, EmbeddedConfig};
pub use onnx::{Device, OnnxBackbone};
