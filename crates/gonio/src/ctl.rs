//! `gonio ctl`: the command-line client of the daemon's HTTP/JSON API.
//!
//! A small HTTP/1.1 client on hyper (already in the binary through the daemon's server): one connection per
//! request, a deadline on every call, and the server's `{"error": ...}` message as the command's error.

mod align;
mod client;
mod console;

use std::io::Write as _;
use std::path::PathBuf;
use std::time::Duration;

use clap::{Args, Subcommand};
use http_body_util::BodyExt;
use hyper::Method;

use gonio_daemon::api::wire::{CampaignView, StreamItem, StreamNotice, Submitted};
use gonio_engine::control::Event;
use gonio_engine::store::CampaignState;

use crate::CliError;
use client::{Client, collect, parse_sse_data, server_error};

/// `watch` gives up when the stream is silent this long (the daemon sends a keep-alive every 15 s).
const WATCH_IDLE_TIMEOUT: Duration = Duration::from_secs(60);

#[derive(Debug, Args)]
pub struct CtlArgs {
    /// The daemon's address.
    #[arg(long, default_value = "http://127.0.0.1:7878")]
    pub url: String,
    /// Token for a daemon that requires one; default: the GONIO_TOKEN variable.
    #[arg(long)]
    pub token: Option<String>,
    #[command(subcommand)]
    pub command: CtlCommand,
}

#[derive(Debug, Subcommand)]
pub enum CtlCommand {
    /// Submit a campaign file; prints its id.
    Submit { file: PathBuf },
    /// All campaigns, or one in detail.
    Status { id: Option<i64> },
    /// Pause a campaign (at its next safe point when running; a queued one leaves the queue).
    Pause { id: i64 },
    /// Resume a paused campaign (it goes back into the queue).
    Resume { id: i64 },
    /// Abort a campaign.
    Abort { id: i64 },
    /// Confirm that the operator did what a waiting campaign asked.
    Confirm { id: i64 },
    /// Emergency stop: halt the instrument now and hold the queue.
    Estop,
    /// Follow the daemon's events; with an id, until that campaign ends (exit 0 if it completed).
    Watch { id: Option<i64> },
    /// Download a campaign's points as CSV.
    Points {
        id: i64,
        /// Write here instead of standard output.
        #[arg(long)]
        out: Option<PathBuf>,
    },
    /// Align the instrument through the daemon (`gonio align`'s procedure, taking the instrument as the console
    /// does): follow it, then print the calibration it stored, which the daemon applies to every campaign
    /// submitted after it.
    Align {
        /// Dry-runs: the preset the simulated operator mounts as the alignment mirror (default `mirror`).
        #[arg(long)]
        mirror: Option<String>,
        /// Dry-runs: each operator step waits for `gonio ctl align --confirm`, as on hardware (the simulated
        /// holder follows once it is confirmed).
        #[arg(long, conflicts_with_all = ["confirm", "abort", "status"])]
        no_simulated_operator: bool,
        /// Confirm that the operator did what the waiting alignment asked.
        #[arg(long, conflicts_with_all = ["abort", "status", "mirror"])]
        confirm: bool,
        /// End an alignment waiting for its operator.
        #[arg(long, conflicts_with_all = ["status", "mirror"])]
        abort: bool,
        /// Where the alignment is (or how the last one ended), without starting one.
        #[arg(long, conflicts_with = "mirror")]
        status: bool,
    },
    /// The daemon's stored calibrations (the current one marked), or one's calibration file.
    Calibrations { id: Option<i64> },
    /// Console: every axis's position and state, the wheel, the meter, each device's identity and health.
    State {
        /// Print the daemon's JSON (one object; `axes` a list with `name` and `position_deg`).
        #[arg(long)]
        json: bool,
    },
    /// Console: move axes to physical angles in one safe move (`detector=40 tilt=2`), or to the pose that
    /// measures a geometry (`--geometry 30,0,30,180`: theta_i, phi_i, theta_o, phi_o in degrees).
    Move {
        /// AXIS=DEG ...
        #[arg(allow_hyphen_values = true)]
        targets: Vec<String>,
        #[arg(long, value_delimiter = ',', allow_hyphen_values = true)]
        geometry: Option<Vec<f64>>,
    },
    /// Console: move one axis by DELTA degrees.
    Jog {
        axis: String,
        #[arg(allow_hyphen_values = true)]
        delta_deg: f64,
    },
    /// Console: home one axis, or every axis (never sweeping an arm through the other).
    Home { axis: Option<String> },
    /// Console: turn the filter wheel to a position (`3`) or a band (`550nm`).
    Filter { filter: String },
    /// Console: meter readings with their time, pose, band and range.
    Read {
        #[arg(long, default_value_t = 1)]
        count: usize,
        /// Follow the daemon's live reading stream (until COUNT readings have come).
        #[arg(long)]
        stream: bool,
        /// Time between streamed readings (ms).
        #[arg(long, default_value_t = 250)]
        interval_ms: u64,
    },
}

