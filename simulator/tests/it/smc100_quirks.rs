//! SMC100 conformance beyond the manual's motion subset: the whole command list (TB, parameters, ZT, SE, RS##),
//! the replies real controllers were recorded giving (VE, TP decimals), and both variants of the recorded quirks:
//! on the ideal instrument (the manual's behaviour, the defaults) every line is taken and every TS answered; under
//! the recorded variants (config/instruments/realistic.toml) input sent too soon is lost and the TS after power-up
//! and after homing gets no reply.

use crate::common;

use std::time::Duration;

use common::{Port, recorded_quirks, sim, sim_scaled, sim_with};

/// The manual's controller (no pacing, every TS answered), for the command-list checks.
fn manual() -> gonio_simulator::SimInstrument {
    sim_with(|f| {
        f.simulator.quirks.smc100_min_command_gap_ms = 0.0;
        f.simulator.quirks.smc100_drop_first_ts = false;
    })
}

/// A host that paces its commands: 100 ms after each line.
async fn paced(p: &mut Port, sim: &gonio_simulator::SimInstrument, line: &str) -> Option<String> {
    sim.clock().sleep_s(0.1).await;
    p.send(line.as_bytes()).await;
    p.read_until(b"\n", Duration::from_millis(300)).await
}

async fn home(p: &mut Port, sim: &gonio_simulator::SimInstrument, addr: u8) {
    p.send(format!("{addr}OR\r\n").as_bytes()).await;
    sim.clock().sleep_s(5.0).await;
    assert_eq!(
        p.query(&format!("{addr}TS\r\n")).await,
        Some(format!("{addr}TS000032\r\n"))
    );
}

#[tokio::test(start_paused = true)]
async fn tb_prints_the_error_string() {
    let sim = manual();
    let mut p = Port::open(&sim, "arms");
    assert_eq!(
        p.query("1TBH\r\n").await.as_deref(),
        Some("1TBH Command not allowed in NOT REFERENCED state.\r\n")
    );
    // Without a letter: the last command's error, cleared as TE clears it.
    p.send(b"1PA10\r\n").await;
    assert_eq!(
        p.query("1TB\r\n").await.as_deref(),
        Some("1TBH Command not allowed in NOT REFERENCED state.\r\n")
    );
    assert_eq!(p.query("1TB?\r\n").await.as_deref(), Some("1TB@ No error\r\n"));
    p.send(b"1XY\r\n").await;
    assert_eq!(
        p.query("1TB\r\n").await.as_deref(),
        Some("1TBA Unknown message code or floating point controller address.\r\n")
    );
}

#[tokio::test(start_paused = true)]
async fn every_command_of_the_manual_is_known() {
    let sim = manual();
    let mut p = Port::open(&sim, "arms");
    // Parameters answer a query; none is an unknown command (A).
    for code in [
        "AC", "BA", "BH", "FD", "FE", "FF", "HT", "ID", "JM", "JR", "KD", "KI", "KP", "KV", "OH", "OT", "PA",
        "PW", "QI", "SA", "SB", "SC", "SE", "SL", "SR", "SU", "VA", "ZX", "MM",
    ] {
        let r = p.query(&format!("1{code}?\r\n")).await;
        assert!(
            r.as_deref().is_some_and(|r| r.starts_with(&format!("1{code}"))),
            "{code}: {r:?}"
        );
        assert_eq!(p.query("1TE\r\n").await.as_deref(), Some("1TE@\r\n"), "{code}");
    }
    for code in ["TE", "TH", "TP", "TS", "VE", "RA", "RB"] {
        let r = p.query(&format!("1{code}\r\n")).await;
        assert!(r.is_some_and(|r| r.starts_with(&format!("1{code}"))), "{code}");
    }
    // Stepper-only commands on this CC controller: X.
    for code in ["DV", "FR", "VB"] {
        p.send(format!("1{code}?\r\n").as_bytes()).await;
        assert_eq!(p.query("1TE\r\n").await.as_deref(), Some("1TEX\r\n"), "{code}");
    }
    // Configuration-only parameters are refused outside CONFIGURATION, taken inside it.
    p.send(b"1HT2\r\n").await;
    assert_eq!(p.query("1TE\r\n").await.as_deref(), Some("1TEH\r\n"));
    p.send(b"1PW1\r\n1HT2\r\n1BA0.005\r\n1ZX1\r\n").await;
    assert_eq!(p.query("1TE\r\n").await.as_deref(), Some("1TE@\r\n"));
    assert_eq!(p.query("1HT?\r\n").await.as_deref(), Some("1HT2\r\n"));
    p.send(b"1HT9\r\n").await;
    assert_eq!(
        p.query("1TE\r\n").await.as_deref(),
        Some("1TEC\r\n"),
        "out of range"
    );
    // ZT lists the parameters, one line each.
    p.send(b"1ZT\r\n").await;
    let mut lines = Vec::new();
    while let Some(l) = p.read_until(b"\n", Duration::from_millis(50)).await {
        lines.push(l);
    }
    assert!(lines.contains(&"1BA0.005\r\n".to_string()), "{lines:?}");
    assert!(lines.contains(&"1HT2\r\n".to_string()), "{lines:?}");
    assert!(lines.iter().all(|l| l.starts_with('1') && l.ends_with("\r\n")));
    // Gains may be set outside CONFIGURATION.
    sim.clock().sleep_s(0.0).await;
    p.send(b"2KP12.5\r\n").await;
    assert_eq!(p.query("2KP?\r\n").await.as_deref(), Some("2KP12.5\r\n"));
    // RS## resets the controller (and its address to 1).
    p.send(b"2RS##\r\n").await;
    sim.clock().sleep_s(3.0).await;
    assert_eq!(p.query("2TS\r\n").await.as_deref(), Some("2TS00000A\r\n"));
}

