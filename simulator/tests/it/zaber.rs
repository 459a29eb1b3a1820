//! Zaber ASCII conformance: addressing, message ids, checksums, OK/RJ reasons, warning flags, alerts, motion.

use crate::common;

use std::time::Duration;

use common::{Port, sim, sim_with};
use gonio_simulator::motion::trapezoid_time_s;
use gonio_simulator::zaber::lrc;

/// `/body:CC\n` with the documented LRC.
fn with_checksum(body: &str) -> String {
    format!("/{body}:{:02X}\n", lrc(body.as_bytes()))
}

/// A reply's checksum verifies: (sum of the bytes between the lead and ':' + cs) & 0xFF == 0.
fn checksum_ok(reply: &str) -> bool {
    let line = reply.trim_end();
    let Some((body, cs)) = line[1..].rsplit_once(':') else {
        return false;
    };
    let Ok(cs) = u8::from_str_radix(cs, 16) else {
        return false;
    };
    body.bytes().fold(cs, |s, b| s.wrapping_add(b)) == 0
}

async fn home_all(p: &mut Port, sim: &gonio_simulator::SimInstrument) {
    assert_eq!(
        p.query("/home\n").await.as_deref(),
        Some("@01 0 OK BUSY WR 0\r\n")
    );
    assert_eq!(p.line().await.as_deref(), Some("@02 0 OK BUSY WR 0\r\n"));
    sim.clock().sleep_s(2.0).await;
}

#[tokio::test(start_paused = true)]
async fn status_get_and_message_ids() {
    let sim = sim();
    let mut p = Port::open(&sim, "stage");
    assert_eq!(
        p.query("/1 0 get pos\n").await.as_deref(),
        Some("@01 0 OK IDLE WR 0\r\n")
    );
    assert_eq!(
        p.query("/1 1 12 get pos\n").await.as_deref(),
        Some("@01 1 12 OK IDLE WR 0\r\n")
    );
    assert_eq!(
        p.query("/2 get system.serial\n").await.as_deref(),
        Some("@02 0 OK IDLE WR 33002\r\n")
    );
    assert_eq!(
        p.query("/1 get system.axiscount\n").await.as_deref(),
        Some("@01 0 OK IDLE WR 1\r\n")
    );
    let r = p.query("/1 get comm.packet.size.max\n").await.expect("reply");
    assert!(
        r.starts_with("@01 0 OK IDLE WR ")
            && r.trim_end()
                .rsplit(' ')
                .next()
                .and_then(|v| v.parse::<u32>().ok())
                .is_some()
    );
    // maxspeed in data units: 30 deg/s / 0.000234375 deg per microstep * 1.6384.
    let expected = (30.0 / 0.000_234_375 * 1.6384f64).round();
    assert_eq!(
        p.query("/1 1 get maxspeed\n").await,
        Some(format!("@01 1 OK IDLE WR {expected}\r\n"))
    );
}

#[tokio::test(start_paused = true)]
async fn rejections_carry_the_documented_reasons() {
    let sim = sim();
    let mut p = Port::open(&sim, "stage");
    assert_eq!(
        p.query("/1 fly\n").await.as_deref(),
        Some("@01 0 RJ IDLE WR BADCOMMAND\r\n")
    );
    assert_eq!(
        p.query("/1 3 home\n").await.as_deref(),
        Some("@01 3 RJ IDLE WR BADAXIS\r\n")
    );
    assert_eq!(
        p.query("/1 1 get system.serial\n").await.as_deref(),
        Some("@01 1 RJ IDLE WR DEVICEONLY\r\n")
    );
    assert_eq!(
        p.query("/1 1 move abs x\n").await.as_deref(),
        Some("@01 1 RJ IDLE WR BADDATA\r\n")
    );
    // No reference position yet: every movement to a position is refused, relative ones too (the firmware-6
    // manual: `/move rel 10000` answered `@01 0 RJ IDLE WR BADDATA`).
    assert_eq!(
        p.query("/1 1 move abs 1000\n").await.as_deref(),
        Some("@01 1 RJ IDLE WR BADDATA\r\n")
    );
    assert_eq!(
        p.query("/1 move rel 10000\n").await.as_deref(),
        Some("@01 0 RJ IDLE WR BADDATA\r\n")
    );
    // Numbers may be written in hexadecimal.
    assert_eq!(
        p.query("/1 1 set maxspeed 0x2710\n").await.as_deref(),
        Some("@01 1 OK IDLE WR 0\r\n")
    );
    assert_eq!(
        p.query("/1 1 get maxspeed\n").await.as_deref(),
        Some("@01 1 OK IDLE WR 10000\r\n")
    );
    // The firmware-6 manual's identity values.
    assert_eq!(
        p.query("/1 get deviceid\n").await.as_deref(),
        Some("@01 0 OK IDLE WR 20022\r\n")
    );
    assert_eq!(
        p.query("/1 get version\n").await.as_deref(),
        Some("@01 0 OK IDLE WR 6.06\r\n")
    );
    assert_eq!(
        p.query("/1 get nonsense.setting\n").await.as_deref(),
        Some("@01 0 RJ IDLE WR BADCOMMAND\r\n")
    );
    // Nobody at device 7: silence.
    p.send(b"/7 get pos\n").await;
    assert!(p.silent_for(Duration::from_millis(200)).await);
}

