//! Fitting an analytic model (crates/brdf models) to a measured run.
//!
//! Objective: robust weighted least squares over the valid points of the selected bands,
//! `sum_k c_k^2 rho(z_k / s)` with `z_k = (f_model(wi_k, wo_k) - f_k) / u_k`, where
//! - `u_k` is the point's stated standard uncertainty (`brdf_u_sr`; 0.1% of the value when absent or zero),
//! - `c_k = cos(theta_i) cos(theta_o)` is the cosine weight: errors count as they matter in rendered radiance
//!   (Ngan et al. 2005 weight by cos(theta_i); the product keeps the weight reciprocal, which matters because a
//!   plan with `reciprocity = true` measures either member of a pair),
//! - `rho` is Cauchy's loss (default; Huber's or plain squares on request) on the residuals standardised by
//!   their own uncertainties and by their robust scale `s` (1.4826 x the median of `|z_k|`): whether a point is
//!   an outlier is judged against its own noise, not against its cosine weight. It is minimised by iteratively
//!   reweighted least squares: each round solves the weighted problem with Levenberg-Marquardt ([`lm`]) and
//!   recomputes the weights, until they stop changing.
//!
//! Parameters: shape parameters (sigma, alpha, exponent, ior) are shared by all bands; reflectances and optical
//! constants (albedo, diffuse, specular, eta, k) are one per band and written as spectral tables (a constant
//! when one band is fitted). Bounds are those of the models' constructors. alpha and eta are fitted in log
//! space and the Phong exponent as log(1 + n), so that one step size suits every decade; uncertainties are
//! converted back to the parameters' own units to first order.
//!
//! Uncertainties: the sandwich covariance `(J^T W J)^-1 (J^T W C^2 J) (J^T W J)^-1` of the final weighted problem
//! (`C` the cosine weights, `W` the robust ones: the residuals are weighted other than by their own errors, and
//! `(J^T W J)^-1` alone would be the covariance only if they were not), scaled by the scatter seen against the
//! scatter the stated uncertainties predict, `s^2 = sum w c^2 e^2 / (sum w c^2 (n - p) / n)` (with a robust
//! loss, the squared robust scale of `e`, 1.4826 x its median magnitude, times `n / (n - p)`: the weighted sum
//! understates the scatter, its weights being smallest where the residuals are largest): they account for the
//! scatter actually seen, including model error, not only for the stated uncertainties. A parameter stuck at a bound is
//! reported as such; its uncertainty is then not meaningful.
//!
//! Starts: a few values of the shape parameters (and of eta, k for a conductor) across their plausible range,
//! the reflectances from the data's median (or low quantile); the best start is refined. With a robust loss,
//! the robust rounds also start from the raw starts nearest the data, and the result with the smallest median
//! residual wins: outliers can pull plain least squares into a wrong basin (a diffuse sample's roughness at 0,
//! where Oren-Nayar is flat in it) that re-weighting alone cannot leave.
//!
//! Aperture: a measurement is the BRDF averaged over the detector's aperture, cos-weighted
//! (`<f> = integral f cos(theta) d omega / (Omega cos(theta_o))`); fitting point values to it would widen a sharp
//! lobe by the aperture's angle (a Phong exponent of 60 comes out 0.15% low with a 0.57 degree aperture, far
//! beyond its statistical uncertainty). When the caller gives the aperture's half-angle, the starts use point
//! values (cheap) and the refinement averages the model over the aperture with a 7-point disk rule (exact to
//! degree 5 in the offsets: the lobe's curvature across the aperture is captured). A value that a completed
//! campaign already corrected to the nominal geometry (it has a `brdf_aperture_sr`, crate::aperture) is fitted
//! as the aperture average it was before the correction, with its independent uncertainty less the
//! correction's (the `aperture` component): the correction came from a model fitted to the same points, so its
//! error is shared by them and is no scatter, and fitting the averages with the averaged model needs no
//! correction at all. Without the half-angle, the corrected values are met as point values.