#[tokio::test(start_paused = true)]
async fn se_starts_both_axes_at_once() {
    let sim = manual();
    let mut p = Port::open(&sim, "arms");
    home(&mut p, &sim, 1).await;
    home(&mut p, &sim, 2).await;
    p.send(b"1SE10\r\n2SE-10\r\n").await;
    sim.clock().sleep_s(0.2).await;
    assert_eq!(
        p.query("1TS\r\n").await.as_deref(),
        Some("1TS000032\r\n"),
        "stored, not started"
    );
    p.send(b"SE\r\n").await;
    assert_eq!(p.query("1TS\r\n").await.as_deref(), Some("1TS000028\r\n"));
    assert_eq!(p.query("2TS\r\n").await.as_deref(), Some("2TS000028\r\n"));
    sim.clock().sleep_s(3.0).await;
    assert!((sim.pose().light_deg - 10.0).abs() < 0.02);
    assert!((sim.pose().detector_deg + 10.0).abs() < 0.02);
}

#[tokio::test(start_paused = true)]
async fn ve_and_tp_look_like_a_real_controller() {
    let sim = manual();
    let mut p = Port::open(&sim, "arms");
    assert_eq!(
        p.query("1VE\r\n").await.as_deref(),
        Some("1VE SMC_CC - Controller-driver version  3. 1. 2\r\n")
    );
    home(&mut p, &sim, 1).await;
    // The set-point keeps more than six decimals (up to ten); TP shows the encoder's steps of 0.0005.
    p.send(b"1PA12.34567891\r\n").await;
    sim.clock().sleep_s(3.0).await;
    assert_eq!(p.query("1TH\r\n").await.as_deref(), Some("1TH12.34567891\r\n"));
    assert_eq!(p.query("1TP\r\n").await.as_deref(), Some("1TP12.3455\r\n"));
    p.send(b"1PA-1.000000000049\r\n").await;
    sim.clock().sleep_s(3.0).await;
    assert_eq!(
        p.query("1TH\r\n").await.as_deref(),
        Some("1TH-1\r\n"),
        "rounded to ten decimals"
    );
}

#[tokio::test(start_paused = true)]
async fn commands_sent_in_a_burst_are_lost_and_paced_ones_are_taken() {
    let sim = sim_with(|f| {
        recorded_quirks(f);
        f.simulator.quirks.smc100_drop_first_ts = false;
    });
    let mut p = Port::open(&sim, "arms");
    // Two queries to one controller in one write: the second arrives while the first's reply is still on
    // the line. To two controllers: each has its own processor, both answer.
    p.send(b"1TS\r\n1TS\r\n").await;
    assert_eq!(p.line().await.as_deref(), Some("1TS00000A\r\n"));
    assert!(
        p.silent_for(Duration::from_millis(300)).await,
        "the second query was lost"
    );
    p.send(b"1TS\r\n2TS\r\n").await;
    assert_eq!(p.line().await.as_deref(), Some("1TS00000A\r\n"));
    assert_eq!(p.line().await.as_deref(), Some("2TS00000A\r\n"));
    // A set command then TE at once: TE is lost; 60 ms later it is taken.
    p.send(b"1PA10\r\n1TE\r\n").await;
    assert!(p.silent_for(Duration::from_millis(300)).await);
    p.send(b"1PA10\r\n").await;
    assert!(p.silent_for(Duration::from_millis(10)).await);
    p.send(b"1TE\r\n").await;
    assert!(
        p.silent_for(Duration::from_millis(100)).await,
        "within 60 ms of the set command: lost"
    );
    assert_eq!(paced(&mut p, &sim, "1TE\r\n").await.as_deref(), Some("1TEH\r\n"));
    // A host that waits for each reply before the next query is never refused.
    for _ in 0..5 {
        assert_eq!(p.query("1TS\r\n").await.as_deref(), Some("1TS00000A\r\n"));
    }
}

