//! Characterisation: the detector and the source measured from their own readings, with the holder empty
//! (issue 27, second part). It runs inside `gonio align` (crate::align): steps 1-5 right after the direct-beam
//! scans, which give them the detector angle that faces the beam, step 6 after the mirror's scans with the sample
//! back in the holder.
//!
//! Steps 1-5 with the direct beam (the light arm at one angle, the detector arm facing it; [`empty`]), step 6
//! with the sample back in the holder ([`sample`]); [`finish`] makes the calibration from all of them:
//! 1. **Warm-up watch**: the direct beam read at the facing angle every [`WATCH_INTERVAL_S`] for the options'
//!    watch time, then at every later step: the source's warm-up and drift ([`drift`]).
//! 2. **Direct beam per band**: `P` in every open band of the wheel (the signature's and the NEBRDF's
//!    denominators).
//! 3. **Darks per range** through the wheel's blank position, each range fixed, each read beside range 0's:
//!    the offsets ([`ranges`]).
//! 4. **Overlaps**: the detector walked out of the beam gives every signal level from the beam's peak down to
//!    the smallest range; at levels from 0.2 to 0.9 of each range's full scale the same light is read on that
//!    range and the next (A-B-B-A, so a linear drift cancels): the gains and nonlinearities ([`ranges`]).
//! 5. **Signature**: the detector at angles from a few degrees to as far as the arms allow from the beam's
//!    forward direction, every band read with its dark: the instrument signature and, from the darks' noise, the
//!    NEBRDF ([`signature`]).
//! 6. **Overlaps on the sample**: its reflection gives the levels of the smallest ranges, which the edge of a
//!    top-hat beam falls through within one encoder count ([`sample`]).
//!
//! Nothing here reads the simulator's truth: every value comes from the meter's readings.

pub mod correction;
pub mod drift;
pub mod empty;
pub mod finish;
mod meter;
pub mod ranges;
pub mod sample;
pub mod signature;

use serde::{Deserialize, Serialize};

use crate::motion::MotionError;

pub use drift::SourceDrift;
pub use empty::{EmptyHolder, read_empty_holder};
pub use finish::finish;
pub use meter::Meter;
pub use ranges::{Overlap, RangeDark, RangesCalibration};
pub use sample::sample_overlaps;
pub use signature::BandSignature;

/// Why the characterisation stopped.
#[derive(Debug, thiserror::Error)]
pub enum CharacteriseError {
    #[error(transparent)]
    Motion(#[from] MotionError),
    /// Every band's direct beam is over the meter's largest range.
    #[error(
        "characterisation: the direct beam saturates the meter in every band ({power_w:.3e} W): attenuate the beam"
    )]
    Saturated { power_w: f64 },
}

/// Seconds between the warm-up watch's readings.
pub const WATCH_INTERVAL_S: f64 = 20.0;

/// What the characterisation does beyond its fixed steps.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CharacteriseOptions {
    /// How long to watch the direct beam before the other steps (s of instrument time).
    pub warmup_watch_s: f64,
}

impl Default for CharacteriseOptions {
    fn default() -> Self {
        CharacteriseOptions {
            warmup_watch_s: 1800.0,
        }
    }
}

/// The calibration file's `[detector]`: the ranges' correction and the signature per band.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DetectorCalibration {
    #[serde(default)]
    pub ranges: Option<RangesCalibration>,
    #[serde(default)]
    pub signature: Vec<BandSignature>,
}

/// What the characterisation found, for the report and the calibration file.
#[derive(Debug, Clone, Serialize)]
pub struct CharacterisationReport {
    pub detector: DetectorCalibration,
    pub source: Option<SourceDrift>,
    /// The direct beam per band at the facing angle (nm, W, corrected by the ranges when they were found).
    pub direct_beam_w: Vec<(f64, f64)>,
    pub darks: Vec<RangeDark>,
    pub overlaps: Vec<Overlap>,
    /// How many of `overlaps` were read on the sample's reflection (crate::characterise::sample).
    pub sample_overlaps: usize,
    /// The walk out of the beam the overlaps' levels come from (deg from the facing angle, W).
    pub walk: Vec<(f64, f64)>,
    /// The fine pass over the beam's edge (deg from the facing angle, W).
    pub fine: Vec<(f64, f64)>,
    /// The signature's readings before the ranges' correction (crate::characterise::empty::RawSignature).
    pub signature_readings: Vec<empty::RawSignature>,
    /// The watch's readings (instrument time s, W).
    pub drift_readings: Vec<(f64, f64)>,
    /// Steps that could not be done, and why.
    pub not_done: Vec<String>,
    pub instrument_s: f64,
}
