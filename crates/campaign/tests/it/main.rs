//! The campaign crate's integration tests, one binary (one link): the typed campaign model (`model`), speed
//! that follows the BRDF from a first pass (`follow`) and an adaptive plan's rehearsals (`rehearsal`).

mod follow;
mod model;
mod rehearsal;
