//! `gonio ctl`'s console commands: the instrument's state, moves (by axis or by geometry), jog, homing, the
//! wheel and the meter's readings, through the daemon's `/api/console` routes.

use std::io::Write as _;
use std::time::Duration;

use gonio_daemon::api::wire::{AxisPosition, ConsoleReading, FilterMoved, InstrumentState, LiveReading};
use http_body_util::BodyExt;
use hyper::Method;
use serde::de::DeserializeOwned;
use serde_json::{Value, json};

use super::client::{Client, collect, parse_sse_data, server_error};
use crate::CliError;

/// A console move, jog or homing may take this long (the daemon's own limit, and a little more).
const MOTION_CALL_TIMEOUT: Duration = Duration::from_secs(610);
/// `read --stream` gives up when the stream is silent this long.
const STREAM_IDLE_TIMEOUT: Duration = Duration::from_secs(60);

/// `AXIS=DEG` arguments as the move request's axes.
pub(super) fn parse_targets(args: &[String]) -> Result<Vec<(String, f64)>, CliError> {
    args.iter()
        .map(|a| {
            let (name, deg) = a
                .split_once('=')
                .ok_or_else(|| CliError::input(format!("{a:?}: expected AXIS=DEG, e.g. detector=40")))?;
            let deg: f64 = deg
                .trim()
                .parse()
                .map_err(|_| CliError::input(format!("{a:?}: {deg:?} is not a number of degrees")))?;
            Ok((name.trim().to_string(), deg))
        })
        .collect()
}

async fn post_motion<T: DeserializeOwned>(client: &Client, path: &str, body: Value) -> Result<T, CliError> {
    let bytes = client
        .call_within(
            Method::POST,
            path,
            Some((
                body.to_string().into_bytes(),
                "application/json",
                "gonio ctl".into(),
            )),
            MOTION_CALL_TIMEOUT,
        )
        .await?;
    serde_json::from_slice(&bytes).map_err(|e| {
        CliError::input(format!(
            "unexpected reply from the daemon to {path} ({e}): {}",
            String::from_utf8_lossy(&bytes)
        ))
    })
}

fn positions_line(axes: &[AxisPosition]) -> String {
    axes.iter()
        .map(|a| format!("{} {:.4} deg", a.name, a.position_deg))
        .collect::<Vec<_>>()
        .join(", ")
}

/// The read-back positions in a state, for the line after a homing.
fn state_positions(state: &InstrumentState) -> String {
    state
        .axes
        .iter()
        .map(|a| match a.position_deg {
            Some(p) => format!("{} {p:.4} deg", a.name),
            None => format!("{} ?", a.name),
        })
        .collect::<Vec<_>>()
        .join(", ")
}

pub(super) async fn move_axes(
    client: &Client,
    targets: &[String],
    geometry: Option<&[f64]>,
) -> Result<(), CliError> {
    let body = match (targets.is_empty(), geometry) {
        (false, None) => {
            let axes: serde_json::Map<String, Value> = parse_targets(targets)?
                .into_iter()
                .map(|(n, d)| (n, json!(d)))
                .collect();
            json!({ "axes": axes })
        }
        (true, Some(g)) if g.len() == 4 => json!({ "geometry": g }),
        (true, Some(g)) => {
            return Err(CliError::input(format!(
                "--geometry takes THETA_I,PHI_I,THETA_O,PHI_O (4 angles), not {} values",
                g.len()
            )));
        }
        _ => {
            return Err(CliError::input(
                "name the axes (AXIS=DEG ...) or a geometry (--geometry THETA_I,PHI_I,THETA_O,PHI_O), not both",
            ));
        }
    };
    let axes: Vec<AxisPosition> = post_motion(client, "/api/console/move", body).await?;
    println!("moved: {}", positions_line(&axes));
    Ok(())
}

