//! What every axis was told over its wire protocol and how it really moved: a record for tests and audits of
//! the safety invariants (arm separation at every instant, axis limits, emergency-stop latency).
//!
//! Recording is off until [`crate::SimInstrument::start_motion_recording`]. Two logs per axis:
//! - commands as the device emulators received them ([`MotionCommand`]: a move with its requested target, even
//!   one the controller refused; a home; a stop), in controller degrees;
//! - every change of the motor's profile ([`ProfileChange`]): the constant-acceleration segments the motor follows
//!   from that instant on. Between changes the motor position is exact, so [`MotionRecord::motor_pieces`] and
//!   [`MotionRecord::load_pieces`] give the whole trajectory as quadratic pieces; no sampling is involved.
//!
//! The load (what the optics see) follows the motor with backlash as `crate::motion` models it: on a rising
//! stretch it is `max(load, motor)`, on a falling one `min(load, motor + backlash)`.

use gonio_instrument::Axis;

use crate::move_end::MoveEnd;

/// Records kept per axis at most; further entries are dropped and the record says it is truncated.
pub const MAX_RECORDS_PER_AXIS: usize = 1_000_000;

/// One stretch of constant acceleration of the motor (controller degrees).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ProfileSegment {
    pub t0_s: f64,
    pub p0_deg: f64,
    pub v0_deg_s: f64,
    pub a_deg_s2: f64,
    pub dur_s: f64,
}

impl ProfileSegment {
    pub fn end_s(&self) -> f64 {
        self.t0_s + self.dur_s
    }

    /// Position at `t_s`, clamped to the segment's time span.
    pub fn position_at(&self, t_s: f64) -> f64 {
        let dt = (t_s - self.t0_s).clamp(0.0, self.dur_s);
        self.p0_deg + self.v0_deg_s * dt + 0.5 * self.a_deg_s2 * dt * dt
    }
}

/// A motion command as a device emulator received it over the wire (controller degrees).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum MotionCommand {
    /// A move to `target_deg` was requested (absolute, relative resolved to absolute, or a velocity move's end
    /// of travel). Recorded before the controller's own checks: a refused target is recorded too.
    MoveTo { target_deg: f64 },
    /// A homing search.
    Home,
    /// A stop (decelerating) or an emergency stop (abrupt).
    Stop { abrupt: bool },
}

#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CommandRecord {
    pub t_s: f64,
    pub command: MotionCommand,
}

/// What changed the profile.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum ChangeKind {
    /// Recording started: the state at that instant.
    Started,
    /// A move towards `requested_deg` (a limit switch or a stall may end it short: see [`ProfileChange::end`]).
    Move { requested_deg: f64 },
    /// A pause at rest appended to the profile.
    Dwell,
    /// A decelerating stop.
    Stop,
    /// An abrupt stop (the simulator's emergency stop, a reset).
    Halt,
    /// The position counter was redefined without motion (homing).
    SetPosition,
}

/// The motor's profile from `t_s` on, as it was set at `t_s`.
#[derive(Debug, Clone, PartialEq)]
pub struct ProfileChange {
    pub t_s: f64,
    pub kind: ChangeKind,
    /// Motor and load at `t_s` (after the change: a counter redefinition shifts both).
    pub motor_deg: f64,
    pub load_deg: f64,
    /// Segments to follow (the first may have started before `t_s`); empty when at rest.
    pub segments: Vec<ProfileSegment>,
    /// Where the motor rests once the segments end.
    pub rest_deg: f64,
    /// How the move ends.
    pub end: MoveEnd,
}

/// A quadratic stretch of a trajectory: `p(t) = p0 + v0 (t - t0) + a/2 (t - t0)^2` on `[t0, t1]`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Piece {
    pub t0_s: f64,
    pub t1_s: f64,
    pub p0_deg: f64,
    pub v0_deg_s: f64,
    pub a_deg_s2: f64,
}

