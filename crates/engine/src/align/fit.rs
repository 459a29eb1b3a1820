//! The model's parameters from the observed scan centres: weighted least squares with a weak prior on each
//! parameter, so that a combination the observations cannot see stays at its prior (and is reported as not
//! observable) instead of making the problem singular.
//!
//! Method: Gauss-Newton on the residuals `(observed - predicted) / u` and `x_k / prior_k`, the Jacobian by
//! central differences (gonio_results::fit::lm). The covariance is the inverse of `J^T J` at the solution,
//! scaled by the observations' reduced chi-squared when it exceeds 1 (the Birge ratio: scatter the scans'
//! own uncertainties do not explain, such as an error the model leaves out, widens every uncertainty rather
//! than being ignored). A parameter whose posterior standard uncertainty is more than a tenth of its prior's is
//! reported as not observable by these observations.

use gonio_results::fit::lm;

use super::model::{Dimensions, GeometryParams, Model, N_PARAMS, Observation, PARAM_NAMES};

/// One observed centre.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Observed {
    pub what: Observation,
    /// The scan's centre (deg, nominal axis angle).
    pub value_deg: f64,
    /// Its standard uncertainty (deg).
    pub u_deg: f64,
}

/// The fit's outcome.
#[derive(Debug, Clone)]
pub struct GeometryFit {
    pub params: GeometryParams,
    /// Standard uncertainty of each parameter, in [`PARAM_NAMES`] order.
    pub u: [f64; N_PARAMS],
    /// Whether each parameter is determined by the observations (posterior well inside the prior).
    pub observable: [bool; N_PARAMS],
    /// The observations' chi-squared per degree of freedom (before scaling).
    pub reduced_chi2: f64,
    /// Residuals (observed - predicted, deg) in observation order.
    pub residuals_deg: Vec<f64>,
    /// The parameters' covariance (scaled as `u`), in [`PARAM_NAMES`] order.
    pub covariance: Vec<Vec<f64>>,
}

impl GeometryFit {
    /// The beam's line as the detector sees it, `beam_deg - asin(beam_lateral_mm / d)` (deg), with its standard
    /// uncertainty: the beam's direction and offset are observed only in this combination (module doc of
    /// crate::align).
    pub fn beam_line_deg(&self, dims: Dimensions) -> (f64, f64) {
        self.line_deg(0, 1, dims)
    }

    /// The beam's line out of the plane, `beam_elevation_deg - asin(beam_vertical_mm / d)` (deg), with its
    /// standard uncertainty: its elevation and height are observed only in this combination, as in the plane.
    pub fn beam_elevation_line_deg(&self, dims: Dimensions) -> (f64, f64) {
        self.line_deg(2, 3, dims)
    }

    /// `x[angle] - asin(x[offset] / d)` (deg) with its standard uncertainty from the covariance.
    fn line_deg(&self, angle: usize, offset: usize, dims: Dimensions) -> (f64, f64) {
        let d = dims.detector_distance_mm;
        let x = self.params.to_vec();
        let h = x[offset];
        let value = x[angle] - (h / d).clamp(-1.0, 1.0).asin().to_degrees();
        // Gradient of the combination in (angle, offset).
        let g = [
            1.0,
            -(1.0 / (d * (1.0 - (h / d).powi(2)).max(1e-12).sqrt())).to_degrees(),
        ];
        let c = &self.covariance;
        let var = g[0] * g[0] * c[angle][angle]
            + 2.0 * g[0] * g[1] * c[angle][offset]
            + g[1] * g[1] * c[offset][offset];
        (value, var.max(0.0).sqrt())
    }
}

/// Prior standard deviation of each parameter: far wider than any aligned instrument's error (a tenth of a
/// degree or a millimetre is already a badly set-up instrument), so that it only holds what nothing observes.
/// The encoders' cyclic errors take a tighter prior: the accuracy rotation stages are sold with (hundredths of a
/// degree), since over the arcs the scans cover a once-per-revolution error looks much like a zero offset.
fn prior(k: usize) -> f64 {
    match PARAM_NAMES[k] {
        (name, _) if name.contains("encoder") => ENCODER_PRIOR_DEG,
        (_, "mm") => 2.0,
        _ => 0.5,
    }
}

/// Prior standard deviation of each encoder term (deg).
const ENCODER_PRIOR_DEG: f64 = 0.02;

