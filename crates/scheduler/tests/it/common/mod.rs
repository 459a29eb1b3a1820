//! Shared test helpers: random instruments, an independent trajectory simulator, brute-force checks.
#![allow(dead_code)]

use gonio_instrument::{AxisRole, GeometryKind, Instrument, InstrumentFile};
use gonio_scheduler::kinematics::Pose;
use gonio_scheduler::timing::{BACKLASH_OVERSHOOT, Move, TimeModel};
use proptest::prelude::*;

pub fn simulated() -> Instrument {
    InstrumentFile::simulated().instrument
}

/// Parameters of a random instrument derived from the simulated one.
#[derive(Debug, Clone)]
pub struct RandomInstrument {
    pub offsets: [f64; 4],
    pub directions: [i8; 4],
    pub arm_limits: (f64, f64),
    pub detector_limits: (f64, f64),
    pub tilt_limits: (f64, f64),
    pub rotation_limits: (f64, f64),
    pub speeds: [f64; 4],
    pub accels: [f64; 4],
    pub backlash: [f64; 4],
    pub settle: [f64; 4],
    pub min_sep: f64,
    pub retro: f64,
    pub grazing: f64,
    pub in_plane: bool,
}

pub fn random_instrument() -> impl Strategy<Value = RandomInstrument> {
    let four = |lo: f64, hi: f64| prop::array::uniform4(lo..hi);
    (
        (
            four(-60.0, 60.0),
            prop::array::uniform4(prop_oneof![Just(1i8), Just(-1i8)]),
        ),
        (
            (-180.0..-60.0f64, 60.0..180.0f64),
            (-180.0..-60.0f64, 60.0..180.0f64),
        ),
        (
            (-90.0..-20.0f64, 20.0..90.0f64),
            prop_oneof![
                Just((-180.0, 180.0)),
                Just((-400.0, 400.0)),
                Just((-170.0, 170.0))
            ],
        ),
        (four(4.0, 40.0), four(10.0, 200.0)),
        (
            prop::array::uniform4(prop_oneof![Just(0.0), 0.005..0.1f64]),
            four(0.0, 0.2),
        ),
        (
            4.0..15.0f64,
            1.0..8.0f64,
            70.0..89.0f64,
            prop::bool::weighted(0.25),
        ),
    )
        .prop_map(
            |(
                (offsets, directions),
                (al, dl),
                (tl, rl),
                (speeds, accels),
                (backlash, settle),
                (min_sep, retro, grazing, in_plane),
            )| {
                RandomInstrument {
                    offsets,
                    directions,
                    arm_limits: al,
                    detector_limits: dl,
                    tilt_limits: tl,
                    rotation_limits: rl,
                    speeds,
                    accels,
                    backlash,
                    settle,
                    min_sep,
                    retro,
                    grazing,
                    in_plane,
                }
            },
        )
}

impl RandomInstrument {
    pub fn build(&self) -> Instrument {
        let mut inst = simulated();
        if self.in_plane {
            inst.geometry = GeometryKind::InPlane;
            inst.axes.retain(|a| a.role != AxisRole::SampleTilt);
        }
        for a in inst.axes.iter_mut() {
            let k = match a.role {
                AxisRole::LightArm => 0,
                AxisRole::DetectorArm => 1,
                AxisRole::SampleTilt => 2,
                AxisRole::SampleRotation => 3,
            };
            a.zero_offset_deg = self.offsets[k];
            a.direction = self.directions[k];
            let (lo, hi) = [
                self.arm_limits,
                self.detector_limits,
                self.tilt_limits,
                self.rotation_limits,
            ][k];
            a.min_deg = lo;
            a.max_deg = hi;
            a.max_speed_deg_s = self.speeds[k];
            a.accel_deg_s2 = self.accels[k];
            a.backlash_deg = self.backlash[k];
            a.settle_s = self.settle[k];
        }
        inst.safety.min_arm_separation_deg = self.min_sep;
        inst.safety.retro_block_deg = self.retro;
        inst.safety.grazing_limit_deg = self.grazing;
        inst.validate().expect("random instrument is valid");
        inst
    }
}