impl Piece {
    pub fn position_at(&self, t_s: f64) -> f64 {
        let dt = (t_s - self.t0_s).clamp(0.0, (self.t1_s - self.t0_s).max(0.0));
        self.p0_deg + self.v0_deg_s * dt + 0.5 * self.a_deg_s2 * dt * dt
    }

    fn constant(t0_s: f64, t1_s: f64, p_deg: f64) -> Piece {
        Piece {
            t0_s,
            t1_s,
            p0_deg: p_deg,
            v0_deg_s: 0.0,
            a_deg_s2: 0.0,
        }
    }

    /// The same motion restricted to `[t0, t1]` (re-based at `t0`).
    fn restrict(&self, t0_s: f64, t1_s: f64) -> Piece {
        let dt = t0_s - self.t0_s;
        Piece {
            t0_s,
            t1_s,
            p0_deg: self.position_at(t0_s),
            v0_deg_s: self.v0_deg_s + self.a_deg_s2 * dt,
            a_deg_s2: self.a_deg_s2,
        }
    }

    /// Shifted by `offset_deg`.
    fn shifted(&self, offset_deg: f64) -> Piece {
        Piece {
            p0_deg: self.p0_deg + offset_deg,
            ..*self
        }
    }
}

/// One axis's record.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct MotionRecord {
    pub commands: Vec<CommandRecord>,
    pub changes: Vec<ProfileChange>,
    /// True when entries were dropped past [`MAX_RECORDS_PER_AXIS`].
    pub truncated: bool,
}

impl MotionRecord {
    pub(crate) fn push_command(&mut self, record: CommandRecord) {
        if self.commands.len() < MAX_RECORDS_PER_AXIS {
            self.commands.push(record);
        } else {
            self.truncated = true;
        }
    }

    pub(crate) fn push_change(&mut self, change: ProfileChange) {
        if self.changes.len() < MAX_RECORDS_PER_AXIS {
            self.changes.push(change);
        } else {
            self.truncated = true;
        }
    }

    /// When recording started.
    pub fn start_s(&self) -> Option<f64> {
        self.changes.first().map(|c| c.t_s)
    }

    /// The motor's trajectory from the start of the record to `t_end_s`, as contiguous quadratic pieces
    /// (controller degrees). Empty when nothing was recorded.
    pub fn motor_pieces(&self, t_end_s: f64) -> Vec<Piece> {
        let mut out = Vec::new();
        for (i, change) in self.changes.iter().enumerate() {
            let from = change.t_s;
            let until = self
                .changes
                .get(i + 1)
                .map_or(t_end_s, |next| next.t_s)
                .min(t_end_s);
            if until < from {
                continue;
            }
            let mut t = from;
            for seg in &change.segments {
                let (s0, s1) = (seg.t0_s.max(from), seg.end_s().min(until));
                if s1 <= s0 {
                    continue;
                }
                if s0 > t {
                    // A gap between segments is rest at the previous end (segments are contiguous in practice).
                    let p = out
                        .last()
                        .map_or(change.motor_deg, |p: &Piece| p.position_at(p.t1_s));
                    out.push(Piece::constant(t, s0, p));
                }
                let whole = Piece {
                    t0_s: seg.t0_s,
                    t1_s: seg.end_s(),
                    p0_deg: seg.p0_deg,
                    v0_deg_s: seg.v0_deg_s,
                    a_deg_s2: seg.a_deg_s2,
                };
                out.push(whole.restrict(s0, s1));
                t = s1;
            }
            if until > t || (until == from && change.segments.is_empty()) {
                let rest = if change.segments.iter().any(|s| s.end_s() > t) {
                    change
                        .segments
                        .last()
                        .map_or(change.rest_deg, |s| s.position_at(t))
                } else {
                    change.rest_deg
                };
                out.push(Piece::constant(t, until, rest));
            }
        }
        out
    }

