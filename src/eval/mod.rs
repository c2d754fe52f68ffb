//! Evaluation: image degradations for simulated photos and the patch re-identification
//! benchmark that chose the embedded backbone's design.

pub mod degrade;
pub mod reid;
