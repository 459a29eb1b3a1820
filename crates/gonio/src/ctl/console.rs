//! `gonio ctl`'s console commands: the instrument's state, moves (by axis or by geometry), jog, homing, the
//! wheel and the meter's readings, through the daemon's `/api/console` routes.

use std::io::Write as _;
use std::time::Duration;

use http_body_util::BodyExt;
use hyper::Method;
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

async fn post_motion(client: &Client, path: &str, body: Value) -> Result<Value, CliError> {
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
    serde_json::from_slice(&bytes)
        .map_err(|e| CliError::input(format!("the reply to {path} is not JSON: {e}")))
}

fn positions_line(axes: &Value) -> String {
    axes.as_array()
        .map(|list| {
            list.iter()
                .map(|a| {
                    let name = a.get("name").and_then(Value::as_str).unwrap_or("?");
                    match a.get("position_deg").and_then(Value::as_f64) {
                        Some(p) => format!("{name} {p:.4} deg"),
                        None => format!("{name} ?"),
                    }
                })
                .collect::<Vec<_>>()
                .join(", ")
        })
        .unwrap_or_default()
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
    let axes = post_motion(client, "/api/console/move", body).await?;
    println!("moved: {}", positions_line(&axes));
    Ok(())
}

pub(super) async fn jog(client: &Client, axis: &str, delta_deg: f64) -> Result<(), CliError> {
    let axes = post_motion(
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
    let state = post_motion(client, "/api/console/home", body).await?;
    println!(
        "homed {}: {}",
        axis.unwrap_or("every axis"),
        positions_line(state.get("axes").unwrap_or(&Value::Null))
    );
    Ok(())
}

pub(super) async fn filter(client: &Client, choice: &str) -> Result<(), CliError> {
    let answer = post_motion(client, "/api/console/filter", json!({ "filter": choice })).await?;
    let position = answer.get("position").and_then(Value::as_u64).unwrap_or(0);
    println!("the wheel is at position {position}");
    Ok(())
}

pub(super) async fn state(client: &Client, as_json: bool) -> Result<(), CliError> {
    let s = client.json(Method::GET, "/api/console/state", None).await?;
    if as_json {
        println!("{s}");
    } else {
        print!("{}", state_text(&s));
    }
    Ok(())
}

/// The state for a person: one line per axis, the wheel, the meter, the devices.
pub(super) fn state_text(s: &Value) -> String {
    let mut out = String::new();
    let name = s.get("instrument").and_then(Value::as_str).unwrap_or("?");
    let dry = if s.get("dry_run").and_then(Value::as_bool) == Some(true) {
        " (simulated)"
    } else {
        ""
    };
    out.push_str(&format!("instrument {name}{dry}\n"));
    for a in s.get("axes").and_then(Value::as_array).into_iter().flatten() {
        let n = a.get("name").and_then(Value::as_str).unwrap_or("?");
        let pos = a
            .get("position_deg")
            .and_then(Value::as_f64)
            .map(|p| format!("{p:>10.4} deg"))
            .unwrap_or_else(|| "         ? deg".into());
        let mut flags = Vec::new();
        if a.get("referenced").and_then(Value::as_bool) == Some(false) {
            flags.push("not referenced".to_string());
        }
        if a.get("moving").and_then(Value::as_bool) == Some(true) {
            flags.push("moving".to_string());
        }
        if let Some(f) = a.get("fault").and_then(Value::as_str) {
            flags.push(format!("fault: {f}"));
        }
        let flags = if flags.is_empty() {
            String::new()
        } else {
            format!("  ({})", flags.join("; "))
        };
        out.push_str(&format!("  axis {n:<10} {pos}{flags}\n"));
    }
    if let Some(w) = s.get("wheel").filter(|w| !w.is_null()) {
        let p = w
            .get("position")
            .and_then(Value::as_u64)
            .map(|p| p.to_string())
            .unwrap_or("?".into());
        let band = w
            .get("band_nm")
            .and_then(Value::as_f64)
            .map(|b| format!("{b} nm"))
            .unwrap_or_else(|| "no band filter".into());
        out.push_str(&format!("  wheel at position {p} ({band})\n"));
    }
    match s.get("meter").filter(|m| !m.is_null()) {
        Some(m) => out.push_str(&format!("  meter {}\n", reading_text(m))),
        None => out.push_str("  meter: no reading\n"),
    }
    for d in s.get("devices").and_then(Value::as_array).into_iter().flatten() {
        let ok = if d.get("ok").and_then(Value::as_bool) == Some(true) {
            "ok"
        } else {
            "NOT OK"
        };
        out.push_str(&format!(
            "  device {:<8} {ok:<6} {}\n",
            d.get("name").and_then(Value::as_str).unwrap_or("?"),
            d.get("identity").and_then(Value::as_str).unwrap_or("?")
        ));
    }
    out
}

/// One reading for a person: power, range, band and time.
pub(super) fn reading_text(r: &Value) -> String {
    let f = |k: &str| r.get(k).and_then(Value::as_f64).unwrap_or(f64::NAN);
    let band = r
        .get("band_nm")
        .and_then(Value::as_f64)
        .map(|b| format!("{b} nm"))
        .unwrap_or_else(|| format!("unfiltered, set for {} nm", f("wavelength_nm")));
    let over = if r.get("overload").and_then(Value::as_bool) == Some(true) {
        "  OVERLOAD"
    } else {
        ""
    };
    format!(
        "t {:.3} s  {:.6e} W  (range {:.1e} W, {band}){over}",
        f("t_s"),
        f("power_w"),
        f("range_w")
    )
}

pub(super) async fn read(
    client: &Client,
    count: usize,
    stream: bool,
    interval_ms: u64,
) -> Result<(), CliError> {
    if !stream {
        let list = client
            .json(Method::GET, &format!("/api/console/read?count={count}"), None)
            .await?;
        for r in list.as_array().into_iter().flatten() {
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
            let Some(v) = parse_sse_data(&block) else { continue };
            match v.get("error").and_then(Value::as_str) {
                Some(e) => println!("(unavailable: {e})"),
                None => {
                    println!("{}", reading_text(&v));
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
        let s = json!({
            "instrument": "simulated", "dry_run": true,
            "axes": [{"name": "light", "position_deg": -30.0, "referenced": true, "moving": false},
                     {"name": "tilt", "position_deg": null, "fault": "no status: timed out"}],
            "wheel": {"position": 2, "band_nm": 450.0},
            "meter": {"t_s": 1.5, "power_w": 1.25e-6, "range_w": 1e-5, "wavelength_nm": 450.0, "band_nm": 450.0},
            "devices": [{"name": "arms", "identity": "SMC100", "ok": true}]
        });
        let text = state_text(&s);
        assert!(text.contains("instrument simulated (simulated)"), "{text}");
        assert!(text.contains("axis light        -30.0000 deg"), "{text}");
        assert!(text.contains("fault: no status: timed out"), "{text}");
        assert!(text.contains("wheel at position 2 (450 nm)"), "{text}");
        assert!(text.contains("1.250000e-6 W"), "{text}");
        assert!(text.contains("device arms     ok"), "{text}");
    }
}
