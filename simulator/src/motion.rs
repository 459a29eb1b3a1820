//! Per-axis motion physics, as a function of simulated time.
//!
//! A move is a list of constant-acceleration segments (accelerate, cruise, decelerate), so the motor position at
//! any instant is exact and cheap. Each axis has its own profile, so axes move simultaneously and independently.
//! Positions here are controller positions in degrees (the device emulators convert to their own units).
//!
//! - Trapezoidal profile: `t = d/v + v/a` if `d >= v^2/a`, else `2 sqrt(d/a)`.
//! - Backlash: the load sits in `[motor, motor + backlash]`: driving up pushes it from below, driving down lets it
//!   lag until the play is taken up. So an approach from below lands exactly, one from above lands `backlash` high.
//!   The encoder reads the load, quantised to the encoder resolution.
//! - Hardware limit switches at the axis limits stop the motor abruptly; a stall (fault injection) stops it short.
//! - A new move during a move first decelerates to rest, then starts the new profile (a conservative controller).
//! - Optionally, every command and profile change is recorded ([`crate::recording`]) for safety audits.
//! - Optionally, the load rings after each move and dies down within the axis's real settle time ([`settling`]);
//!   only the optics see it ([`AxisMotion::optical_deg`]).

mod settling;

use settling::Ring;
pub use settling::Settling;

use crate::move_end::MoveEnd;
use crate::recording::{
    ChangeKind, CommandRecord, MotionCommand, MotionRecord, ProfileChange, ProfileSegment,
};

/// Kinematic parameters of one axis, in controller degrees.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AxisParams {
    /// Hardware limit switches (controller degrees).
    pub hw_min_deg: f64,
    pub hw_max_deg: f64,
    pub backlash_deg: f64,
    pub encoder_resolution_deg: f64,
}

#[derive(Debug, Clone, Copy, PartialEq)]
struct Segment {
    t0_s: f64,
    p0_deg: f64,
    v0_deg_s: f64,
    a_deg_s2: f64,
    dur_s: f64,
}

impl Segment {
    fn end_s(&self) -> f64 {
        self.t0_s + self.dur_s
    }
    fn pos_at(&self, t_s: f64) -> f64 {
        let dt = (t_s - self.t0_s).clamp(0.0, self.dur_s);
        self.p0_deg + self.v0_deg_s * dt + 0.5 * self.a_deg_s2 * dt * dt
    }
    fn vel_at(&self, t_s: f64) -> f64 {
        let dt = (t_s - self.t0_s).clamp(0.0, self.dur_s);
        self.v0_deg_s + self.a_deg_s2 * dt
    }
    fn end_pos(&self) -> f64 {
        self.pos_at(self.end_s())
    }
    /// Earliest time in the segment at which the position equals `p`, if it does.
    fn time_at_position(&self, p: f64) -> Option<f64> {
        let (a, v, c) = (0.5 * self.a_deg_s2, self.v0_deg_s, self.p0_deg - p);
        let dt = if a.abs() < 1e-15 {
            if v.abs() < 1e-15 {
                return None;
            }
            -c / v
        } else {
            let disc = v * v - 4.0 * a * c;
            if disc < 0.0 {
                return None;
            }
            let s = disc.sqrt();
            let r1 = (-v - s) / (2.0 * a);
            let r2 = (-v + s) / (2.0 * a);
            let (lo, hi) = if r1 <= r2 { (r1, r2) } else { (r2, r1) };
            if lo >= -1e-12 { lo } else { hi }
        };
        (dt >= -1e-12 && dt <= self.dur_s + 1e-12).then(|| self.t0_s + dt.clamp(0.0, self.dur_s))
    }
}

/// Duration of a trapezoidal (or triangular) move of `distance` at speed limit `v` and acceleration `a`.
pub fn trapezoid_time_s(distance_deg: f64, v_deg_s: f64, a_deg_s2: f64) -> f64 {
    let d = distance_deg.abs();
    if d == 0.0 || !(v_deg_s > 0.0 && a_deg_s2 > 0.0) {
        return 0.0;
    }
    if d >= v_deg_s * v_deg_s / a_deg_s2 {
        d / v_deg_s + v_deg_s / a_deg_s2
    } else {
        2.0 * (d / a_deg_s2).sqrt()
    }
}