#[tokio::test(start_paused = true)]
async fn checksums_are_verified_and_produced_on_request() {
    let sim = sim();
    let mut p = Port::open(&sim, "stage");
    assert_eq!(with_checksum("1 tools echo"), "/1 tools echo:BF\n");
    assert_eq!(
        p.query("/1 tools echo:BF\n").await.as_deref(),
        Some("@01 0 OK IDLE WR \r\n")
    );
    // A wrong checksum (the default variant): every device on the chain rejects it, with the message id.
    p.send(b"/1 tools echo:BE\n").await;
    assert_eq!(p.line().await.as_deref(), Some("@01 0 RJ IDLE -- BADDATA\r\n"));
    assert_eq!(p.line().await.as_deref(), Some("@02 0 RJ IDLE -- BADDATA\r\n"));
    assert!(p.silent_for(Duration::from_millis(200)).await);
    let mut bad = with_checksum("1 1 42 get pos");
    bad.replace_range(bad.len() - 3..bad.len() - 1, "00");
    p.send(bad.as_bytes()).await;
    assert_eq!(p.line().await.as_deref(), Some("@01 0 42 RJ IDLE -- BADDATA\r\n"));
    assert_eq!(p.line().await.as_deref(), Some("@02 0 42 RJ IDLE -- BADDATA\r\n"));
    // The other variant: the message is ignored.
    let quiet =
        sim_with(|f| f.simulator.quirks.zaber_bad_checksum = gonio_instrument::ZaberBadChecksum::Ignore);
    let mut q = Port::open(&quiet, "stage");
    q.send(b"/1 tools echo:BE\n").await;
    assert!(q.silent_for(Duration::from_millis(200)).await);
    let r = p
        .query(&with_checksum("2 0 5 get maxspeed"))
        .await
        .expect("reply");
    assert!(r.starts_with("@02 0 5 OK"), "{r}");
    // With comm.checksum 1 the device appends a valid checksum to its replies.
    assert!(
        p.query("/1 set comm.checksum 1\n")
            .await
            .expect("reply")
            .starts_with("@01 0 OK")
    );
    let r = p.query(&with_checksum("1 1 7 get pos")).await.expect("reply");
    assert!(r.starts_with("@01 1 7 OK IDLE WR 0:"), "{r}");
    assert!(checksum_ok(&r), "{r}");
}

#[tokio::test(start_paused = true)]
async fn broadcast_gets_one_reply_per_device_and_terminators_cr_lf_crlf() {
    let sim = sim();
    let mut p = Port::open(&sim, "stage");
    for term in ["\n", "\r", "\r\n"] {
        p.send(format!("/{term}").as_bytes()).await;
        assert_eq!(p.line().await.as_deref(), Some("@01 0 OK IDLE WR 0\r\n"));
        assert_eq!(p.line().await.as_deref(), Some("@02 0 OK IDLE WR 0\r\n"));
        assert!(
            p.silent_for(Duration::from_millis(50)).await,
            "no extra reply for {term:?}"
        );
    }
    // Split into single bytes, and two commands in one write.
    for b in b"/1 get pos\n" {
        p.send(&[*b]).await;
    }
    assert_eq!(p.line().await.as_deref(), Some("@01 0 OK IDLE WR 0\r\n"));
    p.send(b"/1 get pos\n/2 get pos\n").await;
    assert_eq!(p.line().await.as_deref(), Some("@01 0 OK IDLE WR 0\r\n"));
    assert_eq!(p.line().await.as_deref(), Some("@02 0 OK IDLE WR 0\r\n"));
    // Garbage before '/' is ignored; a DEL discards a partial command; a control byte discards it too.
    p.send(b"xyz/1 ge\x7f/1 get pos\n/1 g\x01et pos\n").await;
    assert_eq!(p.line().await.as_deref(), Some("@01 0 OK IDLE WR 0\r\n"));
    assert!(p.silent_for(Duration::from_millis(50)).await);
}

