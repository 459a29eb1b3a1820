//! The pure fits of the self-test: a move's top speed and acceleration from positions sampled while it ran,
//! and a mean with its spread. Each returns None when the samples cannot say (too few, no cruise, no ramp).

/// One sample: instrument time (s) and read-back position (deg), both of the moving axis.
pub type Sample = (f64, f64);

/// Least-squares line through `(x, y)`: (slope, intercept); None with fewer than 3 points or no spread in x.
pub fn line(points: &[(f64, f64)]) -> Option<(f64, f64)> {
    if points.len() < 3 {
        return None;
    }
    let n = points.len() as f64;
    let mx = points.iter().map(|p| p.0).sum::<f64>() / n;
    let my = points.iter().map(|p| p.1).sum::<f64>() / n;
    let sxx: f64 = points.iter().map(|p| (p.0 - mx).powi(2)).sum();
    let sxy: f64 = points.iter().map(|p| (p.0 - mx) * (p.1 - my)).sum();
    if sxx.is_nan() || sxx <= 0.0 {
        return None;
    }
    let slope = sxy / sxx;
    Some((slope, my - slope * mx))
}

/// Mean and sample standard deviation; None for fewer than 2 values.
pub fn mean_std(values: &[f64]) -> Option<(f64, f64)> {
    if values.len() < 2 {
        return None;
    }
    let n = values.len() as f64;
    let mean = values.iter().sum::<f64>() / n;
    let var = values.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (n - 1.0);
    Some((mean, var.sqrt()))
}

/// The top speed (deg/s) of a long move from `start_deg` to `end_deg`: the slope of position against time
/// over its middle (30 % to 70 % of the way), where a trapezoidal move cruises.
pub fn cruise_speed(samples: &[Sample], start_deg: f64, end_deg: f64) -> Option<f64> {
    let span = end_deg - start_deg;
    let middle: Vec<(f64, f64)> = samples
        .iter()
        .filter(|(_, p)| {
            let f = (p - start_deg) / span;
            (0.3..=0.7).contains(&f)
        })
        .copied()
        .collect();
    let (slope, _) = line(&middle)?;
    Some(slope.abs())
}

/// The acceleration (deg/s^2) of the same move from its first ramp: while the speed rises from rest,
/// `|p - p0| = a (t - t0)^2 / 2`, so `sqrt(2 |p - p0|)` is a line in t of slope `sqrt(a)`. The ramp's samples are
/// those moved from the start but short of the distance a ramp to `speed_deg_s` covers at the acceleration
/// estimated so far (two passes: first the samples below a tenth of the cruise's distance).
pub fn ramp_acceleration(samples: &[Sample], start_deg: f64, speed_deg_s: f64) -> Option<f64> {
    let moved = |p: f64| (p - start_deg).abs();
    let fit = |limit_deg: f64| -> Option<f64> {
        let ramp: Vec<(f64, f64)> = samples
            .iter()
            .filter(|(_, p)| moved(*p) > 1e-6 && moved(*p) < limit_deg)
            .map(|(t, p)| (*t, (2.0 * moved(*p)).sqrt()))
            .collect();
        let (slope, _) = line(&ramp)?;
        (slope > 0.0).then_some(slope * slope)
    };
    // First pass: the first samples of the move, inside any ramp that reaches `speed_deg_s` within the move's
    // first fiftieth; a ramp shorter than that makes this estimate low, and each further pass, on 80 % of the
    // ramp the estimate implies, comes closer: once the estimate is within 20 % of the truth, the pass sees ramp
    // samples only and gives the acceleration itself.
    let first_guess = samples.iter().map(|(_, p)| moved(*p)).fold(0.0, f64::max) * 0.02;
    let mut a = fit(first_guess.max(1e-3))?;
    for _ in 0..8 {
        let ramp_deg = speed_deg_s * speed_deg_s / (2.0 * a);
        let Some(next) = fit(0.8 * ramp_deg) else {
            break;
        };
        let settled = (next - a).abs() <= 1e-4 * a;
        a = next;
        if settled {
            break;
        }
    }
    Some(a)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A trapezoidal move sampled every `dt` from `t0`, as a controller's read-back would show it.
    fn trapezoid(d: f64, v: f64, a: f64, t0: f64, dt: f64) -> Vec<Sample> {
        let ramp_t = v / a;
        let ramp_d = v * ramp_t / 2.0;
        let cruise_t = (d - 2.0 * ramp_d) / v;
        let total = 2.0 * ramp_t + cruise_t;
        let pos = |t: f64| {
            let t = (t - t0).clamp(0.0, total);
            if t < ramp_t {
                a * t * t / 2.0
            } else if t < ramp_t + cruise_t {
                ramp_d + v * (t - ramp_t)
            } else {
                let u = total - t;
                d - a * u * u / 2.0
            }
        };
        (0..)
            .map(|i| t0 - 0.05 + i as f64 * dt)
            .take_while(|t| *t < t0 + total + 0.1)
            .map(|t| (t, -40.0 + pos(t)))
            .collect()
    }

    #[test]
    fn a_sampled_trapezoid_gives_back_its_speed_and_acceleration() {
        for (v, a, dt) in [
            (20.0, 80.0, 0.004),
            (10.0, 40.0, 0.007),
            (5.0, 200.0, 0.002),
            (10.0, 80.0, 0.004),
        ] {
            let s = trapezoid(120.0, v, a, 1.3, dt);
            let speed = cruise_speed(&s, -40.0, 80.0).expect("speed");
            assert!((speed - v).abs() < 1e-9 * v, "{speed} for {v}");
            let acc = ramp_acceleration(&s, -40.0, speed).expect("acceleration");
            assert!((acc - a).abs() < 0.03 * a, "{acc} for {a} (dt {dt})");
        }
    }

    #[test]
    fn too_few_samples_say_nothing() {
        assert_eq!(cruise_speed(&[(0.0, 0.0), (1.0, 50.0)], 0.0, 100.0), None);
        assert_eq!(line(&[(1.0, 1.0), (1.0, 2.0), (1.0, 3.0)]), None);
        assert_eq!(mean_std(&[1.0]), None);
        let (m, s) = mean_std(&[1.0, 3.0]).expect("two");
        assert_eq!((m, s), (2.0, 2.0f64.sqrt()));
    }
}
