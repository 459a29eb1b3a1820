//! The run record: a run's provenance, the content of `run.json`, in one typed form.
//!
//! `gonio run --out DIR` writes it as DIR/run.json; a campaign read from a daemon's store gets the same record
//! from the same facts (crates/engine/src/export.rs assembles both from the store), so the two export
//! byte-identical provenance. It is therefore a function of what the store holds: the campaign row, its
//! points, calibrations and device identities, and the prediction of its stored configuration. What one process
//! saw and the store does not keep (the wall time of the last `gonio run`) is printed, not recorded.
//!
//! Layout (keys of the JSON object): `campaign` (id, name, state, last error, counts, flag counts, creation
//! time), `software_version`, `config` (`campaign_toml`, `instrument_toml`: the texts the run used),
//! `devices` (name, identity), `calibrations`, `timing` (predicted and actual instrument time), `truth`
//! (dry-runs: errors against the simulator's ground truth), and on an imperfect simulated instrument
//! `simulator_truth` (its hidden imperfections, [`SimulatorTruth`]; absent otherwise, so the ideal instrument's
//! run.json is unchanged).

mod simulator_truth;

pub use simulator_truth::{
    ActualAxisRecord, ActualHardwareRecord, AxisTruthRecord, BeamTruthRecord, DetectorTruthRecord,
    FilterTruthRecord, FiltersTruthRecord, GeometryTruthRecord, RangeTruthRecord, SampleTruthRecord,
    SeatingRecord, SimulatorTruth, SourceTruthRecord,
};

use crate::budget_summary::{BudgetSummary, summarise};
use std::collections::BTreeMap;

use serde::de::DeserializeOwned;
use serde::{Deserialize, Serialize};
use serde_json::Value;

use crate::error::ResultsError;
use crate::points::Point;

/// The whole run record (module doc).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RunRecord {
    pub campaign: CampaignSummary,
    /// The software that measured, e.g. "gonio 0.1.0".
    pub software_version: String,
    pub config: RunConfig,
    pub devices: Vec<DeviceIdentity>,
    pub calibrations: Vec<CalibrationReading>,
    pub timing: Timing,
    pub truth: TruthSummary,
    /// The points' uncertainty budgets over the run (crate::budget_summary); absent for runs without budgets.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub uncertainty: Option<BudgetSummary>,
    /// An imperfect simulated instrument's hidden values; absent on the ideal one and on hardware.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub simulator_truth: Option<SimulatorTruth>,
}

/// The campaign's identity, state and counts.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CampaignSummary {
    /// The store's campaign id.
    pub id: i64,
    /// The campaign (sample) id from `[campaign] id`.
    pub name: String,
    /// queued, running, pausing, paused, waiting-operator, completed, aborted, failed.
    pub state: String,
    pub last_error: Option<String>,
    pub dry_run: bool,
    pub total_points: u64,
    /// Points committed (valid, flagged or failed).
    pub points_done: u64,
    pub valid_points: u64,
    pub failed_points: u64,
    /// How many points carry each flag (the flag's words before any `:`).
    pub flags: BTreeMap<String, u64>,
    /// When the campaign was stored, Unix seconds. Absent from run.json files written before it was recorded.
    #[serde(default)]
    pub created_unix_s: Option<f64>,
}

/// The configuration the run used, verbatim as stored (the campaign text ends with its `[resolved]` materials).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RunConfig {
    pub campaign_toml: String,
    pub instrument_toml: String,
    /// The alignment calibration applied to every point's pose (`gonio align`'s file, verbatim); null when none
    /// was (absent from run.json files written before it was recorded).
    #[serde(default)]
    pub alignment_toml: Option<String>,
}

/// A device and the identity string it reported (e.g. `*IDN?`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct DeviceIdentity {
    pub name: String,
    pub identity: String,
}

/// One calibration reading (direct beam, reference sample, dark).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CalibrationReading {
    /// "direct-beam", "reference" or "dark".
    pub kind: String,
    pub band_nm: Option<f64>,
    /// Instrument time of the reading, s from the start of the run.
    pub t_s: f64,
    pub value_w: f64,
    pub u_w: f64,
}

/// Instrument time, s.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Timing {
    /// The time model's prediction for the stored configuration; `None` when that no longer parses.
    pub predicted_instrument_s: Option<f64>,
    /// When the last run ended (its closing wheel turn and operator step included), else the last point's or
    /// calibration reading's instrument time: what the time model predicts.
    pub actual_instrument_s: f64,
}

