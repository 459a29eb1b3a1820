//! Fitting an analytic model (crates/brdf models) to a measured run.
//!
//! Objective: robust weighted least squares over the valid points of the selected bands,
//! `sum_k rho(e_k)` with `e_k = c_k (f_model(wi_k, wo_k) - f_k) / u_k`, where
//! - `u_k` is the point's stated standard uncertainty (`brdf_u_sr`; 0.1% of the value when absent or zero),
//! - `c_k = cos(theta_i) cos(theta_o)` is the cosine weight: errors count as they matter in rendered radiance
//!   (Ngan et al. 2005 weight by cos(theta_i); the product keeps the weight reciprocal, which matters because a
//!   plan with `reciprocity = true` measures either member of a pair),
//! - `rho` is Cauchy's loss (default; Huber's or plain squares on request) on the residuals standardised by
//!   their robust scale (1.4826 x the median absolute residual), minimised by iteratively reweighted least
//!   squares: each round solves the weighted problem with Levenberg-Marquardt ([`lm`]) and recomputes the
//!   weights, until they stop changing.
//!
//! Parameters: shape parameters (sigma, alpha, exponent, ior) are shared by all bands; reflectances and optical
//! constants (albedo, diffuse, specular, eta, k) are one per band and written as spectral tables (a constant
//! when one band is fitted). Bounds are those of the models' constructors. alpha and eta are fitted in log
//! space and the Phong exponent as log(1 + n), so that one step size suits every decade; uncertainties are
//! converted back to the parameters' own units to first order.
//!
//! Uncertainties: the covariance `(J^T W J)^-1` of the final weighted problem, scaled by its residual variance
//! `s^2 = sum w e^2 / (n - p)` (as scipy's `curve_fit` does by default): they account for the scatter actually
//! seen, including model error, not only for the stated uncertainties. A parameter stuck at a bound is
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
//! degree 5 in the offsets: the lobe's curvature across the aperture is captured).

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
    /// Standard uncertainty (k = 1); `None` when the data do not determine the parameter.
    pub std_uncertainty: Option<f64>,
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
    /// `sum((m - f)/u)^2 / (n - p)` with the stated uncertainties: about 1 when the model explains the data
    /// to within them.
    pub chi2_per_dof: f64,
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
}

#[derive(Debug, Clone, Copy)]
enum Transform {
    Linear,
    Log,
    Log1p,
}

impl Transform {
    fn to_internal(self, v: f64) -> f64 {
        match self {
            Transform::Linear => v,
            Transform::Log => v.ln(),
            Transform::Log1p => v.ln_1p(),
        }
    }
    fn to_natural(self, x: f64) -> f64 {
        match self {
            Transform::Linear => x,
            Transform::Log => x.exp(),
            Transform::Log1p => x.exp_m1(),
        }
    }
    /// d natural / d internal.
    fn derivative(self, x: f64) -> f64 {
        match self {
            Transform::Linear => 1.0,
            Transform::Log | Transform::Log1p => x.exp(),
        }
    }
}

#[derive(Debug, Clone, Copy)]
struct ParamDef {
    key: &'static str,
    band: Option<usize>,
    transform: Transform,
    lo: f64,
    hi: f64,
}

/// Smallest roughness fitted: below 1e-3 the models switch to a delta lobe, which has no pointwise value.
const ALPHA_MIN: f64 = 1.5e-3;