pub fn run(args: CtlArgs) -> Result<(), CliError> {
    let token = args.token.clone().or_else(|| std::env::var("GONIO_TOKEN").ok());
    let client = Client::new(&args.url, token)?;
    let runtime = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .map_err(|e| CliError::io("cannot start the async runtime", e))?;
    runtime.block_on(execute(&client, args.command))
}

async fn execute(client: &Client, command: CtlCommand) -> Result<(), CliError> {
    match command {
        CtlCommand::Submit { file } => {
            let text = std::fs::read(&file)
                .map_err(|e| CliError::io(format!("cannot read {}", file.display()), e))?;
            let origin = file.display().to_string();
            let Submitted { id } = client
                .typed(
                    Method::POST,
                    "/api/campaigns",
                    Some((text, "application/toml", origin)),
                )
                .await?;
            println!("submitted campaign {id} ({})", file.display());
        }
        CtlCommand::Status { id: None } => {
            let list: Vec<CampaignView> = client.typed(Method::GET, "/api/campaigns", None).await?;
            if list.is_empty() {
                println!("no campaigns");
            }
            for c in &list {
                println!("{}", summary_line(c));
            }
        }
        CtlCommand::Status { id: Some(id) } => {
            let c: CampaignView = client
                .typed(Method::GET, &format!("/api/campaigns/{id}"), None)
                .await?;
            print!("{}", details(&c));
        }
        CtlCommand::Pause { id } => action(client, id, "pause").await?,
        CtlCommand::Resume { id } => action(client, id, "resume").await?,
        CtlCommand::Abort { id } => action(client, id, "abort").await?,
        CtlCommand::Confirm { id } => action(client, id, "confirm").await?,
        CtlCommand::Estop => {
            client.json(Method::POST, "/api/estop", None).await?;
            println!("emergency stop sent: the instrument is halted and queued campaigns are paused");
        }
        CtlCommand::Watch { id } => watch(client, id).await?,
        CtlCommand::Align {
            mirror,
            no_simulated_operator,
            confirm,
            abort,
            status,
        } => match (confirm, abort, status) {
            (true, _, _) => align::request(client, Some("confirm")).await?,
            (_, true, _) => align::request(client, Some("abort")).await?,
            (_, _, true) => align::request(client, None).await?,
            _ => align::align(client, mirror.as_deref(), !no_simulated_operator).await?,
        },
        CtlCommand::Calibrations { id } => align::calibrations(client, id).await?,
        CtlCommand::State { json } => console::state(client, json).await?,
        CtlCommand::Move { targets, geometry } => {
            console::move_axes(client, &targets, geometry.as_deref()).await?
        }
        CtlCommand::Jog { axis, delta_deg } => console::jog(client, &axis, delta_deg).await?,
        CtlCommand::Home { axis } => console::home(client, axis.as_deref()).await?,
        CtlCommand::Filter { filter } => console::filter(client, &filter).await?,
        CtlCommand::Read {
            count,
            stream,
            interval_ms,
        } => console::read(client, count, stream, interval_ms).await?,
        CtlCommand::Points { id, out } => {
            let csv = client.text(&format!("/api/campaigns/{id}/points.csv")).await?;
            match out {
                Some(path) => {
                    std::fs::write(&path, csv.as_bytes())
                        .map_err(|e| CliError::io(format!("cannot write {}", path.display()), e))?;
                    let rows = csv.lines().count().saturating_sub(1);
                    println!("wrote {rows} points to {}", path.display());
                }
                None => {
                    let mut stdout = std::io::stdout().lock();
                    stdout
                        .write_all(csv.as_bytes())
                        .map_err(|e| CliError::io("cannot write to stdout", e))?;
                }
            }
        }
    }
    Ok(())
}