/// Dry-runs: the measured values against the simulator's ground truth; `None` without a valid point that has one.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TruthSummary {
    pub against_aperture_average: Option<TruthErrors>,
    pub against_point_value: Option<TruthErrors>,
}

/// Error of a dry-run against the simulator's ground truth, over valid points (a BRDF value and a truth).
/// Metrics of radiometry-and-materials.md "Error metrics": cosine-weighted relative RMS
/// `sqrt(sum(((f - t) cos theta_i)^2) / sum((t cos theta_i)^2))`, RMS log error
/// `sqrt(mean((ln(1 + f cos theta_i) - ln(1 + t cos theta_i))^2))`, and the largest relative error `|f - t| / t`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct TruthErrors {
    pub points: u64,
    /// `None` when every truth is zero (the ratio has no denominator).
    pub cos_weighted_relative_rms: Option<f64>,
    pub log_rms: f64,
    pub max_relative_error: f64,
    /// Largest |f - t| / u (u: the point's standard uncertainty).
    pub max_normalised_error: f64,
}

/// A valid point's value and the simulator's BRDF at its nominal geometry, for [`truth_errors`].
pub fn against_point_truth(p: &Point) -> Option<(f64, f64)> {
    Some((p.value()?, p.truth_point_sr?))
}

/// A valid point's aperture average (its value before the aperture correction, when it had one) and the
/// simulator's aperture average, for [`truth_errors`].
pub fn against_aperture_truth(p: &Point) -> Option<(f64, f64)> {
    let f = p.value()?;
    Some((p.brdf_aperture_sr.unwrap_or(f), p.truth_aperture_sr?))
}

/// Errors of the valid points against their truth, `pair` giving a point's value and its truth
/// ([`against_point_truth`], [`against_aperture_truth`]); `None` without such a point.
pub fn truth_errors(points: &[Point], pair: impl Fn(&Point) -> Option<(f64, f64)>) -> Option<TruthErrors> {
    let (mut n, mut num, mut den, mut log2, mut max_rel, mut max_norm) =
        (0u64, 0.0, 0.0, 0.0, 0.0f64, 0.0f64);
    for p in points {
        let Some((f, t)) = pair(p) else {
            continue;
        };
        if !t.is_finite() {
            continue;
        }
        let c = p.theta_i_deg.to_radians().cos();
        n += 1;
        num += ((f - t) * c).powi(2);
        den += (t * c).powi(2);
        log2 += ((1.0 + f * c).max(1e-300).ln() - (1.0 + t * c).max(1e-300).ln()).powi(2);
        if t > 0.0 {
            max_rel = max_rel.max((f - t).abs() / t);
        }
        if let Some(u) = p.brdf_u_sr.filter(|u| *u > 0.0) {
            max_norm = max_norm.max((f - t).abs() / u);
        }
    }
    (n > 0).then(|| TruthErrors {
        points: n,
        cos_weighted_relative_rms: (den > 0.0).then(|| (num / den).sqrt()),
        log_rms: (log2 / n as f64).sqrt(),
        max_relative_error: max_rel,
        max_normalised_error: max_norm,
    })
}

/// What the store keeps about a campaign, besides its points: the inputs of [`RunRecord::assemble`].
#[derive(Debug, Clone, PartialEq)]
pub struct StoredCampaign {
    pub id: i64,
    pub name: String,
    pub state: String,
    pub last_error: Option<String>,
    pub dry_run: bool,
    pub total_points: u64,
    pub points_done: u64,
    pub created_unix_s: f64,
    pub software_version: String,
    pub config: RunConfig,
    pub devices: Vec<DeviceIdentity>,
    pub calibrations: Vec<CalibrationReading>,
    pub predicted_instrument_s: Option<f64>,
    /// Instrument time (s) at which the last run ended (after its closing wheel turn and operator step), if
    /// recorded.
    pub ended_instrument_s: Option<f64>,
    /// The simulated instrument's hidden imperfections (a function of the stored instrument file).
    pub simulator_truth: Option<SimulatorTruth>,
}

