//! From the aperture average to the BRDF at the nominal geometry (issue 29).
//!
//! A reading is the BRDF averaged over the detector's aperture, cos-weighted:
//! `<f> = ∫_cone f cos(theta) d omega / (Omega cos(theta_o))` (gonio_brdf::measurement). Near a lobe's peak that
//! average lies below the point value (gold's specular lobe: about -0.4 % with a 0.57 degree aperture), on a
//! lobe's flank above it; a diffuse sample's is within 1e-5 of it. Each point's correction factor is
//! `c = f_m(nominal) / <f_m>` of a model `f_m` fitted to the campaign's own data: the local curvature that the
//! aperture averages over is the model's, so the correction is only as good as the model's shape there.
//!
//! The model: Oren-Nayar, the microfacet conductor and plastic (GGX, height-correlated masking) and Phong are
//! fitted to a subset of the valid points ([`MAX_FIT_POINTS`]: the brightest half, where lobes are, and an even
//! spread of the rest), by plain least squares on point values (cheap; fitting to point values widens a lobe by about
//! the aperture, which moves a correction of 1 % by about 0.01 %). The model with the smallest cos-weighted
//! relative rms residual corrects; every model whose residual is within [`ACCEPTABLE_RMS_RATIO`] of it
//! is an acceptable description too, and the spread of their corrections is the correction's uncertainty, with
//! a floor of [`CORRECTION_U_FRACTION`] of the correction itself (what no fitted shape is trusted beyond). Where
//! the best model cannot correct a point (below) but an acceptable Oren-Nayar, a model without a lobe, can, the
//! data do not ask for a lobe there and Oren-Nayar corrects it (a few points of a diffuse sample can be fitted
//! best by a hair by a lobe they do not have).
//!
//! No honest correction (the point is flagged [`FLAG_NARROW_LOBE`] and keeps its aperture average): the model's
//! lobe is narrower than the instrument resolves (its roughness below [`Optics::resolution_rad`], the aperture's
//! and the beam's half-angles together: a mirror, or a fit that ran to its bound) and within reach of it, or
//! the correction exceeds [`NARROW_LIMIT`] (the average no longer says what the peak is), or a value near the
//! specular direction is [`UNRESOLVED_RATIO`] times off the model's average (the fit missed a lobe it had too
//! few points of), or no model describes the data at all (the best one's residual above [`MODEL_RMS_LIMIT`]:
//! then nothing is corrected, and every point a delta lobe could reach is flagged). "Within reach" is the
//! optics' ([`Optics::delta_reach_rad`]): a mirror's reflection is the beam, a tube of its width, and it lies
//! where the sample's tilt and the zeros put it; an aperture-only reach missed a mirror read at 12 /sr a degree
//! from its nominal specular direction (issue 29, 48 instruments).
//! Its uncertainty, `u = value x max(1, 2 |c - 1|)` (the point-value fit widens a lobe narrower than the
//! aperture, so the model's `c` understates the bias), covers a point value anywhere from 0 (a mirror's, delta
//! lobe excluded) to three times the average; a finite lobe's peak can lie higher, and no average tells how
//! much: the flag says so.

use gonio_brdf::integrate::{Region, Rule, Tolerance, integrate_adaptive};
use gonio_brdf::radiometry::cone_solid_angle_sr;
use gonio_brdf::{Brdf, Direction, Material, Wavelength};

use crate::fit::{Chi2Whole, FitModel, FitOptions, FitReport, Loss, fit_unshared};
use crate::iso::directions;
use crate::points::Point;
use crate::run::Run;

