//! The beam as it really is: its profile, where it points, how much it diverges.
//!
//! # Models (magnitudes from `[simulator.imperfections.beam]`)
//! - **Profile.** The ideal beam is uniform over a disc of `[instrument.source] beam_radius_mm` (a top hat), so
//!   the fraction of it that lands on the sample inside the detector's field is an area ratio
//!   (crate::optics::footprint). A Gaussian beam has intensity `exp(-2 r^2 / w^2)` across its section (w the
//!   1/e^2 radius, `gaussian_radius_mm`); on the sample plane its footprint is the same Gaussian stretched by
//!   `1 / cos(theta_i)` along the plane of incidence, and the intercepted fraction is the Gaussian's weight over
//!   the sample and the field (crate::optics::footprint_gaussian: exact along each ray, a trapezoid rule over the
//!   rays' angle). Its footprint is never wholly inside anything: at grazing incidence, where the footprint's
//!   long axis is `w / cos(theta_i)`, its tails spill past the sample's edge long before a top hat of the same
//!   radius would.
//! - **The sample's non-uniformity seen through the profile** (crate::imperfections::sample): the footprint mean
//!   of `m` is the profile-weighted mean. For the Gaussian the second moments of the footprint along and across
//!   the plane of incidence are `w^2 / (4 cos^2 theta_i)` and `w^2 / 4`, the same as a uniform ellipse of
//!   semi-axes `w / cos(theta_i)` and `w`, so the sample group's closed form is used with those semi-axes (over
//!   the whole, unclipped footprint, as for the top hat).
//! - **Pointing.** The beam leaves the source `source_distance_mm` (L) from the arms' axis at a small angle to
//!   the light arm's axis: two components, each `N(0, pointing_sd_deg)`, the first in the arms' (horizontal)
//!   plane towards increasing arm angle, the second vertical (up). The direction towards the source becomes
//!   `s' = unit(s + tan(p_1) e_1 + tan(p_2) Z)` (`s` the arm's direction, `e_1 = Z x s`), and the beam, a line
//!   through the source's output `S = C + L s` (C on the arms' axis, crate::imperfections::geometry) along
//!   `-s'`, meets the sample plane at `P = S - (S.n / s'.n) s'`: the incidence direction turns by the pointing
//!   angle and the spot moves by about L times it (stretched by 1 / cos(theta_i) along the plane of incidence).
//!   The sample sees the detector's aperture centre `D = C + d o` along `unit(D - P)`. Applied after the true
//!   geometry of the geometry group, so both together are right.
//! - **Divergence.** The true full divergence angle is `max(0, divergence_deg + N(0, divergence_sd_deg))`. It
//!   matters where the beam itself reaches the detector: a delta (mirror) lobe and the direct beam. A top-hat
//!   beam keeps the far-field cone model (crate::optics::cap) with the true angle. A Gaussian beam is treated as
//!   Gaussian in angle too, its 1/e^2 half-angle half the full divergence, so at the detector (distance d) its
//!   1/e^2 radius is `w_d = sqrt(w^2 + (d tan(divergence / 2))^2)` (spatial and angular Gaussian spreads add in
//!   quadrature) and the power through the aperture (radius a) with the beam's axis `s` from the aperture's
//!   centre is the Gaussian's weight over that disc (`1 - exp(-2 a^2 / w_d^2)` when centred): a Gaussian
//!   wider than the aperture loses its tails, also in the direct-beam reading. The offset `s` is the distance
//!   from the aperture centre to the beam's axis for the direct beam, `d sin(g)` for a mirror lobe `g` off the
//!   aperture's axis.
//! - **Divergence and the regular BRDF (neglected).** A beam spread over a cone of incidence directions
//!   averages the BRDF over incidence as well. Near a glossy lobe moving the incidence by an angle moves the
//!   mirror direction by the same angle, so the incidence spread adds to the aperture's own spread of outgoing
//!   directions: a uniform cone of half-angle delta has a mean squared angle delta^2 / 2 against the aperture's
//!   beta^2 / 2 (beta = atan(2.5 / 250) = 0.57 deg here). The aperture's averaging biases the sharpest realistic
//!   lobe (gold) by at most 1.85 % at specular (issue 16), so the divergence adds about 1.85 % x (delta /
//!   beta)^2 (the bias is the lobe's curvature times the mean squared angle): 3.5e-5 at 0.05 deg full
//!   divergence (delta 0.025 deg), 1.4e-4 at 0.1 deg, 5.6e-4 at 0.2 deg, and only within a fraction of a degree
//!   of a mirror-like lobe's peak; elsewhere the lobe's curvature over 0.05 deg is far below 1e-4. At the
//!   realistic instrument's 0.05 deg (plus its drawn error) that is below the error budget's resolution
//!   (~1e-4), so it is not modelled: the regular part is integrated over the outgoing aperture only, at the
//!   beam's central incidence direction. A beam diverging 0.2 deg or more would need it.
//!
//! Direct-beam geometry (no sample): the reading is taken with the detector facing the light arm, far from the
//! sample plane's influence; the offset `s` is measured in the plane through the aperture centre perpendicular
//! to the beam.