#[tokio::test(start_paused = true)]
async fn home_then_move_abs_takes_the_trapezoid_time_and_reports_microsteps() {
    let sim = sim();
    let mut p = Port::open(&sim, "stage");
    home_all(&mut p, &sim).await;
    assert_eq!(
        p.query("/1 1 get pos\n").await.as_deref(),
        Some("@01 1 OK IDLE -- 0\r\n"),
        "WR cleared by homing"
    );
    let steps = 128_000; // 30 deg
    let deg = f64::from(steps) * 0.000_234_375;
    let expected = trapezoid_time_s(deg, 30.0, 120.0);
    let t0 = sim.now_s();
    assert_eq!(
        p.query(&format!("/1 1 move abs {steps}\n")).await.as_deref(),
        Some("@01 1 OK BUSY -- 0\r\n")
    );
    sim.clock().sleep_until_s(t0 + expected - 0.01).await;
    assert!(
        p.query("/1 1 get pos\n")
            .await
            .expect("reply")
            .starts_with("@01 1 OK BUSY --")
    );
    sim.clock().sleep_until_s(t0 + expected + 0.01).await;
    assert_eq!(
        p.query("/1 1 get pos\n").await,
        Some(format!("@01 1 OK IDLE -- {steps}\r\n"))
    );
    assert!((sim.pose().tilt_deg - 30.0).abs() < 1e-9);
    // Out of the travel range: BADDATA.
    assert_eq!(
        p.query("/1 1 move abs 99999999\n").await.as_deref(),
        Some("@01 1 RJ IDLE -- BADDATA\r\n")
    );
}

#[tokio::test(start_paused = true)]
async fn alerts_when_enabled_and_ni_after_a_stop() {
    let sim = sim();
    let mut p = Port::open(&sim, "stage");
    home_all(&mut p, &sim).await;
    assert_eq!(
        p.query("/2 set comm.alert 1\n").await.as_deref(),
        Some("@02 0 OK IDLE -- 0\r\n")
    );
    assert!(
        p.query("/2 1 move abs 100000\n")
            .await
            .expect("reply")
            .starts_with("@02 1 OK BUSY")
    );
    // The alert comes when the move ends.
    let alert = p.read_until(b"\r\n", Duration::from_secs(5)).await;
    assert_eq!(alert.as_deref(), Some("!02 1 IDLE --\r\n"));
    assert!(
        p.query("/2 1 move abs 0\n")
            .await
            .expect("reply")
            .starts_with("@02 1 OK BUSY")
    );
    sim.clock().sleep_s(0.2).await;
    assert_eq!(
        p.query("/2 1 stop\n").await.as_deref(),
        Some("@02 1 OK BUSY NI 0\r\n")
    );
    let alert = p.read_until(b"\r\n", Duration::from_secs(5)).await;
    assert_eq!(alert.as_deref(), Some("!02 1 IDLE NI\r\n"));
    assert_eq!(
        p.query("/2 warnings\n").await.as_deref(),
        Some("@02 0 OK IDLE NI 01 NI\r\n")
    );
    assert_eq!(
        p.query("/2 warnings clear\n").await.as_deref(),
        // The data lists what was set; the status flag already shows the cleared state.
        Some("@02 0 OK IDLE -- 01 NI\r\n")
    );
    assert_eq!(
        p.query("/2 warnings\n").await.as_deref(),
        Some("@02 0 OK IDLE -- 00\r\n")
    );
}

