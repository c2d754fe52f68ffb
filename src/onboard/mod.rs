//! Onboarding: from a mesh to an object model (templates with descriptors and 3D points).

pub mod artefact;
pub mod model;
pub mod pipeline;

pub use model::{ObjectModel, OnboardConfig, Template};
pub use pipeline::{onboard, validate_object_id, OnboardError, Progress};
