//! The campaign crate's integration tests, one binary (one link): the typed campaign model (`model`) and speed
//! that follows the BRDF from a first pass (`follow`).

mod follow;
mod model;
