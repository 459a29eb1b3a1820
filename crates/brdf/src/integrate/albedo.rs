//! Directional albedo: the deterministic rules chosen from the model's lobe, and randomised quasi-Monte Carlo
//! through the model's own importance sampling.

use super::*;

/// Rule choice threshold: lobes narrower than this (radians) use the lobe-adapted rule.
pub const LOBE_ADAPTED_BELOW_RAD: f64 = 0.3;

/// Evaluation budget of [`directional_albedo`] per rule.
const ALBEDO_BUDGET: usize = 2_000_000;

/// The directional albedo `a(wi) = integral of f(wi, wo) cos(theta_o) d wo` over the upper hemisphere, plus the
/// reflectance of the model's delta lobe (added analytically, with no error).
///
/// Rule choice, from [`Brdf::lobe_width`] and [`Brdf::is_isotropic`]:
/// - no lobe, or one wider than [`LOBE_ADAPTED_BELOW_RAD`]: Gauss-Legendre x trapezoid about the normal;
/// - a narrow isotropic lobe: the lobe-adapted rule centred on the mirror direction of `wi`;
/// - a narrow anisotropic lobe (a thin streak in direction space that no azimuthal grid of fixed size resolves):
///   quasi-Monte Carlo through the model's own importance sampling ([`sampled_albedo`]), when it offers one.
///
/// The deterministic rules double their resolution until the error estimate is below `rel_tol * albedo`
/// (or 1e-15 absolute) or 2 million evaluations are spent (500 thousand when the model can sample); if they stop
/// short and the model can sample, the sampled estimate (at most 500 thousand evaluations) is computed too and the one with the smaller error is returned. The returned error says
/// how far it got. An incidence at or below the horizon gives 0: the model reflects nothing there by contract.
pub fn directional_albedo(
    brdf: &dyn Brdf,
    wi: &Direction,
    wavelength: Wavelength,
    rel_tol: f64,
) -> Result<Estimate, SpectrumError> {
    if !wi.is_above_horizon() {
        return Ok(Estimate::exact(0.0));
    }
    let integrand = |wo: &Direction| -> Result<f64, SpectrumError> {
        let c = wo.cos_theta();
        if c <= 0.0 {
            Ok(0.0)
        } else {
            Ok(brdf.eval(wi, wo, wavelength)? * c)
        }
    };
    // With a sampler to fall back on, the deterministic rules get a quarter of the budget.
    let can_sample = brdf.sample(wi, [0.5, 0.5], wavelength)?.is_some();
    let budget = if can_sample {
        ALBEDO_BUDGET / 4
    } else {
        ALBEDO_BUDGET
    };
    let tolerance = Tolerance {
        rel: rel_tol,
        abs: 1e-15,
        max_evaluations: budget,
    };
    let narrow = brdf
        .lobe_width()
        .filter(|w| w.is_finite() && *w > 0.0 && *w < LOBE_ADAPTED_BELOW_RAD);
    let sampled = |brdf: &dyn Brdf| sampled_albedo(brdf, wi, wavelength, rel_tol, ALBEDO_BUDGET / 4);
    let diffuse = match narrow {
        Some(_) if !brdf.is_isotropic() => match sampled(brdf)? {
            Some(e) => e,
            None => integrate_adaptive(
                integrand,
                &Region::upper_hemisphere_about(wi.reflect_about_normal()),
                Rule::LobeAdapted {
                    lobe_width_rad: narrow.unwrap_or(LOBE_ADAPTED_BELOW_RAD),
                    n_per_panel: 8,
                    n_azimuth: 16,
                },
                tolerance,
            )?,
        },
        _ => {
            let deterministic = match narrow {
                Some(width) => integrate_adaptive(
                    integrand,
                    &Region::upper_hemisphere_about(wi.reflect_about_normal()),
                    Rule::LobeAdapted {
                        lobe_width_rad: width,
                        n_per_panel: 8,
                        n_azimuth: 16,
                    },
                    tolerance,
                )?,
                None => integrate_adaptive(
                    integrand,
                    &Region::upper_hemisphere(),
                    Rule::GaussTrapezoid {
                        n_radial: 8,
                        n_azimuth: 16,
                    },
                    tolerance,
                )?,
            };
            if deterministic.meets(tolerance.rel, tolerance.abs) {
                deterministic
            } else {
                match sampled(brdf)? {
                    Some(s) if s.error < deterministic.error => s,
                    _ => deterministic,
                }
            }
        }
    };
    let delta = brdf.delta_lobe(wi, wavelength)?.map_or(0.0, |d| d.reflectance);
    Ok(Estimate {
        value: diffuse.value + delta,
        error: diffuse.error,
    })
}

