//! Training-free pose refinement by contour alignment (the region-based trackers' family:
//! PWP3D, RBOT, SRT3D): the stored contour model's points are projected at the hypothesis,
//! correspondence lines along their normals find the detection mask's outline, and
//! regularised Gauss–Newton moves the pose until the outlines agree. DESIGN.md,
//! "Refinement without training".

pub mod lines;
pub mod occlusion;
pub mod photo_edge;
pub mod posterior;
pub mod print_points;
pub mod print_refine;
pub mod refiner;
pub mod solve;

pub use print_refine::PrintRefineConfig;
pub use refiner::{Agreement, Begun, CoarseRun, ContourRefiner, ContourRefinerConfig, PhotoEdges};
