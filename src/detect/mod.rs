//! Training-free detection (DESIGN.md "Detection without training"): shape-based matching
//! in the manner of LINE-2D. Onboarding renders each object from many viewpoints and keeps
//! sparse gradient-orientation templates (`templates`); per image, quantised and spread
//! orientations become response maps once per scale for every object (`gradients`,
//! `responses`, `scales`); the templates slide over them (`search`); overlaps are
//! suppressed across objects and instances (`nms`); each detection gets the coarse pose of
//! its template and a mask (`detector`). The estimator takes the masks like any caller's.
//!
//! With a depth camera (`frame::detect` given the registered depth), the frame is cut into
//! the surfaces standing off the large planes (`depth_segments`, with the other readings of
//! them in `segment_cuts`: cut at depths and necks, joined in pairs), and each of an
//! object's size is its candidate (`depth_detector`); the estimate of each is confirmed by the
//! photo's evidence and the depth at its pose together (`confirm`, `depth_check`).

pub mod align;
pub mod colour_prior;
pub mod compared;
pub mod confirm;
pub mod depth_check;
pub mod depth_detector;
pub mod depth_segments;
pub mod detector;
pub mod frame;
pub mod gradients;
pub mod nms;
pub mod responses;
pub mod rivals;
pub mod scales;
pub mod search;
pub mod segment_cuts;
pub mod templates;
pub mod verify;

pub use detector::{check_options, DetectError, DetectOptions, DetectReport, Detection, MaskSource, Searched, Target};
pub use frame::detect;
pub use templates::{DetectorConfig, ShapeModel};
