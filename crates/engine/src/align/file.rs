//! The calibration file `gonio align` writes and `gonio run --calibration` reads: a header naming the
//! instrument file it belongs to (name and SHA-256), the software and the time, then every fitted value with its
//! standard uncertainty, and what could not be observed.

use gonio_results::provenance_summary::{iso8601_utc, sha256_hex};
use serde::{Deserialize, Serialize};

use gonio_instrument::Instrument;

use super::AlignmentReport;
use super::beam_split::BeamSplit;
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

    /// The geometric model's parameters a correction applies on `instrument` (a value the file does not give
    /// is 0).
    ///
    /// A value the scans could not observe stays at its nominal 0: its fitted value is its prior's, moved along
    /// a direction the observations do not constrain by whatever they weakly see, and applying it would move
    /// the arms by that noise (a beam offset of half a millimetre "found" where the truth is a tenth). Where an
    /// observed combination stands for it, the combination is kept: the beam's line (`beam_line_deg`), when the
    /// beam's lateral offset is not observable, is split between the beam's direction and its offset by the
    /// instrument file's priors (crate::align::beam_split; all direction when they say nothing). The sample's own
    /// tilt (`sample_own_tilt_*`, crate::align::sample_tilt), when it was measured, replaces the mirror's.
    pub fn params(&self, instrument: &Instrument) -> GeometryParams {
        let mut x = self.pick(|v| v.value);
        for pair in &BEAM_PAIRS {
            if let Some((line, _)) = self.beam_line(pair) {
                pair.set(&mut x, beam_at(BeamSplit::of(instrument), line, false));
            }
        }
        GeometryParams::from_slice(&x)
    }

    /// The applied parameters ([`Self::params`]) moved by each uncertainty the file gives, one at a time, with
    /// the name of what moved: each picked parameter by its standard uncertainty; in each plane (the arms' and
    /// across it) where the beam's line stands for the beam, the line by its uncertainty (`beam_line_deg`,
    /// `beam_elevation_line_deg`, split as the line is) and the beam's direction along the line held
    /// (`beam_deg`, `beam_elevation_deg`, by the split's uncertainty); where a file has no line, the beam's
    /// direction and offset by the file's priors. What an alignment's uncertainty does to a campaign's angles,
    /// one independent error each (crate::budget's pointing).
    pub fn perturbations(&self, instrument: &Instrument) -> Vec<(&'static str, GeometryParams)> {
        let base = self.params(instrument).to_vec();
        let u = self.pick(|v| v.u);
        let moved = |change: &dyn Fn(&mut [f64; N_PARAMS])| {
            let mut x = base;
            change(&mut x);
            GeometryParams::from_slice(&x)
        };
        let mut out: Vec<(&'static str, GeometryParams)> = (0..N_PARAMS)
            .filter(|&k| u[k] > 0.0 && u[k].is_finite())
            .map(|k| (PARAM_NAMES[k].0, moved(&|x| x[k] += u[k])))
            .collect();
        let split = BeamSplit::of(instrument);
        for pair in &BEAM_PAIRS {
            if let Some((line, line_u)) = self.beam_line(pair) {
                if line_u > 0.0 {
                    let beam = beam_at(split, line + line_u, false);
                    out.push((pair.line, moved(&|x| pair.set(x, beam))));
                }
                if split.is_some_and(|s| s.held_line_u_deg > 0.0) {
                    let beam = beam_at(split, line, true);
                    out.push((pair.direction, moved(&|x| pair.set(x, beam))));
                }
                continue;
            }
            // A file whose alignment fitted the beam but holds no line for it (an older gonio's): the beam stays
            // at 0 there, uncertain by the instrument file's priors (crate::align::priors).
            let prior = super::priors::prior_u(instrument);
            for name in [pair.direction, pair.offset] {
                if let Some(k) = PARAM_NAMES.iter().position(|(n, _)| *n == name)
                    && self.values.iter().any(|v| v.name == name)
                    && u[k] == 0.0
                    && prior[k] > 0.0
                    && prior[k].is_finite()
                {
                    out.push((PARAM_NAMES[k].0, moved(&|x| x[k] += prior[k])));
                }
            }
        }
        out
    }

    /// The beam's observed line (value, u; deg) in `pair`'s plane when it stands for the beam: the line
    /// observed, the offset not.
    fn beam_line(&self, pair: &BeamPair) -> Option<(f64, f64)> {
        let get = |name: &str| self.values.iter().find(|v| v.name == name);
        if get(pair.offset).is_some_and(|v| v.observable) {
            return None;
        }
        get(pair.line).filter(|v| v.observable).map(|v| (v.value, v.u))
    }

    /// The parameters by [`Self::params`]'s rules, each value's `of`, the beam's line aside.
    fn pick(&self, of: impl Fn(&Value) -> f64) -> [f64; N_PARAMS] {
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
        x
    }
}

/// The beam's `(beam_deg, beam_lateral_mm)` for its line at `line_deg`: split by `split` (moved along the line
/// by the split's uncertainty when `moved`), all direction without one.
fn beam_at(split: Option<BeamSplit>, line_deg: f64, moved: bool) -> (f64, f64) {
    match (split, moved) {
        (Some(s), false) => s.params(line_deg),
        (Some(s), true) => s.moved_along_line(line_deg),
        (None, _) => (line_deg, 0.0),
    }
}

