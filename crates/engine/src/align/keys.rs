//! The alignment's estimates under the keys of a dry-run's `simulator_truth` (crates/results/src/provenance/
//! simulator_truth.rs): the same structure, axes by `role`, the simulator's sign conventions, each estimate `K`
//! with its standard uncertainty `K_u` beside it, so that a test (or a person) can hold one against the other.
//!
//! Keys, and what each estimate is:
//! - `geometry.axes[]` with `role` `detector-arm`: `zero_offset_deg`, and the once-per-revolution encoder error as
//!   `encoder_amplitude_deg`, `encoder_harmonic` (1) and `encoder_phase_deg` (true = nominal + zero + A sin(a +
//!   phase), a the nominal angle). The zero and the encoder terms are strongly correlated over the arcs scanned:
//!   `detector_error_at_deg` gives their sum, with its uncertainty, at a few angles in those arcs.
//! - `geometry.axes[]` with `role` `sample-tilt`: `zero_offset_deg`, the tilt's true angle at nominal 0 (its
//!   encoder error there included).
//! - `geometry.eccentricity_x_mm` (the y component is not observable with a mirror).
//! - `geometry.mirror_tilt_x_deg`, `mirror_tilt_y_deg`: the alignment mirror's normal in its mounting, towards the
//!   stage's x' and y' at the nominal rotation: the truth's `sample_tilt_*` plus that mounting's own seating.
//! - `beam.line_deg`: the light arm's zero plus the beam's in-plane pointing, less asin(lateral offset / detector
//!   distance): the one combination of the light side the scans see.
//! - `detector.ranges[]` by index (with the characterisation): `gain` relative to the reference range
//!   (`detector.reference_range`, whose gain is 0 by definition: every BRDF is a ratio of two readings, so the
//!   common gain is not observable), `nonlinearity`, and `offset_fs`, the offset relative to range 0's (which a
//!   campaign's dark takes with it) as a fraction of the range's full scale, each with `_u`.
//! - `detector.signature_floor_sr`: the signature at the largest angle measured from the beam, the mean over the
//!   bands; `detector.signature` the whole table per band.
//! - `source.warmup_deficit_at_first_reading` (the truth's `warmup_fraction` times `exp(-t / warmup_time_s)`,
//!   t the first reading's time in `source.first_s`) and `source.warmup_time_s`.
//! - `unobservable`: what could not be estimated, and why.

use serde_json::{Map, Value, json};

use super::AlignmentReport;

/// Standard uncertainties of amplitude and phase (deg) of `s sin a + c cos a` from the covariance of (s, c).
fn polar(s: f64, c: f64, var_s: f64, var_c: f64, cov: f64) -> (f64, f64, f64, f64) {
    let amplitude = s.hypot(c);
    let phase = c.atan2(s).to_degrees();
    if amplitude == 0.0 {
        return (0.0, var_s.max(var_c).max(0.0).sqrt(), 0.0, 180.0);
    }
    let (ds, dc) = (s / amplitude, c / amplitude);
    let var_a = ds * ds * var_s + 2.0 * ds * dc * cov + dc * dc * var_c;
    let (ps, pc) = (-c / (amplitude * amplitude), s / (amplitude * amplitude));
    let var_p = ps * ps * var_s + 2.0 * ps * pc * cov + pc * pc * var_c;
    (
        amplitude,
        var_a.max(0.0).sqrt(),
        phase,
        var_p.max(0.0).sqrt().to_degrees(),
    )
}

impl AlignmentReport {
    /// The whole report as JSON (every scan, every estimate, the covariance) with the estimates under
    /// simulator_truth's keys as `estimated`: `gonio align --json`, and the report the daemon keeps with a
    /// calibration it made.
    pub fn to_json_pretty(&self) -> Result<String, serde_json::Error> {
        let mut value = serde_json::to_value(self)?;
        if let Some(map) = value.as_object_mut() {
            map.insert("estimated".into(), self.estimated());
        }
        serde_json::to_string_pretty(&value)
    }