#[tokio::test(start_paused = true)]
async fn stall_stops_short_idle_with_fs() {
    let sim = sim_with(|f| f.simulator.faults.stall_rate = 1.0);
    let mut p = Port::open(&sim, "stage");
    // Homing from the power-up position (the home) does not travel: no stall.
    home_all(&mut p, &sim).await;
    assert!(
        p.query("/1 1 move abs 100000\n")
            .await
            .expect("reply")
            .starts_with("@01 1 OK BUSY")
    );
    sim.clock().sleep_s(5.0).await;
    let r = p.query("/1 1 get pos\n").await.expect("reply");
    let pos: i64 = r
        .trim_end()
        .rsplit(' ')
        .next()
        .and_then(|v| v.parse().ok())
        .expect("position");
    assert!(r.starts_with("@01 1 OK IDLE FS"), "{r}");
    assert!((20_000..=80_000).contains(&pos), "stopped short: {pos}");
    assert_eq!(sim.fault_counts().stalls, 1);
    assert_eq!(
        p.query("/1 warnings clear\n").await.as_deref(),
        Some("@01 0 OK IDLE -- 01 FS\r\n")
    );
    assert_eq!(
        p.query("/1 warnings\n").await.as_deref(),
        Some("@01 0 OK IDLE -- 00\r\n")
    );
}

/// The position (microsteps) in a `get pos` reply.
fn reply_pos(reply: &str) -> i64 {
    reply
        .trim_end()
        .rsplit(' ')
        .next()
        .and_then(|v| v.parse().ok())
        .unwrap_or_else(|| panic!("no position in {reply:?}"))
}

#[tokio::test(start_paused = true)]
async fn move_vel_turns_at_the_commanded_speed_and_stops_at_the_travel_limit() {
    let sim = sim();
    let mut p = Port::open(&sim, "stage");
    home_all(&mut p, &sim).await;
    let ustep_deg = 0.000_234_375;
    // 10 deg/s in velocity data units (microsteps/s x 1.6384).
    let v_deg_s = 10.0;
    let data = (v_deg_s / ustep_deg * 1.6384f64).round() as i64;
    let t0 = sim.now_s();
    assert_eq!(
        p.query(&format!("/1 1 move vel {data}\n")).await.as_deref(),
        Some("@01 1 OK BUSY -- 0\r\n")
    );
    // Past the acceleration (v / a = 83 ms), two reads 1 s apart are v * 1 s apart. (Each read is handled
    // when its last byte has arrived, the same delay for both.)
    sim.clock().sleep_until_s(t0 + 1.0).await;
    let r = p.query("/1 1 get pos\n").await.expect("reply");
    assert!(r.starts_with("@01 1 OK BUSY --"), "{r}");
    let first = reply_pos(&r);
    assert!(
        first as f64 * ustep_deg > 0.9 * v_deg_s,
        "moving forward: {first}"
    );
    sim.clock().sleep_until_s(t0 + 2.0).await;
    let second = reply_pos(&p.query("/1 1 get pos\n").await.expect("reply"));
    // The data unit rounds the speed to 1/1.6384 microstep/s; positions round to a microstep.
    let travelled_deg = (second - first) as f64 * ustep_deg;
    assert!(
        (travelled_deg - v_deg_s).abs() < 2.0 * ustep_deg,
        "{travelled_deg} deg in 1 s, expected {v_deg_s}"
    );
    // `move vel 0` brings the axis to rest.
    assert!(
        p.query("/1 1 move vel 0\n")
            .await
            .expect("reply")
            .starts_with("@01 1 OK")
    );
    sim.clock().sleep_s(1.0).await;
    let r = p.query("/1 1 get pos\n").await.expect("reply");
    assert!(r.starts_with("@01 1 OK IDLE --"), "{r}");
    // Backwards: the device stops by itself at limit.min (-90 deg), without a limit warning.
    let limit_min = reply_pos(&p.query("/1 1 get limit.min\n").await.expect("reply"));
    assert!(
        p.query(&format!("/1 1 move vel -{data}\n"))
            .await
            .expect("reply")
            .starts_with("@01 1 OK BUSY")
    );
    sim.clock().sleep_s(15.0).await;
    assert_eq!(
        p.query("/1 1 get pos\n").await,
        Some(format!("@01 1 OK IDLE -- {limit_min}\r\n"))
    );
    assert!((sim.pose().tilt_deg + 90.0).abs() < 1e-9);
    assert_eq!(
        p.query("/1 1 move vel x\n").await.as_deref(),
        Some("@01 1 RJ IDLE -- BADDATA\r\n")
    );
}