/// Segments of a move from rest at `p0` to rest at `p1` starting at `t0`.
fn trapezoid_segments(t0: f64, p0: f64, p1: f64, v: f64, a: f64) -> Vec<Segment> {
    let d = (p1 - p0).abs();
    let s = if p1 >= p0 { 1.0 } else { -1.0 };
    if d == 0.0 || !(v > 0.0 && a > 0.0) {
        return Vec::new();
    }
    let (t_acc, t_cruise, v_peak) = if d >= v * v / a {
        (v / a, (d - v * v / a) / v, v)
    } else {
        ((d / a).sqrt(), 0.0, (a * d).sqrt())
    };
    let mut segs = Vec::with_capacity(3);
    let acc = Segment {
        t0_s: t0,
        p0_deg: p0,
        v0_deg_s: 0.0,
        a_deg_s2: s * a,
        dur_s: t_acc,
    };
    segs.push(acc);
    let mut last = acc;
    if t_cruise > 0.0 {
        let cruise = Segment {
            t0_s: last.end_s(),
            p0_deg: last.end_pos(),
            v0_deg_s: s * v_peak,
            a_deg_s2: 0.0,
            dur_s: t_cruise,
        };
        segs.push(cruise);
        last = cruise;
    }
    segs.push(Segment {
        t0_s: last.end_s(),
        p0_deg: last.end_pos(),
        v0_deg_s: s * v_peak,
        a_deg_s2: -s * a,
        dur_s: t_acc,
    });
    // Pin the final position exactly to the target (no floating drift).
    if let Some(lastseg) = segs.last_mut() {
        let err = p1 - lastseg.end_pos();
        if err.abs() < 1e-9 {
            lastseg.p0_deg += err;
        }
    }
    segs
}

/// One axis: motor profile, load with backlash, encoder read-back.
#[derive(Debug, Clone)]
pub struct AxisMotion {
    params: AxisParams,
    segments: Vec<Segment>,
    /// Where the motor ends when the current segments run out.
    target_deg: f64,
    /// How the current (or last) move ends.
    end: MoveEnd,
    /// Motor and load at `last_t_s`.
    motor_deg: f64,
    load_deg: f64,
    last_t_s: f64,
    /// What the axis was told and how its profile changed, while recording.
    record: Option<Box<MotionRecord>>,
    /// The fastest the mechanics really move and accelerate (controller deg/s, deg/s^2), whatever the
    /// controller is told (`[simulator.actual]`); infinite unless set.
    max_speed_deg_s: f64,
    max_accel_deg_s2: f64,
    /// How the load settles after a move (None: it stops dead), the vibration the last move left, and where
    /// the motor was when the current move was commanded.
    settling: Option<Settling>,
    ring: Option<Ring>,
    move_from_deg: f64,
}

impl AxisMotion {
    pub fn new(params: AxisParams, position_deg: f64) -> AxisMotion {
        AxisMotion {
            params,
            segments: Vec::new(),
            target_deg: position_deg,
            end: MoveEnd::Arrived,
            motor_deg: position_deg,
            load_deg: position_deg,
            last_t_s: 0.0,
            record: None,
            max_speed_deg_s: f64::INFINITY,
            max_accel_deg_s2: f64::INFINITY,
            settling: None,
            ring: None,
            move_from_deg: position_deg,
        }
    }

    /// The load rings after each move as `settling` says (module doc).
    pub fn with_settling(mut self, settling: Option<Settling>) -> AxisMotion {
        self.settling = settling;
        self
    }

    /// The mechanics' real limits (controller deg/s and deg/s^2, finite and > 0): a commanded speed or
    /// acceleration above them is not reached (`[simulator.actual]`: an axis slower than its file claims).
    pub fn with_mechanical_limits(mut self, max_speed_deg_s: f64, max_accel_deg_s2: f64) -> AxisMotion {
        if max_speed_deg_s.is_finite() && max_speed_deg_s > 0.0 {
            self.max_speed_deg_s = max_speed_deg_s;
        }
        if max_accel_deg_s2.is_finite() && max_accel_deg_s2 > 0.0 {
            self.max_accel_deg_s2 = max_accel_deg_s2;
        }
        self
    }