pub mod lm;

/// How many distinct refined starts a robust fit follows to the end (see `fit`'s choice by least median).
const ROBUST_CANDIDATES: usize = 3;

use std::f64::consts::{FRAC_PI_2, PI};

use gonio_brdf::geometry::Direction;
use gonio_brdf::material::Material;
use gonio_brdf::microfacet::{Distribution, Masking};
use gonio_brdf::models::{Conductor, Lambertian, OrenNayar, Phong, Plastic};
use gonio_brdf::{Brdf, Spectral, Wavelength};
use serde_json::{Value, json};

use crate::error::ResultsError;
use crate::fit::lm::Residuals as _;
use crate::iso::directions;
use crate::run::{BAND_TOLERANCE_NM, Run, list_nm};

pub(crate) mod observations;
mod params;
mod report;
mod shared;

use observations::{Obs, aperture_samples, median, pairs_per_band, predict, starts};
use params::{ParamDef, Transform, band_model, final_material, param_defs, phong_split};
pub use report::chi2_meaning;
use report::{fix_phong_params, residual_stats};

/// The models that can be fitted.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FitModel {
    Lambertian,
    OrenNayar,
    Conductor,
    Plastic,
    Phong,
}

impl FitModel {
    pub const ALL: [FitModel; 5] = [
        FitModel::Lambertian,
        FitModel::OrenNayar,
        FitModel::Conductor,
        FitModel::Plastic,
        FitModel::Phong,
    ];

    /// The model's name in material files.
    pub fn name(self) -> &'static str {
        match self {
            FitModel::Lambertian => "lambertian",
            FitModel::OrenNayar => "oren-nayar",
            FitModel::Conductor => "conductor",
            FitModel::Plastic => "plastic",
            FitModel::Phong => "phong",
        }
    }

    pub fn from_name(name: &str) -> Option<FitModel> {
        FitModel::ALL.into_iter().find(|m| m.name() == name)
    }
}

/// The robust loss.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Loss {
    /// `rho(t) = c^2/2 log(1 + (t/c)^2)`, c = 2.385: weights fall as 1/t^2 far out (gross outliers hardly count).
    #[default]
    Cauchy,
    /// Quadratic within c = 1.345, linear beyond: weights fall as 1/|t|.
    Huber,
    /// Plain least squares.
    None,
}

impl Loss {
    pub fn name(self) -> &'static str {
        match self {
            Loss::Cauchy => "cauchy",
            Loss::Huber => "huber",
            Loss::None => "none",
        }
    }

    pub fn from_name(name: &str) -> Option<Loss> {
        [Loss::Cauchy, Loss::Huber, Loss::None]
            .into_iter()
            .find(|l| l.name() == name)
    }

    /// IRLS weight of a standardised residual.
    fn weight(self, t: f64) -> f64 {
        match self {
            Loss::Cauchy => 1.0 / (1.0 + (t / 2.385).powi(2)),
            Loss::Huber => {
                if t.abs() <= 1.345 {
                    1.0
                } else {
                    1.345 / t.abs()
                }
            }
            Loss::None => 1.0,
        }
    }
}

/// What to fit.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FitOptions {
    pub model: FitModel,
    /// Fit this band only (nm); all bands when `None`.
    pub wavelength_nm: Option<f64>,
    pub loss: Loss,
    /// Microfacet choices for conductor and plastic (not fitted: named).
    pub distribution: Distribution,
    pub masking: Masking,
    /// Half-angle of the detector's aperture seen from the sample (radians), when known: the model is then
    /// averaged over the aperture as the instrument averages the BRDF (module doc). `None`: point values.
    pub aperture_half_angle_rad: Option<f64>,
}