/// The flag of a point whose lobe is narrower than the aperture: its value is the aperture average.
pub const FLAG_NARROW_LOBE: &str = "narrow-lobe";
/// Points the models are fitted to, at most.
pub const MAX_FIT_POINTS: usize = 300;
/// A model whose residual is within this factor of the best one's is an acceptable description.
pub const ACCEPTABLE_RMS_RATIO: f64 = 1.5;
/// The floor of a correction's relative standard uncertainty, as a fraction of `|c - 1|`.
pub const CORRECTION_U_FRACTION: f64 = 0.25;
/// A best model whose cos-weighted relative rms residual is above this does not describe the sample: nothing is
/// corrected by it. The models fitted to the seed materials on realistic.toml leave 0.1-1.4 % (paper, spectralon,
/// styrofoam 0.1-0.2 %, gold 1.0 %, plastic 1.4 %); to a mirror's few bright points and many dark ones, 48-100 %.
/// A sample no model fits closely (a measured table's kinks) still has its corrections from the best of them,
/// their spread its uncertainty, up to this.
pub const MODEL_RMS_LIMIT: f64 = 0.3;
/// A larger `|c - 1|` is not corrected: the point is flagged.
pub const NARROW_LIMIT: f64 = 0.1;
/// A value near the specular direction this many times the best model's aperture average (or less than its
/// inverse) is a lobe the model does not resolve ([`unresolved_lobe`]): a misfit, not a shape to correct by.
pub const UNRESOLVED_RATIO: f64 = 2.0;
/// The angle step of the slopes' central differences (deg): small against every lobe the models fit, large
/// against rounding.
pub const SLOPE_STEP_DEG: f64 = 0.01;
/// The models fitted (module doc).
pub const MODELS: [FitModel; 4] = [
    FitModel::OrenNayar,
    FitModel::Conductor,
    FitModel::Plastic,
    FitModel::Phong,
];

/// One point's correction.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Correction {
    /// `brdf_sr = factor x aperture average`; `u_rel` is the correction's relative standard uncertainty.
    Applied { factor: f64, u_rel: f64 },
    /// No honest correction: flagged, the value kept, `u_rel` (relative to the value) covering the bias.
    NarrowLobe { u_rel: f64 },
}

/// The corrections of a run's points.
#[derive(Debug, Clone)]
pub struct Corrections {
    /// The model that corrected, with its cos-weighted relative rms residual.
    pub model: FitModel,
    pub residual_rms: f64,
    /// One per point of the run, in its order: `None` for points not corrected (flagged, no value).
    pub points: Vec<Option<Correction>>,
    /// One per point: the model's relative slopes `d ln f` per radian of `theta_i`, of `theta_o` and of arc
    /// across it (`d phi_o sin theta_o`), where the model has a value; what an angle's uncertainty does to the
    /// value (the pointing component, gonio_engine::budget).
    pub slopes: Vec<Option<[f64; 3]>>,
    /// The best-fitting model itself, to evaluate where the instrument really was (the positioning component,
    /// gonio_engine::budget).
    pub material: Material,
}

/// What the instrument's optics do to a lobe narrower than they resolve: how far from its direction a delta
/// lobe's light still reaches the detector.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Optics {
    /// The detector aperture's half-angle seen from the sample (rad).
    pub aperture_half_angle_rad: f64,
    /// The reflected beam's own half-width at the detector seen from the sample (rad): its radius there (the
    /// beam's radius and half its divergence over the distance) over the distance. A mirror's collimated
    /// reflection is a tube of the beam's width, not a ray: it overlaps the aperture while the angle between its
    /// direction and the aperture's centre is below the sum of the two half-angles.
    pub beam_half_angle_rad: f64,
    /// How far the specular direction may lie from where the nominal geometry puts it (rad): three standard
    /// uncertainties of the reflected direction (the sample's tilt, which turns it twice, the zeros, the beam),
    /// from the instrument file.
    pub misalignment_rad: f64,
}

impl Optics {
    /// An aperture alone: a point-like beam exactly where the geometry says.
    pub fn aperture_only(half_angle_rad: f64) -> Optics {
        Optics {
            aperture_half_angle_rad: half_angle_rad,
            beam_half_angle_rad: 0.0,
            misalignment_rad: 0.0,
        }
    }

    /// The instrument's angular resolution (rad): the half-width of what it reads from a delta lobe, the
    /// aperture's and the beam's half-angles together. A fitted lobe no wider than it is the instrument's own
    /// response, not the sample's.
    pub fn resolution_rad(&self) -> f64 {
        self.aperture_half_angle_rad + self.beam_half_angle_rad
    }

    /// How far from the nominal specular direction a delta lobe can still put light into the aperture (rad).
    pub fn delta_reach_rad(&self) -> f64 {
        self.resolution_rad() + self.misalignment_rad
    }

    fn is_valid(&self) -> bool {
        let ok = |x: f64| x.is_finite() && x >= 0.0;
        self.aperture_half_angle_rad > 0.0
            && ok(self.aperture_half_angle_rad)
            && ok(self.beam_half_angle_rad)
            && ok(self.misalignment_rad)
    }
}

