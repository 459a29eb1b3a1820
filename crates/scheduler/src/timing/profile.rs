//! The single-device models: an axis's dynamics and backlash approach (its legs as trapezoids, `trapezoid`), and
//! the filter wheel.

use gonio_instrument::AxisRole;

use super::legs::LegTiming;
use super::trapezoid::{Trapezoid, trapezoid_time_s};
use super::{BACKLASH_OVERSHOOT, EXCHANGE_S, STILL_DEG, WHEEL_EXCHANGES};

/// The dynamics of one axis.
#[derive(Debug, Clone, PartialEq)]
pub struct AxisModel {
    pub name: String,
    pub role: AxisRole,
    pub axis_index: usize,
    pub max_speed_deg_s: f64,
    pub accel_deg_s2: f64,
    pub backlash_deg: f64,
    pub settle_s: f64,
    pub zero_offset_deg: f64,
    pub direction: f64,
    /// What the axis's driver spends around each leg (`super::legs`).
    pub leg: LegTiming,
}

impl AxisModel {
    pub fn controller_deg(&self, physical_deg: f64) -> f64 {
        self.zero_offset_deg + self.direction * physical_deg
    }

    pub fn physical_deg(&self, controller_deg: f64) -> f64 {
        self.direction * (controller_deg - self.zero_offset_deg)
    }

    /// Controller waypoints from `from` to `to` (controller degrees); empty when the axis does not move.
    pub fn waypoints(&self, from_ctrl_deg: f64, to_ctrl_deg: f64) -> Vec<f64> {
        if (to_ctrl_deg - from_ctrl_deg).abs() <= STILL_DEG {
            return Vec::new();
        }
        if self.backlash_deg > 0.0 && to_ctrl_deg < from_ctrl_deg {
            vec![to_ctrl_deg - BACKLASH_OVERSHOOT * self.backlash_deg, to_ctrl_deg]
        } else {
            vec![to_ctrl_deg]
        }
    }

    /// Physical-angle segments for a move starting at `t0_s`.
    pub(super) fn segments(&self, from_ctrl_deg: f64, waypoints: &[f64], t0_s: f64) -> Vec<Trapezoid> {
        let mut out = Vec::with_capacity(waypoints.len());
        let (mut t, mut at) = (t0_s, from_ctrl_deg);
        for w in waypoints {
            let seg = Trapezoid {
                t0_s: t,
                from_deg: self.physical_deg(at),
                to_deg: self.physical_deg(*w),
                v: self.max_speed_deg_s,
                a: self.accel_deg_s2,
            };
            t += seg.duration_s();
            at = *w;
            out.push(seg);
        }
        out
    }

    /// Time the daemon takes to drive the axis through the waypoints, from its first exchange until it has seen
    /// the last arrival: each leg's motion and the driver's exchanges around it ([`LegTiming::leg_s`]).
    pub fn driven_time_s(&self, from_ctrl_deg: f64, waypoints: &[f64]) -> f64 {
        let mut at = from_ctrl_deg;
        let mut t = 0.0;
        for w in waypoints {
            t += self
                .leg
                .leg_s(trapezoid_time_s(w - at, self.max_speed_deg_s, self.accel_deg_s2));
            at = *w;
        }
        t
    }
}

/// The filter wheel.
#[derive(Debug, Clone, PartialEq)]
pub struct WheelModel {
    pub seconds_per_position: f64,
    /// 6 or 12.
    pub slots: u8,
    /// (band nm, position) for every filter.
    pub bands: Vec<(f64, u8)>,
    pub blank: Option<u8>,
}

impl WheelModel {
    /// Steps the shortest way round.
    pub fn steps(&self, from: u8, to: u8) -> u32 {
        let d = u32::from(from.abs_diff(to)) % u32::from(self.slots);
        d.min(u32::from(self.slots) - d)
    }

    pub fn time_s(&self, from: u8, to: u8) -> f64 {
        match self.steps(from, to) {
            0 => 0.0,
            n => f64::from(n) * self.seconds_per_position + WHEEL_EXCHANGES * EXCHANGE_S,
        }
    }

    pub fn position_of(&self, band_nm: f64) -> Option<u8> {
        self.bands
            .iter()
            .find(|(b, _)| (b - band_nm).abs() <= 1e-6)
            .map(|(_, p)| *p)
    }
}