impl FitOptions {
    pub fn new(model: FitModel) -> FitOptions {
        FitOptions {
            model,
            wavelength_nm: None,
            loss: Loss::default(),
            distribution: Distribution::Ggx,
            masking: Masking::HeightCorrelated,
            aperture_half_angle_rad: None,
        }
    }
}

/// One fitted parameter, in the units of the material file.
#[derive(Debug, Clone, PartialEq)]
pub struct FittedParam {
    /// The `[material]` key.
    pub key: &'static str,
    /// The band of a spectral parameter.
    pub band_nm: Option<f64>,
    pub value: f64,
    /// Standard uncertainty (k = 1) from the points' independent errors (the fit's covariance, scaled by the
    /// residuals); `None` when the data do not determine the parameter.
    pub std_uncertainty: Option<f64>,
    /// Standard uncertainty (k = 1) from what the points share (the solid angle, a band's normalisation, ...:
    /// [`shared`]); `None` when nothing shared is known to move it.
    pub shared_uncertainty: Option<f64>,
    pub at_bound: bool,
}

/// How well the fitted model describes the points (all fitted points, unweighted by the robust loss).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ResidualStats {
    pub points: usize,
    /// `sqrt(sum((m - f) cos theta_i)^2 / sum(f cos theta_i)^2)` (Ngan et al. 2005).
    pub cos_weighted_relative_rms: f64,
    /// `sqrt(mean((ln(1 + m cos theta_i) - ln(1 + f cos theta_i))^2))` (Low et al. 2012).
    pub log_rms: f64,
    /// Largest `|m - f| / f`.
    pub max_relative: f64,
    /// `r^T V^-1 r / (n - p)` with `r = m - f` and `V` the points' whole stated budget: the independent parts
    /// on the diagonal, each shared group's signed entries fully correlated within it ([`shared`]), `m` at the
    /// parameters that minimise it (Levenberg-Marquardt from the fit's solution and from plain least squares'):
    /// about 1 when the model explains the data to within what the budget says, correlations included.
    pub chi2_per_dof: f64,
    /// `sum((m - f)/u)^2 / (n - p)` against the independent parts alone: above the other when what the points
    /// share leaves structure the model cannot absorb (an angle error tilting a lobe).
    pub chi2_per_dof_independent: f64,
}

/// The result of a fit.
#[derive(Debug, Clone)]
pub struct FitReport {
    pub model: FitModel,
    pub options: FitOptions,
    pub origin: String,
    pub campaign: String,
    pub bands_nm: Vec<f64>,
    pub params: Vec<FittedParam>,
    pub material: Material,
    pub residuals: ResidualStats,
    /// Points whose final robust weight is below 1/2 (treated as outliers).
    pub downweighted: usize,
    /// Levenberg-Marquardt iterations, all rounds together.
    pub iterations: usize,
    /// The fit linearised at its solution, for propagating what the points share ([`shared`]).
    pub(crate) linear: Option<shared::Linear>,
}

/// Fits the model to the run (module doc), each parameter with its uncertainty from the points' independent
/// errors and, apart, from what they share ([`shared`]).
pub fn fit(run: &Run, opts: &FitOptions) -> Result<FitReport, ResultsError> {
    let mut report = fit_unshared(run, opts, Chi2Whole::Search)?;
    let shared = shared::shared_uncertainties(run, opts, &report);
    for (p, u) in report.params.iter_mut().zip(shared) {
        p.shared_uncertainty = u;
    }
    Ok(report)
}

/// Whether a fit searches its chi2/dof against the whole budget ([`ResidualStats::chi2_per_dof`]) or leaves it
/// out (NaN): a search is up to [`shared::whole_budget_minimum`]'s steps of a Jacobian each, from two starts,
/// and the aperture's model fits (crate::aperture) read only their parameters and rms residual.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Chi2Whole {
    Search,
    Skip,
}

