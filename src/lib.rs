//! b2tfpose: training-free zero-shot 6DoF pose estimation from one RGB image and a CAD mesh.
//! See DESIGN.md in the repository for the method, the conventions and the architecture.

pub mod bop;
pub mod cli;
pub mod depth;
pub mod detect;
pub mod estimate;
pub mod eval;
pub mod features;
pub mod fuzzing;
pub mod geometry;
pub mod limits;
pub mod linalg;
pub mod masks;
pub mod mesh;
pub mod onboard;
pub mod parallel;
pub mod percent;
pub mod render;
pub mod service;
pub mod store;
pub mod telemetry;
pub mod track;
pub mod video;