use gonio_instrument::{BeamImperfections, BeamProfile};
use serde::Serialize;

use super::draw::Draws;
use crate::kinematics::LabVector;

/// The hidden beam of one instrument.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct BeamTruth {
    pub profile: BeamProfile,
    /// The Gaussian's 1/e^2 radius (mm); 0 for the top hat.
    pub gaussian_radius_mm: f64,
    /// The pointing error: in the arms' plane (towards increasing arm angle) and vertical (degrees).
    pub pointing_deg: [f64; 2],
    /// From the source's output to the arms' axis (mm).
    pub source_distance_mm: f64,
    /// The true full divergence angle (degrees), and the nominal one the instrument file states.
    pub divergence_deg: f64,
    pub nominal_divergence_deg: f64,
}

impl BeamTruth {
    /// Draw the beam for `settings` about the nominal full divergence `nominal_divergence_deg`.
    pub fn draw(settings: &BeamImperfections, nominal_divergence_deg: f64, seed: u64) -> BeamTruth {
        let draws = Draws::new(seed);
        let (p1, p2) = draws.normal_pair("beam-pointing", 0);
        let (dv, _) = draws.normal_pair("beam-divergence", 0);
        let nominal = nominal_divergence_deg.max(0.0);
        BeamTruth {
            profile: settings.profile,
            gaussian_radius_mm: match settings.profile {
                BeamProfile::TopHat => 0.0,
                BeamProfile::Gaussian => settings.gaussian_radius_mm,
            },
            pointing_deg: [settings.pointing_sd_deg * p1, settings.pointing_sd_deg * p2],
            source_distance_mm: settings.source_distance_mm,
            divergence_deg: (nominal + settings.divergence_sd_deg * dv).max(0.0),
            nominal_divergence_deg: nominal,
        }
    }

    pub fn is_ideal(&self) -> bool {
        self.profile == BeamProfile::TopHat
            && self.pointing_deg == [0.0, 0.0]
            && self.divergence_deg == self.nominal_divergence_deg
    }

    /// The Gaussian's 1/e^2 radius, `None` for the top hat.
    pub fn gaussian_mm(&self) -> Option<f64> {
        (self.profile == BeamProfile::Gaussian && self.gaussian_radius_mm > 0.0)
            .then_some(self.gaussian_radius_mm)
    }

    pub fn has_pointing(&self) -> bool {
        self.pointing_deg != [0.0, 0.0]
    }

    /// The true direction towards the source for a light arm along `s` (lab, horizontal unit vector).
    pub fn pointed(&self, s: &LabVector) -> LabVector {
        let (t1, t2) = (
            self.pointing_deg[0].to_radians().tan(),
            self.pointing_deg[1].to_radians().tan(),
        );
        // e_1 = Z x s: horizontal, towards increasing arm angle.
        let v = [s[0] - t1 * s[1], s[1] + t1 * s[0], s[2] + t2];
        let len = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
        [v[0] / len, v[1] / len, v[2] / len]
    }
}

/// Rays of the trapezoid rule for a Gaussian's weight over a disc.
const DISC_RAYS: usize = 256;

