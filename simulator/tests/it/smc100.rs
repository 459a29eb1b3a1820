//! SMC100 conformance: the documented command set, state machine, TE letters, TS bits, framing and motion time.

use crate::common;

use std::time::Duration;

use common::Port;

/// The controller as the manual describes it: no input pacing, every TS answered (the recorded real-device
/// variants are tested in smc100_quirks.rs).
fn sim_with(f: impl FnOnce(&mut gonio_instrument::InstrumentFile)) -> gonio_simulator::SimInstrument {
    common::sim_with(|file| {
        file.simulator.quirks.smc100_min_command_gap_ms = 0.0;
        file.simulator.quirks.smc100_drop_first_ts = false;
        f(file);
    })
}

fn sim() -> gonio_simulator::SimInstrument {
    sim_with(|_| {})
}
use gonio_simulator::motion::trapezoid_time_s;

async fn home(port: &mut Port, sim: &gonio_simulator::SimInstrument, addr: u8) {
    port.send(format!("{addr}OR\r\n").as_bytes()).await;
    for _ in 0..200 {
        let ts = port.query(&format!("{addr}TS\r\n")).await.expect("TS reply");
        if ts.ends_with("32\r\n") {
            return;
        }
        sim.clock().sleep_s(0.1).await;
    }
    panic!("controller {addr} never became READY after homing");
}

#[tokio::test(start_paused = true)]
async fn move_while_not_referenced_is_error_h_and_homing_goes_through_homing_to_ready() {
    let sim = sim();
    let mut p = Port::open(&sim, "arms");
    assert_eq!(p.query("1TS\r\n").await.as_deref(), Some("1TS00000A\r\n"));
    // Set commands are silent; the error is fetched with TE, which then reads '@'.
    p.send(b"1PA10\r\n").await;
    assert!(p.silent_for(Duration::from_millis(100)).await);
    assert_eq!(p.query("1TE\r\n").await.as_deref(), Some("1TEH\r\n"));
    assert_eq!(p.query("1TE\r\n").await.as_deref(), Some("1TE@\r\n"));
    p.send(b"1OR\r\n").await;
    assert_eq!(p.query("1TS\r\n").await.as_deref(), Some("1TS00001E\r\n"));
    // OR again while homing: E (home sequence already started).
    p.send(b"1OR\r\n").await;
    assert_eq!(p.query("1TE\r\n").await.as_deref(), Some("1TEE\r\n"));
    sim.clock().sleep_s(5.0).await;
    assert_eq!(p.query("1TS\r\n").await.as_deref(), Some("1TS000032\r\n"));
    // OR in READY: K.
    p.send(b"1OR\r\n").await;
    assert_eq!(p.query("1TE\r\n").await.as_deref(), Some("1TEK\r\n"));
    // Controller 2 is untouched.
    assert_eq!(p.query("2TS\r\n").await.as_deref(), Some("2TS00000A\r\n"));
}

#[tokio::test(start_paused = true)]
async fn move_takes_the_trapezoid_time_and_ends_ready_from_moving_at_the_target() {
    let sim = sim();
    let mut p = Port::open(&sim, "arms");
    home(&mut p, &sim, 1).await;
    let axis = &sim.file().instrument.axes[0];
    let (v, a) = (axis.max_speed_deg_s, axis.accel_deg_s2);
    let expected = trapezoid_time_s(30.0, v, a);
    // The controller's own estimate agrees.
    let pt = p.query("1PT30\r\n").await.expect("PT reply");
    let pt: f64 = pt
        .trim_end()
        .strip_prefix("1PT")
        .expect("prefix")
        .parse()
        .expect("number");
    assert!((pt - expected).abs() < 1e-5, "PT {pt} vs {expected}");
    let t0 = sim.now_s();
    p.send(b"1PA30\r\n").await;
    assert_eq!(p.query("1TS\r\n").await.as_deref(), Some("1TS000028\r\n"));
    sim.clock().sleep_until_s(t0 + expected - 0.01).await;
    assert_eq!(
        p.query("1TS\r\n").await.as_deref(),
        Some("1TS000028\r\n"),
        "still moving just before the end"
    );
    let tp: f64 = p.query("1TP\r\n").await.expect("TP")[3..]
        .trim_end()
        .parse()
        .expect("number");
    assert!(tp < 30.0 && tp > 29.9, "{tp}");
    sim.clock().sleep_until_s(t0 + expected + 0.01).await;
    assert_eq!(
        p.query("1TS\r\n").await.as_deref(),
        Some("1TS000033\r\n"),
        "READY from MOVING just after"
    );
    assert_eq!(p.query("1TP\r\n").await.as_deref(), Some("1TP30\r\n"));
    assert!((sim.pose().light_deg - 30.0).abs() < 1e-12);
}

