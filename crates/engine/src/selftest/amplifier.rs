//! The head's amplifier noise (`detector.amplifier_noise_a_per_rthz`): what a dim value's noise on the lowest
//! ranges is made of beyond the photocurrent's shot noise, the feedback resistor's Johnson noise and the
//! converter's quantisation, which the meter's model knows (gonio_instrument::meter_noise).
//!
//! The blank in the beam, the meter on its smallest range at averaging 1: [`READINGS`] readings in a row. Half
//! the variance of consecutive differences is one sample's (room light drifting over minutes cancels in the
//! differences); less the model's floor at the dark's level ([`super::noise::meter_floor_w2`]), the rest, in
//! current through the file's responsivity at the set wavelength, over one sample's noise bandwidth, is the
//! amplifier's current noise density. Its statistical uncertainty (the variance of N - 1 differences known to
//! about sqrt(2 / (N - 1)) of itself) sets the verdict: the figure passes within the tolerance of the claim or
//! [`SIGMAS`] of its own uncertainty, whichever is wider.

use gonio_instrument::meter_noise;

use super::noise::{meter_floor_w2, readings_at_averaging_1, responsivity, white_variance};
use super::report::line;
use crate::motion::{Motion, MotionError};
use crate::selftest::Check;

/// Dark readings at averaging 1 on the smallest range (about 3 ms each): the differences' variance to about 5 %.
pub const READINGS: usize = 800;
/// How many of its own standard uncertainties a measured figure may stand from the claim and still pass.
pub const SIGMAS: f64 = 3.0;

/// A measured amplifier noise density (A/sqrt(Hz)) with its standard uncertainty.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Measured {
    pub a_per_rthz: f64,
    pub u_a_per_rthz: f64,
}

/// The amplifier noise density of dark readings `values` (W, averaging 1) on a range of `range_w`, the head
/// delivering `a_per_w` at the set wavelength (module doc). None for fewer than three readings.
pub fn amplifier_noise(values: &[f64], range_w: f64, a_per_w: f64) -> Option<Measured> {
    let (mean_w, sample_w2, differences) = white_variance(values)?;
    let floor_w2 = meter_floor_w2(mean_w.max(0.0), range_w, a_per_w);
    // W^2 of one sample -> A^2/Hz.
    let to_density = a_per_w * a_per_w / meter_noise::bandwidth_hz();
    let excess = (sample_w2 - floor_w2).max(0.0) * to_density;
    let u_excess = sample_w2 * (2.0 / (differences as f64 - 1.0).max(1.0)).sqrt() * to_density;
    let a_per_rthz = excess.sqrt();
    // Near zero the square root's slope diverges: there the figure is known to within sqrt(u_excess).
    let u_a_per_rthz = if excess > u_excess {
        u_excess / (2.0 * a_per_rthz)
    } else {
        u_excess.sqrt()
    };
    (a_per_rthz.is_finite() && u_a_per_rthz.is_finite()).then_some(Measured {
        a_per_rthz,
        u_a_per_rthz,
    })
}

/// The verdict (module doc).
pub fn amplifier_check(claimed: f64, measured: Measured, tolerance: f64) -> Check {
    let allowed = (tolerance * claimed).max(SIGMAS * measured.u_a_per_rthz);
    line(
        "detector.amplifier_noise_a_per_rthz".into(),
        "amplifier current noise (blank, smallest range, averaging 1)",
        "A/sqrt(Hz)",
        claimed,
        measured.a_per_rthz,
        (measured.a_per_rthz - claimed).abs() <= allowed,
    )
}

