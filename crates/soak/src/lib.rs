//! gonio-soak: the reliability soaks of issue 8, shared by the `gonio-soak` command (which writes
//! `RELIABILITY.md`) and the CI-sized tests in `tests/`, so that both run the same code.
//!
//! Each soak's tests are a test binary of their own (the workspace's other crates have one each): a soak judges
//! the daemon under load it makes itself (SIGKILLed worker processes, a store filled to SQLite's limit, hostile
//! connections on the real clock), and run in one process with another soak beside it, its verdict would be
//! about both.
//!
//! Module map:
//! - [`setup`]: the soak campaigns (an exact number of points) and the instrument ([`setup::SoakInstrument`]:
//!   the ideal `simulated.toml` or the imperfect `realistic.toml`) with `[simulator.faults]` set.
//! - [`logcap`]: a `tracing` layer that counts what the simulator injected, what the drivers and the engine
//!   logged about it, and keeps a log file of warnings.
//! - [`fault_soak`]: a dry-run campaign through the real drivers and engine on a faulty simulator; every point is
//!   checked against the simulator's ground truth, every injected fault against what the host saw.
//! - [`crash_soak`]: `kill -9` of the daemon at chosen and random moments of one campaign (mid-move, mid-commit,
//!   start-up), restarted each time; the committed rows are compared byte for byte.
//! - [`worker`]: the daemon process the crash soak kills (the daemon's service, queue and HTTP API on the
//!   simulated instrument), with its probes for self-inflicted kills at exact moments.
//! - [`rows`]: a campaign's committed points against its plan ([`rows::RowSummary`]: the row verdict of the fault,
//!   crash, disk and HTTP soaks), and raw rows of the store, read with SQLite directly (independent of the store's
//!   own decoding).
//! - [`disk_soak`]: the store made full (SQLite's own SQLITE_FULL) several times in one campaign, room given back
//!   each time: the pause, its reason, no motion while paused, nothing committed lost, every point once.
//! - [`http_abuse`]: slowloris, idle and body-trickling connections beyond the daemon's connection limit and
//!   oversized bodies, while the daemon runs a campaign and a client times its status requests; the daemon on a
//!   loopback port and HTTP read off the wire, shared with the abuse tests (`tests/http_abuse.rs`).
//! - [`safety_soak`]: random campaigns with random pause/abort/estop interleavings, checked on the simulator's
//!   motion record: closest arm approach, commanded extremes against the limits, emergency-stop latency; its
//!   [`safety_soak::scenarios`] are the fixed cases (regressions, controllers reset behind the engine's back) of
//!   the safety tests (`tests/safety_soak.rs`).
//! - [`truth_check`]: what "silently wrong" means for a point on the ideal and on an imperfect instrument (its
//!   value against its ground truth, with the imperfections' allowance from the point's own attribution).
//! - [`inputs`]: random and mutated inputs through the public wire parsers and file loaders.
//! - [`report`]: the Markdown of `RELIABILITY.md`.

pub mod crash_soak;
pub mod disk_soak;
pub mod fault_soak;
pub mod http_abuse;
pub mod inputs;
pub mod logcap;
pub mod report;
pub mod rows;
pub mod safety_soak;
pub mod setup;
pub mod truth_check;
pub mod worker;

/// Why a soak could not run at all (as opposed to a soak that ran and found a defect, which is in its report).
#[derive(Debug, thiserror::Error)]
pub enum SoakError {
    #[error("setup: {0}")]
    Setup(String),
    #[error("engine: {0}")]
    Engine(#[from] gonio_engine::EngineError),
    #[error("store: {0}")]
    Store(#[from] gonio_engine::store::StoreError),
    #[error("sqlite: {0}")]
    Sqlite(#[from] rusqlite::Error),
    #[error("{what}: {source}")]
    Io { what: String, source: std::io::Error },
    #[error("worker process: {0}")]
    Worker(String),
}

impl SoakError {
    pub(crate) fn io(what: impl Into<String>) -> impl FnOnce(std::io::Error) -> SoakError {
        let what = what.into();
        move |source| SoakError::Io { what, source }
    }
}