async fn action(client: &Client, id: i64, what: &str) -> Result<(), CliError> {
    let c: CampaignView = client
        .typed(Method::POST, &format!("/api/campaigns/{id}/{what}"), None)
        .await?;
    println!("campaign {id}: {what} accepted (state {})", c.state);
    Ok(())
}

fn summary_line(c: &CampaignView) -> String {
    let mut line = format!(
        "{:>4}  {:<16}  {:>6}/{:<6}  {}",
        c.id.0,
        c.state.to_string(),
        c.points_done,
        c.total_points,
        c.name
    );
    if let Some(eta) = c.eta_s {
        line.push_str(&format!("  ETA {}", duration_text(eta)));
    }
    line
}

fn details(c: &CampaignView) -> String {
    let mut s = String::new();
    s.push_str(&format!("campaign {}: {}\n", c.id.0, c.name));
    s.push_str(&format!("  state:  {}\n", c.state));
    s.push_str(&format!("  points: {}/{}\n", c.points_done, c.total_points));
    if let Some(eta) = c.eta_s {
        s.push_str(&format!("  ETA:    {}\n", duration_text(eta)));
    }
    if c.dry_run {
        s.push_str("  dry-run on the simulator\n");
    }
    if let Some(cal) = c.calibration_id {
        let cal = cal.0;
        s.push_str(&format!(
            "  calibration {cal} applied (`gonio ctl calibrations {cal}`)\n"
        ));
    }
    if let Some(m) = &c.operator_message {
        s.push_str(&format!("  operator: {m}\n"));
    }
    if let Some(e) = &c.last_error {
        s.push_str(&format!("  last error: {e}\n"));
    }
    s
}

/// `1h02m03s`, `4m05s`, `6s`.
fn duration_text(seconds: f64) -> String {
    if !seconds.is_finite() || seconds < 0.0 {
        return "?".into();
    }
    let total = seconds.round() as u64;
    let (h, m, s) = (total / 3600, total / 60 % 60, total % 60);
    match (h, m) {
        (0, 0) => format!("{s}s"),
        (0, _) => format!("{m}m{s:02}s"),
        _ => format!("{h}h{m:02}m{s:02}s"),
    }
}

/// Follow the event stream. With an id: print that campaign's events until it ends.
async fn watch(client: &Client, id: Option<i64>) -> Result<(), CliError> {
    // Subscribe first, then look at the current state, so that no change in between is missed.
    let response = client.send(Method::GET, "/api/events", None).await?;
    if !response.status().is_success() {
        let status = response.status();
        let body = collect(response).await?;
        return Err(server_error(status, &body));
    }
    if let Some(id) = id {
        let c: CampaignView = client
            .typed(Method::GET, &format!("/api/campaigns/{id}"), None)
            .await?;
        println!("{}", summary_line(&c));
        if let Some(end) = final_outcome(id, c.state) {
            return end;
        }
    }
    let mut body = response.into_body();
    let mut buffer = String::new();
    loop {
        let frame = match tokio::time::timeout(WATCH_IDLE_TIMEOUT, body.frame()).await {
            Err(_) => {
                return Err(CliError::input(format!(
                    "no event nor keep-alive from {} for {} s: giving up",
                    client.authority,
                    WATCH_IDLE_TIMEOUT.as_secs()
                )));
            }
            Ok(None) => {
                return Err(CliError::input(
                    "the daemon closed the event stream (shutting down?)",
                ));
            }
            Ok(Some(Err(e))) => return Err(CliError::input(format!("event stream broken: {e}"))),
            Ok(Some(Ok(frame))) => frame,
        };
        let Ok(data) = frame.into_data() else { continue };
        buffer.push_str(&String::from_utf8_lossy(&data).replace('\r', ""));
        while let Some(end) = buffer.find("\n\n") {
            let block: String = buffer.drain(..end + 2).collect();
            // An item this client does not know (a newer daemon's) is left out, not misread.
            let Some(item) =
                parse_sse_data(&block).and_then(|v| serde_json::from_value::<StreamItem>(v).ok())
            else {
                continue;
            };
            if let Some(done) = print_event(&item, id) {
                return done;
            }
        }
    }
}