pub(super) async fn jog(client: &Client, axis: &str, delta_deg: f64) -> Result<(), CliError> {
    let axes: Vec<AxisPosition> = post_motion(
        client,
        "/api/console/jog",
        json!({ "axis": axis, "delta_deg": delta_deg }),
    )
    .await?;
    println!("jogged {axis} by {delta_deg} deg: {}", positions_line(&axes));
    Ok(())
}

pub(super) async fn home(client: &Client, axis: Option<&str>) -> Result<(), CliError> {
    let body = match axis {
        Some(a) => json!({ "axis": a }),
        None => json!({}),
    };
    let state: InstrumentState = post_motion(client, "/api/console/home", body).await?;
    println!(
        "homed {}: {}",
        axis.unwrap_or("every axis"),
        state_positions(&state)
    );
    Ok(())
}

pub(super) async fn filter(client: &Client, choice: &str) -> Result<(), CliError> {
    let FilterMoved { position } =
        post_motion(client, "/api/console/filter", json!({ "filter": choice })).await?;
    println!("the wheel is at position {position}");
    Ok(())
}

pub(super) async fn state(client: &Client, as_json: bool) -> Result<(), CliError> {
    let s: InstrumentState = client.typed(Method::GET, "/api/console/state", None).await?;
    if as_json {
        let text = serde_json::to_string(&s)
            .map_err(|e| CliError::input(format!("cannot write the state as JSON: {e}")))?;
        println!("{text}");
    } else {
        print!("{}", state_text(&s));
    }
    Ok(())
}

/// The state for a person: one line per axis, the wheel, the meter, the devices.
pub(super) fn state_text(s: &InstrumentState) -> String {
    let mut out = String::new();
    let dry = if s.dry_run { " (simulated)" } else { "" };
    out.push_str(&format!("instrument {}{dry}\n", s.instrument));
    for a in &s.axes {
        let pos = a
            .position_deg
            .map(|p| format!("{p:>10.4} deg"))
            .unwrap_or_else(|| "         ? deg".into());
        let mut flags = Vec::new();
        if a.referenced == Some(false) {
            flags.push("not referenced".to_string());
        }
        if a.moving == Some(true) {
            flags.push("moving".to_string());
        }
        if let Some(f) = &a.fault {
            flags.push(format!("fault: {f}"));
        }
        let flags = if flags.is_empty() {
            String::new()
        } else {
            format!("  ({})", flags.join("; "))
        };
        out.push_str(&format!("  axis {:<10} {pos}{flags}\n", a.name));
    }
    if let Some(w) = &s.wheel {
        let p = w.position.map(|p| p.to_string()).unwrap_or("?".into());
        let band = w
            .band_nm
            .map(|b| format!("{b} nm"))
            .unwrap_or_else(|| "no band filter".into());
        out.push_str(&format!("  wheel at position {p} ({band})\n"));
    }
    match &s.meter {
        Some(m) => out.push_str(&format!("  meter {}\n", reading_text(m))),
        None => out.push_str("  meter: no reading\n"),
    }
    for d in &s.devices {
        let ok = if d.ok { "ok" } else { "NOT OK" };
        out.push_str(&format!("  device {:<8} {ok:<6} {}\n", d.name, d.identity));
    }
    out
}

/// One reading for a person: power, range, band and time.
pub(super) fn reading_text(r: &ConsoleReading) -> String {
    let band = r
        .band_nm
        .map(|b| format!("{b} nm"))
        .unwrap_or_else(|| format!("unfiltered, set for {} nm", r.wavelength_nm));
    let over = if r.overload { "  OVERLOAD" } else { "" };
    format!(
        "t {:.3} s  {:.6e} W  (range {:.1e} W, {band}){over}",
        r.t_s, r.power_w, r.range_w
    )
}