    /// Motor position at `t_s` (controller degrees), or None before the record starts.
    pub fn motor_deg_at(&self, t_s: f64) -> Option<f64> {
        let i = self.changes.iter().rposition(|c| c.t_s <= t_s)?;
        let change = self.changes.get(i)?;
        for seg in &change.segments {
            if t_s >= seg.t0_s && t_s <= seg.end_s() {
                return Some(seg.position_at(t_s));
            }
        }
        if change.segments.iter().all(|s| s.end_s() <= t_s) {
            return Some(change.rest_deg);
        }
        // Before the first segment starts: at the change's position.
        Some(change.motor_deg)
    }

    /// The load's trajectory (what the optics see) to `t_end_s` for an axis with `backlash_deg` of play.
    pub fn load_pieces(&self, backlash_deg: f64, t_end_s: f64) -> Vec<Piece> {
        let motor = self.motor_pieces(t_end_s);
        let mut out = Vec::with_capacity(motor.len());
        let mut change_idx = 0;
        let mut load = self.changes.first().map_or(0.0, |c| c.load_deg);
        for piece in motor {
            // A profile change may redefine the counter (homing): take the recorded load at each change.
            while let Some(c) = self.changes.get(change_idx) {
                if c.t_s <= piece.t0_s {
                    load = c.load_deg;
                    change_idx += 1;
                } else {
                    break;
                }
            }
            let (m0, m1) = (piece.position_at(piece.t0_s), piece.position_at(piece.t1_s));
            load = load.clamp(m0, m0 + backlash_deg);
            if m1 > m0 {
                // Rising: the motor pushes the load from below once it reaches it.
                if load >= m1 {
                    out.push(Piece::constant(piece.t0_s, piece.t1_s, load));
                } else {
                    let tc = crossing_time(&piece, load, 0.0);
                    if tc > piece.t0_s {
                        out.push(Piece::constant(piece.t0_s, tc, load));
                    }
                    out.push(piece.restrict(tc, piece.t1_s));
                    load = m1;
                }
            } else if m1 < m0 {
                // Falling: the load lags by the backlash once the play is taken up.
                if load <= m1 + backlash_deg {
                    out.push(Piece::constant(piece.t0_s, piece.t1_s, load));
                } else {
                    let tc = crossing_time(&piece, load, backlash_deg);
                    if tc > piece.t0_s {
                        out.push(Piece::constant(piece.t0_s, tc, load));
                    }
                    out.push(piece.restrict(tc, piece.t1_s).shifted(backlash_deg));
                    load = m1 + backlash_deg;
                }
            } else {
                out.push(Piece::constant(piece.t0_s, piece.t1_s, load));
            }
        }
        out
    }
}