    /// The estimates under simulator_truth's keys (module doc).
    pub fn estimated(&self) -> Value {
        let e = |name: &str| self.get(name).map_or((f64::NAN, f64::NAN), |e| (e.value, e.u));
        let c = |i: usize, j: usize| {
            self.covariance
                .get(i)
                .and_then(|r| r.get(j))
                .copied()
                .unwrap_or(f64::NAN)
        };
        let (dz, dz_u) = e("detector_zero_deg");
        let (s, _) = e("detector_encoder_sin_deg");
        let (cc, _) = e("detector_encoder_cos_deg");
        let (amp, amp_u, phase, phase_u) = polar(s, cc, c(12, 12), c(13, 13), c(12, 13));
        let mut at = Map::new();
        for a in [15.0, 30.0, 60.0, 90.0] {
            let (v, u) = self.detector_error_deg(a);
            at.insert(format!("{a}"), json!({ "value_deg": v, "value_deg_u": u }));
        }
        let (tz, tz_u) = e("tilt_zero_deg");
        let (mx, mx_u) = e("sample_tilt_x_deg");
        let (my, my_u) = e("sample_tilt_y_deg");
        let (ex, ex_u) = e("eccentricity_x_mm");
        let (line, line_u) = e("beam_line_deg");
        json!({
            "geometry": {
                "axes": [
                    {
                        "role": "detector-arm",
                        "zero_offset_deg": dz,
                        "zero_offset_deg_u": dz_u,
                        "encoder_amplitude_deg": amp,
                        "encoder_amplitude_deg_u": amp_u,
                        "encoder_harmonic": 1,
                        "encoder_phase_deg": phase,
                        "encoder_phase_deg_u": phase_u,
                        "detector_error_at_deg": Value::Object(at),
                    },
                    { "role": "sample-tilt", "zero_offset_deg": tz, "zero_offset_deg_u": tz_u },
                ],
                "mirror_tilt_x_deg": mx,
                "mirror_tilt_x_deg_u": mx_u,
                "mirror_tilt_y_deg": my,
                "mirror_tilt_y_deg_u": my_u,
                "eccentricity_x_mm": ex,
                "eccentricity_x_mm_u": ex_u,
            },
            "beam": { "line_deg": line, "line_deg_u": line_u },
            "detector": self.estimated_detector(),
            "source": self.characterisation.as_ref().and_then(|c| c.source.as_ref()).map(|d| json!({
                "warmup_deficit_at_first_reading": d.warmup_deficit,
                "warmup_deficit_at_first_reading_u": d.warmup_deficit_u,
                "first_s": d.first_s,
                "warmup_time_s": d.warmup_time_s,
            })),
            "unobservable": self.unobservable,
        })
    }

    /// `detector` of [`AlignmentReport::estimated`] (module doc); null without a characterisation.
    fn estimated_detector(&self) -> Value {
        let Some(c) = &self.characterisation else {
            return Value::Null;
        };
        let ranges = c.detector.ranges.as_ref().map(|rc| {
            rc.ranges
                .iter()
                .map(|r| {
                    json!({
                        "index": r.index,
                        "gain": r.gain,
                        "gain_u": r.gain_u,
                        "nonlinearity": r.nonlinearity,
                        "nonlinearity_u": r.nonlinearity_u,
                        "offset_fs": r.offset_w / r.full_scale_w,
                        "offset_fs_u": r.offset_w_u / r.full_scale_w,
                        "observable": r.observable,
                    })
                })
                .collect::<Vec<_>>()
        });
        let far: Vec<f64> = c
            .detector
            .signature
            .iter()
            .filter_map(|s| s.brdf_sr.last().copied())
            .collect();
        let floor = (!far.is_empty()).then(|| far.iter().sum::<f64>() / far.len() as f64);
        json!({
            "reference_range": c.detector.ranges.as_ref().map(|r| r.reference_range),
            "ranges": ranges,
            "signature_floor_sr": floor,
            "signature": c.detector.signature,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::polar;

    #[test]
    fn amplitude_and_phase_follow_the_simulators_convention() {
        // A sin(a + phi) = A cos(phi) sin(a) + A sin(phi) cos(a).
        let (a, phi) = (0.005f64, 40.0f64);
        let (s, c) = (a * phi.to_radians().cos(), a * phi.to_radians().sin());
        let (amp, _, phase, _) = polar(s, c, 1e-8, 1e-8, 0.0);
        assert!(
            (amp - a).abs() < 1e-15 && (phase - phi).abs() < 1e-9,
            "{amp} {phase}"
        );
    }
}
