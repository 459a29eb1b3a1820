//! The calibration file `gonio align` writes and `gonio run --calibration` reads: a header naming the
//! instrument file it belongs to (name and SHA-256), the software and the time, then every fitted value with its
//! standard uncertainty, and what could not be observed.

use gonio_results::provenance_summary::{iso8601_utc, sha256_hex};
use serde::{Deserialize, Serialize};

use super::AlignmentReport;
use super::model::{GeometryParams, N_PARAMS, PARAM_NAMES};
use crate::characterise::{DetectorCalibration, SourceDrift};

/// The calibration file's contents.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CalibrationFile {
    pub calibration: Header,
    pub values: Vec<Value>,
    #[serde(default)]
    pub unobservable: Vec<String>,
    /// The detector's characterisation (crate::characterise), when it ran.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub detector: Option<DetectorCalibration>,
    /// The source's warm-up and drift, when they were watched.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub source: Option<SourceDrift>,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Header {
    pub instrument: String,
    pub instrument_sha256: String,
    pub software: String,
    pub created_utc: String,
    pub dry_run: bool,
    pub method: String,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Value {
    pub name: String,
    pub value: f64,
    pub u: f64,
    pub unit: String,
    pub observable: bool,
}

/// Why a calibration file cannot be used.
#[derive(Debug, thiserror::Error)]
pub enum CalibrationFileError {
    #[error("{origin}: not a calibration file: {source}")]
    Parse {
        origin: String,
        #[source]
        source: toml::de::Error,
    },
    #[error("{origin}: value {name} is not finite ({value})")]
    NotFinite {
        origin: String,
        name: String,
        value: f64,
    },
    #[error(
        "{origin} was made for instrument file {made_for:?} with SHA-256 {expected}, not this one ({actual}): align this \
         instrument (`gonio align`) or use its own calibration"
    )]
    OtherInstrument {
        origin: String,
        made_for: String,
        expected: String,
        actual: String,
    },
}

impl CalibrationFile {
    /// The file for `report`, made with `instrument_text` at unix time `now_s`.
    pub fn from_report(r: &AlignmentReport, instrument_text: &str, now_s: f64) -> CalibrationFile {
        CalibrationFile {
            calibration: Header {
                instrument: r.instrument.clone(),
                instrument_sha256: sha256_hex(instrument_text.as_bytes()),
                software: format!("gonio {}", env!("CARGO_PKG_VERSION")),
                created_utc: iso8601_utc(now_s),
                dry_run: r.dry_run,
                method: if r.characterisation.is_some() {
                    "scans through the direct beam and a mirror's reflection (edge mid-points), fitted with the \
                     geometric model of gonio_engine::align::model; the meter's ranges from darks and overlaps, the \
                     instrument signature and the source's drift with the holder empty (gonio_engine::characterise); \
                     u is the standard uncertainty"
                } else {
                    "scans through the direct beam and a mirror's reflection (edge mid-points), fitted with the \
                     geometric model of gonio_engine::align::model; u is the standard uncertainty"
                }
                .into(),
            },
            values: r
                .estimates
                .iter()
                .map(|e| Value {
                    name: e.name.clone(),
                    value: e.value,
                    u: e.u,
                    unit: e.unit.clone(),
                    observable: e.observable,
                })
                .collect(),
            unobservable: r.unobservable.clone(),
            detector: r.characterisation.as_ref().map(|c| c.detector.clone()),
            source: r.characterisation.as_ref().and_then(|c| c.source.clone()),
        }
    }

    /// The file as TOML, with a comment line first.
    pub fn to_toml(&self) -> Result<String, toml::ser::Error> {
        Ok(format!(
            "# Alignment of instrument {} by `gonio align` at {}. Apply with `gonio run --calibration FILE`.\n{}",
            self.calibration.instrument,
            self.calibration.created_utc,
            toml::to_string(self)?
        ))
    }

    /// Read a calibration file (`origin` names it in errors).
    pub fn parse(text: &str, origin: &str) -> Result<CalibrationFile, CalibrationFileError> {
        let file: CalibrationFile = toml::from_str(text).map_err(|source| CalibrationFileError::Parse {
            origin: origin.to_string(),
            source,
        })?;
        if let Some(v) = file
            .values
            .iter()
            .find(|v| !(v.value.is_finite() && v.u.is_finite()))
        {
            return Err(CalibrationFileError::NotFinite {
                origin: origin.to_string(),
                name: v.name.clone(),
                value: v.value,
            });
        }
        Ok(file)
    }

    /// Refuse a calibration made for another instrument file than `instrument_text`.
    pub fn check_instrument(&self, instrument_text: &str, origin: &str) -> Result<(), CalibrationFileError> {
        let actual = sha256_hex(instrument_text.as_bytes());
        if actual == self.calibration.instrument_sha256 {
            Ok(())
        } else {
            Err(CalibrationFileError::OtherInstrument {
                origin: origin.to_string(),
                made_for: self.calibration.instrument.clone(),
                expected: self.calibration.instrument_sha256.clone(),
                actual,
            })
        }
    }

    /// The geometric model's parameters a correction applies (a value the file does not give is 0).
    ///
    /// A value the scans could not observe stays at its nominal 0: its fitted value is its prior's, moved along
    /// a direction the observations do not constrain by whatever they weakly see, and applying it would move
    /// the arms by that noise (a beam offset of half a millimetre "found" where the truth is a tenth). Where an
    /// observed combination stands for it, the combination is kept: the beam's line (`beam_line_deg`) becomes
    /// its direction when the beam's lateral offset is not observable. The sample's own tilt
    /// (`sample_own_tilt_*`, crate::align::sample_tilt), when it was measured, replaces the mirror's.
    pub fn params(&self) -> GeometryParams {
        self.pick(|v| v.value)
    }

    /// Each of [`Self::params`]'s standard uncertainties, the same values picked (0 where a parameter keeps
    /// its nominal 0): what the angles of a campaign the calibration was applied to are uncertain by.
    pub fn params_u(&self) -> GeometryParams {
        self.pick(|v| v.u)
    }

    /// The parameters by [`Self::params`]'s rules, each value's `of`.
    fn pick(&self, of: impl Fn(&Value) -> f64) -> GeometryParams {
        let mut x = [0.0; N_PARAMS];
        let get = |name: &str| self.values.iter().find(|v| v.name == name);
        for (k, (name, _)) in PARAM_NAMES.iter().enumerate() {
            if let Some(v) = get(name).filter(|v| v.observable) {
                x[k] = of(v);
            }
        }
        // Aligned on the sample itself: its own tilt, as it sat, stands for the mirror's.
        for (own, of_mirror) in [
            ("sample_own_tilt_x_deg", "sample_tilt_x_deg"),
            ("sample_own_tilt_y_deg", "sample_tilt_y_deg"),
        ] {
            if let (Some(v), Some(k)) = (
                get(own).filter(|v| v.observable),
                PARAM_NAMES.iter().position(|(n, _)| *n == of_mirror),
            ) {
                x[k] = of(v);
            }
        }
        let lateral_seen = get("beam_lateral_mm").is_some_and(|v| v.observable);
        if let (false, Some(line), Some(k)) = (
            lateral_seen,
            get("beam_line_deg").filter(|v| v.observable),
            PARAM_NAMES.iter().position(|(n, _)| *n == "beam_deg"),
        ) {
            x[k] = of(line);
        }
        GeometryParams::from_slice(&x)
    }
}