    /// Start recording commands and profile changes from `t_s` (an earlier record is discarded).
    pub fn start_recording(&mut self, t_s: f64) {
        self.record = Some(Box::default());
        self.note_change(t_s, ChangeKind::Started);
    }

    /// The record so far, if recording.
    pub fn record(&self) -> Option<&MotionRecord> {
        self.record.as_deref()
    }

    /// Stop recording and return the record.
    pub fn take_record(&mut self) -> Option<MotionRecord> {
        self.record.take().map(|r| *r)
    }

    /// Note a command as the device received it (the emulators call this before their own checks).
    pub fn note_command(&mut self, t_s: f64, command: MotionCommand) {
        if let Some(r) = &mut self.record {
            r.push_command(CommandRecord { t_s, command });
        }
    }

    fn note_change(&mut self, t_s: f64, kind: ChangeKind) {
        if self.record.is_none() {
            return;
        }
        self.advance(t_s);
        let change = ProfileChange {
            t_s,
            kind,
            motor_deg: self.motor_deg,
            load_deg: self.load_deg,
            segments: self
                .segments
                .iter()
                .map(|s| ProfileSegment {
                    t0_s: s.t0_s,
                    p0_deg: s.p0_deg,
                    v0_deg_s: s.v0_deg_s,
                    a_deg_s2: s.a_deg_s2,
                    dur_s: s.dur_s,
                })
                .collect(),
            rest_deg: self.target_deg,
            end: self.end,
        };
        if let Some(r) = &mut self.record {
            r.push_change(change);
        }
    }

    pub fn params(&self) -> &AxisParams {
        &self.params
    }

    /// Bring the state up to time `t_s` (earlier times are ignored: time only runs forward).
    pub fn advance(&mut self, t_s: f64) {
        if t_s < self.last_t_s {
            return;
        }
        let b = self.params.backlash_deg;
        // The move ends by `t_s`: from then on its vibration, if the load has one.
        let ended_s = self.segments.last().map(Segment::end_s).filter(|end| *end <= t_s);
        // Each segment is monotone, so the load follows with a clamp at every segment boundary.
        let mut i = 0;
        while i < self.segments.len() {
            let seg = self.segments[i];
            if seg.end_s() <= self.last_t_s {
                i += 1;
                continue;
            }
            if seg.t0_s > t_s {
                break;
            }
            let m = seg.pos_at(t_s.min(seg.end_s()));
            self.load_deg = self.load_deg.clamp(m, m + b);
            self.motor_deg = m;
            i += 1;
        }
        self.segments.retain(|s| s.end_s() > t_s);
        if self.segments.is_empty() {
            self.motor_deg = self.target_deg;
            self.load_deg = self.load_deg.clamp(self.motor_deg, self.motor_deg + b);
        }
        if let (Some(end), Some(s)) = (ended_s, self.settling) {
            self.ring = s.ring(end, self.target_deg - self.move_from_deg);
        }
        self.last_t_s = t_s;
    }

    pub fn is_moving(&mut self, t_s: f64) -> bool {
        self.advance(t_s);
        !self.segments.is_empty()
    }

    /// When the current move ends (None when at rest).
    pub fn end_time_s(&self) -> Option<f64> {
        self.segments.last().map(Segment::end_s)
    }

    /// How the current or last move ends.
    pub fn end_reason(&self) -> MoveEnd {
        self.end
    }

    pub fn motor_deg(&mut self, t_s: f64) -> f64 {
        self.advance(t_s);
        self.motor_deg
    }

    /// Where the load (what the optics see) really is.
    pub fn load_deg(&mut self, t_s: f64) -> f64 {
        self.advance(t_s);
        self.load_deg
    }

    /// Where the optics see the load: [`AxisMotion::load_deg`] with the vibration the last move left.
    pub fn optical_deg(&mut self, t_s: f64) -> f64 {
        let load = self.load_deg(t_s);
        load + self.ring.map_or(0.0, |r| r.at(t_s))
    }