/// A fitted model ready to evaluate.
struct Fitted {
    model: FitModel,
    material: Material,
    rms: f64,
    /// The microfacet roughness (GGX alpha) where the model has one.
    alpha: Option<f64>,
}

/// The corrections of `run`'s points measured through `optics` (module doc); `None` when no model could be
/// fitted (too few points, nothing valid) or the aperture is not positive.
/// When even the best model leaves residuals above [`MODEL_RMS_LIMIT`] it describes nothing: no point is
/// corrected by it, and every point a delta lobe could reach is flagged.
pub fn corrections(run: &Run, optics: &Optics) -> Option<Corrections> {
    if !optics.is_valid() {
        return None;
    }
    let subset = Run {
        origin: run.origin.clone(),
        name: run.name.clone(),
        points: fit_subset(&run.points),
        axis_names: run.axis_names.clone(),
        dry_run: run.dry_run,
        provenance: None,
    };
    // The fits and the points are independent of each other: on the machine's cores (crate::parallel).
    let mut fitted: Vec<Fitted> = crate::parallel::map(&MODELS, |&model| {
        let mut opts = FitOptions::new(model);
        opts.loss = Loss::None;
        let report = fit_unshared(&subset, &opts, Chi2Whole::Skip).ok()?;
        fitted_of(report)
    })
    .into_iter()
    .flatten()
    .collect();
    fitted.sort_by(|a, b| a.rms.total_cmp(&b.rms));
    let best = fitted.first()?;
    let acceptable: Vec<&Fitted> = fitted
        .iter()
        .filter(|f| f.rms <= best.rms * ACCEPTABLE_RMS_RATIO)
        .collect();
    let described = best.rms <= MODEL_RMS_LIMIT;
    let (points, slopes) = crate::parallel::map(&run.points, |p| {
        (
            if described {
                correction(p, optics, &acceptable)
            } else {
                // The poor fit's roughness widens the reach only where it is a lobe the instrument does not
                // resolve: a broad one would flag the whole hemisphere.
                let alpha = best.alpha.filter(|a| *a < optics.resolution_rad()).unwrap_or(0.0);
                undescribed(p, optics, alpha)
            },
            slopes(p, &best.material),
        )
    })
    .into_iter()
    .unzip();
    Some(Corrections {
        model: best.model,
        residual_rms: best.rms,
        points,
        slopes,
        material: best.material.clone(),
    })
}

/// The model's relative slopes at a valid point (see [`Corrections::slopes`]), by central differences of
/// [`SLOPE_STEP_DEG`].
fn slopes(p: &Point, model: &Material) -> Option<[f64; 3]> {
    p.value()?;
    let wavelength = Wavelength::from_nm(p.band_nm).ok()?;
    let f = |ti: f64, to: f64, po: f64| {
        let wi = Direction::from_spherical_deg(ti, p.phi_i_deg);
        let wo = Direction::from_spherical_deg(to, po);
        model.eval(&wi, &wo, wavelength).ok().filter(|v| v.is_finite())
    };
    let (ti, to, po) = (p.theta_i_deg, p.theta_o_deg, p.phi_o_deg);
    let centre = f(ti, to, po).filter(|v| *v > 0.0)?;
    let h = SLOPE_STEP_DEG;
    let step_rad = 2.0 * h.to_radians();
    let d = |a: Option<f64>, b: Option<f64>| Some((a? - b?) / centre / step_rad);
    let sin_o = to.to_radians().sin().max(1e-3);
    Some([
        d(f(ti + h, to, po), f(ti - h, to, po))?,
        d(f(ti, to + h, po), f(ti, to - h, po))?,
        d(f(ti, to, po + h), f(ti, to, po - h))? / sin_o,
    ])
}

fn fitted_of(report: FitReport) -> Option<Fitted> {
    let rms = report.residuals.cos_weighted_relative_rms;
    if !rms.is_finite() {
        return None;
    }
    let param = |key: &str| report.params.iter().find(|p| p.key == key).map(|p| p.value);
    // Phong's exponent as the microfacet roughness of the same lobe width (Walter et al. 2007:
    // alpha_Beckmann = sqrt(2 / (n + 2))).
    let alpha = param("alpha").or_else(|| param("exponent").map(|n| (2.0 / (n + 2.0)).sqrt()));
    Some(Fitted {
        model: report.model,
        material: report.material,
        rms,
        alpha,
    })
}

