//! The hardware's real timing: each axis's top speed, acceleration, settle time and backlash and the wheel's time
//! per position, drawn about what the instrument file claims.
//!
//! # Model (magnitudes from `[simulator.imperfections.timing]`)
//! Each axis's real top speed is `max_speed_deg_s (1 + speed_sd z)`, its acceleration `accel_deg_s2 (1 +
//! accel_sd z')`, its settle time `settle_s (1 + settle_sd z'')` and its backlash `backlash_deg (1 + backlash_sd
//! z''')`, the wheel's time per position `seconds_per_position (1 + wheel_sd z'''')`, each `z ~ N(0, 1)` drawn
//! from the seed, clamped to within three standard deviations. The meter's noise figures are drawn the same way
//! on their own stream (the timing draws stay as they were): the detector's real dark current
//! `dark_current_a (1 + dark_current_sd z)` and the source's real white relative noise `relative_noise (1 +
//! relative_noise_sd z')`. (The settle time is what the load's ringing
//! takes to die down within the axis's tolerance: crate::motion::settling.) A real speed above the claimed one is never
//! seen (the drivers command the claimed value); one below it is: the mechanics do not follow. The real
//! instrument these make ([`TimingTruth::apply`]) is what the simulated devices are built from; stated values
//! in `[simulator.actual]` then win over the draws.

use gonio_instrument::{Instrument, TimingImperfections};
use serde::Serialize;

use super::draw::Draws;

/// One axis's real timing factors (real / claimed).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct AxisTiming {
    pub name: String,
    pub speed_factor: f64,
    pub accel_factor: f64,
    pub settle_factor: f64,
    pub backlash_factor: f64,
}

/// The hidden timing of the hardware (module doc).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct TimingTruth {
    pub axes: Vec<AxisTiming>,
    /// The wheel's real time per position over the claimed one.
    pub wheel_factor: f64,
    /// The detector's real dark current over the claimed one.
    pub dark_current_factor: f64,
    /// The source's real white relative noise over the claimed one.
    pub relative_noise_factor: f64,
}

/// `1 + sd z`, z clamped to three standard deviations.
fn factor(sd: f64, z: f64) -> f64 {
    1.0 + sd * z.clamp(-3.0, 3.0)
}

impl TimingTruth {
    pub fn draw(settings: &TimingImperfections, instrument: &Instrument, seed: u64) -> TimingTruth {
        let draws = Draws::new(seed);
        let axes = instrument
            .axes
            .iter()
            .enumerate()
            .map(|(i, a)| {
                let (zs, za) = draws.normal_pair("timing-axis", i as u64);
                // Their own stream: the speed and acceleration drawn before settle and backlash were stay.
                let (zt, zb) = draws.normal_pair("timing-axis-settle", i as u64);
                AxisTiming {
                    name: a.name.clone(),
                    speed_factor: factor(settings.speed_sd, zs),
                    accel_factor: factor(settings.accel_sd, za),
                    settle_factor: factor(settings.settle_sd, zt),
                    backlash_factor: factor(settings.backlash_sd, zb),
                }
            })
            .collect();
        let (zw, _) = draws.normal_pair("timing-wheel", 0);
        // Their own stream, like settle and backlash: the timing drawn before the noise figures were stays.
        let (zd, zn) = draws.normal_pair("timing-noise", 0);
        TimingTruth {
            axes,
            wheel_factor: factor(settings.wheel_sd, zw),
            dark_current_factor: factor(settings.dark_current_sd, zd),
            relative_noise_factor: factor(settings.relative_noise_sd, zn),
        }
    }

    pub fn is_ideal(&self) -> bool {
        self.wheel_factor == 1.0
            && self.dark_current_factor == 1.0
            && self.relative_noise_factor == 1.0
            && self.axes.iter().all(|a| {
                a.speed_factor == 1.0
                    && a.accel_factor == 1.0
                    && a.settle_factor == 1.0
                    && a.backlash_factor == 1.0
            })
    }