    /// Where the optics will see the load at `t_s`, without advancing the axis's state: what a meter integrating
    /// over a window that is still ahead asks. The state only moves forward ([`AxisMotion::advance`]); advanced
    /// to the window's end, it would answer every earlier question (the window's own samples, a controller's
    /// position report during the window) with the window's end. Before the state's time it answers the state.
    pub fn optical_deg_ahead(&self, t_s: f64) -> f64 {
        if t_s < self.last_t_s {
            return self.load_deg + self.ring.map_or(0.0, |r| r.at(t_s));
        }
        let b = self.params.backlash_deg;
        let mut load = self.load_deg;
        let mut running = false;
        for seg in &self.segments {
            if seg.end_s() <= self.last_t_s {
                continue;
            }
            if seg.t0_s > t_s {
                running = true;
                break;
            }
            let m = seg.pos_at(t_s.min(seg.end_s()));
            load = load.clamp(m, m + b);
            running |= seg.end_s() > t_s;
        }
        if !running {
            load = load.clamp(self.target_deg, self.target_deg + b);
        }
        let ended_s = self.segments.last().map(Segment::end_s).filter(|end| *end <= t_s);
        let ring = match (ended_s, self.settling) {
            (Some(end), Some(s)) => s.ring(end, self.target_deg - self.move_from_deg),
            _ => self.ring,
        };
        load + ring.map_or(0.0, |r| r.at(t_s))
    }

    /// The encoder read-back: the load quantised to the encoder resolution.
    pub fn encoder_deg(&mut self, t_s: f64) -> f64 {
        let load = self.load_deg(t_s);
        let r = self.params.encoder_resolution_deg;
        if r > 0.0 { (load / r).round() * r } else { load }
    }

    /// A motor-side encoder's read-back: the motor quantised to the encoder resolution (the load may differ by
    /// the backlash). What a servo controller holds on its set-point.
    pub fn motor_encoder_deg(&mut self, t_s: f64) -> f64 {
        let motor = self.motor_deg(t_s);
        let r = self.params.encoder_resolution_deg;
        if r > 0.0 { (motor / r).round() * r } else { motor }
    }

    pub fn velocity_deg_s(&mut self, t_s: f64) -> f64 {
        self.advance(t_s);
        self.segments.first().map(|s| s.vel_at(t_s)).unwrap_or(0.0)
    }

    /// Where the motor is heading (the set-point once the move ends).
    pub fn target_deg(&self) -> f64 {
        self.target_deg
    }

    /// Start a move to `target_deg`; returns when it ends (simulated seconds). A move in progress first
    /// decelerates to rest. `stall_fraction` stops the move abruptly after that fraction of the distance;
    /// a target beyond a limit switch stops there.
    pub fn start_move(
        &mut self,
        t_s: f64,
        target_deg: f64,
        v_deg_s: f64,
        a_deg_s2: f64,
        stall_fraction: Option<f64>,
    ) -> f64 {
        self.advance(t_s);
        self.ring = None;
        self.move_from_deg = self.motor_deg;
        let v_deg_s = v_deg_s.min(self.max_speed_deg_s);
        let a_deg_s2 = a_deg_s2.min(self.max_accel_deg_s2);
        let (t_start, p_start) = self.decelerate_segments(t_s, a_deg_s2);
        let mut segs = self.segments.clone();
        segs.extend(trapezoid_segments(
            t_start, p_start, target_deg, v_deg_s, a_deg_s2,
        ));
        self.segments = segs;
        self.target_deg = target_deg;
        self.end = MoveEnd::Arrived;
        if let Some(f) = stall_fraction {
            let stop_at = p_start + f.clamp(0.0, 1.0) * (target_deg - p_start);
            self.truncate_at(stop_at, MoveEnd::Stalled);
        }
        let (lo, hi) = (self.params.hw_min_deg, self.params.hw_max_deg);
        if self.target_deg > hi {
            self.truncate_at(hi, MoveEnd::LimitPositive);
        } else if self.target_deg < lo {
            self.truncate_at(lo, MoveEnd::LimitNegative);
        }
        self.note_change(
            t_s,
            ChangeKind::Move {
                requested_deg: target_deg,
            },
        );
        self.end_time_s().unwrap_or(t_s)
    }