/// The first time in a monotone piece at which `motor + offset` reaches `level` (bisection: robust for any
/// quadratic, and the piece is monotone by construction).
fn crossing_time(piece: &Piece, level: f64, offset: f64) -> f64 {
    let f = |t: f64| piece.position_at(t) + offset - level;
    let (mut lo, mut hi) = (piece.t0_s, piece.t1_s);
    let rising = f(hi) > f(lo);
    for _ in 0..200 {
        let mid = 0.5 * (lo + hi);
        if mid <= lo || mid >= hi {
            break;
        }
        let below = if rising { f(mid) < 0.0 } else { f(mid) > 0.0 };
        if below {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    hi
}

// ---------------------------------------------------------------- checking two arms' trajectories

/// Pieces (controller degrees) in physical degrees of `axis`: `a = direction * (p - zero_offset)`.
pub fn physical_pieces(axis: &Axis, pieces: Vec<Piece>) -> Vec<Piece> {
    let dir = f64::from(axis.direction);
    pieces
        .into_iter()
        .map(|p| Piece {
            p0_deg: dir * (p.p0_deg - axis.zero_offset_deg),
            v0_deg_s: dir * p.v0_deg_s,
            a_deg_s2: dir * p.a_deg_s2,
            ..p
        })
        .collect()
}

/// Position and velocity of a piece at `t` (inside it).
fn state_at(p: &Piece, t: f64) -> (f64, f64) {
    (p.position_at(t), p.v0_deg_s + p.a_deg_s2 * (t - p.t0_s))
}

/// One interval between the breakpoints of both trajectories, with `f = l - d` at its start and its extremes.
#[derive(Debug, Clone, Copy)]
struct Stretch {
    ta: f64,
    tb: f64,
    fa: f64,
    lo: f64,
    hi: f64,
}

/// `l(t) - d(t)` on each interval between the breakpoints of both trajectories: on each such interval the
/// difference is one quadratic, whose extremes lie at its ends or at its vertex.
fn difference_extremes(l: &[Piece], d: &[Piece]) -> Vec<Stretch> {
    let mut breaks: Vec<f64> = l.iter().chain(d.iter()).flat_map(|p| [p.t0_s, p.t1_s]).collect();
    breaks.sort_by(f64::total_cmp);
    breaks.dedup();
    let covering = |pieces: &[Piece], t: f64| pieces.iter().find(|p| p.t0_s <= t && t <= p.t1_s).copied();
    let mut out = Vec::new();
    for w in breaks.windows(2) {
        let (ta, tb) = (w[0], w[1]);
        if tb <= ta {
            continue;
        }
        let mid = 0.5 * (ta + tb);
        let (Some(lp), Some(dp)) = (covering(l, mid), covering(d, mid)) else {
            continue;
        };
        let ((l0, lv), (d0, dv)) = (state_at(&lp, ta), state_at(&dp, ta));
        let (c0, c1, c2) = (l0 - d0, lv - dv, 0.5 * (lp.a_deg_s2 - dp.a_deg_s2));
        let f = |t: f64| c0 + c1 * (t - ta) + c2 * (t - ta) * (t - ta);
        let (fa, fb) = (f(ta), f(tb));
        let (mut lo, mut hi) = (fa.min(fb), fa.max(fb));
        if c2 != 0.0 {
            let tv = ta - c1 / (2.0 * c2);
            if tv > ta && tv < tb {
                lo = lo.min(f(tv));
                hi = hi.max(f(tv));
            }
        }
        out.push(Stretch { ta, tb, fa, lo, hi });
    }
    out
}

/// Slack on the "separation may only grow" comparison before the arms are first apart (rounding of degrees).
const GROWTH_SLACK_DEG: f64 = 1e-9;

/// The arm-separation rule checked exactly on two arms' trajectories (physical degrees; the light arm `l`, the
/// detector `d`): once the arms have been apart (`separation_ok`), they never come closer than that at any
/// instant; before (the simulator powers up with both arms at 0), their separation may only grow. `Err` names
/// the first stretch that breaks the rule; `Ok` is the smallest separation seen once apart (infinite if they
/// never were). `min_separation_deg` is only quoted in the message.
pub fn check_arm_separation(
    l: &[Piece],
    d: &[Piece],
    min_separation_deg: f64,
    separation_ok: impl Fn(f64) -> bool,
) -> Result<f64, SeparationViolation> {
    separation(l, d, min_separation_deg, separation_ok).map_err(SeparationViolation)
}

/// Where two arms' trajectories broke the separation rule ([`check_arm_separation`]): the stretch, the
/// separation reached and the rule's minimum.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{0}")]
pub struct SeparationViolation(pub String);

fn separation(
    l: &[Piece],
    d: &[Piece],
    min_separation_deg: f64,
    separation_ok: impl Fn(f64) -> bool,
) -> Result<f64, String> {
    let mut apart = false;
    let mut min_seen = f64::INFINITY;
    for Stretch { ta, tb, fa, lo, hi } in difference_extremes(l, d) {
        // The arms are within 200 degrees of each other (axis limits +-100): |l - d| is their separation
        // whenever it is below 180, which is all that matters here.
        let nearest = if lo > 0.0 {
            lo
        } else if hi < 0.0 {
            -hi
        } else {
            0.0
        };
        let farthest = lo.abs().max(hi.abs());
        apart |= separation_ok(fa.abs());
        if apart {
            min_seen = min_seen.min(nearest);
            if !separation_ok(nearest) {
                return Err(format!(
                    "arms {nearest:.6} deg apart between t = {ta:.4} s and {tb:.4} s (minimum {min_separation_deg} deg)"
                ));
            }
        } else {
            if nearest + GROWTH_SLACK_DEG < fa.abs() {
                return Err(format!(
                    "before the arms were apart their separation shrank from {:.6} to {nearest:.6} deg between \
                     t = {ta:.4} s and {tb:.4} s",
                    fa.abs()
                ));
            }
            apart = separation_ok(farthest);
            if apart {
                min_seen = min_seen.min(farthest);
            }
        }
    }
    Ok(min_seen)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::motion::{AxisMotion, AxisParams};

    fn piece(t0_s: f64, t1_s: f64, p0_deg: f64, v0_deg_s: f64, a_deg_s2: f64) -> Piece {
        Piece {
            t0_s,
            t1_s,
            p0_deg,
            v0_deg_s,
            a_deg_s2,
        }
    }

    #[test]
    fn the_separation_check_finds_a_brief_approach_between_samples() {
        let check = |l: &[Piece], d: &[Piece]| check_arm_separation(l, d, 10.0, |s| s >= 10.0 - 1e-9);
        // Both arms apart at every breakpoint, but the detector swings (quadratic) to within 9.5 deg of the
        // light arm in between: the vertex must be found.
        let light = vec![piece(0.0, 2.0, 0.0, 0.0, 0.0)];
        // d(t) = 20 - 42 t + 42 t^2 on [0, 1]: 9.5 deg at t = 0.5, between breakpoints where it is 20.
        let detector = vec![
            piece(0.0, 1.0, 20.0, -42.0, 84.0),
            piece(1.0, 2.0, 20.0, 0.0, 0.0),
        ];
        let err = check(&light, &detector).expect_err("too close at t = 0.5");
        assert!(err.0.contains("9.5"), "{err}");
        // The same swing kept at 10.5 deg at its closest is fine, and the minimum is measured exactly.
        let detector = vec![
            piece(0.0, 1.0, 20.0, -38.0, 76.0),
            piece(1.0, 2.0, 20.0, 0.0, 0.0),
        ];
        let min = check(&light, &detector).expect("apart");
        assert!((min - 10.5).abs() < 1e-9, "{min}");
        // Arms that start together may only separate until they are apart.
        let detector = vec![piece(0.0, 1.0, 0.0, 12.0, 0.0), piece(1.0, 2.0, 12.0, -4.0, 0.0)];
        let err = check(&light, &detector).expect_err("came back");
        assert!(err.0.contains("8.0"), "{err}");
    }

    /// A SplitMix64 stream: reproducible pseudo-random numbers without a dependency.
    struct Rng(u64);
    impl Rng {
        fn next(&mut self) -> f64 {
            self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
            let mut z = self.0;
            z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
            z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
            ((z ^ (z >> 31)) >> 11) as f64 / (1u64 << 53) as f64
        }
    }

    fn eval(pieces: &[Piece], t: f64) -> f64 {
        let p = pieces
            .iter()
            .find(|p| t >= p.t0_s && t <= p.t1_s)
            .unwrap_or_else(|| panic!("no piece covers t = {t}"));
        p.position_at(t)
    }

    /// The record reproduces the simulator's own motor and load positions, sampled at random instants
    /// (sampling does not change an axis's motion), over random moves, moves interrupted by new moves, stops,
    /// halts, dwells, limit-switch hits and stalls, with backlash.
    #[test]
    fn pieces_reproduce_motor_and_load_of_random_motion() {
        for seed in 0..30u64 {
            let mut r = Rng(seed);
            let params = AxisParams {
                hw_min_deg: -100.0,
                hw_max_deg: 100.0,
                backlash_deg: 0.01 + 0.5 * r.next(),
                encoder_resolution_deg: 0.0,
            };
            let mut m = AxisMotion::new(params, 0.0);
            m.start_recording(0.0);
            // Commands and samples in time order.
            let mut t = 0.0;
            let mut truth = Vec::new();
            for _ in 0..40 {
                for _ in 0..(r.next() * 4.0) as usize {
                    let ts = t + 0.5 * r.next();
                    truth.push((ts, m.motor_deg(ts), m.load_deg(ts)));
                    t = ts;
                }
                t += 2.0 * r.next();
                let what = r.next();
                if what < 0.6 {
                    let target = -120.0 + 240.0 * r.next();
                    let stall = (r.next() < 0.1).then(|| r.next());
                    m.start_move(t, target, 5.0 + 20.0 * r.next(), 10.0 + 80.0 * r.next(), stall);
                } else if what < 0.75 {
                    m.stop(t, 40.0);
                } else if what < 0.85 {
                    m.halt(t);
                } else {
                    m.dwell(t, r.next());
                }
            }
            let end = t + 20.0;
            truth.push((end, m.motor_deg(end), m.load_deg(end)));
            let record = m.take_record().expect("recording");
            let motor = record.motor_pieces(end);
            let load = record.load_pieces(params.backlash_deg, end);
            for w in motor.windows(2) {
                assert!((w[0].t1_s - w[1].t0_s).abs() < 1e-12, "contiguous: {w:?}");
                let jump = (w[0].position_at(w[0].t1_s) - w[1].position_at(w[1].t0_s)).abs();
                assert!(jump < 1e-9, "seed {seed}: motor jumps by {jump} at {}", w[1].t0_s);
            }
            for (ts, true_motor, true_load) in truth {
                let (pm, pl) = (eval(&motor, ts), eval(&load, ts));
                let rm = record.motor_deg_at(ts).expect("in record");
                assert!(
                    (pm - true_motor).abs() < 1e-9,
                    "seed {seed} t {ts}: motor {pm} vs {true_motor}"
                );
                assert!(
                    (rm - true_motor).abs() < 1e-9,
                    "seed {seed} t {ts}: motor_deg_at {rm} vs {true_motor}"
                );
                assert!(
                    (pl - true_load).abs() < 1e-9,
                    "seed {seed} t {ts}: load {pl} vs {true_load}"
                );
            }
        }
    }

    #[test]
    fn commands_are_recorded_only_while_recording() {
        let params = AxisParams {
            hw_min_deg: -10.0,
            hw_max_deg: 10.0,
            backlash_deg: 0.0,
            encoder_resolution_deg: 0.0,
        };
        let mut m = AxisMotion::new(params, 0.0);
        m.note_command(0.0, MotionCommand::MoveTo { target_deg: 50.0 });
        assert!(m.take_record().is_none());
        m.start_recording(1.0);
        m.note_command(1.0, MotionCommand::MoveTo { target_deg: 50.0 });
        m.start_move(1.0, 50.0, 10.0, 10.0, None);
        let record = m.take_record().expect("recording");
        assert_eq!(
            record.commands,
            vec![CommandRecord {
                t_s: 1.0,
                command: MotionCommand::MoveTo { target_deg: 50.0 }
            }]
        );
        // The limit switch ends the move at 10: the record shows the requested target and the real end.
        let last = record.changes.last().expect("change");
        assert_eq!(last.kind, ChangeKind::Move { requested_deg: 50.0 });
        assert_eq!(last.end, MoveEnd::LimitPositive);
        assert_eq!(record.motor_deg_at(100.0), Some(10.0));
    }
}
