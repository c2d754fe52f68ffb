//! Onboarding: from a mesh to an object model (templates with descriptors and 3D points).

pub mod contour;
pub mod model;
pub mod patch_descriptors;
pub mod patch_points;
pub mod pca;
pub mod pca_setting;
pub mod per_view_rows;
pub mod pipeline;
pub mod point_grid;
pub mod pq;
pub mod profile;
pub mod stored_rows;
pub mod template_camera;
#[doc(hidden)]
pub mod test_model;

pub use contour::{ContourConfig, ContourModel};
pub use model::{DescriptorCoding, PatchRows};
pub use model::{ObjectModel, OnboardConfig, Template, MODEL_FORMAT_VERSION};
pub use patch_descriptors::PatchDescriptors;
pub use patch_points::PatchPoints;
pub use pca_setting::PcaSetting;
pub use per_view_rows::share_rows_per_view;
pub use pipeline::{apply_coding, apply_pca, compress, mesh_symmetries, onboard, onboard_profiled, validate_object_id, OnboardError, Progress};
pub use profile::OnboardProfile;
