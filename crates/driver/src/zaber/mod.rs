//! Zaber motion devices over the ASCII protocol, written from Zaber's ASCII protocol manual.
//!
//! Every command carries a message id (0..=99) and a checksum: `/<dev> <axis> <id> <command>:<CC>\n`. Replies
//! `@DD A [id] FL STATUS WW data[:CC]` are matched by device, axis and id; their checksum is verified when present,
//! and the driver turns a device's reply checksums on (`set comm.checksum 1`) whenever a reply comes without one;
//! an idle axis's position is only taken from a checksummed reply or confirmed by a second read (see
//! [`ZaberChain`]). Alerts (`!`) and info lines (`#`) interleaved with replies are handled, and a
//! reply or info line ending in `\` continues in the next `#... cont` info line. `move abs`, `get`, `stop` and
//! `warnings` are idempotent and retried (bounded); `home` is sent once. Positions are integer microsteps,
//! converted to degrees with the axis's `microstep_deg`. A wait for a move asks at once, then on a
//! [`PollSchedule`](crate::poll::PollSchedule).
//!
//! Split by job: [`protocol`] (checksums, command lines, reply parsing, warning flags), [`chain`] (the port:
//! requests, message ids, reply checksums, stop), [`axis`] (one axis: status, homing, verified moves).
//!
//! Protocol notes, and where each comes from (Zaber's firmware-6 ASCII protocol manual unless said otherwise):
//! - An unhomed device refuses a movement to a position, relative ones too: `/move rel 10000` answers
//!   `@01 0 RJ IDLE WR BADDATA`. A rejection showing WR (or, because flags show in priority order, a rejection
//!   whose `warnings` include WR) is "not referenced".
//! - On a bad checksum the manual says both that every device on the chain replies with a rejection and that
//!   the message is ignored. Either way the command did not run: a rejection carrying this request's message id
//!   from another device or axis marks a checksum rejection, and the command is sent again (even one that is
//!   otherwise sent once); silence is a timeout, retried as usual.
//! - Warning flags show in the manual's priority order (FD FS FE WL WV WT WM WR NC NI NU), not
//!   alphabetically: the flag of a reply is only the first; decisions read `warnings`.
//! - Numbers may be written as `0x...` ([`parse_int`]).

mod axis;
mod chain;
mod protocol;

use std::time::Duration;

pub use axis::ZaberAxis;
pub use chain::ZaberChain;
pub use protocol::*;

const REPLY_TIMEOUT: Duration = Duration::from_millis(300);
const ATTEMPTS: usize = 3;
/// Shortest pause between two status questions to one device. The manual sets no minimum (a device answers each
/// command before the next is sent, as this driver waits for every reply); 10 ms leaves the shared chain free for
/// the other axes between questions.
const POLL_MIN: Duration = Duration::from_millis(10);
/// Longest pause between two status questions while a move runs: bounds how late a stall is noticed.
const POLL_MAX: Duration = Duration::from_millis(50);
/// Zaber's speed data unit: microsteps/s x 1.6384.
const SPEED_UNIT: f64 = 1.6384;
/// Zaber's acceleration data unit: microsteps/s^2 x 1.6384 / 10000.
const ACCEL_UNIT: f64 = 1.6384 / 10_000.0;
