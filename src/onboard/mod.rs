//! Onboarding: from a mesh to an object model (templates with descriptors and 3D points).

pub mod contour;
pub mod model;
pub mod pca;
pub mod pca_setting;
pub mod pipeline;

pub use contour::{ContourConfig, ContourModel};
pub use model::{ObjectModel, OnboardConfig, Template, MODEL_FORMAT_VERSION};
pub use pca_setting::PcaSetting;
pub use pipeline::{apply_pca, compress, mesh_symmetries, onboard, onboard_cancellable, validate_object_id, OnboardError, Progress};
