//! The simulated instrument's imperfections and their hidden truth.
//!
//! The instrument file's `[simulator.imperfections]` gives magnitudes (crates/instrument/src/imperfections.rs);
//! [`HiddenTruth::draw`] turns them into the actual values of one instrument, deterministically from
//! `[simulator] seed` ([`draw`]: each value a pure function of the seed and its name). The simulator computes its
//! readings from the TRUE geometry these values make, while the devices report what the controllers believe; the
//! truth leaves the simulator only through [`crate::SimInstrument::hidden_truth`] and
//! [`crate::optics::Optics::hidden_truth`] (tests) and through the rig into a dry-run's run.json (crates/engine
//! /src/rig/), never into the engine, the drivers or the calibration code.
//!
//! Groups (one sub-module each), each a field of [`HiddenTruth`] (`None` when off) applied where its physics
//! lives: [`geometry`] (axis zero offsets and periodic encoder error, sample tilt and re-seating, the arms'
//! eccentricity; crate::optics), [`detector`] (range gains, nonlinearity and offsets, saturation, amplifier
//! noise and ambient light in the power meter, crate::pm100::physics; stray light by pose in crate::optics),
//! [`source`] (warm-up, random walk drawn where asked for by [`walk`], flicker; crate::optics::source),
//! [`sample`] (reflectance varying over the sample's area; crate::optics), [`filters`] (finite bands and out-of-band leakage; crate::optics::spectral),
//! [`beam`] (profile, pointing, divergence; crate::optics).
//!
//! An all-zero table is the ideal instrument bit for bit: [`HiddenTruth::draw`] returns `None` for a group that
//! is off, and the optics then take exactly the code path they take with no table at all.

pub mod beam;
pub mod detector;
pub mod draw;
pub mod effects;
pub mod filters;
pub mod geometry;
pub mod sample;
pub mod source;
pub mod timing;
pub mod walk;

use gonio_instrument::{AxisRole, InstrumentFile};
use serde::Serialize;

pub use beam::BeamTruth;
pub use detector::{DetectorTruth, RangeTruth, Signature};
pub use effects::{MeterEffects, OpticsEffects};
pub use filters::{FilterTruth, FiltersTruth};
pub use geometry::{AxisTruth, GeometryTruth, Tilt, TrueGeometry};
pub use sample::SampleTruth;
pub use source::SourceTruth;
pub use timing::{AxisTiming, TimingTruth};

/// The hidden values of one simulated instrument: what each imperfection actually is.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct HiddenTruth {
    /// The seed they were drawn from (`[simulator] seed`).
    pub seed: u64,
    /// `None` when every geometric magnitude is zero.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub geometry: Option<GeometryTruth>,
    /// `None` when every detector magnitude is zero.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub detector: Option<DetectorTruth>,
    /// `None` when every source magnitude is zero.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub source: Option<SourceTruth>,
    /// `None` when every sample magnitude is zero.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub sample: Option<SampleTruth>,
    /// `None` when the filters' bands are single wavelengths.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub filters: Option<FiltersTruth>,
    /// `None` when the beam is the ideal one (top hat, no pointing or divergence error).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub beam: Option<BeamTruth>,
    /// `None` when the hardware's timing is as the file claims.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub timing: Option<TimingTruth>,
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
        let ranges = file.instrument.detector.ranges_w.len();
        let detector = (!settings.detector.is_ideal())
            .then(|| DetectorTruth::draw(&settings.detector, ranges, seed))
            .filter(|d| !d.is_ideal());
        let source = (!settings.source.is_ideal())
            .then(|| SourceTruth::draw(&settings.source, seed))
            .filter(|s| !s.is_ideal());
        let sample = (!settings.sample.is_ideal())
            .then(|| SampleTruth::draw(&settings.sample, seed))
            .filter(|s| !s.is_ideal());
        let filters = FiltersTruth::draw(&settings.filters, file);
        let beam = (!settings.beam.is_ideal())
            .then(|| BeamTruth::draw(&settings.beam, file.instrument.source.divergence_deg, seed))
            .filter(|b| !b.is_ideal());
        let timing = (!settings.timing.is_ideal())
            .then(|| TimingTruth::draw(&settings.timing, &file.instrument, seed))
            .filter(|t| !t.is_ideal());
        let any = geometry.is_some()
            || timing.is_some()
            || detector.is_some()
            || source.is_some()
            || sample.is_some()
            || filters.is_some()
            || beam.is_some();
        any.then_some(HiddenTruth {
            seed,
            geometry,
            detector,
            source,
            sample,
            filters,
            beam,
            timing,
        })
    }

    /// The hardware as it really is: the file's instrument with the hidden timing applied, then the values
    /// `[simulator.actual]` states (which win). What the simulated devices are built from.
    pub fn real_instrument(
        file: &InstrumentFile,
        hidden: Option<&HiddenTruth>,
    ) -> gonio_instrument::Instrument {
        let mut inst = file.instrument.clone();
        if let Some(t) = hidden.and_then(|h| h.timing.as_ref()) {
            t.apply(&mut inst);
        }
        file.simulator.actual.apply_to(&mut inst);
        inst
    }

    /// The values as JSON (for run.json and reports).
    pub fn to_json(&self) -> serde_json::Value {
        serde_json::to_value(self).unwrap_or(serde_json::Value::Null)
    }
}
