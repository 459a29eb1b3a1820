//! The observations a fit works on, the model's predictions at them (averaged over the detector aperture with a
//! 7-point disk rule), robust statistics and the start points.

use super::*;

/// One observation.
#[derive(Debug, Clone)]
pub(super) struct Obs {
    /// The point it is (index into the run's points).
    pub(super) point: usize,
    /// How much `f` moves per unit of the point's value (`brdf_sr`): 1, or the aperture average's ratio to
    /// the corrected value when the fit reads the average.
    pub(super) per_value: f64,
    pub(super) wi: Direction,
    pub(super) wo: Direction,
    pub(super) band: usize,
    pub(super) f: f64,
    pub(super) u: f64,
    /// cos(theta_i) cos(theta_o).
    pub(super) cos_weight: f64,
    pub(super) cos_i: f64,
    /// Directions across the detector aperture around `wo`, with weights `w_j cos(theta_j) / cos(theta_o)`
    /// (empty: the point value).
    pub(super) aperture: Vec<(Direction, f64)>,
}

/// The 7-point rule for the mean over a disk, exact for polynomials up to degree 5: the centre with weight 1/4,
/// six points at `sqrt(2/3)` of the radius, 60 degrees apart, with weight 1/8 each.
pub(super) fn aperture_samples(wo: &Direction, half_angle_rad: f64) -> Vec<(Direction, f64)> {
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
pub(super) fn predict(
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

pub(crate) fn median(mut v: Vec<f64>) -> f64 {
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

/// The (eta, k) pairs a conductor's starts take, across the metals' plausible range.
pub(super) const CONDUCTOR_PAIRS: [(f64, f64); 3] = [(0.3, 3.0), (1.5, 2.0), (1.2, 6.0)];

/// A conductor's start with each band's (eta, k) the [`CONDUCTOR_PAIRS`] pair of lowest `cost` (of the whole
/// start, natural units) with the other bands held; a band keeps its pair when none is lower.
pub(super) fn pairs_per_band(
    start: &mut [f64],
    defs: &[ParamDef],
    bands: usize,
    cost: impl Fn(&[f64]) -> f64,
) {
    for b in 0..bands {
        let at = |key: &str| defs.iter().position(|d| d.key == key && d.band == Some(b));
        let (Some(ie), Some(ik)) = (at("eta"), at("k")) else {
            continue;
        };
        let mut best = (cost(start), start[ie], start[ik]);
        for (eta, k) in CONDUCTOR_PAIRS {
            let mut trial = start.to_vec();
            (trial[ie], trial[ik]) = (eta, k);
            let c = cost(&trial);
            if c < best.0 {
                best = (c, eta, k);
            }
        }
        (start[ie], start[ik]) = (best.1, best.2);
    }
}

/// Start points (natural units) for the model: a small grid over the shape parameters.
pub(super) fn starts(opts: &FitOptions, defs: &[ParamDef], obs: &[Obs], bands: usize) -> Vec<Vec<f64>> {
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
                for (eta, k) in CONDUCTOR_PAIRS {
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