pub(super) async fn read(
    client: &Client,
    count: usize,
    stream: bool,
    interval_ms: u64,
) -> Result<(), CliError> {
    if !stream {
        let list: Vec<ConsoleReading> = client
            .typed(Method::GET, &format!("/api/console/read?count={count}"), None)
            .await?;
        for r in &list {
            println!("{}", reading_text(r));
        }
        return Ok(());
    }
    let path = format!("/api/console/readings?interval_ms={interval_ms}");
    let response = client.send(Method::GET, &path, None).await?;
    if !response.status().is_success() {
        let status = response.status();
        let body = collect(response).await?;
        return Err(server_error(status, &body));
    }
    let mut body = response.into_body();
    let mut buffer = String::new();
    let mut shown = 0usize;
    while shown < count {
        let frame = match tokio::time::timeout(STREAM_IDLE_TIMEOUT, body.frame()).await {
            Err(_) => {
                return Err(CliError::input(format!(
                    "no reading from {} for {} s: giving up",
                    client.authority,
                    STREAM_IDLE_TIMEOUT.as_secs()
                )));
            }
            Ok(None) => return Err(CliError::input("the daemon closed the reading stream")),
            Ok(Some(Err(e))) => return Err(CliError::input(format!("reading stream broken: {e}"))),
            Ok(Some(Ok(frame))) => frame,
        };
        let Ok(data) = frame.into_data() else { continue };
        buffer.push_str(&String::from_utf8_lossy(&data).replace('\r', ""));
        while let Some(end) = buffer.find("\n\n") {
            let block: String = buffer.drain(..end + 2).collect();
            let Some(item) =
                parse_sse_data(&block).and_then(|v| serde_json::from_value::<LiveReading>(v).ok())
            else {
                continue;
            };
            match item {
                LiveReading::Unavailable(u) => println!("(unavailable: {})", u.error),
                LiveReading::Reading(r) => {
                    println!("{}", reading_text(&r));
                    shown += 1;
                }
            }
            let _ = std::io::stdout().flush();
            if shown >= count {
                break;
            }
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn targets_are_axis_equals_degrees() {
        let t = parse_targets(&["detector=40".into(), "tilt = -2.5".into()]).expect("targets");
        assert_eq!(
            t,
            vec![("detector".to_string(), 40.0), ("tilt".to_string(), -2.5)]
        );
        assert!(parse_targets(&["detector:40".into()]).is_err());
        assert!(parse_targets(&["detector=forty".into()]).is_err());
    }

    #[test]
    fn a_state_reads_one_line_per_thing() {
        // As the daemon writes it: a renamed field on either side fails here or to compile.
        let s: InstrumentState = serde_json::from_value(json!({
            "instrument": "simulated", "dry_run": true,
            "axes": [{"name": "light", "role": "light-arm", "position_deg": -30.0, "referenced": true,
                      "moving": false, "fault": null, "min_deg": -100.0, "max_deg": 100.0},
                     {"name": "tilt", "role": "sample-tilt", "position_deg": null, "referenced": null,
                      "moving": null, "fault": "no status: timed out", "min_deg": -90.0, "max_deg": 90.0}],
            "wheel": {"position": 2, "band_nm": 450.0, "fault": null, "filters": []},
            "meter": {"t_s": 1.5, "unix_s": 0.0, "power_w": 1.25e-6, "range_w": 1e-5, "overload": false,
                      "wavelength_nm": 450.0, "band_nm": 450.0, "filter_position": 2, "axes": []},
            "devices": [{"name": "arms", "identity": "SMC100", "ok": true}]
        }))
        .expect("the daemon's state");
        let text = state_text(&s);
        assert!(text.contains("instrument simulated (simulated)"), "{text}");
        assert!(text.contains("axis light        -30.0000 deg"), "{text}");
        assert!(text.contains("fault: no status: timed out"), "{text}");
        assert!(text.contains("wheel at position 2 (450 nm)"), "{text}");
        assert!(text.contains("1.250000e-6 W"), "{text}");
        assert!(text.contains("device arms     ok"), "{text}");
    }
}