impl RunRecord {
    /// The record of a stored campaign and its points: counts, timing and truth errors derived from the points.
    pub fn assemble(stored: StoredCampaign, points: &[Point]) -> RunRecord {
        let valid_points = points.iter().filter(|p| p.is_valid()).count() as u64;
        let failed_points = points
            .iter()
            .filter(|p| p.flags.iter().any(|f| f.starts_with("failed")))
            .count() as u64;
        let mut flags = BTreeMap::<String, u64>::new();
        for p in points {
            for f in &p.flags {
                let key = f.split(':').next().unwrap_or(f).to_string();
                *flags.entry(key).or_default() += 1;
            }
        }
        let actual_instrument_s = points
            .iter()
            .filter_map(|p| p.t_s)
            .chain(stored.calibrations.iter().map(|c| c.t_s))
            .chain(stored.ended_instrument_s)
            .filter(|t| t.is_finite())
            .fold(0.0f64, f64::max);
        RunRecord {
            campaign: CampaignSummary {
                id: stored.id,
                name: stored.name,
                state: stored.state,
                last_error: stored.last_error,
                dry_run: stored.dry_run,
                total_points: stored.total_points,
                points_done: stored.points_done,
                valid_points,
                failed_points,
                flags,
                created_unix_s: Some(stored.created_unix_s),
            },
            software_version: stored.software_version,
            config: stored.config,
            devices: stored.devices,
            calibrations: stored.calibrations,
            timing: Timing {
                predicted_instrument_s: stored.predicted_instrument_s,
                actual_instrument_s,
            },
            truth: TruthSummary {
                against_aperture_average: truth_errors(points, against_aperture_truth),
                against_point_value: truth_errors(points, against_point_truth),
            },
            uncertainty: summarise(points),
            simulator_truth: stored.simulator_truth,
        }
    }

    /// The record as a JSON value (an object; keys in the order serde_json's map keeps them).
    pub fn to_value(&self) -> Value {
        // A struct of strings, numbers, options and maps with string keys always serialises.
        serde_json::to_value(self).unwrap_or(Value::Null)
    }

    /// The text of run.json: the record as pretty JSON, from [`RunRecord::to_value`] so that the file, a JSON
    /// export and a CSV export list the keys in the same order.
    pub fn to_json_text(&self) -> String {
        let mut text = serde_json::to_string_pretty(&self.to_value()).unwrap_or_default();
        text.push('\n');
        text
    }

