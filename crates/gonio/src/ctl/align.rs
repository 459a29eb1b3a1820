//! `gonio ctl align` and `gonio ctl calibrations`: the daemon's alignment action (started, followed to its end
//! with its steps and the operator's instructions, its calibration summarised) and its stored calibrations,
//! through `/api/align` and `/api/calibrations`.

use std::io::Write as _;
use std::time::{Duration, Instant};

use gonio_daemon::api::wire::{AlignPhase, AlignStatus, CalibrationView};
use gonio_engine::align::file::CalibrationFile;
use hyper::Method;
use serde_json::json;

use super::client::Client;
use crate::CliError;
use crate::align::value_line;

/// How often `align` asks for the alignment's progress.
const POLL: Duration = Duration::from_millis(500);
/// `align` gives up following after this long (the daemon waits an hour at most for each operator step; the
/// scans take minutes).
const FOLLOW_LIMIT: Duration = Duration::from_secs(3 * 3600);

/// Start the alignment and follow it to its end; print the calibration it made.
pub(super) async fn align(
    client: &Client,
    mirror: Option<&str>,
    simulate_operator: bool,
) -> Result<(), CliError> {
    let mut body = json!({ "simulate_operator": simulate_operator });
    if let Some(m) = mirror {
        body["mirror"] = json!(m);
    }
    let started: AlignStatus = client
        .typed(
            Method::POST,
            "/api/align",
            Some((
                body.to_string().into_bytes(),
                "application/json",
                "gonio ctl".into(),
            )),
        )
        .await?;
    println!(
        "alignment started{}",
        match (started.dry_run, simulate_operator) {
            (Some(true), true) => " (dry-run: the simulated operator does the operator's steps)",
            (Some(true), false) => " (dry-run: each operator step waits for your confirmation)",
            _ => "",
        }
    );
    let status = follow(client).await?;
    match status.state {
        AlignPhase::Completed => {
            let id = status
                .calibration_id
                .ok_or_else(|| CliError::input("the daemon's completed alignment names no calibration"))?
                .0;
            let text = client.text(&format!("/api/calibrations/{id}")).await?;
            let cal = CalibrationFile::parse(&text, &format!("calibration {id}"))
                .map_err(|e| CliError::input(e.to_string()))?;
            let instrument_s = status.instrument_s.unwrap_or(f64::NAN);
            print!("{}", summary(id, &cal, instrument_s));
            Ok(())
        }
        other => Err(CliError::CheckFailed(format!(
            "the alignment {}: {}",
            other.as_str(),
            status.error.as_deref().unwrap_or("no reason given")
        ))),
    }
}

/// Print each new step and operator instruction until the alignment ends; its last status.
async fn follow(client: &Client) -> Result<AlignStatus, CliError> {
    let start = Instant::now();
    let mut last_step = String::new();
    loop {
        let status: AlignStatus = client.typed(Method::GET, "/api/align", None).await?;
        if !status.state.in_progress() {
            return Ok(status);
        }
        let step = status.step.clone().unwrap_or_else(|| "?".into());
        if step != last_step {
            println!("alignment: {step}");
            if status.state == AlignPhase::WaitingOperator {
                println!(
                    "operator: {}; when done, run `gonio ctl align --confirm`",
                    status.operator_message.as_deref().unwrap_or("?")
                );
            }
            let _ = std::io::stdout().flush();
            last_step = step;
        }
        if start.elapsed() > FOLLOW_LIMIT {
            return Err(CliError::input(format!(
                "the alignment has not ended after {} s: `gonio ctl align --status` shows where it is",
                FOLLOW_LIMIT.as_secs()
            )));
        }
        tokio::time::sleep(POLL).await;
    }
}

/// `--confirm`, `--abort` (`what`) or `--status` (None).
pub(super) async fn request(client: &Client, what: Option<&str>) -> Result<(), CliError> {
    let status: AlignStatus = match what {
        Some(action) => {
            client
                .typed(Method::POST, &format!("/api/align/{action}"), None)
                .await?
        }
        None => client.typed(Method::GET, "/api/align", None).await?,
    };
    let mut line = format!("alignment: {}", status.state.as_str());
    for (key, v) in [
        ("step", &status.step),
        ("operator message", &status.operator_message),
        ("error", &status.error),
    ] {
        if let Some(v) = v {
            line.push_str(&format!("; {key}: {v}"));
        }
    }
    if let Some(id) = status.calibration_id {
        line.push_str(&format!("; calibration {}", id.0));
    }
    println!("{line}");
    Ok(())
}

/// The calibration's values for a person: one line each, as `gonio align` prints them.
fn summary(id: i64, cal: &CalibrationFile, instrument_s: f64) -> String {
    let h = &cal.calibration;
    let mut s = format!(
        "calibration {id} of {}{}, made {} in {:.0} s of instrument time; applied to the campaigns submitted from now on\n",
        h.instrument,
        if h.dry_run { " (simulated)" } else { "" },
        h.created_utc,
        instrument_s
    );
    for v in &cal.values {
        s.push_str(&value_line(&v.name, v.value, v.u, &v.unit, v.observable));
    }
    for m in &cal.unobservable {
        s.push_str(&format!("  not observable: {m}\n"));
    }
    s
}

/// The stored calibrations, or one's file.
pub(super) async fn calibrations(client: &Client, id: Option<i64>) -> Result<(), CliError> {
    if let Some(id) = id {
        print!("{}", client.text(&format!("/api/calibrations/{id}")).await?);
        return Ok(());
    }
    let list: Vec<CalibrationView> = client.typed(Method::GET, "/api/calibrations", None).await?;
    if list.is_empty() {
        println!("no calibrations");
    }
    for c in &list {
        let mark = if c.current {
            "current"
        } else if c.for_this_instrument {
            ""
        } else {
            "other instrument file"
        };
        println!(
            "{:>4}  {}  {:<16}  {:<21}  {}",
            c.id.0, c.created_utc, c.instrument, mark, c.source
        );
    }
    Ok(())
}
