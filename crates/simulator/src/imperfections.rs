//! The simulated instrument's imperfections and their hidden truth.
//!
//! The instrument file's `[simulator.imperfections]` gives magnitudes (crates/instrument/src/imperfections.rs);
//! [`HiddenTruth::draw`] turns them into the actual values of one instrument, deterministically from
//! `[simulator] seed` ([`draw`]: each value a pure function of the seed and its name). The simulator computes its
//! readings from the TRUE geometry these values make, while the devices report what the controllers believe; the
//! truth leaves the simulator only through [`crate::SimInstrument::hidden_truth`] and
//! [`crate::optics::Optics::hidden_truth`] (tests) and through the rig into a dry-run's run.json (crates/daemon
//! /src/rig/), never into the engine, the drivers or the calibration code.
//!
//! Groups (one sub-module each): [`geometry`] (axis zero offsets and periodic encoder error, sample tilt and
//! re-seating, the arms' eccentricity). Still to come (issue 16): detector, source, filters, sample; each adds a
//! field to [`HiddenTruth`] (`None` when off) and applies itself where its physics lives in crate::optics.
//!
//! An all-zero table is the ideal instrument bit for bit: [`HiddenTruth::draw`] returns `None` for a group that
//! is off, and the optics then take exactly the code path they take with no table at all.

pub mod draw;
pub mod geometry;

use gonio_instrument::{AxisRole, InstrumentFile};
use serde::Serialize;

pub use geometry::{AxisTruth, GeometryTruth, Tilt, TrueGeometry};

/// The hidden values of one simulated instrument: what each imperfection actually is.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct HiddenTruth {
    /// The seed they were drawn from (`[simulator] seed`).
    pub seed: u64,
    /// `None` when every geometric magnitude is zero.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub geometry: Option<GeometryTruth>,
}

impl HiddenTruth {
    /// Draw the hidden values of the instrument `file` describes; `None` for the ideal instrument (every
    /// magnitude zero). The file is validated by its loader; a magnitude that is not finite or is negative
    /// gives the ideal group here rather than a panic.
    pub fn draw(file: &InstrumentFile) -> Option<HiddenTruth> {
        let settings = &file.simulator.imperfections;
        if settings.is_ideal() || settings.validate().is_err() {
            return None;
        }
        let roles: Vec<AxisRole> = file.instrument.axes.iter().map(|a| a.role).collect();
        let seed = file.simulator.seed;
        let geometry = (!settings.geometry.is_ideal())
            .then(|| GeometryTruth::draw(&settings.geometry, &roles, seed))
            .filter(|g| !g.is_ideal());
        geometry.is_some().then_some(HiddenTruth { seed, geometry })
    }

    /// The values as JSON (for run.json and reports).
    pub fn to_json(&self) -> serde_json::Value {
        serde_json::to_value(self).unwrap_or(serde_json::Value::Null)
    }
}