    /// The real hardware: `inst` with the drawn factors applied.
    pub fn apply(&self, inst: &mut Instrument) {
        for a in &mut inst.axes {
            if let Some(t) = self.axes.iter().find(|t| t.name == a.name) {
                a.max_speed_deg_s *= t.speed_factor;
                a.accel_deg_s2 *= t.accel_factor;
                a.settle_s *= t.settle_factor;
                a.backlash_deg *= t.backlash_factor;
            }
        }
        if let Some(w) = inst.filter_wheel.as_mut() {
            w.seconds_per_position *= self.wheel_factor;
        }
        inst.detector.dark_current_a *= self.dark_current_factor;
        inst.source.relative_noise *= self.relative_noise_factor;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use gonio_instrument::InstrumentFile;

    #[test]
    fn the_factors_follow_their_magnitudes_and_the_seed() {
        let file = InstrumentFile::simulated();
        let settings = TimingImperfections {
            speed_sd: 0.02,
            accel_sd: 0.03,
            wheel_sd: 0.05,
            settle_sd: 0.04,
            backlash_sd: 0.05,
            dark_current_sd: 0.04,
            relative_noise_sd: 0.04,
        };
        let a = TimingTruth::draw(&settings, &file.instrument, 7);
        assert_eq!(
            a,
            TimingTruth::draw(&settings, &file.instrument, 7),
            "the same seed, the same hardware"
        );
        assert_ne!(a, TimingTruth::draw(&settings, &file.instrument, 8));
        assert_eq!(a.axes.len(), file.instrument.axes.len());
        for t in &a.axes {
            assert!(
                (t.speed_factor - 1.0).abs() <= 0.06 + 1e-12 && (t.accel_factor - 1.0).abs() <= 0.09 + 1e-12
            );
            assert!(
                (t.settle_factor - 1.0).abs() <= 0.12 + 1e-12
                    && (t.backlash_factor - 1.0).abs() <= 0.15 + 1e-12
            );
        }
        assert!(
            a.axes
                .iter()
                .any(|t| t.settle_factor != 1.0 && t.backlash_factor != 1.0),
            "settle and backlash drawn"
        );
        let off = TimingTruth::draw(&TimingImperfections::default(), &file.instrument, 7);
        assert!(off.is_ideal());
        // Over many seeds the spread is the magnitude's.
        let z: Vec<f64> = (0..4000)
            .map(|s| TimingTruth::draw(&settings, &file.instrument, s).wheel_factor - 1.0)
            .collect();
        let sd = (z.iter().map(|v| v * v).sum::<f64>() / z.len() as f64).sqrt();
        assert!((sd / 0.05 - 1.0).abs() < 0.05, "wheel spread {sd}");
        let mut inst = file.instrument.clone();
        a.apply(&mut inst);
        let w = inst
            .filter_wheel
            .as_ref()
            .map(|w| w.seconds_per_position)
            .unwrap_or_default();
        let claimed = file
            .instrument
            .filter_wheel
            .as_ref()
            .map(|w| w.seconds_per_position)
            .unwrap_or_default();
        assert!((w - claimed * a.wheel_factor).abs() < 1e-12);
        let (real, claim) = (&inst.axes[0], &file.instrument.axes[0]);
        assert!((real.settle_s - claim.settle_s * a.axes[0].settle_factor).abs() < 1e-15);
        assert!((real.backlash_deg - claim.backlash_deg * a.axes[0].backlash_factor).abs() < 1e-15);
        assert!(a.dark_current_factor != 1.0 && a.relative_noise_factor != 1.0);
        assert!(
            (inst.detector.dark_current_a - file.instrument.detector.dark_current_a * a.dark_current_factor)
                .abs()
                < 1e-25
        );
        assert!(
            (inst.source.relative_noise - file.instrument.source.relative_noise * a.relative_noise_factor)
                .abs()
                < 1e-18
        );
    }
}
