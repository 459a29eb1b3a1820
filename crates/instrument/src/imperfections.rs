//! `[simulator.imperfections]`: how imperfect the simulated instrument is, as MAGNITUDES.
//!
//! The file states the size of each error (a standard deviation or an amplitude); the simulator draws the hidden
//! actual values from `[simulator] seed` (simulator/src/imperfections/). Two instruments with the same
//! magnitudes and different seeds are two instruments of the same kind; the same seed is the same instrument.
//! Everything is zero by default: a file without the table (or with every key 0) is the ideal instrument, bit for
//! bit.
//!
//! One sub-table per group of effects, each a struct with `Default` = off and a `validate` that names its keys:
//! [`geometry`], [`detector`], [`source`], [`sample`], [`filters`], [`beam`]: the groups of
//! issue 16; [`timing`]: the hardware's speeds against the file's (issue 28).

pub mod beam;
pub mod detector;
pub mod filters;
pub mod geometry;
pub mod sample;
pub mod source;
pub mod timing;

use serde::{Deserialize, Serialize};

pub use beam::{BeamImperfections, BeamProfile};
pub use detector::DetectorImperfections;
pub use filters::FilterImperfections;
pub use geometry::GeometryImperfections;
pub use sample::SampleImperfections;
pub use source::SourceImperfections;
pub use timing::TimingImperfections;

/// `[simulator.imperfections]`: every group off by default.
#[derive(Debug, Clone, Default, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Imperfections {
    /// Where the axes and the sample really are (zero offsets, sample tilt, re-seating, eccentricity, encoder).
    #[serde(default)]
    pub geometry: GeometryImperfections,
    /// What the photodiode and the meter do to a reading (range gains, nonlinearity, offsets, saturation,
    /// amplifier noise, stray light by pose, ambient light).
    #[serde(default)]
    pub detector: DetectorImperfections,
    /// How the source's power really varies (warm-up, random walk, flicker).
    #[serde(default)]
    pub source: SourceImperfections,
    /// How the sample's reflectance varies over its area (gradient, centre to rim).
    #[serde(default)]
    pub sample: SampleImperfections,
    /// How wide the filters' bands really are and what they leak (finite bandwidth, out-of-band leakage).
    #[serde(default)]
    pub filters: FilterImperfections,
    /// What the beam really is (profile, pointing, divergence).
    #[serde(default)]
    pub beam: BeamImperfections,
    /// How fast the axes and the wheel really are, against the file's claims.
    #[serde(default)]
    pub timing: TimingImperfections,
}

/// Why `[simulator.imperfections]` was refused: the key (full TOML path) and the value.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ImperfectionsError {
    #[error("[simulator.imperfections.{group}] {key} must be finite and >= 0, got {value}")]
    Negative {
        group: &'static str,
        key: &'static str,
        value: f64,
    },
    #[error(
        "[simulator.imperfections.{group}] {key} = {value} is beyond the largest plausible {limit} ({why})"
    )]
    TooLarge {
        group: &'static str,
        key: &'static str,
        value: f64,
        limit: f64,
        why: &'static str,
    },
    #[error("[simulator.imperfections.geometry] encoder_error_harmonic must be at most {limit}, got {value}")]
    Harmonic { value: u32, limit: u32 },
    #[error("instrument file: {0}")]
    Text(String),
    #[error(
        "[simulator.imperfections.{group}] {key} must be [low, high] with low < high (nm), got [{lo}, {hi}]"
    )]
    Range {
        group: &'static str,
        key: &'static str,
        lo: f64,
        hi: f64,
    },
    #[error("[simulator.imperfections.{group}] {key} must be > 0 when {needed_by} is on, got {value}")]
    Needed {
        group: &'static str,
        key: &'static str,
        needed_by: &'static str,
        value: f64,
    },
}

/// The instrument file `text` with only the groups of `[simulator.imperfections]` named in `keep` (none: the
/// same instrument, ideal): how one group's effect is isolated (the benchmark's error budget, tests). Comments
/// are not kept. Without `filters` the simulated filters pass a single wavelength and leak nothing, and the
/// file's filter positions say so (`bandwidth_nm = 0`, `out_of_band_transmission = 0`): the completion
/// corrects every value for the leak the file states and counts its passband in each value's uncertainty,
/// which on filters that have neither would be an error, and a padding, of its own.
pub fn keep_only_groups(text: &str, keep: &[&str]) -> Result<String, ImperfectionsError> {
    let mut doc: toml::Table = text
        .parse()
        .map_err(|e| ImperfectionsError::Text(format!("{e}")))?;
    if let Some(groups) = doc
        .get_mut("simulator")
        .and_then(|s| s.get_mut("imperfections"))
        .and_then(|i| i.as_table_mut())
    {
        groups.retain(|group, _| keep.contains(&group));
    }
    if !keep.contains(&"filters")
        && let Some(positions) = doc
            .get_mut("instrument")
            .and_then(|i| i.get_mut("filter_wheel"))
            .and_then(|w| w.get_mut("positions"))
            .and_then(|p| p.as_array_mut())
    {
        for p in positions.iter_mut().filter_map(|p| p.as_table_mut()) {
            if p.contains_key("out_of_band_transmission") || p.contains_key("band_nm") {
                p.insert("out_of_band_transmission".into(), toml::Value::Float(0.0));
            }
            if p.contains_key("bandwidth_nm") {
                p.insert("bandwidth_nm".into(), toml::Value::Float(0.0));
            }
        }
    }
    toml::to_string(&doc).map_err(|e| ImperfectionsError::Text(e.to_string()))
}

/// One magnitude: finite, >= 0 and at most `limit` (`why` says what a larger value would mean).
pub(crate) fn check(
    group: &'static str,
    key: &'static str,
    value: f64,
    limit: f64,
    why: &'static str,
) -> Result<(), ImperfectionsError> {
    if !(value.is_finite() && value >= 0.0) {
        return Err(ImperfectionsError::Negative { group, key, value });
    }
    if value > limit {
        return Err(ImperfectionsError::TooLarge {
            group,
            key,
            value,
            limit,
            why,
        });
    }
    Ok(())
}

impl Imperfections {
    /// True when every magnitude is zero: the ideal instrument.
    pub fn is_ideal(&self) -> bool {
        self.geometry.is_ideal()
            && self.detector.is_ideal()
            && self.source.is_ideal()
            && self.sample.is_ideal()
            && self.filters.is_ideal()
            && self.beam.is_ideal()
            && self.timing.is_ideal()
    }

    pub fn validate(&self) -> Result<(), ImperfectionsError> {
        self.geometry.validate()?;
        self.detector.validate()?;
        self.source.validate()?;
        self.sample.validate()?;
        self.filters.validate()?;
        self.beam.validate()?;
        self.timing.validate()
    }
}