    /// Reads a run.json; `origin` names it in errors. Each part is read on its own, so that an error names the
    /// key that is wrong; unknown keys are ignored (a newer or older gonio may add or drop some).
    pub fn parse(text: &str, origin: &str) -> Result<RunRecord, ResultsError> {
        let err = |message: String| ResultsError::Json {
            origin: origin.to_string(),
            message,
        };
        let value: Value = serde_json::from_str(text).map_err(|e| err(format!("not valid JSON: {e}")))?;
        let Some(object) = value.as_object() else {
            return Err(err(
                "expected a JSON object (the run's provenance), found another value".into(),
            ));
        };
        fn part<T: DeserializeOwned>(
            object: &serde_json::Map<String, Value>,
            key: &str,
            err: &dyn Fn(String) -> ResultsError,
        ) -> Result<T, ResultsError> {
            let v = object
                .get(key)
                .ok_or_else(|| err(format!("key `{key}` is missing")))?;
            T::deserialize(v).map_err(|e| err(format!("key `{key}`: {e}")))
        }
        Ok(RunRecord {
            campaign: part(object, "campaign", &err)?,
            software_version: part(object, "software_version", &err)?,
            config: part(object, "config", &err)?,
            devices: part(object, "devices", &err)?,
            calibrations: part(object, "calibrations", &err)?,
            timing: part(object, "timing", &err)?,
            truth: part(object, "truth", &err)?,
            uncertainty: match object.get("uncertainty") {
                None => None,
                Some(_) => Some(part(object, "uncertainty", &err)?),
            },
            simulator_truth: match object.get("simulator_truth") {
                None => None,
                Some(_) => Some(part(object, "simulator_truth", &err)?),
            },
        })
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use proptest::prelude::*;

    fn stored() -> StoredCampaign {
        StoredCampaign {
            id: 3,
            name: "t".into(),
            state: "completed".into(),
            last_error: None,
            dry_run: true,
            total_points: 2,
            points_done: 2,
            created_unix_s: 1.7e9,
            software_version: "gonio 0.1.0".into(),
            config: RunConfig {
                campaign_toml: "[campaign]\nid = \"t\"\n".into(),
                instrument_toml: "[instrument]\n".into(),
                alignment_toml: None,
            },
            devices: vec![DeviceIdentity {
                name: "meter".into(),
                identity: "PM100".into(),
            }],
            calibrations: vec![CalibrationReading {
                kind: "direct-beam".into(),
                band_nm: Some(550.0),
                t_s: 1.0,
                value_w: 5e-4,
                u_w: 1e-7,
            }],
            predicted_instrument_s: Some(20.5),
            ended_instrument_s: None,
            simulator_truth: None,
        }
    }

    /// A record with every part filled, for the tests of this crate.
    pub(crate) fn sample_record() -> RunRecord {
        RunRecord::assemble(stored(), &[])
    }

    fn point(flags: &[&str], f: Option<f64>, truth: Option<f64>, t_s: f64) -> Point {
        Point {
            index: 0,
            band_nm: 550.0,
            theta_i_deg: 0.0,
            phi_i_deg: 0.0,
            theta_o_deg: 30.0,
            phi_o_deg: 180.0,
            signal_w: None,
            dark_w: None,
            incident_w: None,
            brdf_sr: f,
            brdf_u_sr: Some(0.01),
            flags: flags.iter().map(|s| s.to_string()).collect(),
            t_s: Some(t_s),
            readback_deg: Vec::new(),
            brdf_aperture_sr: None,
            budget: Default::default(),
            truth_point_sr: truth,
            truth_aperture_sr: truth,
        }
    }

    #[test]
    fn assemble_counts_times_and_compares_with_the_truth() {
        let points = [
            point(&[], Some(0.22), Some(0.2), 5.0),
            point(&["failed: meter timeout"], None, Some(0.2), 9.0),
            point(&["saturated"], Some(1.0), Some(0.2), 7.0),
        ];
        let mut stored = stored();
        stored.calibrations[0].t_s = 12.0;
        let r = RunRecord::assemble(stored, &points);
        assert_eq!((r.campaign.valid_points, r.campaign.failed_points), (1, 1));
        assert_eq!(r.campaign.flags.get("failed"), Some(&1));
        assert_eq!(r.campaign.flags.get("saturated"), Some(&1));
        assert_eq!(
            r.timing.actual_instrument_s, 12.0,
            "the final calibration ends the run"
        );
        let e = r.truth.against_aperture_average.expect("one valid point");
        assert_eq!(e.points, 1);
        assert!((e.max_relative_error - 0.1).abs() < 1e-12);
        assert!((e.max_normalised_error - 2.0).abs() < 1e-9);
    }

    #[test]
    fn run_json_round_trips_exactly() {
        let mut r = sample_record();
        r.calibrations[0].value_w = 0.1 + 0.2;
        r.truth.against_point_value = Some(TruthErrors {
            points: 4,
            cos_weighted_relative_rms: None,
            log_rms: 1.0 / 3.0,
            max_relative_error: 2e-17,
            max_normalised_error: 0.0,
        });
        let text = r.to_json_text();
        let back = RunRecord::parse(&text, "run.json").expect("reads back");
        assert_eq!(back, r);
        assert_eq!(
            back.to_json_text(),
            text,
            "writing what was read gives the same bytes"
        );
    }

    #[test]
    fn simulator_truth_is_absent_when_none_and_round_trips_when_present() {
        let ideal = sample_record();
        assert!(!ideal.to_json_text().contains("simulator_truth"));
        let mut r = sample_record();
        r.simulator_truth = Some(SimulatorTruth {
            seed: 9,
            geometry: Some(GeometryTruthRecord {
                axes: vec![AxisTruthRecord {
                    role: "light-arm".into(),
                    zero_offset_deg: 0.013,
                    encoder_amplitude_deg: 0.002,
                    encoder_harmonic: 1,
                    encoder_phase_deg: 123.0,
                }],
                sample_tilt_x_deg: 0.05,
                sample_tilt_y_deg: -0.02,
                eccentricity_x_mm: 0.1,
                eccentricity_y_mm: -0.2,
                aperture_radius_error_mm: 0.0012,
                detector_distance_error_mm: -0.08,
                seatings: vec![SeatingRecord {
                    index: 0,
                    tilt_x_deg: 0.01,
                    tilt_y_deg: 0.0,
                }],
            }),
            detector: Some(DetectorTruthRecord {
                ranges: vec![RangeTruthRecord {
                    gain: 1e-3,
                    nonlinearity: -2e-3,
                    offset_fs: 1e-4,
                }],
                saturation_current_a: 2.5,
                amplifier_noise_a_per_rthz: 0.0,
                signature_peak_sr: 1e-3,
                signature_width_deg: 2.0,
                signature_floor_sr: 1e-5,
                ambient_a: 2e-11,
                ambient_variation: 0.2,
                ambient_period_s: 1800.0,
                ambient_phase_deg: 40.0,
                reading_delay_s: 0.0,
            }),
            source: Some(SourceTruthRecord {
                warmup_fraction: 0.01,
                warmup_time_s: 600.0,
                random_walk_per_rthour: 5e-4,
                flicker_rms: 2e-4,
            }),
            sample: Some(SampleTruthRecord {
                gradient_x: 0.002,
                gradient_y: -0.001,
                radial: 0.003,
            }),
            filters: Some(FiltersTruthRecord {
                cavities: 3,
                source_temperature_k: 3000.0,
                out_of_band_transmission: 1e-5,
                leakage_range_nm: [400.0, 1100.0],
                filters: vec![FilterTruthRecord {
                    position: 2,
                    nominal_nm: 550.0,
                    nominal_bandwidth_nm: 10.0,
                    centre_nm: 550.8,
                    bandwidth_nm: 9.6,
                }],
            }),
            beam: Some(BeamTruthRecord {
                profile: "gaussian".into(),
                gaussian_radius_mm: 1.5,
                pointing_in_plane_deg: 0.004,
                pointing_vertical_deg: -0.002,
                source_distance_mm: 500.0,
                divergence_deg: 0.055,
                nominal_divergence_deg: 0.05,
            }),
            actual: Some(ActualHardwareRecord {
                wheel_seconds_per_position: Some(2.0),
                axes: vec![ActualAxisRecord {
                    name: "detector".into(),
                    max_speed_deg_s: Some(10.0),
                    accel_deg_s2: None,
                    settle_s: None,
                    backlash_deg: None,
                }],
                detector_dark_current_a: Some(1.0e-10),
                source_relative_noise: None,
                reply_latency_ms: [("arms".to_string(), 10.0)].into(),
                position_sampled_ms: [("arms".to_string(), 6.0)].into(),
            }),
        });
        let text = r.to_json_text();
        assert!(text.contains("\"simulator_truth\""));
        assert_eq!(RunRecord::parse(&text, "run.json").expect("reads"), r);
    }

    #[test]
    fn errors_name_the_file_and_the_key() {
        let e = RunRecord::parse("[1, 2]", "r.json")
            .expect_err("array")
            .to_string();
        assert!(e.starts_with("r.json: expected a JSON object"), "{e}");
        let mut v = sample_record().to_value();
        v["devices"] = serde_json::json!(3);
        let e = RunRecord::parse(&v.to_string(), "r.json")
            .expect_err("bad type")
            .to_string();
        assert!(e.contains("key `devices`") && e.contains("sequence"), "{e}");
        let mut v = sample_record().to_value();
        v.as_object_mut().expect("object").remove("timing");
        let e = RunRecord::parse(&v.to_string(), "r.json")
            .expect_err("missing part")
            .to_string();
        assert!(e.contains("key `timing` is missing"), "{e}");
        let e = RunRecord::parse("{\"campaign\": ", "dir/run.json")
            .expect_err("truncated")
            .to_string();
        assert!(e.starts_with("dir/run.json: not valid JSON"), "{e}");
    }

    #[test]
    fn older_files_without_the_creation_time_and_with_the_wall_time_still_read() {
        let mut v = sample_record().to_value();
        v["campaign"]
            .as_object_mut()
            .expect("object")
            .remove("created_unix_s");
        v["timing"]["wall_s"] = serde_json::json!(1.5);
        let r = RunRecord::parse(&v.to_string(), "old.json").expect("reads");
        assert_eq!(r.campaign.created_unix_s, None);
    }

    proptest! {
        #[test]
        fn run_json_reader_never_panics(text in any::<String>()) {
            let _ = RunRecord::parse(&text, "fuzz.json");
        }

        #[test]
        fn run_json_reader_never_panics_on_jsonish(text in "[{}\\[\\]\":,0-9a-z_ ]{0,200}") {
            let _ = RunRecord::parse(&text, "fuzz.json");
        }
    }
}
