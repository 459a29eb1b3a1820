//! The measurement physics: photodiode responsivity, photocurrent of the scene's optical power, noise per
//! sample, the 16-bit converter on the range in use, and overload.

use gonio_instrument::meter_noise;
use rand_distr_lite::standard_normal;

use super::{MeterState, Pm100, SAMPLE_S};
use crate::scene::{Band, Pose};

/// Minimal normal deviates without another dependency.
mod rand_distr_lite {
    use rand::Rng;

    /// A standard normal deviate (Box-Muller).
    pub fn standard_normal(rng: &mut impl Rng) -> f64 {
        let u1: f64 = rng.random::<f64>().max(f64::MIN_POSITIVE);
        let u2: f64 = rng.random::<f64>();
        (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
    }
}

impl Pm100 {
    /// Simulate one averaged reading starting at `t0`: the photocurrent (A), or `None` in overload. `r_set` is
    /// the responsivity at the wavelength the meter is set to (auto-range picks its range with it).
    pub(super) fn reading_a(&self, st: &mut MeterState, t0: f64, n: u32, r_set: f64) -> Option<f64> {
        let d = &self.detector;
        let ranges = &d.ranges_w;
        let world = &self.world;
        let sample_times = |k: u32| t0 + (f64::from(k) + 0.5) * SAMPLE_S;
        // Axes and wheel at rest over the window: one scene evaluation serves every sample. The window is still
        // ahead of the present (the reply is due at its end): its poses are looked ahead, never advanced to, so
        // that each sample sees its own instant and a position report during the window sees its own.
        let (p_first, b_first) = (world.pose_ahead(sample_times(0)), world.band(sample_times(0)));
        let (p_last, b_last) = (
            world.pose_ahead(sample_times(n - 1)),
            world.band(sample_times(n - 1)),
        );
        let steady = p_first == p_last && b_first == b_last;
        let optical_at = |k: u32| -> (f64, Band) {
            let t = sample_times(k);
            let (pose, band): (Pose, Band) = if steady {
                (p_first, b_first)
            } else {
                (world.pose_ahead(t), world.band(t))
            };
            let p = world.scene.detector_power_w(&pose, &band, t);
            (if p.is_finite() { p.max(0.0) } else { 0.0 }, band)
        };
        // Current of each sample: the light's, the dark current, and stray light (the wheel's lit sensors); on an
        // imperfect instrument also the ambient light, through the photodiode's saturation
        // (crate::imperfections::detector).
        let stray_a = world.stray_a(t0);
        let imperfect = self.imperfections.as_ref();
        let ambient_a = imperfect.map_or(0.0, |t| t.ambient_at_a(t0 + 0.5 * f64::from(n) * SAMPLE_S));
        let current = |p: f64, band: &Band| {
            let r_band = band.band_nm.map(|nm| self.responsivity.at(nm)).unwrap_or(0.0);
            p * r_band + d.dark_current_a + stray_a
        };
        // What the photodiode delivers for a current: the same on the ideal instrument.
        let delivered = |i: f64| imperfect.map_or(i, |t| t.photodiode_a(i + ambient_a));
        let amplifier_noise = imperfect.map_or(0.0, |t| t.amplifier_noise_a_per_rthz);
        let noisy = d.noise || amplifier_noise > 0.0;
        // Photocurrents of the samples as the light generates them, before the photodiode delivers them.
        let generated: Vec<f64> = if steady && !noisy {
            // At rest and without noise every sample is the same.
            let (p, band) = optical_at(n / 2);
            vec![current(p, &band); n as usize]
        } else if steady {
            // At rest, only the source changes from sample to sample: the scene computes the geometry once.
            let times: Vec<f64> = (0..n).map(sample_times).collect();
            let mut powers = Vec::with_capacity(times.len());
            world
                .scene
                .detector_power_series_w(&p_first, &b_first, &times, &mut powers);
            powers.iter().map(|p| current(p.max(0.0), &b_first)).collect()
        } else {
            (0..n)
                .map(|k| {
                    let (p, band) = optical_at(k);
                    current(p, &band)
                })
                .collect()
        };
        // The light's own mean current (beam and its stray light), for the attribution; imperfect instrument only.
        let light_a =
            imperfect.map(|_| generated.iter().sum::<f64>() / f64::from(n) - d.dark_current_a - stray_a);
        let currents: Vec<f64> = match imperfect {
            Some(_) => generated.iter().map(|&i| delivered(i)).collect(),
            None => generated,
        };
        let mean_i = currents.iter().sum::<f64>() / f64::from(n);
        // Range in use: auto picks the smallest whose full-scale current holds the signal.
        let full_scale_i = |idx: usize| ranges.get(idx).copied().unwrap_or(0.0) * r_set;
        let range = if st.settings.auto_range {
            ranges
                .iter()
                .position(|r| r * r_set >= mean_i.abs())
                .unwrap_or(ranges.len().saturating_sub(1))
        } else {
            st.settings.range
        };
        let fs = full_scale_i(range);
        let saturate = self.faults.injector().saturate_reading(&self.name);
        if saturate || mean_i > fs {
            tracing::info!(meter = %self.name, current_a = mean_i, full_scale_a = fs, "PM100 overload");
            return None;
        }
        // The meter's own transfer on this range: exact on the ideal instrument, gain, nonlinearity and offset on
        // an imperfect one.
        let transfer = |i: f64| imperfect.map_or(i, |t| t.meter_a(range, i, fs));
        let mut i = transfer(mean_i);
        if let (Some(t), Some(light_a)) = (imperfect, light_a) {
            // What the imperfections did (crate::imperfections::effects).
            let total = light_a + ambient_a + d.dark_current_a + stray_a;
            let effects = crate::imperfections::MeterEffects {
                range_w: ranges.get(range).copied().unwrap_or(0.0),
                light_a,
                ambient_a,
                saturation_rel: if total > 0.0 {
                    t.photodiode_a(total) / total - 1.0
                } else {
                    0.0
                },
                meter_rel: if mean_i != 0.0 { i / mean_i - 1.0 } else { 0.0 },
            };
            *self.last_effects.lock().unwrap_or_else(|e| e.into_inner()) = Some(effects);
        }
        if noisy && fs > 0.0 {
            // Each sample: shot noise of its current, Johnson noise of the range's feedback resistor and the
            // amplifier's excess current noise (imperfect instrument), then the meter's transfer and the 16-bit
            // converter over the range; the reading is the mean of the quantised samples.
            // (gonio_instrument::meter_noise: the figures the self-test subtracts too.)
            let johnson_var = if d.noise { meter_noise::johnson_a2(fs) } else { 0.0 };
            let amplifier_var = amplifier_noise * amplifier_noise * meter_noise::bandwidth_hz();
            let lsb = meter_noise::lsb(fs);
            let mut sum = 0.0;
            for c in &currents {
                let shot_var = if d.noise { meter_noise::shot_a2(*c) } else { 0.0 };
                let sample =
                    c + (shot_var + johnson_var + amplifier_var).sqrt() * standard_normal(&mut st.rng);
                sum += (transfer(sample) / lsb).round() * lsb;
            }
            i = sum / f64::from(n);
        }
        Some(i)
    }
}