/// The amplifier noise on the smallest range with the blank already in the beam, the meter set to `nm`; or
/// why it is not measured.
pub(super) async fn measure(
    motion: &Motion<'_>,
    nm: f64,
    tolerance: f64,
) -> Result<Result<Check, String>, MotionError> {
    let detector = &motion.rig().file().instrument.detector;
    let Some(&range_w) = detector.ranges_w.first() else {
        return Ok(Err("no meter range".into()));
    };
    let claimed = detector.amplifier_noise_a_per_rthz;
    let r = match responsivity(motion) {
        Ok(r) => r.at(nm),
        Err(e) => return Ok(Err(e)),
    };
    tracing::info!(
        range_w,
        readings = READINGS,
        "self-test: the head's amplifier noise on the dark"
    );
    let Some(values) = readings_at_averaging_1(motion, nm, range_w, READINGS).await? else {
        return Ok(Err(format!("the dark overloads the {range_w:e} W range")));
    };
    Ok(match amplifier_noise(&values, range_w, r) {
        Some(m) => Ok(amplifier_check(claimed, m, tolerance)),
        None => Err("too few dark readings".into()),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::selftest::Verdict::{Fail, Pass};

    /// Dark readings (W) with white noise of `std_w` per sample about `mean_w`, from a fixed sequence of
    /// standard normals (Box-Muller on a small linear congruential generator), drifting by `drift_w` over them.
    fn darks(n: usize, mean_w: f64, std_w: f64, drift_w: f64) -> Vec<f64> {
        let mut state: u64 = 0x2545_F491_4F6C_DD1D;
        let mut uniform = || {
            state = state.wrapping_mul(6_364_136_223_846_793_005).wrapping_add(1);
            ((state >> 11) as f64 + 0.5) / (1u64 << 53) as f64
        };
        (0..n)
            .map(|i| {
                let z = (-2.0 * uniform().ln()).sqrt() * (std::f64::consts::TAU * uniform()).cos();
                mean_w + std_w * z + drift_w * i as f64 / n as f64
            })
            .collect()
    }

    #[test]
    fn the_amplifier_is_what_the_darks_scatter_beyond_the_meters_model() {
        let (range_w, r) = (5.0e-8, 0.17);
        let dark_w = 7.0e-11 / r;
        let floor_w2 = meter_floor_w2(dark_w, range_w, r);
        // 20 fA/sqrt(Hz) over one sample's bandwidth, in W.
        let amp_w2 = (2.0e-14f64.powi(2) * meter_noise::bandwidth_hz()) / (r * r);
        let values = darks(READINGS, dark_w, (floor_w2 + amp_w2).sqrt(), 0.0);
        let m = amplifier_noise(&values, range_w, r).expect("measured");
        assert!(
            (m.a_per_rthz / 2.0e-14 - 1.0).abs() < 3.0 * m.u_a_per_rthz / 2.0e-14 + 0.02,
            "{m:?}"
        );
        assert!(m.u_a_per_rthz / m.a_per_rthz < 0.15, "{m:?}");
        // Room light drifting by ten times the noise over the record changes nothing.
        let drifting = darks(READINGS, dark_w, (floor_w2 + amp_w2).sqrt(), 10.0 * amp_w2.sqrt());
        let d = amplifier_noise(&drifting, range_w, r).expect("measured");
        assert!(
            (d.a_per_rthz / m.a_per_rthz - 1.0).abs() < 0.01,
            "{d:?} against {m:?}"
        );
        // The model's noise alone: no amplifier, within its uncertainty.
        let quiet = darks(READINGS, dark_w, floor_w2.sqrt(), 0.0);
        let q = amplifier_noise(&quiet, range_w, r).expect("measured");
        assert!(q.a_per_rthz <= SIGMAS * q.u_a_per_rthz, "{q:?}");
    }

    #[test]
    fn the_verdict_allows_the_tolerance_or_the_measurements_own_uncertainty() {
        let m = |a: f64, u: f64| Measured {
            a_per_rthz: a,
            u_a_per_rthz: u,
        };
        let c = |claimed: f64, measured: Measured| amplifier_check(claimed, measured, 0.1).verdict;
        assert_eq!(c(2.0e-14, m(2.1e-14, 1e-16)), Pass);
        assert_eq!(c(2.0e-14, m(3.0e-14, 1e-15)), Fail);
        // A file silent on it (0) passes an amplifier too quiet to tell from none.
        assert_eq!(c(0.0, m(2.0e-15, 1e-15)), Pass);
        assert_eq!(c(0.0, m(2.0e-14, 1e-15)), Fail);
    }
}
