//! Evaluation: image degradations for simulated photos, the patch re-identification
//! benchmark that chose the embedded backbone's design, and synthetic BOP-format scenes.

pub mod degrade;
pub mod pose_error;
pub mod reid;
pub mod scenes;