/// Print one event (when it concerns the watched campaign); `Some` ends the watch with that result.
fn print_event(item: &StreamItem, watched: Option<i64>) -> Option<Result<(), CliError>> {
    let event = match item {
        StreamItem::Notice(StreamNotice::Lagged { missed }) => {
            println!("(missed {missed} events: too slow)");
            return None;
        }
        StreamItem::Event(event) => event,
    };
    let campaign = match event {
        Event::State { campaign, .. }
        | Event::Point { campaign, .. }
        | Event::Progress { campaign, .. }
        | Event::Fault { campaign, .. }
        | Event::Sweep { campaign, .. } => campaign.0,
    };
    if watched.is_some_and(|w| w != campaign) {
        return None;
    }
    let c = campaign;
    match event {
        Event::State { state, message, .. } => {
            match message {
                Some(m) => println!("campaign {c}: {state}: {m}"),
                None => println!("campaign {c}: {state}"),
            }
            if *state == CampaignState::WaitingOperator {
                println!("campaign {c}: when done, run `gonio ctl confirm {c}`");
            }
            if watched == Some(campaign) {
                return final_outcome(campaign, *state);
            }
        }
        Event::Progress {
            done, total, eta_s, ..
        } => {
            let percent = if *total > 0 {
                100.0 * *done as f64 / *total as f64
            } else {
                0.0
            };
            let eta = eta_s.map(|e| format!(", ETA {}", duration_text(e)));
            println!(
                "campaign {c}: {done}/{total} points ({percent:.0}%){}",
                eta.unwrap_or_default()
            );
        }
        Event::Fault { message, .. } => println!("campaign {c}: fault: {message}"),
        Event::Sweep {
            segment,
            segments,
            readings,
            ..
        } => println!(
            "campaign {c}: sweep {} of {segments} committed ({readings} readings)",
            segment + 1
        ),
        // Every point also comes with a progress event: that is the line to show.
        Event::Point { .. } => {}
    }
    let _ = std::io::stdout().flush();
    None
}

/// For a watched campaign: `Some` once it is in a final state (Ok when completed).
fn final_outcome(id: i64, state: CampaignState) -> Option<Result<(), CliError>> {
    match state {
        CampaignState::Completed => Some(Ok(())),
        CampaignState::Aborted | CampaignState::Failed => {
            Some(Err(CliError::CheckFailed(format!("campaign {id} ended {state}"))))
        }
        _ => None,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn urls_are_parsed_into_an_authority() {
        assert_eq!(
            Client::new("http://127.0.0.1:7878", None).expect("url").authority,
            "127.0.0.1:7878"
        );
        assert_eq!(
            Client::new("http://127.0.0.1:7878/", None)
                .expect("url")
                .authority,
            "127.0.0.1:7878"
        );
        assert_eq!(
            Client::new("http://localhost", None).expect("url").authority,
            "localhost:80"
        );
        assert!(Client::new("https://127.0.0.1:7878", None).is_err());
        assert!(Client::new("127.0.0.1:7878", None).is_err());
        assert!(Client::new("http://127.0.0.1:7878/api", None).is_err());
    }

    #[test]
    fn sse_blocks_yield_their_json() {
        let block =
            "event: progress\ndata: {\"type\":\"progress\",\"campaign\":3,\"done\":2,\"total\":4}\n\n";
        let v = parse_sse_data(block).expect("json");
        assert_eq!(v["done"], 2);
        assert_eq!(parse_sse_data(":\n\n"), None);
    }

    #[test]
    fn durations_read_like_a_clock() {
        assert_eq!(duration_text(5.4), "5s");
        assert_eq!(duration_text(245.0), "4m05s");
        assert_eq!(duration_text(3723.0), "1h02m03s");
        assert_eq!(duration_text(f64::NAN), "?");
    }

    #[test]
    fn watch_ends_only_on_final_states() {
        assert!(matches!(final_outcome(1, CampaignState::Completed), Some(Ok(()))));
        assert!(matches!(final_outcome(1, CampaignState::Aborted), Some(Err(_))));
        assert!(matches!(final_outcome(1, CampaignState::Failed), Some(Err(_))));
        for s in CampaignState::ALL.into_iter().filter(|s| !s.is_final()) {
            assert!(final_outcome(1, s).is_none(), "{s}");
        }
    }
}
