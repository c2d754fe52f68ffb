//! Training-free detection (DESIGN.md "Detection without training"): shape-based matching
//! in the manner of LINE-2D. Onboarding renders each object from many viewpoints and keeps
//! sparse gradient-orientation templates (`templates`); per image, quantised and spread
//! orientations become response maps once per scale for every object (`gradients`,
//! `responses`, `scales`); the templates slide over them (`search`); overlaps are
//! suppressed across objects and instances (`nms`); each detection gets the coarse pose of
//! its template and a mask (`detector`). The estimator takes the masks like any caller's.

pub mod align;
pub mod colour_prior;
pub mod confirm;
pub mod depth_check;
pub mod depth_detector;
pub mod depth_segments;
pub mod detector;
pub mod gradients;
pub mod nms;
pub mod responses;
pub mod scales;
pub mod search;
pub mod templates;
pub mod verify;

pub use detector::{check_options, detect, DetectError, DetectOptions, DetectReport, Detection, MaskSource, Searched, Target};
pub use templates::{DetectorConfig, ShapeModel};
