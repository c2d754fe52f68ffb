//! Intrinsics, poses, crops, viewpoint sampling and rotation distances. No images, no IO.

pub mod camera;
pub mod crop;
pub mod pixel;
pub mod pose;
pub mod surface_distance;
pub mod symmetric_poses;
pub mod symmetry;
pub mod turn;
pub mod views;

pub use camera::{Intrinsics, IntrinsicsError};
pub use crop::{CropBox, PatchGrid, ScaleShift};
pub use pose::{geodesic_distance, Pose};
pub use turn::Turn;
pub use views::{icosphere, view_pose, ViewSampling};
