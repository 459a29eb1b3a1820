//! Integration tests of gonio-daemon: one test binary (the engine, the simulator and the HTTP stack are linked
//! once).
//!
//! - `adaptive`: adaptive campaigns through the engine (tokio's paused clock, the in-process simulator).
//! - `alignment`: the daemon's calibrations.
//! - `api`: the HTTP/JSON control API in process.
//! - `api_fuzz`: the HTTP API's routes fed random requests in process.
//! - `console`: the console through the HTTP API on the simulated instrument (tokio's paused clock).
//! - `disk`: disk trouble.
//! - `last_error`: a campaign's `last_error` says why it stopped; once it completed there is none left to show.
//! - `origin`: a web page in the operator's browser cannot drive the daemon.
//! - `ownership`: the service handing the instrument to one owner at a time.
//! - `paths`: paths in campaign files.
//! - `pausing`: the `pausing` state.
//! - `status_page`: the status page's routes on the daemon's real router.

mod common;

mod adaptive;
mod alignment;
mod api;
mod api_fuzz;
mod console;
mod disk;
mod last_error;
mod origin;
mod ownership;
mod paths;
mod pausing;
mod status_page;