#[tokio::test(start_paused = true)]
async fn axes_on_the_chain_move_simultaneously() {
    let sim = sim();
    let mut p = Port::open(&sim, "arms");
    home(&mut p, &sim, 1).await;
    home(&mut p, &sim, 2).await;
    let t0 = sim.now_s();
    p.send(b"1PA40\r\n2PA-20\r\n").await;
    let t1 = trapezoid_time_s(40.0, 20.0, 80.0);
    sim.clock().sleep_until_s(t0 + t1 + 0.01).await;
    let pose = sim.pose();
    // The detector arm approached from above: its load lags by the backlash (0.01 deg).
    assert_eq!(pose.light_deg, 40.0);
    assert!((pose.detector_deg + 19.99).abs() < 1e-12, "{}", pose.detector_deg);
}

#[tokio::test(start_paused = true)]
async fn backlash_shows_on_the_load_not_on_the_encoder_when_approaching_from_above() {
    let sim = sim();
    let mut p = Port::open(&sim, "arms");
    home(&mut p, &sim, 1).await;
    p.send(b"1PA10\r\n").await;
    sim.clock().sleep_s(2.0).await;
    assert_eq!(p.query("1TP\r\n").await.as_deref(), Some("1TP10\r\n"));
    p.send(b"1PA5\r\n").await;
    sim.clock().sleep_s(2.0).await;
    // backlash 0.01 deg: the load stays 0.01 high. The servo holds the motor-side encoder on the set-point: in
    // READY, TP equals it (the manual: "equal or very close to the set point").
    assert_eq!(p.query("1TP\r\n").await.as_deref(), Some("1TP5\r\n"));
    assert_eq!(p.query("1TH\r\n").await.as_deref(), Some("1TH5\r\n"));
    assert!((sim.pose().light_deg - 5.01).abs() < 1e-9);
}

#[tokio::test(start_paused = true)]
async fn software_limits_refuse_and_hardware_limit_switch_stops_the_axis() {
    let sim = sim();
    let mut p = Port::open(&sim, "arms");
    home(&mut p, &sim, 1).await;
    assert_eq!(p.query("1SR?\r\n").await.as_deref(), Some("1SR100\r\n"));
    p.send(b"1PA150\r\n").await;
    assert_eq!(
        p.query("1TE\r\n").await.as_deref(),
        Some("1TEG\r\n"),
        "beyond the software limit"
    );
    // Widen the software limit past the switch: the move runs into the positive end of run.
    p.send(b"1SR200\r\n").await;
    assert_eq!(p.query("1TE\r\n").await.as_deref(), Some("1TE@\r\n"));
    p.send(b"1PA150\r\n").await;
    sim.clock().sleep_s(10.0).await;
    assert_eq!(
        p.query("1TS\r\n").await.as_deref(),
        Some("1TS00020F\r\n"),
        "end of run, NOT REFERENCED from MOVING"
    );
    assert_eq!(p.query("1TP\r\n").await.as_deref(), Some("1TP100\r\n"));
}

#[tokio::test(start_paused = true)]
async fn stall_ends_in_disable_from_moving_with_a_following_error() {
    let sim = sim_with(|f| f.simulator.faults.stall_rate = 1.0);
    let mut p = Port::open(&sim, "arms");
    // The axis powers up at the home position: homing does not travel, so nothing can stall.
    home(&mut p, &sim, 1).await;
    assert_eq!(sim.fault_counts().stalls, 0);
    p.send(b"1PA30\r\n").await;
    sim.clock().sleep_s(5.0).await;
    assert_eq!(p.query("1TS\r\n").await.as_deref(), Some("1TS00203D\r\n"));
    let tp: f64 = p.query("1TP\r\n").await.expect("TP")[3..]
        .trim_end()
        .parse()
        .expect("num");
    assert!(
        tp > 0.2 * 30.0 - 1e-3 && tp < 0.8 * 30.0 + 1e-3,
        "stopped short: {tp}"
    );
    assert_eq!(sim.fault_counts().stalls, 1);
}

#[tokio::test(start_paused = true)]
async fn stalled_move_leaves_disable_from_moving_and_mm1_recovers() {
    let sim = sim_with(|f| f.simulator.faults.stall_rate = 0.5);
    let mut p = Port::open(&sim, "arms");
    // Retry homing until it succeeds (some homing attempts stall by design of the fault).
    let mut homed = false;
    for _ in 0..20 {
        p.send(b"1OR\r\n").await;
        sim.clock().sleep_s(5.0).await;
        if p.query("1TS\r\n").await.as_deref() == Some("1TS000032\r\n") {
            homed = true;
            break;
        }
    }
    assert!(homed);
    let mut stalled = false;
    for k in 0..40 {
        let before = sim.fault_counts().stalls;
        let target = if k % 2 == 0 { 50 } else { 0 };
        p.send(format!("1PA{target}\r\n").as_bytes()).await;
        sim.clock().sleep_s(5.0).await;
        let ts = p.query("1TS\r\n").await.expect("TS");
        if sim.fault_counts().stalls > before {
            assert_eq!(ts, "1TS00203D\r\n", "following error + DISABLE from MOVING");
            let tp: f64 = p.query("1TP\r\n").await.expect("TP")[3..]
                .trim_end()
                .parse()
                .expect("num");
            assert!((tp - f64::from(target)).abs() > 1.0, "stopped short: {tp}");
            // PA in DISABLE: J; MM1 back to READY from DISABLE.
            p.send(b"1PA10\r\n").await;
            assert_eq!(p.query("1TE\r\n").await.as_deref(), Some("1TEJ\r\n"));
            p.send(b"1MM1\r\n").await;
            assert_eq!(p.query("1TS\r\n").await.as_deref(), Some("1TS000034\r\n"));
            stalled = true;
            break;
        }
        assert_eq!(ts, "1TS000033\r\n");
    }
    assert!(stalled, "a 50 % stall rate stalls within 40 moves");
}

