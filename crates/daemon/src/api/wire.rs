//! The bodies of the API's answers as types: the daemon writes them and `gonio ctl` reads them, so that a field
//! renamed on one side fails to compile on the other instead of reading as nothing.

use gonio_engine::control::Event;
use gonio_engine::store::CampaignId;
use serde::{Deserialize, Serialize};

pub use crate::service::{AlignPhase, AlignStatus, CalibrationView, CampaignView};
pub use gonio_engine::console::{
    AxisPosition, AxisState, ConsoleReading, DeviceHealth, FilterSlot, InstrumentState, WheelState,
};

/// Every error answer (4xx, 5xx): what went wrong, for a person.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ErrorBody {
    pub error: String,
}

/// `POST /api/campaigns` (201): the new campaign's id.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Submitted {
    pub id: CampaignId,
}

// The console: `GET /api/console/state` and `POST /api/console/home` answer an [`InstrumentState`]; move and jog
// a list of [`AxisPosition`]; `POST /api/console/filter` a [`FilterMoved`]; `GET /api/console/read` a list of
// [`ConsoleReading`].
pub use crate::service::FilterMoved;

/// A reading the live stream (`GET /api/console/readings`) could not take, and why (the instrument is busy, a
/// device failed).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Unavailable {
    pub error: String,
}

/// One `data:` of the live reading stream.
#[derive(Debug, Clone, Deserialize)]
#[serde(untagged)]
pub enum LiveReading {
    Reading(ConsoleReading),
    Unavailable(Unavailable),
}

/// What the event stream adds to the engine's events.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "type", rename_all = "kebab-case")]
pub enum StreamNotice {
    /// The client read too slowly: this many events were dropped for it.
    Lagged { missed: u64 },
}

/// One `data:` of `GET /api/events`: an engine event, or the stream's own notice.
#[derive(Debug, Clone, Deserialize)]
#[serde(untagged)]
pub enum StreamItem {
    Event(Event),
    Notice(StreamNotice),
}

#[cfg(test)]
mod tests {
    use super::*;
    use gonio_engine::store::CampaignState;

    #[test]
    fn stream_items_read_back_what_the_daemon_writes() {
        let event = Event::Progress {
            campaign: CampaignId(3),
            done: 2,
            total: 4,
            eta_s: Some(1.5),
        };
        let text = serde_json::to_string(&event).expect("json");
        assert!(matches!(
            serde_json::from_str::<StreamItem>(&text).expect("event"),
            StreamItem::Event(Event::Progress {
                done: 2,
                total: 4,
                ..
            })
        ));
        let state = Event::State {
            campaign: CampaignId(3),
            state: CampaignState::WaitingOperator,
            message: Some("remove the sample".into()),
        };
        let text = serde_json::to_string(&state).expect("json");
        assert!(matches!(
            serde_json::from_str::<StreamItem>(&text).expect("state"),
            StreamItem::Event(Event::State {
                state: CampaignState::WaitingOperator,
                ..
            })
        ));
        let text = serde_json::to_string(&StreamNotice::Lagged { missed: 7 }).expect("json");
        assert_eq!(text, r#"{"type":"lagged","missed":7}"#);
        assert!(matches!(
            serde_json::from_str::<StreamItem>(&text).expect("notice"),
            StreamItem::Notice(StreamNotice::Lagged { missed: 7 })
        ));
    }
}
