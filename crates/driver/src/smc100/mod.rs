//! Newport SMC100CC/PP motion controllers on one daisy-chained RS-232 port, written from the SMC100 user manual.
//!
//! Split by job: [`protocol`] (reply parsing, states, error codes), [`chain`] (the port: paced exchanges,
//! queries, set commands, stop), `controller` (one controller as axis and wait see it: confirmation of alarming
//! states, agreement of two reads), `wait` (polling a controller until a state), [`axis`] (one axis: status,
//! homing, moves with verified arrival).
//!
//! Wire format: `<addr><CC><arg>\r\n`. Queries answer `<addr><CC><value>\r\n`; set commands are silent, so every
//! set command is followed, in the same exchange, by `<addr>TE` (last command error, `@` = none). Status `TS`
//! answers 4 hex digits of positioner error bits and 2 hex digits of controller state. `PA` is idempotent and may
//! be retried; `OR` (home) and `PR` are never retried blindly. A wait loop treats DISABLE (3C..3E) and the NOT
//! REFERENCED states as terminal (once a second TS confirms them).
//!
//! Replies carry no checksum, so a position the driver acts on is read twice in one exchange and the two reads
//! must agree within the encoder resolution ([`Smc100Axis::verified_position`]). Several queries share one
//! exchange (one command per line, as the manual requires): a move is `TP TP PA TE`, then `PT TS` (plus `TP TP`
//! once the move should be over) on a [`PollSchedule`](crate::poll::PollSchedule).
//!
//! Protocol notes, and where each comes from:
//! - Pacing: host drivers written against real controllers pace their commands (the widely copied Python SMC100
//!   driver waits 60 ms after each set command, "arrived at by trial and error"; others up to 0.5 s) and report
//!   that a reply can arrive late and land in the next query's read. So an exchange is never a burst: each
//!   query goes out once the previous reply is in, each set command is followed by a pause before the next
//!   command to the same controller ([`SET_GAP`], widened up to [`MAX_SET_GAP`] when the line after a set
//!   command goes unanswered; the port is free for the other controllers meanwhile), and every reply is matched
//!   to its query by address and command code (a late one is dropped as stale). The stop on the priority path
//!   goes out at once and again after the pause.
//! - A `TS` may get no reply at all right after power-up or right after homing completes (a real-hardware
//!   driver reports it as undocumented): every query is retried, so a lost TS costs one reply timeout. That
//!   loss is expected, so it is logged at debug and counted at info once the axis is homed; any other lost
//!   reply stays a warning (`first_ts`).
//! - `TP` prints up to 10 decimals and `VE` looks like `1VE SMC_CC - Controller-driver version  3. 1. 2`
//!   (real-controller replies): numbers are parsed whatever their length; `VE` is not used.
//! - In READY, `TP` equals the set-point within the encoder resolution (manual): the encoder is on the motor,
//!   so the read-back cannot show backlash; the backlash approach ([`approach_waypoints`]) is what removes it.
//!
//! [`approach_waypoints`]: crate::motion::approach_waypoints

mod axis;
mod chain;
mod controller;
mod first_ts;
mod protocol;
mod wait;

use std::time::Duration;

pub use axis::Smc100Axis;
pub use chain::Smc100Chain;
pub use protocol::{
    State, Ts, describe_error_bits, describe_te, parse_number, parse_reply, parse_te, parse_ts,
};

/// Time allowed for one query's reply.
const REPLY_TIMEOUT: Duration = Duration::from_millis(300);
/// Attempts for idempotent requests (queries, PA).
const ATTEMPTS: usize = 3;
/// Pause after a set command before the next command goes out: the 60 ms real-hardware drivers found by trial
/// (see the module notes), plus a margin.
pub const SET_GAP: Duration = Duration::from_millis(65);
/// The widest pause after a set command: the longest any real-hardware driver uses.
pub const MAX_SET_GAP: Duration = Duration::from_millis(500);
/// Shortest pause between two status questions to one controller: the manual (section 6.4, "Command Execution
/// Time") gives about 10 ms for a controller to execute a TP query, so asking faster only queues questions.
const POLL_MIN: Duration = Duration::from_millis(10);
/// Longest pause between two status questions while a move runs: bounds how late a stall is noticed.
const POLL_MAX: Duration = Duration::from_millis(50);
/// Span of two position reads in one exchange of a moving axis (two TP executions and their replies), for the
/// agreement allowed between them: what the axis travels at full speed in that time.
const MOVING_READ_WINDOW_S: f64 = 0.05;