/// Position along a trapezoidal profile, written independently of the crate: integrate the velocity law
/// (accelerate at a up to v, cruise, decelerate) numerically with a fine step.
fn profile_position(from: f64, to: f64, v: f64, a: f64, t: f64) -> f64 {
    let d = (to - from).abs();
    if d == 0.0 {
        return from;
    }
    // Peak speed: v if the cruise is reachable, else sqrt(a d).
    let peak = v.min((a * d).sqrt());
    let t_ramp = peak / a;
    let d_ramp = 0.5 * a * t_ramp * t_ramp;
    let t_cruise = (d - 2.0 * d_ramp).max(0.0) / peak;
    let total = 2.0 * t_ramp + t_cruise;
    let t = t.clamp(0.0, total);
    let s = if t < t_ramp {
        0.5 * a * t * t
    } else if t < t_ramp + t_cruise {
        d_ramp + peak * (t - t_ramp)
    } else {
        let r = total - t;
        d - 0.5 * a * r * r
    };
    from + (to - from).signum() * s
}

fn profile_duration(from: f64, to: f64, v: f64, a: f64) -> f64 {
    let d = (to - from).abs();
    let peak = v.min((a * d).sqrt());
    if peak == 0.0 {
        return 0.0;
    }
    let t_ramp = peak / a;
    2.0 * t_ramp + (d - peak * t_ramp).max(0.0) / peak
}

/// (arm index, controller segments, speed, acceleration, zero offset, direction).
type ArmPath = (usize, Vec<(f64, f64)>, f64, f64, f64, f64);

/// Physical arm angles over time during a move, sampled every `dt` seconds; returns the smallest separation
/// (circular) seen. Rebuilt from the move's waypoints with the instrument's axis data only.
pub fn min_separation_during(inst: &Instrument, from: &Pose, m: &Move, dt: f64) -> f64 {
    let arms = [AxisRole::LightArm, AxisRole::DetectorArm];
    let mut pos = [from.light_deg, from.detector_deg];
    let mut worst = circ(pos[0] - pos[1]);
    for phase in &m.phases {
        // Each arm's path in this phase: list of (from_ctrl, to_ctrl) segments.
        let mut paths: Vec<Option<ArmPath>> = vec![None, None];
        for am in phase {
            if let Some(k) = arms.iter().position(|r| *r == am.role) {
                let axis = inst.axis(am.role).expect("axis");
                let mut at = axis.controller_from_physical_deg(pos[k]);
                let mut segs = Vec::new();
                for w in &am.waypoints_deg {
                    segs.push((at, *w));
                    at = *w;
                }
                paths[k] = Some((
                    k,
                    segs,
                    axis.max_speed_deg_s,
                    axis.accel_deg_s2,
                    axis.zero_offset_deg,
                    f64::from(axis.direction),
                ));
            }
        }
        let duration = phase.iter().map(|a| a.duration_s).fold(0.0, f64::max);
        let steps = (duration / dt).ceil() as usize + 1;
        let at_time = |k: usize, t: f64, start: f64| -> f64 {
            match &paths[k] {
                None => start,
                Some((_, segs, v, a, off, dir)) => {
                    let mut t = t;
                    let mut ctrl = segs.first().map_or(0.0, |s| s.0);
                    for (f, to) in segs {
                        let dur = profile_duration(*f, *to, *v, *a);
                        if t <= dur {
                            ctrl = profile_position(*f, *to, *v, *a, t);
                            return dir * (ctrl - off);
                        }
                        t -= dur;
                        ctrl = *to;
                    }
                    dir * (ctrl - off)
                }
            }
        };
        for s in 0..=steps {
            let t = (s as f64 * dt).min(duration);
            let l = at_time(0, t, pos[0]);
            let d = at_time(1, t, pos[1]);
            worst = worst.min(circ(l - d));
        }
        pos = [
            at_time(0, duration + 1.0, pos[0]),
            at_time(1, duration + 1.0, pos[1]),
        ];
    }
    worst
}

pub fn circ(x: f64) -> f64 {
    let r = x.rem_euclid(360.0);
    r.min(360.0 - r)
}

pub fn overshoot(inst: &Instrument) -> f64 {
    inst.axes.iter().map(|a| a.backlash_deg).fold(0.0, f64::max) * BACKLASH_OVERSHOOT
}

pub fn time_model(inst: &Instrument) -> TimeModel {
    TimeModel::new(inst)
}