/// Replicates of the randomised quasi-Monte Carlo estimate.
const QMC_REPLICATES: usize = 8;

/// The directional albedo (delta lobe excluded) by randomised quasi-Monte Carlo through the model's importance
/// sampling [`Brdf::sample`]: the estimator `f cos(theta_o) / pdf` averaged over an R2 low-discrepancy sequence
/// (Roberts 2018), in 8 replicates with independent deterministic random shifts (Cranley-Patterson). The value
/// is the mean of the replicates; the error is 3 standard errors of that mean. The number of points doubles
/// until the error is below `rel_tol * value` or `max_evaluations` would be exceeded.
/// `None` when the model offers no sampling routine. Converges about as 1/N for smooth sampling weights (e.g.
/// visible-normal sampling of a microfacet lobe, whose weight is bounded), whatever the lobe's width and shape.
pub fn sampled_albedo(
    brdf: &dyn Brdf,
    wi: &Direction,
    wavelength: Wavelength,
    rel_tol: f64,
    max_evaluations: usize,
) -> Result<Option<Estimate>, SpectrumError> {
    if brdf.sample(wi, [0.5, 0.5], wavelength)?.is_none() {
        return Ok(None);
    }
    // The R2 sequence: frac(0.5 + k (1/g, 1/g^2)), g the plastic number (root of x^3 = x + 1).
    const G: f64 = 1.324_717_957_244_746;
    let step = [1.0 / G, 1.0 / (G * G)];
    let shifts: Vec<[f64; 2]> = (0..QMC_REPLICATES as u64)
        .map(|r| [unit_from_hash(2 * r + 1), unit_from_hash(2 * r + 2)])
        .collect();
    let mut sums = [0.0f64; QMC_REPLICATES];
    let mut done = 0usize;
    let mut points = 1024usize;
    loop {
        for (sum, shift) in sums.iter_mut().zip(&shifts) {
            for k in done..points {
                let kf = k as f64;
                let u = [
                    (0.5 + kf * step[0] + shift[0]).fract(),
                    (0.5 + kf * step[1] + shift[1]).fract(),
                ];
                let Some(sample) = brdf.sample(wi, u, wavelength)? else {
                    continue;
                };
                let wo = sample.wo;
                if wo.cos_theta() > 0.0 && sample.pdf_per_sr > 0.0 && sample.pdf_per_sr.is_finite() {
                    let w = brdf.eval(wi, &wo, wavelength)? * wo.cos_theta() / sample.pdf_per_sr;
                    *sum += w;
                }
            }
        }
        done = points;
        let means: Vec<f64> = sums.iter().map(|s| s / points as f64).collect();
        let mean = means.iter().sum::<f64>() / QMC_REPLICATES as f64;
        let variance =
            means.iter().map(|m| (m - mean) * (m - mean)).sum::<f64>() / (QMC_REPLICATES as f64 - 1.0);
        let error = 3.0 * (variance / QMC_REPLICATES as f64).sqrt();
        let estimate = Estimate {
            value: mean,
            error: error.max(8.0 * f64::EPSILON * mean.abs()),
        };
        if estimate.meets(rel_tol, 1e-15)
            || 2 * points * QMC_REPLICATES > max_evaluations
            || !mean.is_finite()
        {
            return Ok(Some(estimate));
        }
        points *= 2;
    }
}

/// A deterministic uniform number in [0, 1) from an integer (SplitMix64 finaliser).
fn unit_from_hash(seed: u64) -> f64 {
    let mut z = seed.wrapping_mul(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^= z >> 31;
    (z >> 11) as f64 / (1u64 << 53) as f64
}