/// Fit the model to `observed`. None when the model cannot be evaluated at the start (an observation the
/// geometry cannot produce).
pub fn fit(observed: &[Observed], dims: Dimensions) -> Option<GeometryFit> {
    let residuals = |x: &[f64]| -> Option<Vec<f64>> {
        let m = Model {
            p: GeometryParams::from_slice(x),
            dims,
        };
        let mut r = Vec::with_capacity(observed.len() + N_PARAMS);
        for o in observed {
            let pred = m.predict(&o.what)?;
            r.push((o.value_deg - pred) / o.u_deg);
        }
        for (k, v) in x.iter().enumerate() {
            r.push(v / prior(k));
        }
        Some(r)
    };
    let inf = [f64::INFINITY; N_PARAMS];
    let neg = [f64::NEG_INFINITY; N_PARAMS];
    let mut x = vec![0.0; N_PARAMS];
    let mut r = residuals(&x)?;
    let mut cov = None;
    for _ in 0..8 {
        let jac = lm::jacobian(&residuals, &x, &r, &neg, &inf)?;
        let (a, g) = lm::normal_equations(&jac, &r);
        let inv = lm::spd_inverse(&a)?;
        let step: Vec<f64> = (0..N_PARAMS)
            .map(|i| -(0..N_PARAMS).map(|j| inv[i][j] * g[j]).sum::<f64>())
            .collect();
        for (xi, s) in x.iter_mut().zip(&step) {
            *xi += s;
        }
        r = residuals(&x)?;
        cov = Some(inv);
        let small = step.iter().enumerate().all(|(k, s)| s.abs() < 1e-9 * prior(k));
        if small {
            break;
        }
    }
    let cov = cov?;
    let n = observed.len();
    let chi2: f64 = r[..n].iter().map(|v| v * v).sum();
    let dof = n.saturating_sub(N_PARAMS).max(1) as f64;
    let reduced_chi2 = chi2 / dof;
    let scale = reduced_chi2.max(1.0).sqrt();
    let covariance: Vec<Vec<f64>> = cov
        .iter()
        .map(|row| row.iter().map(|v| v * scale * scale).collect())
        .collect();
    let mut u = [0.0; N_PARAMS];
    let mut observable = [false; N_PARAMS];
    for k in 0..N_PARAMS {
        u[k] = cov[k][k].max(0.0).sqrt() * scale;
        observable[k] = u[k] < 0.1 * prior(k);
    }
    let residuals_deg = r[..n].iter().zip(observed).map(|(z, o)| z * o.u_deg).collect();
    Some(GeometryFit {
        params: GeometryParams::from_slice(&x),
        u,
        observable,
        reduced_chi2,
        residuals_deg,
        covariance,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_fit_recovers_known_errors_from_noiseless_observations() {
        let dims = Dimensions {
            detector_distance_mm: 250.0,
        };
        let truth = GeometryParams {
            beam_deg: 0.013,
            beam_lateral_mm: -0.07,
            beam_elevation_deg: 0.008,
            beam_vertical_mm: 0.05,
            detector_zero_deg: -0.021,
            tilt_zero_deg: 0.017,
            sample_tilt_x_deg: 0.04,
            sample_tilt_y_deg: -0.06,
            eccentricity_x_mm: 0.12,
            eccentricity_y_mm: -0.08,
            ..Default::default()
        };
        let m = Model { p: truth, dims };
        let observed: Vec<Observed> = super::super::plan_observations(&[-90.0, -85.0], 1.0)
            .into_iter()
            .map(|what| {
                let what = match what {
                    Observation::MirrorTilt {
                        light_deg,
                        rotation_deg,
                        ..
                    } => Observation::MirrorTilt {
                        light_deg,
                        detector_deg: m
                            .predict(&Observation::MirrorDetector {
                                light_deg,
                                tilt_deg: 0.0,
                                rotation_deg,
                            })
                            .unwrap(),
                        rotation_deg,
                    },
                    w => w,
                };
                Observed {
                    what,
                    value_deg: m.predict(&what).unwrap(),
                    u_deg: 1e-4,
                }
            })
            .collect();
        let f = fit(&observed, dims).unwrap();
        let got = f.params.to_vec();
        let want = truth.to_vec();
        for k in 0..N_PARAMS {
            if f.observable[k] {
                assert!(
                    (got[k] - want[k]).abs() < 3.0 * f.u[k] + 1e-9,
                    "{}: {} vs {} (u {})",
                    PARAM_NAMES[k].0,
                    got[k],
                    want[k],
                    f.u[k]
                );
            }
        }
        let names: Vec<&str> = (0..N_PARAMS)
            .filter(|&k| !f.observable[k])
            .map(|k| PARAM_NAMES[k].0)
            .collect();
        // The beam's direction and its lateral offset are seen only together (the mirror's reflection of the
        // beam's line crosses the detector's circle where the direct beam would: `beam_line_deg`), and its
        // elevation and height only together.
        for key in [
            "beam_deg",
            "beam_lateral_mm",
            "beam_elevation_deg",
            "beam_vertical_mm",
        ] {
            assert!(
                names.contains(&key),
                "{key} alone should not be observable: {names:?}"
            );
        }
        let (line, u_line) = f.beam_line_deg(dims);
        let want_line = truth.beam_deg - (truth.beam_lateral_mm / 250.0).asin().to_degrees();
        assert!(
            (line - want_line).abs() < 3.0 * u_line + 1e-9 && u_line < 0.05,
            "{line} vs {want_line} ({u_line})"
        );
        // Out of the plane the same: the line is seen.
        let (line, u_line) = f.beam_elevation_line_deg(dims);
        let want_line = truth.beam_elevation_deg - (truth.beam_vertical_mm / 250.0).asin().to_degrees();
        assert!(
            (line - want_line).abs() < 3.0 * u_line + 1e-9 && u_line < 0.05,
            "elevation: {line} vs {want_line} ({u_line})"
        );
        for key in [
            "detector_zero_deg",
            "tilt_zero_deg",
            "sample_tilt_x_deg",
            "sample_tilt_y_deg",
        ] {
            assert!(!names.contains(&key), "{key} should be observable: {names:?}");
        }
    }
}