/// The fraction of a circular Gaussian beam (1/e^2 radius `w`) inside a disc of radius `a` whose centre lies
/// `s` from the beam's axis: `1 - exp(-2 a^2 / w^2)` when centred; otherwise exact along each ray from the
/// beam's axis (`exp(-2 t_lo^2 / w^2) - exp(-2 t_hi^2 / w^2)`), averaged over the rays' angle by the trapezoid
/// rule (spectrally accurate while the axis is inside the disc; the integrand is smooth and periodic).
pub fn gaussian_in_disc(w: f64, a: f64, s: f64) -> f64 {
    if !(w > 0.0 && a > 0.0 && s.is_finite()) {
        return 0.0;
    }
    let s = s.abs();
    let k = 2.0 / (w * w);
    if s == 0.0 {
        return -(-k * a * a).exp_m1();
    }
    // Beyond 6 w the disc holds less than exp(-72) of the beam.
    if s - a > 6.0 * w {
        return 0.0;
    }
    // Along the ray at angle phi: |t e - (s, 0)|^2 <= a^2, i.e. t^2 - 2 t s cos(phi) + s^2 - a^2 <= 0.
    let weight = |phi: f64| {
        let b = s * phi.cos();
        let disc = b * b - (s * s - a * a);
        if disc <= 0.0 {
            return 0.0;
        }
        let root = disc.sqrt();
        let (lo, hi) = ((b - root).max(0.0), b + root);
        if hi <= 0.0 {
            return 0.0;
        }
        (-k * lo * lo).exp() - (-k * hi * hi).exp()
    };
    let n = DISC_RAYS as f64;
    if s < a {
        // The axis inside the disc: every ray crosses its edge once, the integrand is smooth and periodic.
        let sum: f64 = (0..DISC_RAYS)
            .map(|j| weight(std::f64::consts::TAU * (j as f64 + 0.5) / n))
            .sum();
        return sum / n;
    }
    // The axis outside: only rays within asin(a / s) of the centre's direction meet the disc, and the chord
    // vanishes like a square root at the tangents; phi = phi_max sin(tau) smooths both ends.
    let phi_max = (a / s).asin();
    let d_tau = std::f64::consts::PI / n;
    let sum: f64 = (0..DISC_RAYS)
        .map(|j| {
            let tau = -std::f64::consts::FRAC_PI_2 + (j as f64 + 0.5) * d_tau;
            weight(phi_max * tau.sin()) * phi_max * tau.cos() * d_tau
        })
        .sum();
    sum / std::f64::consts::TAU
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The textbook form: the disc's power as a radial integral about its centre,
    /// `∫_0^a 4 r / w^2 exp(-2 (r^2 + s^2) / w^2) I0(4 r s / w^2) dr`, with `exp(-x) I0(x)` from its integral
    /// `1/pi ∫_0^pi exp(x (cos t - 1)) dt`, both by the midpoint rule.
    fn bessel(w: f64, a: f64, s: f64) -> f64 {
        let i0e = |x: f64| {
            let n = 400;
            (0..n)
                .map(|j| (x * ((std::f64::consts::PI * (j as f64 + 0.5) / n as f64).cos() - 1.0)).exp())
                .sum::<f64>()
                / n as f64
        };
        let n = 4000;
        let h = a / n as f64;
        (0..n)
            .map(|i| {
                let r = (i as f64 + 0.5) * h;
                let x = 4.0 * r * s / (w * w);
                4.0 * r / (w * w) * (-2.0 * (r * r + s * s) / (w * w) + x).exp() * i0e(x) * h
            })
            .sum()
    }

    #[test]
    fn the_gaussian_in_a_disc_matches_the_bessel_integral() {
        for (w, a, s) in [
            (1.5, 2.5, 0.0),
            (1.5, 2.5, 0.4),
            (3.0, 2.5, 1.0),
            (1.0, 2.5, 3.0),
            (2.0, 2.5, 2.5),
        ] {
            let f = gaussian_in_disc(w, a, s);
            let g = bessel(w, a, s);
            assert!((f - g).abs() < 1e-6, "({w}, {a}, {s}): {f} vs {g}");
        }
    }

    #[test]
    fn no_pointing_leaves_the_direction_alone() {
        let t = BeamTruth {
            profile: BeamProfile::TopHat,
            gaussian_radius_mm: 0.0,
            pointing_deg: [0.0, 0.0],
            source_distance_mm: 500.0,
            divergence_deg: 0.05,
            nominal_divergence_deg: 0.05,
        };
        let s = [0.6, 0.8, 0.0];
        let p = t.pointed(&s);
        assert!((0..3).all(|k| (p[k] - s[k]).abs() < 1e-16));
        assert!(t.is_ideal());
    }
}