/// At a large time scale a short reply's wire time is microseconds of real time, which tokio's timer cannot
/// wait: the session writes it at once. A host answering the moment it has the reply is not too early (it
/// cannot be: it has the whole reply), so no query of a host that waits for each reply is ever lost, and a set
/// command still keeps its controller busy for its 60 ms.
#[tokio::test(start_paused = true)]
async fn at_a_large_time_scale_a_host_waiting_for_each_reply_loses_nothing() {
    let sim = sim_scaled(
        |f| {
            recorded_quirks(f);
            f.simulator.quirks.smc100_drop_first_ts = false;
        },
        1000.0,
    );
    let mut p = Port::open(&sim, "arms");
    for _ in 0..20 {
        assert_eq!(p.query("1TS\r\n").await.as_deref(), Some("1TS00000A\r\n"));
        assert_eq!(p.query("1TP\r\n").await.as_deref(), Some("1TP0\r\n"));
        assert_eq!(p.query("2TS\r\n").await.as_deref(), Some("2TS00000A\r\n"));
    }
    assert_eq!(sim.lost_input_lines(), 0);
    // A set command: 60 simulated ms, 60 us of tokio time here.
    p.send(b"1PA10\r\n").await;
    tokio::time::advance(Duration::from_micros(30)).await;
    p.send(b"1TE\r\n").await;
    assert!(p.silent_for(Duration::from_millis(1)).await, "30 ms after: lost");
    assert_eq!(sim.lost_input_lines(), 1);
    sim.clock().sleep_s(0.061).await;
    assert_eq!(p.query("1TE\r\n").await.as_deref(), Some("1TEH\r\n"));
}

#[tokio::test(start_paused = true)]
async fn first_ts_after_power_up_and_after_homing_gets_no_reply() {
    let sim = sim_with(|f| {
        recorded_quirks(f);
        f.simulator.quirks.smc100_min_command_gap_ms = 0.0;
    });
    let mut p = Port::open(&sim, "arms");
    p.send(b"1TS\r\n").await;
    assert!(
        p.silent_for(Duration::from_millis(300)).await,
        "first TS after power-up: no reply"
    );
    assert_eq!(p.query("1TS\r\n").await.as_deref(), Some("1TS00000A\r\n"));
    p.send(b"1OR\r\n").await;
    assert_eq!(p.query("1TS\r\n").await.as_deref(), Some("1TS00001E\r\n"));
    sim.clock().sleep_s(5.0).await;
    p.send(b"1TS\r\n").await;
    assert!(
        p.silent_for(Duration::from_millis(300)).await,
        "first TS after homing: no reply"
    );
    assert_eq!(p.query("1TS\r\n").await.as_deref(), Some("1TS000032\r\n"));
    // Only the first: the next ones are answered.
    assert_eq!(p.query("1TS\r\n").await.as_deref(), Some("1TS000032\r\n"));
}

/// The ideal instrument, as config/instruments/simulated.toml and the defaults make it: a host that queries
/// right after a set command, sends queries in a burst, or asks TS first after power-up and after homing (as
/// QuTech's QMI driver and a host following the manual do) gets every reply, and no line is lost.
#[tokio::test(start_paused = true)]
async fn on_the_ideal_instrument_every_line_is_taken_and_every_ts_answered() {
    let sim = sim();
    let mut p = Port::open(&sim, "arms");
    assert_eq!(
        p.query("1TS\r\n").await.as_deref(),
        Some("1TS00000A\r\n"),
        "first TS after power-up"
    );
    // A set command and the query after it in one write, then two queries in one write.
    p.send(b"1PA10\r\n1TE\r\n").await;
    assert_eq!(p.line().await.as_deref(), Some("1TEH\r\n"));
    p.send(b"1TS\r\n1TS\r\n2TS\r\n").await;
    assert_eq!(p.line().await.as_deref(), Some("1TS00000A\r\n"));
    assert_eq!(p.line().await.as_deref(), Some("1TS00000A\r\n"));
    assert_eq!(p.line().await.as_deref(), Some("2TS00000A\r\n"));
    // Homing, then TS the moment it is done.
    p.send(b"1OR\r\n1TS\r\n").await;
    assert_eq!(p.line().await.as_deref(), Some("1TS00001E\r\n"));
    sim.clock().sleep_s(5.0).await;
    assert_eq!(
        p.query("1TS\r\n").await.as_deref(),
        Some("1TS000032\r\n"),
        "first TS after homing"
    );
    // A move and its position query at once.
    p.send(b"1PA10\r\n1TE\r\n").await;
    assert_eq!(p.line().await.as_deref(), Some("1TE@\r\n"));
    assert_eq!(sim.lost_input_lines(), 0);
}

/// The same host on the recorded variants (config/instruments/realistic.toml): the first TS after power-up and
/// the query right after a set command get no reply, and the lost line is counted.
#[tokio::test(start_paused = true)]
async fn under_the_recorded_variants_the_same_host_loses_those_replies() {
    let sim = sim_with(recorded_quirks);
    let mut p = Port::open(&sim, "arms");
    p.send(b"1TS\r\n").await;
    assert!(
        p.silent_for(Duration::from_millis(300)).await,
        "first TS after power-up: no reply"
    );
    assert_eq!(p.query("1TS\r\n").await.as_deref(), Some("1TS00000A\r\n"));
    sim.clock().sleep_s(0.1).await;
    p.send(b"1PA10\r\n1TE\r\n").await;
    assert!(
        p.silent_for(Duration::from_millis(300)).await,
        "TE right after the set command: lost"
    );
    assert_eq!(sim.lost_input_lines(), 1);
}