/// The fit weighted by the points' independent uncertainties, without the shared part.
pub(crate) fn fit_unshared(run: &Run, opts: &FitOptions, chi2: Chi2Whole) -> Result<FitReport, ResultsError> {
    let fail = |message: String| ResultsError::Fit {
        model: opts.model.name().into(),
        origin: run.origin.clone(),
        message,
    };
    let bands: Vec<f64> = match opts.wavelength_nm {
        Some(nm) => vec![run.band(nm)?],
        None => run.bands_nm(),
    };
    if bands.is_empty() {
        return Err(ResultsError::NoData {
            origin: run.origin.clone(),
            message: "no valid points to fit".into(),
        });
    }
    let obs: Vec<Obs> = run
        .points
        .iter()
        .enumerate()
        .filter(|(_, p)| p.is_valid())
        .filter_map(|(point, p)| {
            let band = bands
                .iter()
                .position(|b| (p.band_nm - b).abs() <= BAND_TOLERANCE_NM)?;
            let value = p.value()?;
            let (wi, wo) = directions(p);
            if !(wi.is_above_horizon() && wo.is_above_horizon()) {
                return None;
            }
            // The independent part: what the points share moves them together and is no scatter
            // (crate::budget; [`shared`] propagates it apart).
            let u = p
                .u_independent_sr()
                .filter(|u| *u > 0.0 && u.is_finite())
                .unwrap_or(1e-3 * value.abs().max(1e-12));
            let half_angle = opts.aperture_half_angle_rad.filter(|a| *a > 0.0 && a.is_finite());
            let (f, u, aperture, per_value) = match (half_angle, p.brdf_aperture_sr) {
                // A value a completed campaign corrected to the nominal geometry (crate::aperture) is met as
                // the aperture average it was before, by the model averaged the same way: the fit needs no
                // correction, nor the correction's uncertainty (module doc).
                (Some(a), Some(average)) if average.is_finite() && value != 0.0 => {
                    let scale = (average / value).abs();
                    let correction_u = p.budget.component_sr(crate::budget::components::APERTURE);
                    let u_average = (u * u - correction_u * correction_u).max(0.0).sqrt() * scale;
                    let u_average = if u_average > 0.0 { u_average } else { u * scale };
                    (average, u_average, aperture_samples(&wo, a), scale)
                }
                // Without a correction: the measured aperture average itself, met the same way.
                (Some(a), None) => (value, u, aperture_samples(&wo, a), 1.0),
                // A corrected value without the aperture's size (or without a usable average): a point value.
                _ => (value, u, Vec::new(), 1.0),
            };
            Some(Obs {
                point,
                per_value,
                wi,
                wo,
                band,
                f,
                u,
                cos_weight: wi.cos_theta() * wo.cos_theta(),
                cos_i: wi.cos_theta(),
                aperture,
            })
        })
        .collect();
    let defs = param_defs(opts.model, bands.len());
    let p = defs.len();
    if obs.len() <= p {
        return Err(fail(format!(
            "{} usable points for {p} parameters at {}: a fit needs more points than parameters",
            obs.len(),
            list_nm(&bands)
        )));
    }
    let lower: Vec<f64> = defs
        .iter()
        .map(|d| d.transform.to_internal(d.lo.max(lo_floor(d))))
        .collect();
    let upper: Vec<f64> = defs.iter().map(|d| d.transform.to_internal(d.hi)).collect();
    let natural = |x: &[f64]| -> Vec<f64> {
        defs.iter()
            .zip(x)
            .map(|(d, v)| d.transform.to_natural(*v))
            .collect()
    };
    let residuals_with = |weights: &[f64], aperture: bool| {
        let obs = &obs;
        let defs = &defs;
        let bands = &bands;
        let natural = &natural;
        let weights = weights.to_vec();
        move |x: &[f64]| -> Option<Vec<f64>> {
            let m = predict(opts, defs, &natural(x), obs, bands, aperture)?;
            Some(
                obs.iter()
                    .zip(&m)
                    .zip(&weights)
                    .map(|((o, m), w)| w.sqrt() * o.cos_weight * (m - o.f) / o.u)
                    .collect(),
            )
        }
    };

    // Each start refined by plain least squares (point values: cheap).
    let unit = vec![1.0; obs.len()];
    let mut best: Option<lm::Solution> = None;
    let mut iterations = 0;
    let mut raw_starts: Vec<Vec<f64>> = Vec::new();
    let internal = |start: &[f64]| -> Vec<f64> {
        defs.iter()
            .zip(start)
            .map(|(d, v)| d.transform.to_internal(v.max(lo_floor(d))))
            .collect()
    };
    let point_cost = {
        let f = residuals_with(&unit, false);
        move |x: &[f64]| -> f64 {
            f(x).map(|r| r.iter().map(|v| v * v).sum::<f64>())
                .filter(|c| c.is_finite())
                .unwrap_or(f64::INFINITY)
        }
    };
    for mut start in starts(opts, &defs, &obs, bands.len()) {
        // A conductor's eta and k are each band's own, and the bands' best pairs differ (gold: eta 1.5 at
        // 450 nm, 0.17 at 650): each band takes the grid's pair that fits it best with the rest held, so that
        // no start puts one band in another's basin (from one pair for every band, a realistic instrument's
        // gold at 650 nm was refined to eta 0.05, k 1.4, 4 % off the data, against eta 0.17, k 3.1).
        if opts.model == FitModel::Conductor {
            pairs_per_band(&mut start, &defs, bands.len(), |x| point_cost(&internal(x)));
        }
        let x0 = internal(&start);
        let f = residuals_with(&unit, false);
        if let Some(s) = lm::minimise(&f, &x0, &lower, &upper, 60) {
            iterations += s.iterations;
            if best.as_ref().is_none_or(|b| s.cost < b.cost) {
                best = Some(s);
            }
        }
        raw_starts.push(x0);
    }
    let Some(best) = best else {
        return Err(fail("the model cannot be evaluated at any start point".into()));
    };

    // Residuals at `x` (the aperture-averaged model) standardised by their points' own uncertainties, without
    // the cosine weight: an outlier is a point far from the model for its own noise. Judged cos-weighted, the
    // residuals' scale was set by the grazing points' small weights, and a sound point near normal incidence
    // (cosine weight near 1) read as an outlier: on the ideal instrument a tenth of gold's points were
    // down-weighted (a Gaussian sample's share is 2 %), and alpha scattered 1.19 of its stated uncertainties in
    // rms over 16 seeds (4 of 16 outside k = 2), against 1.01 without the robust loss.
    let standardised = |x: &[f64]| -> Option<Vec<f64>> {
        let m = predict(opts, &defs, &natural(x), &obs, &bands, true)?;
        Some(obs.iter().zip(&m).map(|(o, m)| (m - o.f) / o.u).collect())
    };
    // The candidates' score: the median magnitude of the cos-weighted residuals (the objective's own weighting:
    // errors as they matter in rendered radiance).
    let median_abs = |x: &[f64]| -> f64 {
        standardised(x)
            .map(|e| {
                let weighted = e.iter().zip(&obs).map(|(v, o)| (o.cos_weight * v).abs());
                median(weighted.collect())
            })
            .filter(|m| m.is_finite())
            .unwrap_or(f64::INFINITY)
    };
    // Robust rounds (IRLS) from `x0`: weights from the residuals at the current point, then a weighted solve,
    // until the weights settle. Returns the solution and its final weights; plain least squares is one solve.
    let irls = |x0: &[f64], iterations: &mut usize| -> Option<(lm::Solution, Vec<f64>)> {
        let mut x = x0.to_vec();
        let mut weights = unit.clone();
        let mut last: Option<lm::Solution> = None;
        for _round in 0..30 {
            let mut new = unit.clone();
            if opts.loss != Loss::None {
                let e = standardised(&x)?;
                let scale = 1.4826 * median(e.iter().map(|v| v.abs()).collect());
                if scale.is_finite() && scale > 0.0 {
                    new = e.iter().map(|v| opts.loss.weight(v / scale)).collect();
                }
            }
            let change = new
                .iter()
                .zip(&weights)
                .map(|(a, b)| (a - b).abs())
                .fold(0.0, f64::max);
            weights = new;
            if last.is_some() && change < 1e-4 {
                break;
            }
            let f = residuals_with(&weights, true);
            let s = lm::minimise(&f, &x, &lower, &upper, 200)?;
            *iterations += s.iterations;
            x = s.x.clone();
            last = Some(s);
            if opts.loss == Loss::None {
                break;
            }
        }
        last.map(|s| (s, weights))
    };
    // Plain least squares: from the best start. A robust loss: the outliers can pull plain least squares into
    // the wrong basin (a diffuse sample's roughness driven to 0, where the model is flat in it), so the robust
    // rounds also run from the raw starts nearest the data (by median residual), and the solution whose
    // residuals have the smallest median magnitude wins (least median of squares: a criterion outliers cannot
    // move while they are under half of the points).
    // Plain least squares' solution (point values), kept as a second start for the whole budget's minimum.
    let least_squares_x = best.x.clone();
    let mut candidates = vec![best.x.clone()];
    if opts.loss != Loss::None {
        let mut scored: Vec<(f64, Vec<f64>)> = raw_starts.into_iter().map(|x| (median_abs(&x), x)).collect();
        scored.sort_by(|a, b| a.0.total_cmp(&b.0));
        candidates.extend(scored.into_iter().take(ROBUST_CANDIDATES).map(|(_, x)| x));
    }
    let mut chosen: Option<(f64, lm::Solution, Vec<f64>)> = None;
    for x0 in &candidates {
        let Some((solution, weights)) = irls(x0, &mut iterations) else {
            continue;
        };
        let score = if candidates.len() == 1 {
            0.0
        } else {
            median_abs(&solution.x)
        };
        if chosen.as_ref().is_none_or(|(b, _, _)| score < *b) {
            chosen = Some((score, solution, weights));
        }
    }
    let Some((_, mut solution, weights)) = chosen else {
        return Err(fail("the model cannot be evaluated at the refined start".into()));
    };
    // Final solve with the final weights (a no-op when the weights had converged).
    let f = residuals_with(&weights, true);
    if let Some(s) = lm::minimise(&f, &solution.x, &lower, &upper, 200) {
        iterations += s.iterations;
        solution = s;
    }

    let x = solution.x.clone();
    let nat = natural(&x);
    let r = f
        .residuals(&x)
        .ok_or_else(|| fail("the model cannot be evaluated at the solution".into()))?;
    let jac = lm::jacobian(&f, &x, &r, &lower, &upper);
    let covariance = jac.as_ref().and_then(|j| {
        let (a, _) = lm::normal_equations(j, &r);
        lm::spd_inverse(&a)
    });
    // Each residual's variance from its point's stated uncertainty: the cosine and the robust weight make the
    // residuals other than standardised, so the parameters' covariance is the sandwich, not (J^T J)^-1 alone
    // (on the ideal instrument the latter made the coloured plastic's alpha 2 of its uncertainties off in rms
    // over 16 seeds). It is scaled by the scatter seen against the scatter the stated uncertainties predict.
    let noise: Vec<f64> = obs
        .iter()
        .zip(&weights)
        .map(|(o, w)| w * o.cos_weight * o.cos_weight)
        .collect();
    let n = obs.len() as f64;
    let dof = (obs.len() - p) as f64;
    let expected = noise.iter().sum::<f64>() * dof / n;
    // With a robust loss the weighted cost understates the scatter (the weights are smallest where the residuals
    // are largest): the robust scale of the residuals standardised by their stated uncertainties instead.
    let standardised_abs: Vec<f64> = r
        .iter()
        .zip(&noise)
        .filter(|(_, v)| **v > 0.0)
        .map(|(r, v)| (r / v.sqrt()).abs())
        .collect();
    let robust_scale = 1.4826 * median(standardised_abs);
    let s2 = if opts.loss != Loss::None && robust_scale.is_finite() && robust_scale > 0.0 {
        robust_scale * robust_scale * n / dof
    } else if expected > 0.0 {
        solution.cost / expected
    } else {
        solution.cost / dof
    };
    let at_bound: Vec<bool> = (0..p)
        .map(|j| {
            (x[j] - lower[j]).abs() <= 1e-9 * lower[j].abs().max(1.0)
                || (x[j] - upper[j]).abs() <= 1e-9 * upper[j].abs().max(1.0)
        })
        .collect();
    let parameter_covariance = covariance
        .as_ref()
        .zip(jac.as_ref())
        .map(|(bread, j)| lm::sandwich(bread, j, &noise));
    let params: Vec<FittedParam> = defs
        .iter()
        .enumerate()
        .map(|(j, d)| {
            let std_uncertainty = parameter_covariance
                .as_ref()
                .and_then(|c| c.get(j).and_then(|row| row.get(j)).copied())
                .filter(|v| *v >= 0.0 && v.is_finite())
                .map(|v| (v * s2).sqrt() * d.transform.derivative(x[j]).abs());
            FittedParam {
                key: d.key,
                band_nm: d.band.and_then(|b| bands.get(b).copied()),
                value: nat[j],
                std_uncertainty,
                shared_uncertainty: None,
                at_bound: at_bound[j],
            }
        })
        .collect();
    let params = fix_phong_params(opts, params, &bands);
    let material = final_material(opts, &defs, &nat, &bands)
        .ok_or_else(|| fail("the fitted parameters do not make a valid material".into()))?;
    let m = predict(opts, &defs, &nat, &obs, &bands, true)
        .ok_or_else(|| fail("the model cannot be evaluated at the solution".into()))?;
    // The minimum over the parameters, from the fit's solution and from plain least squares' (a robust fit can
    // sit where the whole budget's sum has a local minimum of its own): the lower is the statistic.
    let chi2_whole = match chi2 {
        Chi2Whole::Search => [x.as_slice(), least_squares_x.as_slice()]
            .into_iter()
            .filter_map(|start| {
                shared::whole_budget_minimum(run, &obs, start, &at_bound, (&lower, &upper), standardised)
            })
            .min_by(f64::total_cmp),
        Chi2Whole::Skip => None,
    };
    let residuals = residual_stats(&obs, &m, p, chi2_whole);
    let downweighted = weights.iter().filter(|w| **w < 0.5).count();
    let linear = jac
        .zip(covariance.clone())
        .map(|(jacobian, covariance)| shared::Linear {
            x: x.clone(),
            jacobian,
            covariance,
            // r_k = sqrt(w_k) c_k (m_k - f_k) / u_k: the residual moves by -this per unit of the observation.
            sensitivity: obs
                .iter()
                .zip(&weights)
                .map(|(o, w)| w.sqrt() * o.cos_weight / o.u)
                .collect(),
            observed: obs.iter().map(|o| (o.point, o.per_value)).collect(),
            defs: defs.clone(),
            bands: bands.clone(),
        });
    Ok(FitReport {
        model: opts.model,
        options: *opts,
        origin: run.origin.clone(),
        campaign: run.name.clone(),
        bands_nm: bands,
        params,
        material,
        residuals,
        downweighted,
        iterations,
        linear,
    })
}

/// The lowest value a transform can take (log needs > 0).
fn lo_floor(d: &ParamDef) -> f64 {
    match d.transform {
        Transform::Log => d.lo.max(1e-9),
        _ => d.lo,
    }
}

#[cfg(test)]
mod tests;
