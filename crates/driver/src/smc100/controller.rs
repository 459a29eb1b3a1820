//! One controller on a chain as an axis and its waits see it: the chain and address, the name in messages, and
//! the checks made on its replies before anything acts on them (a second look at an alarming state, two
//! position reads that must agree).

use std::sync::Arc;

use super::chain::Smc100Chain;
use super::protocol::{State, Ts, ts_reason};
use crate::error::DriverError;

#[derive(Debug)]
pub(super) struct Controller {
    pub(super) chain: Arc<Smc100Chain>,
    pub(super) addr: u8,
    /// The axis in messages: `light (arms/1)`.
    pub(super) device: String,
    /// Two reads of an axis at rest agree within this (controller units): the encoder resolution.
    at_rest: f64,
}

impl Controller {
    pub(super) fn new(chain: Arc<Smc100Chain>, cfg: &gonio_instrument::Axis) -> Controller {
        Controller {
            device: format!("{} ({}/{})", cfg.name, chain.name, cfg.address),
            addr: cfg.address,
            chain,
            at_rest: cfg.encoder_resolution_deg.max(1e-6) + 1e-9,
        }
    }

    /// Whether two position reads (controller units) agree: within the encoder resolution, plus `travel` (what
    /// a moving axis may travel between the two reads; 0 at rest).
    pub(super) fn reads_agree(&self, a: f64, b: f64, travel: f64) -> bool {
        (a - b).abs() <= self.at_rest + travel.abs()
    }

    /// A TS reading that would end a wait or report a fault (DISABLE, NOT REFERENCED, CONFIGURATION, and error
    /// bits when `errors_matter`) is confirmed by a second TS before anything acts on it: one garbled byte turns
    /// READY (33) into DISABLE (3C). Returns the latest reading (the second when a confirmation was asked).
    pub(super) async fn confirmed(&self, ts: Ts, errors_matter: bool) -> Result<Ts, DriverError> {
        let alarming = (errors_matter && ts.errors != 0)
            || matches!(
                ts.state,
                State::Disable(_) | State::NotReferenced(_) | State::Configuration | State::Unknown(_)
            );
        if !alarming {
            return Ok(ts);
        }
        let again = self.chain.ts(self.addr).await?;
        if again != ts {
            tracing::warn!(axis = %self.device, first = %ts_reason(&ts), second = %ts_reason(&again), "status changed on a second look");
        }
        Ok(again)
    }
}
