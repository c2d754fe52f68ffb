//! Synthetic test scenes for the estimation and BOP benchmarks (written as BOP datasets by
//! `bop::scene_dataset`).
//!
//! Each image: random intrinsics; 1–3 (up to 8) object instances, rotation uniform over
//! SO(3), placed wholly inside the frame at a distance that makes them fill a chosen share
//! of the image height; each rendered alone (textured as the mesh is, one random light per
//! image), composited by depth over procedural clutter; flat occluders in front of parts of
//! the objects; blur, colour shift and sensor noise (and, where the appearance asks for them,
//! prints that drift from the texture and JPEG). Placements and occluders that leave an
//! instance less than `1 − max_occlusion` visible are drawn again.
//!
//! `render_to_real_gap`: the templates are rendered elsewhere from the bare mesh, so the
//! generator widens the gap the only way it can, by degrading the scenes more (see
//! `Appearance::harsher`). The flag changes no geometry: with the same seed, both datasets
//! hold the same poses, masks and occluders, so they can be compared image by image.

mod appearance;
mod background;
mod config;
mod generate;
mod layers;
mod occluders;
mod placement;
mod supersample;

pub use background::Background;
pub use config::{Appearance, SceneConfig, MAX_OBJECTS_PER_IMAGE, MAX_SUPERSAMPLING};
pub use generate::{generate_image, generate_image_over, SceneImage, SceneInstance};