fn param_defs(model: FitModel, bands: usize) -> Vec<ParamDef> {
    let shared = |key, transform, lo, hi| ParamDef {
        key,
        band: None,
        transform,
        lo,
        hi,
    };
    let mut defs = Vec::new();
    let spectral: &[(&'static str, Transform, f64, f64)] = match model {
        FitModel::Lambertian => &[("albedo", Transform::Linear, 0.0, 1.0)],
        FitModel::OrenNayar => {
            defs.push(shared("sigma_deg", Transform::Linear, 0.0, 90.0));
            &[("albedo", Transform::Linear, 0.0, 1.0)]
        }
        FitModel::Phong => {
            defs.push(shared("exponent", Transform::Log1p, 0.0, 1e6));
            &[
                ("diffuse", Transform::Linear, 0.0, 1.0),
                ("specular", Transform::Linear, 0.0, 1.0),
            ]
        }
        FitModel::Conductor => {
            defs.push(shared("alpha", Transform::Log, ALPHA_MIN, 1.0));
            &[
                ("eta", Transform::Log, 0.01, 10.0),
                ("k", Transform::Linear, 0.0, 20.0),
            ]
        }
        FitModel::Plastic => {
            defs.push(shared("alpha", Transform::Log, ALPHA_MIN, 1.0));
            defs.push(shared("ior", Transform::Linear, 1.0, 4.0));
            &[("albedo", Transform::Linear, 0.0, 1.0)]
        }
    };
    for &(key, transform, lo, hi) in spectral {
        for b in 0..bands {
            defs.push(ParamDef {
                key,
                band: Some(b),
                transform,
                lo,
                hi,
            });
        }
    }
    defs
}

/// The natural value of parameter `key` for band `b` (or the shared one).
fn get(defs: &[ParamDef], natural: &[f64], key: &str, b: usize) -> f64 {
    defs.iter()
        .zip(natural)
        .find(|(d, _)| d.key == key && d.band.is_none_or(|db| db == b))
        .map(|(_, v)| *v)
        .unwrap_or(f64::NAN)
}

/// The model for one band (spectral parameters as constants); `None` when the constructor refuses them.
fn band_model(opts: &FitOptions, defs: &[ParamDef], natural: &[f64], b: usize) -> Option<Material> {
    let v = |key: &str| get(defs, natural, key, b);
    let c = Spectral::Constant;
    Some(match opts.model {
        FitModel::Lambertian => Material::Lambertian(Lambertian::new(c(v("albedo"))).ok()?),
        FitModel::OrenNayar => Material::OrenNayar(OrenNayar::new(c(v("albedo")), v("sigma_deg")).ok()?),
        FitModel::Phong => {
            let (d, s) = phong_split(v("diffuse"), v("specular"));
            Material::Phong(Phong::new(c(d), c(s), v("exponent")).ok()?)
        }
        FitModel::Conductor => {
            let a = v("alpha");
            Material::Conductor(
                Conductor::new(opts.distribution, opts.masking, a, a, c(v("eta")), c(v("k"))).ok()?,
            )
        }
        FitModel::Plastic => {
            let a = v("alpha");
            Material::Plastic(
                Plastic::new(opts.distribution, opts.masking, a, a, c(v("ior")), c(v("albedo"))).ok()?,
            )
        }
    })
}

/// Phong needs diffuse + specular <= 1: a pair beyond is scaled back onto the boundary.
fn phong_split(d: f64, s: f64) -> (f64, f64) {
    let sum = d + s;
    if sum > 1.0 { (d / sum, s / sum) } else { (d, s) }
}

/// The fitted material with spectral tables over the bands (constants for one band).
fn final_material(opts: &FitOptions, defs: &[ParamDef], natural: &[f64], bands: &[f64]) -> Option<Material> {
    let spectral = |key: &str| -> Option<Spectral> {
        let values: Vec<(f64, f64)> = bands
            .iter()
            .enumerate()
            .map(|(b, nm)| (*nm, get(defs, natural, key, b)))
            .collect();
        if values.len() == 1 {
            values.first().map(|(_, v)| Spectral::Constant(*v))
        } else {
            Spectral::table(values).ok()
        }
    };
    let shared = |key: &str| get(defs, natural, key, 0);
    Some(match opts.model {
        FitModel::Lambertian => Material::Lambertian(Lambertian::new(spectral("albedo")?).ok()?),
        FitModel::OrenNayar => {
            Material::OrenNayar(OrenNayar::new(spectral("albedo")?, shared("sigma_deg")).ok()?)
        }
        FitModel::Phong => {
            let mut d = Vec::new();
            let mut s = Vec::new();
            for (b, nm) in bands.iter().enumerate() {
                let (db, sb) = phong_split(
                    get(defs, natural, "diffuse", b),
                    get(defs, natural, "specular", b),
                );
                d.push((*nm, db));
                s.push((*nm, sb));
            }
            let table = |t: Vec<(f64, f64)>| {
                if t.len() == 1 {
                    t.first().map(|(_, v)| Spectral::Constant(*v))
                } else {
                    Spectral::table(t).ok()
                }
            };
            Material::Phong(Phong::new(table(d)?, table(s)?, shared("exponent")).ok()?)
        }
        FitModel::Conductor => {
            let a = shared("alpha");
            Material::Conductor(
                Conductor::new(
                    opts.distribution,
                    opts.masking,
                    a,
                    a,
                    spectral("eta")?,
                    spectral("k")?,
                )
                .ok()?,
            )
        }
        FitModel::Plastic => {
            let a = shared("alpha");
            Material::Plastic(
                Plastic::new(
                    opts.distribution,
                    opts.masking,
                    a,
                    a,
                    Spectral::Constant(shared("ior")),
                    spectral("albedo")?,
                )
                .ok()?,
            )
        }
    })
}

/// One observation.
#[derive(Debug, Clone)]
struct Obs {
    wi: Direction,
    wo: Direction,
    band: usize,
    f: f64,
    u: f64,
    /// cos(theta_i) cos(theta_o).
    cos_weight: f64,
    cos_i: f64,
    /// Directions across the detector aperture around `wo`, with weights `w_j cos(theta_j) / cos(theta_o)`
    /// (empty: the point value).
    aperture: Vec<(Direction, f64)>,
}

/// The 7-point rule for the mean over a disk, exact for polynomials up to degree 5: the centre with weight 1/4,
/// six points at `sqrt(2/3)` of the radius, 60 degrees apart, with weight 1/8 each.
fn aperture_samples(wo: &Direction, half_angle_rad: f64) -> Vec<(Direction, f64)> {
    // An orthonormal pair across `wo`.
    let helper = if wo.z().abs() < 0.9 {
        Direction::NORMAL
    } else {
        Direction::from_spherical(FRAC_PI_2, 0.0)
    };
    let c = wo.cross(&helper);
    let Some(t1) = Direction::new(c[0], c[1], c[2]) else {
        return Vec::new();
    };
    let c2 = wo.cross(&t1);
    let Some(t2) = Direction::new(c2[0], c2[1], c2[2]) else {
        return Vec::new();
    };
    let tan_r = (half_angle_rad * (2.0f64 / 3.0).sqrt()).tan();
    let mut out = vec![(*wo, 0.25)];
    for j in 0..6 {
        let (s, co) = (f64::from(j) * PI / 3.0).sin_cos();
        let d = Direction::new(
            wo.x() + tan_r * (co * t1.x() + s * t2.x()),
            wo.y() + tan_r * (co * t1.y() + s * t2.y()),
            wo.z() + tan_r * (co * t1.z() + s * t2.z()),
        );
        if let Some(d) = d {
            out.push((d, 0.125));
        }
    }
    let cos_o = wo.cos_theta();
    out.into_iter()
        .map(|(d, w)| (d, w * d.cos_theta().max(0.0) / cos_o))
        .collect()
}

/// Model values at every observation (averaged over the aperture when `aperture` and the observation has
/// samples); `None` when a band's model cannot be built.
fn predict(
    opts: &FitOptions,
    defs: &[ParamDef],
    natural: &[f64],
    obs: &[Obs],
    bands: &[f64],
    aperture: bool,
) -> Option<Vec<f64>> {
    let models: Vec<Material> = (0..bands.len())
        .map(|b| band_model(opts, defs, natural, b))
        .collect::<Option<_>>()?;
    obs.iter()
        .map(|o| {
            let wl = Wavelength::from_nm(bands.get(o.band).copied().unwrap_or(550.0)).ok()?;
            let model = models.get(o.band)?;
            if aperture && !o.aperture.is_empty() {
                let mut sum = 0.0;
                for (d, w) in &o.aperture {
                    sum += w * model.eval(&o.wi, d, wl).ok()?;
                }
                Some(sum)
            } else {
                model.eval(&o.wi, &o.wo, wl).ok()
            }
        })
        .collect()
}

fn median(mut v: Vec<f64>) -> f64 {
    v.retain(|x| x.is_finite());
    if v.is_empty() {
        return f64::NAN;
    }
    v.sort_by(f64::total_cmp);
    let n = v.len();
    if n % 2 == 1 {
        v[n / 2]
    } else {
        0.5 * (v[n / 2 - 1] + v[n / 2])
    }
}

fn quantile(mut v: Vec<f64>, q: f64) -> f64 {
    v.retain(|x| x.is_finite());
    if v.is_empty() {
        return f64::NAN;
    }
    v.sort_by(f64::total_cmp);
    let i = ((v.len() - 1) as f64 * q).round() as usize;
    v[i.min(v.len() - 1)]
}

/// Start points (natural units) for the model: a small grid over the shape parameters.
fn starts(opts: &FitOptions, defs: &[ParamDef], obs: &[Obs], bands: usize) -> Vec<Vec<f64>> {
    let per_band = |q: Option<f64>| -> Vec<f64> {
        (0..bands)
            .map(|b| {
                let v: Vec<f64> = obs.iter().filter(|o| o.band == b).map(|o| o.f).collect();
                let x = match q {
                    Some(q) => quantile(v, q),
                    None => median(v),
                };
                (PI * x).clamp(0.01, 0.95)
            })
            .collect()
    };
    let median_albedo = per_band(None);
    let low_albedo = per_band(Some(0.2));
    let shape: Vec<Vec<(&str, f64)>> = match opts.model {
        FitModel::Lambertian => vec![vec![]],
        FitModel::OrenNayar => [5.0, 20.0, 40.0, 70.0]
            .iter()
            .map(|s| vec![("sigma_deg", *s)])
            .collect(),
        FitModel::Phong => [3.0, 20.0, 100.0, 500.0, 3000.0]
            .iter()
            .map(|n| vec![("exponent", *n)])
            .collect(),
        FitModel::Conductor => {
            let mut v = Vec::new();
            for a in [0.02, 0.08, 0.25, 0.6] {
                for (eta, k) in [(0.3, 3.0), (1.5, 2.0), (1.2, 6.0)] {
                    v.push(vec![("alpha", a), ("eta", eta), ("k", k)]);
                }
            }
            v
        }
        FitModel::Plastic => [0.02, 0.08, 0.25, 0.6]
            .iter()
            .map(|a| vec![("alpha", *a), ("ior", 1.5)])
            .collect(),
    };
    shape
        .into_iter()
        .map(|assign| {
            defs.iter()
                .map(|d| {
                    if let Some((_, v)) = assign.iter().find(|(k, _)| *k == d.key) {
                        return *v;
                    }
                    let b = d.band.unwrap_or(0);
                    match d.key {
                        "albedo" if opts.model == FitModel::Plastic => {
                            low_albedo.get(b).copied().unwrap_or(0.5)
                        }
                        "albedo" => median_albedo.get(b).copied().unwrap_or(0.5),
                        "diffuse" => low_albedo.get(b).copied().unwrap_or(0.5),
                        "specular" => 0.1 * (1.0 - low_albedo.get(b).copied().unwrap_or(0.5)),
                        _ => 0.5 * (d.lo + d.hi),
                    }
                })
                .collect()
        })
        .collect()
}

/// Fits the model to the run (module doc).
pub fn fit(run: &Run, opts: &FitOptions) -> Result<FitReport, ResultsError> {
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
        .valid_points()
        .filter_map(|p| {
            let band = bands
                .iter()
                .position(|b| (p.band_nm - b).abs() <= BAND_TOLERANCE_NM)?;
            let f = p.value()?;
            let (wi, wo) = directions(p);
            if !(wi.is_above_horizon() && wo.is_above_horizon()) {
                return None;
            }
            let u = p
                .brdf_u_sr
                .filter(|u| *u > 0.0 && u.is_finite())
                .unwrap_or(1e-3 * f.abs().max(1e-12));
            Some(Obs {
                wi,
                wo,
                band,
                f,
                u,
                cos_weight: wi.cos_theta() * wo.cos_theta(),
                cos_i: wi.cos_theta(),
                aperture: opts
                    .aperture_half_angle_rad
                    .filter(|a| *a > 0.0 && a.is_finite())
                    .map(|a| aperture_samples(&wo, a))
                    .unwrap_or_default(),
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
    for start in starts(opts, &defs, &obs, bands.len()) {
        let x0: Vec<f64> = defs
            .iter()
            .zip(&start)
            .map(|(d, v)| d.transform.to_internal(v.max(lo_floor(d))))
            .collect();
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

    // Standardised, cos-weighted residuals at `x` (the aperture-averaged model).
    let standardised = |x: &[f64]| -> Option<Vec<f64>> {
        let m = predict(opts, &defs, &natural(x), &obs, &bands, true)?;
        Some(
            obs.iter()
                .zip(&m)
                .map(|(o, m)| o.cos_weight * (m - o.f) / o.u)
                .collect(),
        )
    };
    let median_abs = |x: &[f64]| -> f64 {
        standardised(x)
            .map(|e| median(e.iter().map(|v| v.abs()).collect()))
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
    let covariance = lm::jacobian(&f, &x, &r, &lower, &upper).and_then(|j| {
        let (a, _) = lm::normal_equations(&j, &r);
        lm::spd_inverse(&a)
    });
    let dof = (obs.len() - p) as f64;
    let s2 = solution.cost / dof;
    let params: Vec<FittedParam> = defs
        .iter()
        .enumerate()
        .map(|(j, d)| {
            let at_bound = (x[j] - lower[j]).abs() <= 1e-9 * lower[j].abs().max(1.0)
                || (x[j] - upper[j]).abs() <= 1e-9 * upper[j].abs().max(1.0);
            let std_uncertainty = covariance
                .as_ref()
                .and_then(|c| c.get(j).and_then(|row| row.get(j)).copied())
                .filter(|v| *v >= 0.0 && v.is_finite())
                .map(|v| (v * s2).sqrt() * d.transform.derivative(x[j]).abs());
            FittedParam {
                key: d.key,
                band_nm: d.band.and_then(|b| bands.get(b).copied()),
                value: nat[j],
                std_uncertainty,
                at_bound,
            }
        })
        .collect();
    let params = fix_phong_params(opts, params, &bands);
    let material = final_material(opts, &defs, &nat, &bands)
        .ok_or_else(|| fail("the fitted parameters do not make a valid material".into()))?;
    let m = predict(opts, &defs, &nat, &obs, &bands, true)
        .ok_or_else(|| fail("the model cannot be evaluated at the solution".into()))?;
    let residuals = residual_stats(&obs, &m, p);
    let downweighted = weights.iter().filter(|w| **w < 0.5).count();
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
    })
}

/// The lowest value a transform can take (log needs > 0).
fn lo_floor(d: &ParamDef) -> f64 {
    match d.transform {
        Transform::Log => d.lo.max(1e-9),
        _ => d.lo,
    }
}

/// Phong parameters as written to the file: diffuse + specular scaled back onto <= 1 as the model uses them.
fn fix_phong_params(opts: &FitOptions, mut params: Vec<FittedParam>, bands: &[f64]) -> Vec<FittedParam> {
    if opts.model != FitModel::Phong {
        return params;
    }
    for nm in bands {
        let find =
            |ps: &[FittedParam], key: &str| ps.iter().position(|q| q.key == key && q.band_nm == Some(*nm));
        if let (Some(i), Some(j)) = (find(&params, "diffuse"), find(&params, "specular")) {
            let (d, s) = phong_split(params[i].value, params[j].value);
            params[i].value = d;
            params[j].value = s;
        }
    }
    params
}

fn residual_stats(obs: &[Obs], m: &[f64], p: usize) -> ResidualStats {
    let (mut num, mut den, mut log2, mut max_rel, mut chi2) = (0.0, 0.0, 0.0, 0.0f64, 0.0);
    for (o, m) in obs.iter().zip(m) {
        num += ((m - o.f) * o.cos_i).powi(2);
        den += (o.f * o.cos_i).powi(2);
        log2 += ((1.0 + m * o.cos_i).max(1e-300).ln() - (1.0 + o.f * o.cos_i).max(1e-300).ln()).powi(2);
        if o.f > 0.0 {
            max_rel = max_rel.max((m - o.f).abs() / o.f);
        }
        chi2 += ((m - o.f) / o.u).powi(2);
    }
    let n = obs.len();
    ResidualStats {
        points: n,
        cos_weighted_relative_rms: if den > 0.0 { (num / den).sqrt() } else { f64::NAN },
        log_rms: (log2 / n.max(1) as f64).sqrt(),
        max_relative: max_rel,
        chi2_per_dof: chi2 / (n.saturating_sub(p)).max(1) as f64,
    }
}

impl FitReport {
    /// A parameter's label: `albedo @ 550 nm`, `sigma_deg`.
    pub fn label(p: &FittedParam) -> String {
        match p.band_nm {
            Some(nm) => format!("{} @ {nm} nm", p.key),
            None => p.key.to_string(),
        }
    }

    /// The human-readable report.
    pub fn summary(&self) -> String {
        let mut s = format!(
            "fit of {} to {} (campaign {}): {} points at {}, loss {}, {} LM iterations\n",
            self.model.name(),
            self.origin,
            self.campaign,
            self.residuals.points,
            list_nm(&self.bands_nm),
            self.options.loss.name(),
            self.iterations
        );
        if matches!(self.model, FitModel::Conductor | FitModel::Plastic) {
            s.push_str(&format!(
                "microfacet: {} distribution, {} masking (chosen, not fitted)\n",
                self.options.distribution.name(),
                self.options.masking.name()
            ));
        }
        match self.options.aperture_half_angle_rad {
            Some(a) => s.push_str(&format!(
                "model averaged over the detector aperture ({:.3} deg half-angle), as the instrument measures\n",
                a.to_degrees()
            )),
            None => s.push_str("model taken at the point (the detector aperture is unknown)\n"),
        }
        s.push_str(&format!(
            "{:<22} {:>14} {:>14}\n",
            "parameter", "value", "std. unc."
        ));
        for p in &self.params {
            let u = p
                .std_uncertainty
                .map(|u| format!("{u:.3e}"))
                .unwrap_or_else(|| "undetermined".into());
            s.push_str(&format!(
                "{:<22} {:>14.6} {:>14}{}\n",
                FitReport::label(p),
                p.value,
                u,
                if p.at_bound { "  (at its bound)" } else { "" }
            ));
        }
        let r = &self.residuals;
        s.push_str(&format!(
            "residuals: cos-weighted relative RMS {:.3e}, log RMS {:.3e}, max relative {:.3e}, chi2/dof {:.3} \
             (against the stated uncertainties), {} points down-weighted as outliers",
            r.cos_weighted_relative_rms, r.log_rms, r.max_relative, r.chi2_per_dof, self.downweighted
        ));
        s
    }

    /// The report as JSON (for scripts): parameters, residuals, material.
    pub fn to_json(&self) -> Value {
        json!({
            "model": self.model.name(),
            "source": self.origin,
            "campaign": self.campaign,
            "bands_nm": self.bands_nm,
            "loss": self.options.loss.name(),
            "iterations": self.iterations,
            "parameters": self.params.iter().map(|p| json!({
                "key": p.key,
                "band_nm": p.band_nm,
                "value": p.value,
                "std_uncertainty": p.std_uncertainty,
                "at_bound": p.at_bound,
            })).collect::<Vec<_>>(),
            "residuals": {
                "points": self.residuals.points,
                "cos_weighted_relative_rms": self.residuals.cos_weighted_relative_rms,
                "log_rms": self.residuals.log_rms,
                "max_relative": self.residuals.max_relative,
                "chi2_per_dof": self.residuals.chi2_per_dof,
                "downweighted": self.downweighted,
            },
            "material": serde_json::to_value(self.material.spec()).unwrap_or(Value::Null),
        })
    }

    /// The material file: the summary as comments, then the `[material]` table (the schema of
    /// config/materials/*.toml).
    pub fn material_toml(&self) -> String {
        let mut s = String::from("# Fitted by `gonio fit`; uncertainties are standard (k = 1).\n");
        for line in self.summary().lines() {
            s.push_str("# ");
            s.push_str(line);
            s.push('\n');
        }
        if self.bands_nm.len() > 1 {
            s.push_str(&format!(
                "# Spectral parameters are tables over the fitted bands: the material is defined from {} to {} nm.\n",
                self.bands_nm.first().copied().unwrap_or(0.0),
                self.bands_nm.last().copied().unwrap_or(0.0)
            ));
        } else {
            s.push_str(
                "# One band fitted: its parameters are written as constants (valid at every wavelength).\n",
            );
        }
        s.push('\n');
        s.push_str(&self.material.spec().to_toml());
        s
    }
}
