//! Which controllers' next `TS` may go unanswered because real SMC100s are recorded to leave it so: the first
//! TS after power-up (the port opened) or a reset, and the first right after a homing completes. Losing that
//! reply is expected and logged at debug; every other lost reply is a warning. "Expected" is kept narrow: one
//! unanswered TS per such event, nothing else.

use std::collections::BTreeMap;
use std::sync::Mutex;

use super::protocol::State;

/// Per controller: whether its next unanswered TS is the expected one, and how many were since the last report.
#[derive(Debug, Default)]
pub(super) struct FirstTs {
    inner: Mutex<Inner>,
}

#[derive(Debug, Default)]
struct Inner {
    /// Controllers whose expected loss is used up (they answered a TS since the event, or already lost one).
    /// A controller not in it has had no TS answered since the port opened.
    settled: BTreeMap<u8, bool>,
    /// Expected losses per controller since the last report.
    count: BTreeMap<u8, u32>,
    /// Controllers whose latest exchange lost the expected TS (a TS inside a longer exchange, whose loss the
    /// caller sees as a missing value).
    lost_last: BTreeMap<u8, bool>,
}

impl FirstTs {
    /// The port (re)opened: as after power-up, every controller's next TS may go unanswered.
    pub(super) fn port_opened(&self) {
        if let Ok(mut g) = self.inner.lock() {
            g.settled.clear();
        }
    }

    /// `OR` or `RS` went to `addr`: its first TS once homing completes (or after the reset) may go unanswered.
    pub(super) fn reset(&self, addr: u8) {
        if let Ok(mut g) = self.inner.lock() {
            g.settled.insert(addr, false);
        }
    }

    /// `addr` answered a TS in `state`. While it is homing the loss is still to come; any other answer means
    /// the TS that might have gone unanswered did not.
    pub(super) fn answered(&self, addr: u8, state: State) {
        if matches!(state, State::Homing(_)) {
            return;
        }
        if let Ok(mut g) = self.inner.lock() {
            g.settled.insert(addr, true);
        }
    }

    /// An exchange with `addr` begins.
    pub(super) fn exchange_begins(&self, addr: u8) {
        if let Ok(mut g) = self.inner.lock() {
            g.lost_last.remove(&addr);
        }
    }

    /// A TS to `addr` got no reply: whether that is the expected loss (then counted, and used up).
    pub(super) fn unanswered(&self, addr: u8) -> bool {
        let Ok(mut g) = self.inner.lock() else {
            return false;
        };
        let settled = g.settled.entry(addr).or_insert(false);
        if *settled {
            return false;
        }
        *settled = true;
        *g.count.entry(addr).or_insert(0) += 1;
        g.lost_last.insert(addr, true);
        true
    }

    /// Whether the latest exchange with `addr` lost the expected TS.
    pub(super) fn lost_in_last_exchange(&self, addr: u8) -> bool {
        self.inner
            .lock()
            .ok()
            .is_some_and(|g| g.lost_last.get(&addr).copied().unwrap_or(false))
    }

    /// The expected losses of `addr` since the last call.
    pub(super) fn take_count(&self, addr: u8) -> u32 {
        self.inner
            .lock()
            .ok()
            .and_then(|mut g| g.count.remove(&addr))
            .unwrap_or(0)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn one_expected_loss_per_power_up_or_homing_and_none_otherwise() {
        let f = FirstTs::default();
        // Power-up: the first TS of each controller may be lost, once.
        f.exchange_begins(1);
        assert!(f.unanswered(1));
        assert!(f.lost_in_last_exchange(1));
        f.exchange_begins(1);
        assert!(!f.unanswered(1), "a second loss is not the recorded one");
        assert!(!f.lost_in_last_exchange(1));
        assert!(f.unanswered(2));
        // An answered TS uses the allowance up.
        f.port_opened();
        f.answered(1, State::NotReferenced(0x0A));
        assert!(!f.unanswered(1));
        // Homing: answers while homing keep it; the loss after completion is expected, once.
        f.reset(1);
        f.answered(1, State::Homing(0x1E));
        assert!(f.unanswered(1));
        assert!(!f.unanswered(1));
        // After a move, nothing is expected.
        f.answered(1, State::Ready(0x33));
        assert!(!f.unanswered(1));
        assert_eq!(f.take_count(1), 2);
        assert_eq!(f.take_count(1), 0, "reported once");
        assert_eq!(f.take_count(2), 1);
    }
}
