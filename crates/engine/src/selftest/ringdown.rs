//! An axis's settle time from the meter's readings on an edge after a move (pure).
//!
//! The readings are turned into the load's displacement from where it comes to rest (the reading's difference
//! from the final level over the edge's slope, deg) at each reading's time since the motor stopped. The settle
//! time is when the displacement stays within the axis's tolerance:
//! - a load that rings (a damped oscillation: the usual case for an arm or a stage) is seen as lobes, runs of
//!   readings of one sign beyond the noise; each lobe's peak (a parabola through the largest reading and its
//!   neighbours) lies on the envelope `E exp(-t / tau)` times `cos(atan(1 / (omega tau)))`, the peaks of a
//!   damped cosine falling short of its envelope by that factor. A line through the peaks' logarithms gives
//!   `tau`, their spacing half the period; the settle time is where the envelope comes down to the tolerance.
//!   Only the leading run of lobes above a quarter of the tolerance (and clear of the noise) is fitted: past it
//!   the noise, or a meter's flicker between two steps, makes lobes of its own.
//!   The envelope, not the last reading beyond the tolerance: readings a few milliseconds apart miss the peaks,
//!   and the last peak beyond the tolerance may fall between two readings;
//! - a load that creeps in without ringing (fewer than two whole lobes) settles where the last reading beyond
//!   the tolerance crosses it (linear interpolation to the next);
//! - a load already within the tolerance at the first reading settled before it: the first reading's time is
//!   given (an upper bound: the readings cannot say more).

use super::fit::line;

/// One reading: seconds since the motor stopped, and the load's displacement from rest (deg).
pub type Displacement = (f64, f64);

/// A run of readings of one sign beyond the noise, and its refined peak.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Lobe {
    t_s: f64,
    peak_deg: f64,
    /// Starts at the first reading or ends at the last: its peak may lie outside the readings.
    cut: bool,
}

/// The lobes of `d` beyond `threshold_deg` (module doc).
fn lobes(d: &[Displacement], threshold_deg: f64) -> Vec<Lobe> {
    let mut out = Vec::new();
    let mut i = 0;
    while i < d.len() {
        if d[i].1.abs() < threshold_deg {
            i += 1;
            continue;
        }
        let sign = d[i].1.signum();
        let start = i;
        while i < d.len() && d[i].1.abs() >= threshold_deg && d[i].1.signum() == sign {
            i += 1;
        }
        let end = i; // exclusive
        let Some(k) = (start..end).max_by(|&a, &b| d[a].1.abs().total_cmp(&d[b].1.abs())) else {
            continue;
        };
        let (mut t, mut peak) = (d[k].0, d[k].1.abs());
        // A parabola through the peak reading and its neighbours (readings about evenly spaced).
        if k > 0 && k + 1 < d.len() {
            let (y0, y1, y2) = (d[k - 1].1 * sign, d[k].1 * sign, d[k + 1].1 * sign);
            let h = 0.5 * (d[k + 1].0 - d[k - 1].0);
            let curvature = y0 - 2.0 * y1 + y2;
            if curvature < 0.0 && h > 0.0 {
                let offset = (0.5 * (y0 - y2) / curvature).clamp(-1.0, 1.0);
                peak = y1 - 0.25 * (y0 - y2) * offset;
                t += offset * h;
            }
        }
        out.push(Lobe {
            t_s: t,
            peak_deg: peak,
            cut: start == 0 || end == d.len(),
        });
    }
    out
}

/// The settle time (s) from displacements `d` in time order (module doc): when the load stays within
/// `tolerance_deg`, lobes counted beyond three times `noise_deg` (one reading's scatter at rest). None without
/// readings.
pub fn settle_time_s(d: &[Displacement], tolerance_deg: f64, noise_deg: f64) -> Option<f64> {
    let first = d.first()?.0;
    let Some(last_out) = d.iter().rposition(|(_, x)| x.abs() > tolerance_deg) else {
        return Some(first.max(0.0));
    };
    let threshold = (3.0 * noise_deg).max(1e-12);
    // The ringing's lobes: the leading run of whole lobes above a quarter of the tolerance and twice the
    // noise's threshold. Past them the noise makes lobes of its own, random in height and spacing; fitted with
    // the ringing they bent the envelope until it crossed the tolerance before the motor stopped (a step of
    // the tilt on a realistic instrument gave -0.22 s, another 0.02 s for 0.048 s). (A decade above the
    // threshold left a slowly ringing arm read through a noisy edge only its first, clipped lobes: 0.84 s for
    // 0.2 s.)
    let floor = (2.0 * threshold).max(0.25 * tolerance_deg);
    let whole: Vec<Lobe> = lobes(d, threshold)
        .into_iter()
        .filter(|l| !l.cut)
        .take_while(|l| l.peak_deg > floor)
        .collect();
    if whole.len() >= 2 && whole.iter().any(|l| l.peak_deg > tolerance_deg) {
        let logs: Vec<(f64, f64)> = whole.iter().map(|l| (l.t_s, l.peak_deg.ln())).collect();
        let spacing: Vec<(f64, f64)> = whole.iter().enumerate().map(|(k, l)| (k as f64, l.t_s)).collect();
        if let (Some((slope, intercept)), Some((half_period_s, _))) = (line(&logs), line(&spacing)) {
            if slope < 0.0 && half_period_s > 0.0 {
                return Some(envelope_crossing(slope, intercept, half_period_s, tolerance_deg));
            }
        } else if let [a, b] = whole.as_slice() {
            // Two lobes: the line through both (`line` wants three points).
            let slope = (b.peak_deg.ln() - a.peak_deg.ln()) / (b.t_s - a.t_s);
            let intercept = a.peak_deg.ln() - slope * a.t_s;
            if slope < 0.0 && b.t_s > a.t_s {
                return Some(envelope_crossing(slope, intercept, b.t_s - a.t_s, tolerance_deg));
            }
        }
    }
    // No ringing to fit: where the last reading beyond the tolerance crosses it.
    let (t0, x0) = d[last_out];
    Some(match d.get(last_out + 1) {
        Some(&(t1, x1)) if x0.abs() > x1.abs() => {
            t0 + (x0.abs() - tolerance_deg) / (x0.abs() - x1.abs()) * (t1 - t0)
        }
        _ => t0,
    })
}

