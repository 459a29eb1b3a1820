//! The load's vibration after a move: what an axis's `settle_s` waits for.
//!
//! # Model
//! When a move ends, the load (the arm or stage the optics see) rings about where the drive left it, as a damped
//! oscillation `r(u) = A exp(-u / tau) cos(omega u)`, `u` the time since the motor stopped:
//! - `A` starts in the direction of the move (the load overshoots as the drive stops) at [`RING_START`] times the
//!   axis's arrival tolerance for a move of [`FULL_MOVE_DEG`] or more, proportionally less for a shorter one (a
//!   short move stops from a lower speed);
//! - `tau = settle_s / ln(RING_START)`, so that after a full-size move the envelope is down to the tolerance
//!   exactly at the axis's real `settle_s`;
//! - `omega` is the resonance nearest [`RESONANCE_HZ`] that fits a whole number of periods into `settle_s`, so
//!   that the last peak as large as the tolerance falls exactly at `settle_s`: from then on the load stays within
//!   its tolerance, which is what the settle time means, so the simulator's truth is exact by construction;
//! - once the envelope is below [`CUTOFF`] of the tolerance the vibration is taken as gone (the pose is exact
//!   again, which lets the meter evaluate a reading at rest once).
//!
//! No encoder sees the vibration (it is the arm's flex beyond the drive), so the controller reports the move done
//! at the stop; only the optics see it ([`crate::world::World::pose`]). A new move replaces the vibration left by
//! the last one; a halt (power removed) leaves none. The motion record (crate::recording) and its exact
//! arm-separation check follow the load without it: at most ten tolerances (0.05 deg on realistic.toml), far
//! inside any separation margin.
//!
//! Assumptions, not measurements: one resonance near 20 Hz (light arms of a bench goniometer, about the first
//! bending mode of a 300 mm aluminium arm with a detector head on it), an overshoot of ten times the arrival
//! tolerance after a full-size move, and exponential damping.

/// The vibration's amplitude after a full-size move, over the axis's tolerance.
pub const RING_START: f64 = 10.0;
/// A move at least this long (deg) rings at the full amplitude.
pub const FULL_MOVE_DEG: f64 = 1.0;
/// The resonance the vibration is nearest to (Hz).
pub const RESONANCE_HZ: f64 = 20.0;
/// Below this fraction of the tolerance the vibration is taken as gone.
pub const CUTOFF: f64 = 0.05;

/// How an axis settles: its real settle time and its arrival tolerance (controller degrees).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Settling {
    settle_s: f64,
    tolerance_deg: f64,
}

impl Settling {
    /// None (no vibration) unless both are finite and > 0.
    pub fn new(settle_s: f64, tolerance_deg: f64) -> Option<Settling> {
        (settle_s.is_finite() && settle_s > 0.0 && tolerance_deg.is_finite() && tolerance_deg > 0.0)
            .then_some(Settling {
                settle_s,
                tolerance_deg,
            })
    }

    /// The vibration after a move of `moved_deg` (signed) that ended at `t_end_s`; None for no move.
    pub fn ring(&self, t_end_s: f64, moved_deg: f64) -> Option<Ring> {
        if !(moved_deg.is_finite() && moved_deg != 0.0) {
            return None;
        }
        let size = (moved_deg.abs() / FULL_MOVE_DEG).min(1.0);
        let periods = (RESONANCE_HZ * self.settle_s).round().max(1.0);
        Some(Ring {
            t0_s: t_end_s,
            amplitude_deg: moved_deg.signum() * RING_START * self.tolerance_deg * size,
            tau_s: self.settle_s / RING_START.ln(),
            omega_rad_s: std::f64::consts::TAU * periods / self.settle_s,
            cutoff_deg: CUTOFF * self.tolerance_deg,
        })
    }
}

/// One move's vibration (module doc).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Ring {
    t0_s: f64,
    amplitude_deg: f64,
    tau_s: f64,
    omega_rad_s: f64,
    cutoff_deg: f64,
}

impl Ring {
    /// The load's displacement (deg) at `t_s`: 0 before the stop and once the vibration has died down.
    pub fn at(&self, t_s: f64) -> f64 {
        let u = t_s - self.t0_s;
        // Before the stop (or a time that is not a number): no vibration.
        if u.is_nan() || u < 0.0 {
            return 0.0;
        }
        let envelope = self.amplitude_deg * (-u / self.tau_s).exp();
        if envelope.abs() < self.cutoff_deg {
            return 0.0;
        }
        envelope * (self.omega_rad_s * u).cos()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_full_move_stays_within_the_tolerance_from_the_settle_time_on() {
        for settle_s in [0.05, 0.052, 0.2, 0.013] {
            let s = Settling::new(settle_s, 0.005).expect("settles");
            let r = s.ring(1.0, -3.0).expect("rings");
            assert!(
                (r.at(1.0) + 0.05).abs() < 1e-12,
                "overshoots in the move's direction"
            );
            assert!(
                (r.at(1.0 + settle_s).abs() - 0.005).abs() < 1e-12,
                "at the tolerance at settle_s"
            );
            let late = (1..2000).map(|k| r.at(1.0 + settle_s + k as f64 * 1e-4).abs());
            assert!(late.fold(0.0, f64::max) < 0.005, "within it after");
            let early = (0..200).map(|k| r.at(1.0 + settle_s * (0.5 + k as f64 / 400.0)).abs());
            assert!(early.fold(0.0, f64::max) > 0.005, "not within it before");
            assert_eq!(r.at(0.99), 0.0);
            assert_eq!(r.at(1.0 + 10.0 * settle_s), 0.0, "gone once below the cutoff");
        }
        let short = Settling::new(0.05, 0.005)
            .and_then(|s| s.ring(0.0, 0.1))
            .expect("rings");
        assert!((short.at(0.0) - 0.005).abs() < 1e-12, "a short move rings less");
        assert_eq!(Settling::new(0.0, 0.005), None);
        assert_eq!(Settling::new(0.05, 0.005).and_then(|s| s.ring(0.0, 0.0)), None);
    }
}