/// The valid points the models are fitted to: all when few, else the brightest half (cos-weighted, where
/// lobes are) and an even spread of the rest.
fn fit_subset(points: &[Point]) -> Vec<Point> {
    let valid: Vec<&Point> = points.iter().filter(|p| p.value().is_some()).collect();
    if valid.len() <= MAX_FIT_POINTS {
        return valid.into_iter().cloned().collect();
    }
    let weighted = |p: &Point| {
        let (wi, wo) = directions(p);
        p.value().unwrap_or(0.0) * wi.cos_theta() * wo.cos_theta()
    };
    let mut order: Vec<usize> = (0..valid.len()).collect();
    order.sort_by(|&a, &b| weighted(valid[b]).total_cmp(&weighted(valid[a])));
    let bright = MAX_FIT_POINTS / 2;
    let mut chosen: Vec<usize> = order[..bright].to_vec();
    let rest = &order[bright..];
    let step = rest.len() as f64 / (MAX_FIT_POINTS - bright) as f64;
    chosen
        .extend((0..MAX_FIT_POINTS - bright).map(|k| rest[((k as f64 * step) as usize).min(rest.len() - 1)]));
    chosen.sort_unstable();
    chosen.dedup();
    chosen.into_iter().map(|k| valid[k].clone()).collect()
}

/// `f_m(nominal) / <f_m>` of one model at one point; `None` where the model cannot be evaluated.
fn factor(
    model: &Material,
    wi: &Direction,
    wo: &Direction,
    wavelength: Wavelength,
    half_angle_rad: f64,
) -> Option<f64> {
    let (point, average) = point_and_average(model, wi, wo, wavelength, half_angle_rad)?;
    let c = point / average;
    (c.is_finite() && c > 0.0 && point > 0.0).then_some(c)
}

/// One model's value at the nominal geometry and its cos-weighted average over the aperture (1/sr).
fn point_and_average(
    model: &Material,
    wi: &Direction,
    wo: &Direction,
    wavelength: Wavelength,
    half_angle_rad: f64,
) -> Option<(f64, f64)> {
    let point = model.eval(wi, wo, wavelength).ok()?;
    let cos_o = wo.cos_theta();
    let omega = cone_solid_angle_sr(half_angle_rad);
    let integral = integrate_adaptive(
        |w: &Direction| model.eval(wi, w, wavelength).map(|f| f * w.cos_theta().max(0.0)),
        &Region::cone(*wo, half_angle_rad),
        Rule::GaussTrapezoid {
            n_radial: 4,
            n_azimuth: 8,
        },
        Tolerance {
            rel: 1e-6,
            abs: 1e-300,
            max_evaluations: 20_000,
        },
    )
    .ok()?;
    Some((point, integral.value / (omega * cos_o)))
}

/// Whether a lobe of roughness `alpha` about the mirror direction of `wi` can reach the aperture about `wo`:
/// within a delta lobe's reach ([`Optics::delta_reach_rad`]: the aperture, the beam's width, the
/// misalignment) and three lobe widths (2 alpha each: the half vector turns at half the rate) of it.
fn lobe_within_reach(wi: &Direction, wo: &Direction, alpha: f64, optics: &Optics) -> bool {
    let mirror = [-wi.x(), -wi.y(), wi.z()];
    let cos = mirror[0] * wo.x() + mirror[1] * wo.y() + mirror[2] * wo.z();
    cos.clamp(-1.0, 1.0).acos() <= optics.delta_reach_rad() + 6.0 * alpha
}

/// A point's lot when no model describes the data: flagged with its whole value as uncertainty where a lobe of
/// roughness `alpha` (a poor fit's unresolved lobe, the only estimate of its extent; else 0) could reach it (what
/// it reads may be the beam itself, the BRDF there anything from 0 up), else left as measured (`None`: no
/// correction, none to be had).
fn undescribed(p: &Point, optics: &Optics, alpha: f64) -> Option<Correction> {
    p.value()?;
    let (wi, wo) = directions(p);
    lobe_within_reach(&wi, &wo, alpha, optics).then_some(Correction::NarrowLobe { u_rel: 1.0 })
}