/// Where `exp(intercept + slope t) / cos(atan(1 / (omega tau)))` comes down to `tolerance_deg`, the peaks'
/// line being `intercept + slope t` (ln deg) and the lobes `half_period_s` apart.
fn envelope_crossing(slope: f64, intercept: f64, half_period_s: f64, tolerance_deg: f64) -> f64 {
    let tau_s = -1.0 / slope;
    let omega = std::f64::consts::PI / half_period_s;
    let shortfall = (1.0 / (omega * tau_s)).atan().cos();
    (tolerance_deg.ln() + shortfall.ln() - intercept) / slope
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Readings every `dt` from `t0` of a damped cosine whose envelope is `tol` at `settle`, `periods` in it.
    fn ringing(
        settle: f64,
        tol: f64,
        periods: f64,
        t0: f64,
        dt: f64,
        noise: &mut impl FnMut() -> f64,
    ) -> Vec<Displacement> {
        let tau = settle / 10f64.ln();
        let omega = std::f64::consts::TAU * periods / settle;
        (0..)
            .map(|k| t0 + k as f64 * dt)
            .take_while(|t| *t < 8.0 * settle)
            .map(|t| (t, 10.0 * tol * (-t / tau).exp() * (omega * t).cos() + noise()))
            .collect()
    }

    #[test]
    fn a_ringing_load_settles_where_its_envelope_reaches_the_tolerance() {
        let mut seed = 12345u64;
        let mut noise = move || {
            // xorshift, uniform in +-1e-4 deg
            seed ^= seed << 13;
            seed ^= seed >> 7;
            seed ^= seed << 17;
            (seed as f64 / u64::MAX as f64 - 0.5) * 2e-4
        };
        for (settle, periods, dt) in [(0.05, 1.0, 0.004), (0.2, 4.0, 0.004), (0.0515, 1.0, 0.0035)] {
            let d = ringing(settle, 0.005, periods, 0.003, dt, &mut noise);
            let got = settle_time_s(&d, 0.005, 6e-5).expect("readings");
            assert!((got / settle - 1.0).abs() < 0.03, "{got} for {settle}");
        }
    }

    #[test]
    fn the_noise_after_the_ringing_does_not_bend_the_envelope() {
        // A ringing load read through a meter whose steps are 4.9e-5 deg of displacement, its rest a third of a
        // step off one: once the ringing is down, the readings alternate between two levels, 4.5e-5 and
        // -0.4e-5 deg, and with the scatter at rest estimated at 1.3e-5 deg every upper level is a lobe of its own.
        let step = 4.9e-5;
        let d: Vec<Displacement> = ringing(0.048, 0.005, 1.0, 0.0035, 0.004, &mut || 0.0)
            .into_iter()
            .enumerate()
            .map(|(k, (t, x))| {
                let flicker = if k % 3 == 0 { 0.5 * step } else { 0.0 };
                (t, ((x + flicker) / step).round() * step - 0.4e-5)
            })
            .collect();
        let got = settle_time_s(&d, 0.005, 1.3e-5).expect("readings");
        assert!((got / 0.048 - 1.0).abs() < 0.05, "{got} for 0.048");
    }

    #[test]
    fn a_creeping_or_settled_load() {
        // Exponential creep from 0.02 deg: within 0.005 after ln(4) tau.
        let tau = 0.02;
        let d: Vec<Displacement> = (0..200)
            .map(|k| {
                let t = 0.002 * f64::from(k);
                (t, 0.02 * (-t / tau).exp())
            })
            .collect();
        let got = settle_time_s(&d, 0.005, 1e-5).expect("readings");
        assert!((got - tau * 4f64.ln()).abs() < 0.002, "{got}");
        let still: Vec<Displacement> = (0..50).map(|k| (0.004 + 0.004 * f64::from(k), 1e-5)).collect();
        assert_eq!(settle_time_s(&still, 0.005, 1e-5), Some(0.004));
        assert_eq!(settle_time_s(&[], 0.005, 1e-5), None);
    }
}