/// The beam's observed line in one plane and the two parameters it stands for.
struct BeamPair {
    line: &'static str,
    direction: &'static str,
    offset: &'static str,
}

/// In the plane of the arms, and out of it.
const BEAM_PAIRS: [BeamPair; 2] = [
    BeamPair {
        line: "beam_line_deg",
        direction: "beam_deg",
        offset: "beam_lateral_mm",
    },
    BeamPair {
        line: "beam_elevation_line_deg",
        direction: "beam_elevation_deg",
        offset: "beam_vertical_mm",
    },
];

impl BeamPair {
    /// `x`'s direction and offset in this plane set to `beam`.
    fn set(&self, x: &mut [f64], (direction, offset): (f64, f64)) {
        let index = |name: &str| PARAM_NAMES.iter().position(|(n, _)| *n == name);
        if let (Some(a), Some(h)) = (index(self.direction), index(self.offset)) {
            x[a] = direction;
            x[h] = offset;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use gonio_instrument::InstrumentFile;

    fn value(name: &str, value: f64, u: f64, unit: &str, observable: bool) -> String {
        format!(
            "[[values]]\nname = \"{name}\"\nvalue = {value:e}\nu = {u:e}\nunit = \"{unit}\"\nobservable = {observable}\n"
        )
    }

    /// A calibration whose beam is seen only as its lines (the elevation's when `elevation_line`).
    fn calibration(elevation_line: bool) -> CalibrationFile {
        let mut text = "[calibration]\ninstrument = \"x\"\ninstrument_sha256 = \"0\"\nsoftware = \"gonio\"\n\
                        created_utc = \"now\"\ndry_run = true\nmethod = \"test\"\n"
            .to_string();
        text += &value("beam_deg", 0.5, 0.3, "deg", false);
        text += &value("beam_lateral_mm", -1.0, 1.5, "mm", false);
        text += &value("beam_elevation_deg", 0.4, 0.3, "deg", false);
        text += &value("beam_vertical_mm", 1.0, 1.5, "mm", false);
        text += &value("detector_zero_deg", 0.01, 0.002, "deg", true);
        text += &value("beam_line_deg", 0.03, 0.01, "deg", true);
        if elevation_line {
            text += &value("beam_elevation_line_deg", -0.02, 0.01, "deg", true);
        }
        CalibrationFile::parse(&text, "test").expect("a calibration")
    }

    fn line(d: f64, direction_deg: f64, offset_mm: f64) -> f64 {
        direction_deg - (offset_mm / d).asin().to_degrees()
    }

    #[test]
    fn each_planes_line_is_split_by_the_priors_and_kept() {
        let mut inst = InstrumentFile::simulated().instrument;
        inst.source.pointing_u_deg = Some(0.01);
        inst.source.offset_u_mm = Some(0.07);
        let d = inst.detector.distance_mm;
        let split = BeamSplit::of(&inst).expect("priors");
        let p = calibration(true).params(&inst);
        assert!(
            (line(d, p.beam_deg, p.beam_lateral_mm) - 0.03).abs() < 1e-12,
            "{p:?}"
        );
        assert!((p.beam_deg - split.direction_share * 0.03).abs() < 1e-15);
        assert!(
            (line(d, p.beam_elevation_deg, p.beam_vertical_mm) + 0.02).abs() < 1e-12,
            "{p:?}"
        );
        assert_eq!(p.detector_zero_deg, 0.01);
        let names: Vec<&str> = calibration(true)
            .perturbations(&inst)
            .iter()
            .map(|(n, _)| *n)
            .collect();
        assert_eq!(
            names,
            [
                "detector_zero_deg",
                "beam_line_deg",
                "beam_deg",
                "beam_elevation_line_deg",
                "beam_elevation_deg"
            ]
        );
        // Moving along the line held keeps the line; moving the line moves it by its uncertainty.
        for (name, moved) in calibration(true).perturbations(&inst) {
            let l = line(d, moved.beam_deg, moved.beam_lateral_mm);
            match name {
                "beam_deg" => assert!((l - 0.03).abs() < 1e-12 && moved.beam_deg > p.beam_deg),
                "beam_line_deg" => assert!((l - 0.04).abs() < 1e-12),
                _ => assert!((l - 0.03).abs() < 1e-12, "{name}"),
            }
        }
    }

    #[test]
    fn a_file_without_the_elevations_line_moves_the_beam_out_of_the_plane_by_the_priors() {
        let mut inst = InstrumentFile::simulated().instrument;
        inst.source.pointing_u_deg = Some(0.01);
        inst.source.offset_u_mm = Some(0.07);
        let p = calibration(false).params(&inst);
        assert_eq!((p.beam_elevation_deg, p.beam_vertical_mm), (0.0, 0.0));
        let moved: Vec<(&str, GeometryParams)> = calibration(false).perturbations(&inst);
        let find = |name: &str| moved.iter().find(|(n, _)| *n == name).map(|(_, m)| *m);
        assert_eq!(
            find("beam_elevation_deg").expect("moved").beam_elevation_deg,
            0.01
        );
        assert_eq!(find("beam_vertical_mm").expect("moved").beam_vertical_mm, 0.07);
    }
}