/// Whether `p` sees a lobe the best model does not resolve: within reach of the specular direction (a lobe of
/// no width, [`lobe_within_reach`]) and its value more than [`UNRESOLVED_RATIO`] times the model's aperture
/// average, or less than its inverse.
/// A fit can miss a lobe narrower than the aperture altogether (few points near it: a mirror measured at a
/// hundred geometries came out with a smooth model and its specular values, thousands of 1/sr, "corrected" by
/// a few tenths of a percent); the model's correction says nothing about such a point.
fn unresolved_lobe(
    p: &Point,
    best: &Fitted,
    wi: &Direction,
    wo: &Direction,
    wavelength: Wavelength,
    optics: &Optics,
) -> bool {
    if !lobe_within_reach(wi, wo, 0.0, optics) {
        return false;
    }
    let (Some(value), Some((_, average))) = (
        p.value(),
        point_and_average(&best.material, wi, wo, wavelength, optics.aperture_half_angle_rad),
    ) else {
        return false;
    };
    let ratio = value / average;
    !(average > 0.0 && (1.0 / UNRESOLVED_RATIO..=UNRESOLVED_RATIO).contains(&ratio))
}

fn correction(p: &Point, optics: &Optics, models: &[&Fitted]) -> Option<Correction> {
    p.value()?;
    let wavelength = Wavelength::from_nm(p.band_nm).ok()?;
    let (wi, wo) = directions(p);
    let too_narrow = |m: &Fitted| {
        m.alpha
            .is_some_and(|a| a < optics.resolution_rad() && lobe_within_reach(&wi, &wo, a, optics))
            || unresolved_lobe(p, m, &wi, &wo, wavelength, optics)
    };
    let half_angle_rad = optics.aperture_half_angle_rad;
    // Each acceptable model's correction here and whether its lobe is too narrow to resolve here, once.
    let here: Vec<(Option<f64>, bool)> = models
        .iter()
        .map(|m| {
            (
                factor(&m.material, &wi, &wo, wavelength, half_angle_rad),
                too_narrow(m),
            )
        })
        .collect();
    // Whether a model says no honest correction is possible here: its lobe too narrow, or its correction too
    // large (or none).
    let unresolved_by = |k: usize| {
        let (c, narrow) = here[k];
        narrow || c.is_none_or(|c| (c - 1.0).abs() > NARROW_LIMIT)
    };
    // The best model corrects; where it says no honest correction is possible here but a model without a lobe
    // (Oren-Nayar) describes the data as acceptably and corrects here, the data do not ask for a lobe and that
    // model corrects instead. A spectralon grid of eight points (one lost to a stalled move) was fitted best, by
    // a hair (rms 3.8e-5 against 4.8e-5), by a Phong lobe of exponent near 0, a step across the hemisphere, and
    // the point on its step was flagged with its whole value as uncertainty while it was 4e-5 from the truth.
    models.first()?;
    let best = if unresolved_by(0) {
        (0..models.len())
            .find(|&k| models[k].model == FitModel::OrenNayar && !unresolved_by(k))
            .unwrap_or(0)
    } else {
        0
    };
    let (c, lobe_too_narrow) = here[best];
    let c = match c {
        Some(c) if !lobe_too_narrow && (c - 1.0).abs() <= NARROW_LIMIT => c,
        // At least the whole value, and twice the bias the model sees: fitted to point values, a lobe narrower
        // than the aperture comes out wider than it is, so its `c` understates the bias.
        Some(c) => {
            return Some(Correction::NarrowLobe {
                u_rel: (2.0 * (c - 1.0).abs()).max(1.0),
            });
        }
        None if lobe_too_narrow => return Some(Correction::NarrowLobe { u_rel: 1.0 }),
        // The model has nothing here (zero or not finite): nothing to correct with.
        None => return None,
    };
    // The other acceptable models that can correct here (one that cannot has no correction to compare).
    let spread = (0..models.len())
        .filter(|&k| k != best && !unresolved_by(k))
        .filter_map(|k| here[k].0)
        .map(|other| (other - c).abs() / c)
        .fold(0.0f64, f64::max);
    let floor = CORRECTION_U_FRACTION * (c - 1.0).abs();
    Some(Correction::Applied {
        factor: c,
        u_rel: spread.max(floor),
    })
}

#[cfg(test)]
pub(crate) mod tests;