    /// A pause at rest (e.g. the slow final approach of a homing search) appended to the current profile.
    pub fn dwell(&mut self, t_s: f64, dur_s: f64) -> f64 {
        self.advance(t_s);
        let t0 = self.end_time_s().unwrap_or(t_s);
        if dur_s > 0.0 {
            self.segments.push(Segment {
                t0_s: t0,
                p0_deg: self.target_deg,
                v0_deg_s: 0.0,
                a_deg_s2: 0.0,
                dur_s,
            });
        }
        self.note_change(t_s, ChangeKind::Dwell);
        t0 + dur_s.max(0.0)
    }

    /// Replace the profile with a deceleration to rest from the current velocity; returns when it ends.
    pub fn stop(&mut self, t_s: f64, a_deg_s2: f64) -> f64 {
        self.advance(t_s);
        if self.segments.is_empty() {
            return t_s;
        }
        self.decelerate_segments(t_s, a_deg_s2.min(self.max_accel_deg_s2));
        self.end = MoveEnd::Stopped;
        self.target_deg = self
            .segments
            .last()
            .map(Segment::end_pos)
            .unwrap_or(self.motor_deg);
        self.note_change(t_s, ChangeKind::Stop);
        self.end_time_s().unwrap_or(t_s)
    }

    /// Stop dead (emergency stop, power removed).
    pub fn halt(&mut self, t_s: f64) {
        self.advance(t_s);
        if !self.segments.is_empty() {
            self.segments.clear();
            self.end = MoveEnd::Halted;
        }
        self.ring = None;
        self.target_deg = self.motor_deg;
        self.note_change(t_s, ChangeKind::Halt);
    }

    /// Redefine the position counter without moving (homing sets the reference): motor and load shift together.
    pub fn set_position(&mut self, t_s: f64, position_deg: f64) {
        self.advance(t_s);
        let shift = position_deg - self.motor_deg;
        self.segments.clear();
        self.ring = None;
        self.motor_deg = position_deg;
        self.load_deg += shift;
        self.target_deg = position_deg;
        self.note_change(t_s, ChangeKind::SetPosition);
    }

    /// Make the current segments end with a deceleration to rest from the velocity at `t_s`; returns
    /// (when rest is reached, where).
    fn decelerate_segments(&mut self, t_s: f64, a_deg_s2: f64) -> (f64, f64) {
        let Some(seg) = self.segments.first().copied() else {
            return (t_s, self.motor_deg);
        };
        let v = seg.vel_at(t_s);
        let p = seg.pos_at(t_s);
        if v.abs() < 1e-12 || a_deg_s2.is_nan() || a_deg_s2 <= 0.0 {
            self.segments.clear();
            self.target_deg = p;
            return (t_s, p);
        }
        let a = -v.signum() * a_deg_s2;
        let dur = v.abs() / a_deg_s2;
        let dec = Segment {
            t0_s: t_s,
            p0_deg: p,
            v0_deg_s: v,
            a_deg_s2: a,
            dur_s: dur,
        };
        self.segments = vec![dec];
        self.target_deg = dec.end_pos();
        (dec.end_s(), dec.end_pos())
    }

    /// Cut the profile where it first reaches `p` (abrupt stop there), marking why.
    fn truncate_at(&mut self, p: f64, why: MoveEnd) {
        for i in 0..self.segments.len() {
            let seg = self.segments[i];
            if let Some(t) = seg.time_at_position(p) {
                // A zero-length cut (already there) means the move never starts.
                self.segments.truncate(i + 1);
                if let Some(last) = self.segments.last_mut() {
                    last.dur_s = t - last.t0_s;
                }
                self.segments.retain(|s| s.dur_s > 0.0);
                self.target_deg = p;
                self.end = why;
                return;
            }
        }
    }
}

#[cfg(test)]
mod tests;