#[tokio::test(start_paused = true)]
async fn addressing_unknown_commands_and_malformed_input() {
    let sim = sim();
    let mut p = Port::open(&sim, "arms");
    // Nobody at address 5: no answer at all.
    p.send(b"5TS\r\n").await;
    assert!(p.silent_for(Duration::from_millis(200)).await);
    // No address: error B on the first controller.
    p.send(b"TS\r\n").await;
    assert!(p.silent_for(Duration::from_millis(100)).await);
    assert_eq!(p.query("1TE\r\n").await.as_deref(), Some("1TEB\r\n"));
    // Unknown command code: A.
    p.send(b"1XY\r\n").await;
    assert_eq!(p.query("1TE\r\n").await.as_deref(), Some("1TEA\r\n"));
    // Bad argument: C.
    p.send(b"1VAfast\r\n").await;
    assert_eq!(p.query("1TE\r\n").await.as_deref(), Some("1TEC\r\n"));
    // Garbage bytes, an overlong line and lone terminators never crash the controller.
    p.send(&[0xff, 0x00, 0x11, 0x13, b'\r', b'\n', b'\n']).await;
    p.send(&vec![b'9'; 5000]).await;
    p.send(b"\r\n").await;
    assert_eq!(p.query("1TS\r\n").await.as_deref(), Some("1TS00000A\r\n"));
    // Two-digit address form.
    assert_eq!(p.query("01TS\r\n").await.as_deref(), Some("01TS00000A\r\n"));
}

#[tokio::test(start_paused = true)]
async fn split_and_merged_packets() {
    let sim = sim();
    let mut p = Port::open(&sim, "arms");
    for b in b"1TS\r\n" {
        p.send(&[*b]).await;
        tokio::task::yield_now().await;
    }
    assert_eq!(p.line().await.as_deref(), Some("1TS00000A\r\n"));
    p.send(b"1TS\r\n2TS\r\n").await;
    assert_eq!(p.line().await.as_deref(), Some("1TS00000A\r\n"));
    assert_eq!(p.line().await.as_deref(), Some("2TS00000A\r\n"));
}

#[tokio::test(start_paused = true)]
async fn configuration_state_and_queries() {
    let sim = sim();
    let mut p = Port::open(&sim, "arms");
    p.send(b"1PW1\r\n").await;
    assert_eq!(p.query("1TS\r\n").await.as_deref(), Some("1TS000014\r\n"));
    p.send(b"1OR\r\n").await;
    assert_eq!(p.query("1TE\r\n").await.as_deref(), Some("1TEI\r\n"));
    p.send(b"1VA12.5\r\n").await;
    assert_eq!(p.query("1VA?\r\n").await.as_deref(), Some("1VA12.5\r\n"));
    // PW0 stores the configuration: the controller is deaf for a while, then NOT REFERENCED from CONFIGURATION.
    p.send(b"1PW0\r\n").await;
    p.send(b"1TS\r\n").await;
    assert!(p.silent_for(Duration::from_millis(500)).await);
    sim.clock().sleep_s(11.0).await;
    assert_eq!(p.query("1TS\r\n").await.as_deref(), Some("1TS00000C\r\n"));
    let ve = p.query("1VE\r\n").await.expect("VE");
    assert!(ve.starts_with("1VE") && ve.ends_with("\r\n"));
    let id = p.query("1ID?\r\n").await.expect("ID");
    assert!(id.starts_with("1ID"));
}

#[tokio::test(start_paused = true)]
async fn stop_decelerates_to_ready_from_moving_and_output_is_xon_xoff_safe() {
    let sim = sim();
    let mut p = Port::open(&sim, "arms");
    home(&mut p, &sim, 1).await;
    p.send(b"1PA90\r\n").await;
    sim.clock().sleep_s(1.0).await;
    p.send(b"1ST\r\n").await;
    assert_eq!(
        p.query("1TS\r\n").await.as_deref(),
        Some("1TS000028\r\n"),
        "decelerating"
    );
    sim.clock().sleep_s(0.5).await;
    assert_eq!(p.query("1TS\r\n").await.as_deref(), Some("1TS000033\r\n"));
    let tp: f64 = p.query("1TP\r\n").await.expect("TP")[3..]
        .trim_end()
        .parse()
        .expect("num");
    // 2.5 deg to reach 20 deg/s in 0.25 s, 15 deg cruising to 1 s, then v^2/2a = 2.5 deg to stop.
    assert!((tp - 20.0).abs() < 1e-3, "{tp}");
    assert!(!p.all.contains(&0x11) && !p.all.contains(&0x13));
}
