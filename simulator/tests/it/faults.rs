//! Fault injection seen from the host: each kind shows up as the real device would show it, deterministically.

use crate::common;

use std::time::Duration;

use common::Port;
use gonio_simulator::{SimError, UsbSimError};

/// The devices as their manuals describe them (no recorded quirks: those have their own tests), with `f` applied.
fn sim_with(f: impl FnOnce(&mut gonio_instrument::InstrumentFile)) -> gonio_simulator::SimInstrument {
    common::sim_with(|file| {
        file.simulator.quirks.smc100_min_command_gap_ms = 0.0;
        file.simulator.quirks.smc100_drop_first_ts = false;
        file.simulator.quirks.fw102c_noise_at_open = false;
        f(file);
    })
}

#[tokio::test(start_paused = true)]
async fn garbled_replies_differ_in_one_byte_and_are_reproducible() {
    let run = || async {
        let sim = sim_with(|f| {
            f.simulator.faults.garble_rate = 1.0;
            f.simulator.faults.seed = 3;
        });
        let mut p = Port::open(&sim, "arms");
        let mut replies = Vec::new();
        for _ in 0..10 {
            replies.push(p.query("1TS\r\n").await.expect("reply"));
        }
        (replies, sim.fault_counts().garbled)
    };
    let (a, garbled) = run().await;
    assert_eq!(a, run().await.0);
    assert_eq!(garbled, 10);
    for r in &a {
        let diff = r
            .bytes()
            .zip("1TS00000A\r\n".bytes())
            .filter(|(x, y)| x != y)
            .count();
        assert_eq!(diff, 1, "{r:?}");
    }
}

#[tokio::test(start_paused = true)]
async fn dropped_replies_never_arrive_and_are_counted() {
    let sim = sim_with(|f| f.simulator.faults.drop_rate = 1.0);
    let mut p = Port::open(&sim, "stage");
    p.send(b"/1 set comm.alert 1\n").await;
    assert!(p.silent_for(Duration::from_millis(500)).await);
    assert_eq!(sim.fault_counts().dropped, 1);
}

#[tokio::test(start_paused = true)]
async fn delayed_replies_arrive_late() {
    let sim = sim_with(|f| f.simulator.faults.delay_ms = 250.0);
    let mut p = Port::open(&sim, "wheel");
    let t0 = sim.now_s();
    p.send(b"pos?\r").await;
    assert_eq!(
        p.read_until(b"> ", Duration::from_secs(2)).await.as_deref(),
        Some("pos?\r1\r> ")
    );
    assert!(sim.now_s() - t0 >= 0.25, "{}", sim.now_s() - t0);
    assert!(sim.fault_counts().delayed >= 1);
}

#[tokio::test(start_paused = true)]
async fn serial_disconnect_gives_eof_refuses_opens_then_comes_back() {
    let sim = sim_with(|f| {
        f.simulator.faults.disconnect_after_s = Some(2.0);
        f.simulator.faults.reconnect_after_s = Some(3.0);
    });
    let mut p = Port::open(&sim, "arms");
    assert_eq!(p.query("1TS\r\n").await.as_deref(), Some("1TS00000A\r\n"));
    assert!(p.at_eof(Duration::from_secs(5)).await, "the port vanishes");
    assert!(sim.now_s() >= 2.0);
    assert_eq!(
        sim.serial_port("arms").err(),
        Some(SimError::Disconnected {
            device: "arms".into()
        })
    );
    sim.clock().sleep_until_s(5.0).await;
    let mut p = Port::open(&sim, "arms");
    assert_eq!(
        p.query("1TS\r\n").await.as_deref(),
        Some("1TS00000A\r\n"),
        "the controller kept its state"
    );
    let c = sim.fault_counts();
    assert_eq!((c.disconnects, c.refused_opens), (1, 1));
}

#[tokio::test(start_paused = true)]
async fn usb_disconnect_gives_no_device_until_reopened_after_reconnect() {
    let sim = sim_with(|f| {
        f.simulator.faults.disconnect_after_s = Some(1.0);
        f.simulator.faults.reconnect_after_s = Some(1.0);
    });
    let dev = sim.usb_device("meter").expect("open");
    sim.clock().sleep_until_s(1.5).await;
    assert_eq!(
        dev.bulk_in(0x81, 64, Duration::from_millis(10)).await,
        Err(UsbSimError::NoDevice)
    );
    assert!(matches!(
        sim.usb_device("meter"),
        Err(SimError::Disconnected { .. })
    ));
    sim.clock().sleep_until_s(2.5).await;
    assert_eq!(
        dev.clear_halt(0x02).await,
        Err(UsbSimError::NoDevice),
        "the old handle stays dead"
    );
    let dev = sim.usb_device("meter").expect("reopen after reconnect");
    assert_eq!(dev.clear_halt(0x02).await, Ok(()));
}

#[tokio::test(start_paused = true)]
async fn estop_stops_every_axis_where_it_is() {
    let sim = sim_with(|_| {});
    let mut p = Port::open(&sim, "arms");
    p.send(b"1OR\r\n").await;
    sim.clock().sleep_s(3.0).await;
    p.send(b"1PA90\r\n").await;
    sim.clock().sleep_s(1.0).await;
    sim.estop();
    let at = sim.pose().light_deg;
    sim.clock().sleep_s(5.0).await;
    assert_eq!(sim.pose().light_deg, at);
    assert!(at > 10.0 && at < 90.0);
    assert_eq!(p.query("1TS\r\n").await.as_deref(), Some("1TS000033\r\n"));
}
