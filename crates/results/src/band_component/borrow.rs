//! A geometry measured in one band borrows its spectrum's shape from the nearest probes: geometries of the
//! campaign measured in several bands (a few points in every band beside sweeps in one, for instance).
//!
//! Why: a band's value carries the light its filter leaks from outside the band, `L (fbar - f)` of it, and
//! correcting it needs the sample's spectrum at the same geometry. A campaign measured in one band has none: on
//! construction paper (0.07 at 550 nm, 0.52 at 650 nm and redder beyond) the 550 nm band reads about 3 % high
//! on realistic.toml, outside any uncertainty the band's own data could state. The spectrum's shape, its values
//! relative to the band's, changes slowly with the geometry on most samples (a diffuse sample's is the same
//! everywhere; a glossy one's whitens towards its specular direction): the probe nearest in geometry lends its
//! shape, scaled to the one band's value, and the leak and the band component are worked out from it as if it
//! had been measured there ([`super::solve`]).
//!
//! How far the borrowed shape can be trusted is itself measured: the [`NEAREST`] probes each lend theirs, and the
//! largest difference of their leak means from the nearest's, times the leaked fraction, is added to the band
//! component. One probe alone says nothing of how the shape varies: the whole correction is then its
//! uncertainty (the value is moved to the best estimate, and the interval still holds the uncorrected value).
//!
//! Only values well above their noise ([`SIGNIFICANT`]) lend a shape or borrow one: a value at the noise (a
//! mirror's away from its specular direction) has no spectrum to speak of, and a leak's share of it is noise too.
//!
//! Nearness: the angle between the half vectors (a glossy sample's shape follows its specular direction) plus
//! the angle between the incident directions, both in radians.

use super::{FilterBand, Solved, WeightsCache, solve, spectra};
use crate::points::Point;
use crate::run::BAND_TOLERANCE_NM;

/// Probes whose shapes are compared for the borrowed shape's uncertainty.
pub(super) const NEAREST: usize = 3;

/// A probe's values are at least this many of their standard uncertainties (a value at the noise, a mirror's
/// away from its specular direction, has no shape to lend: its bands' ratios are the noise's).
pub(super) const SIGNIFICANT: f64 = 3.0;

/// One probe: its geometry's incident direction and half vector, and its spectrum (`(nm, value)` ascending).
struct Probe {
    incident: [f64; 3],
    half: [f64; 3],
    spectrum: Vec<(f64, f64)>,
}

/// The probes a campaign offers (module doc).
pub(super) struct Lender {
    probes: Vec<Probe>,
}

fn direction(theta_deg: f64, phi_deg: f64) -> [f64; 3] {
    let (t, p) = (theta_deg.to_radians(), phi_deg.to_radians());
    [t.sin() * p.cos(), t.sin() * p.sin(), t.cos()]
}

fn normalised(v: [f64; 3]) -> Option<[f64; 3]> {
    let n = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
    (n > 1e-12).then(|| [v[0] / n, v[1] / n, v[2] / n])
}

fn angle(a: [f64; 3], b: [f64; 3]) -> f64 {
    (a[0] * b[0] + a[1] * b[1] + a[2] * b[2]).clamp(-1.0, 1.0).acos()
}

/// The incident direction and the half vector of `p`'s geometry (`None` at retro-reflection's opposite, where
/// there is no half vector).
fn geometry(p: &Point) -> Option<([f64; 3], [f64; 3])> {
    let wi = direction(p.theta_i_deg, p.phi_i_deg);
    let wo = direction(p.theta_o_deg, p.phi_o_deg);
    let half = normalised([wi[0] + wo[0], wi[1] + wo[1], wi[2] + wo[2]])?;
    Some((wi, half))
}

/// Whether `p`'s value is at least [`SIGNIFICANT`] times its stated uncertainty (any finite value when it states
/// none).
pub(super) fn significant(p: &Point) -> bool {
    match (p.value(), p.brdf_u_sr) {
        (Some(f), Some(u)) if u.is_finite() => f >= SIGNIFICANT * u,
        (Some(f), _) => f.is_finite(),
        _ => false,
    }
}

impl Lender {
    /// The geometries of `points` measured in at least two bands, every value finite and at least
    /// [`SIGNIFICANT`] times its stated uncertainty.
    pub(super) fn new(points: &[Point]) -> Lender {
        let significant = |i: &usize| significant(&points[*i]);
        let probes = spectra(points)
            .into_iter()
            .filter(|(_, bands)| {
                bands.len() >= 2
                    && bands
                        .iter()
                        .all(|b| b.mean.is_finite() && b.members.iter().all(significant))
            })
            .filter_map(|(first, bands)| {
                let (incident, half) = geometry(&points[first])?;
                Some(Probe {
                    incident,
                    half,
                    spectrum: bands.iter().map(|b| (b.nm, b.mean)).collect(),
                })
            })
            .collect();
        Lender { probes }
    }

    /// Band `nm`'s solution at `at`'s geometry, measured there in that band alone at `value` (1/sr), from the
    /// nearest probes' shapes (module doc); `None` without a probe measured in that band (and another).
    pub(super) fn solve(
        &self,
        at: &Point,
        nm: f64,
        value: f64,
        filter: &impl Fn(f64) -> Option<FilterBand>,
        weights: &mut WeightsCache<'_>,
    ) -> Option<Solved> {
        let (incident, half) = geometry(at)?;
        let mut near: Vec<(f64, &Probe, usize)> = self
            .probes
            .iter()
            .filter_map(|p| {
                let k = p
                    .spectrum
                    .iter()
                    .position(|b| (b.0 - nm).abs() <= BAND_TOLERANCE_NM && b.1 != 0.0)?;
                Some((angle(p.half, half) + angle(p.incident, incident), p, k))
            })
            .collect();
        near.sort_by(|a, b| a.0.total_cmp(&b.0));
        let lent: Vec<Solved> = near
            .iter()
            .take(NEAREST)
            .filter_map(|&(_, p, k)| {
                let scale = value / p.spectrum[k].1;
                let borrowed: Vec<(f64, f64)> = p.spectrum.iter().map(|&(x, f)| (x, f * scale)).collect();
                solve(&borrowed, filter, weights).get(k).copied().flatten()
            })
            .collect();
        let first = *lent.first()?;
        let u_sr = if !first.fbar.is_finite() {
            // No leak spectrum: nothing is corrected, and each shape bounds the leak; the widest bound holds.
            lent.iter().map(|s| s.u_sr).fold(first.u_sr, f64::max)
        } else if lent.len() == 1 {
            first.u_sr.hypot(first.leakage * (value - first.fbar))
        } else {
            let spread = lent
                .iter()
                .map(|s| (s.fbar - first.fbar).abs())
                .fold(0.0f64, f64::max);
            first.u_sr.hypot(first.leakage * spread)
        };
        u_sr.is_finite().then_some(Solved { u_sr, ..first })
    }
}
