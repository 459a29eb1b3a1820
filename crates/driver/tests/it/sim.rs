//! Every driver against the simulator's emulator of the same device (written independently from the same
//! manuals): in process under tokio's paused clock, and through real pseudo-terminals opened by path.

use std::sync::Arc;
use std::time::Duration;

use gonio_driver::fw102c::Fw102c;
use gonio_driver::pm100::Pm100;
use gonio_driver::smc100::{Smc100Axis, Smc100Chain};
use gonio_driver::transport::usb::UsbPipe;
use gonio_driver::zaber::{ZaberAxis, ZaberChain};
use gonio_driver::{Axis, Detector, DetectorConfig, ErrorKind, FilterWheel, PowerRange};

use crate::common::{SimPipe, pty_bridge, pty_port, sim_axis, sim_port, sim_with, trace};

fn arms(port: Arc<gonio_driver::transport::LinePort>) -> (Smc100Axis, Smc100Axis) {
    let chain = Smc100Chain::new("arms", port);
    (
        Smc100Axis::new(Arc::clone(&chain), sim_axis("light")),
        Smc100Axis::new(chain, sim_axis("detector")),
    )
}

fn stage(port: Arc<gonio_driver::transport::LinePort>) -> (ZaberAxis, ZaberAxis) {
    let chain = ZaberChain::new("stage", port);
    (
        ZaberAxis::new(Arc::clone(&chain), sim_axis("tilt")).expect("tilt"),
        ZaberAxis::new(chain, sim_axis("rotation")).expect("rotation"),
    )
}

#[tokio::test(start_paused = true)]
async fn smc100_homes_moves_and_verifies_against_the_emulator() {
    trace();
    let sim = sim_with(|_| {}, 1.0);
    let (light, detector) = arms(sim_port(&sim, "arms"));
    // Before homing, a move is refused for the right reason.
    let err = light.start_move(10.0).await.expect_err("not referenced yet");
    assert_eq!(err.kind(), ErrorKind::NotReferenced, "{err}");
    light.home().await.expect("home light");
    detector.home().await.expect("home detector");
    assert!(light.status().await.expect("status").referenced);
    let read = light.move_to(30.0).await.expect("light to 30");
    assert!((read - 30.0).abs() <= 0.005);
    // Approach from above with backlash: the driver overshoots below first; the true position must match.
    light.move_to(29.0).await.expect("back to 29");
    let read = detector.move_to(-45.0).await.expect("detector to -45");
    let pose = sim.pose();
    assert!(
        (pose.light_deg - 29.0).abs() <= 0.005,
        "light really at {}",
        pose.light_deg
    );
    assert!(
        (pose.detector_deg - -45.0).abs() <= 0.005,
        "detector really at {}",
        pose.detector_deg
    );
    assert!((read - pose.detector_deg).abs() <= 0.005);
    // Outside the configured travel: refused before anything moves.
    assert_eq!(
        light.start_move(150.0).await.expect_err("limit").kind(),
        ErrorKind::OutOfRange
    );
}

#[tokio::test(start_paused = true)]
async fn smc100_stall_ends_in_a_motion_fault_with_the_controller_reason() {
    trace();
    let sim = sim_with(|f| f.stall_rate = 1.0, 1.0);
    let (light, _) = arms(sim_port(&sim, "arms"));
    match light.home().await {
        Ok(()) => {
            let err = light.move_to(40.0).await.expect_err("every move stalls");
            assert_eq!(err.kind(), ErrorKind::MotionFault, "{err}");
            let status = light.status().await.expect("status");
            assert!(status.fault.is_some(), "{status:?}");
            assert!(
                (sim.pose().light_deg - 40.0).abs() > 0.005,
                "it really did not get there"
            );
        }
        // Homing may stall too; then it must be an error, never a success.
        Err(e) => assert!(
            matches!(e.kind(), ErrorKind::MotionFault | ErrorKind::NotReferenced),
            "{e}"
        ),
    }
}

#[tokio::test(start_paused = true)]
async fn smc100_reconnect_after_a_stall_leaves_disable_so_the_move_can_be_retried() {
    trace();
    let sim = sim_with(
        |f| {
            f.stall_rate = 0.5;
            f.seed = 7;
        },
        1.0,
    );
    let (light, _) = arms(sim_port(&sim, "arms"));
    for i in 0..40 {
        let status = light.status().await.expect("status");
        if !status.referenced || status.fault.is_some() {
            // A stalled homing search: try again (homing from DISABLE is MM1).
            let _ = light.home().await;
            continue;
        }
        let target = if i % 2 == 0 { 20.0 } else { -20.0 };
        match light.move_to(target).await {
            Ok(_) => continue,
            Err(e) if e.kind() == ErrorKind::MotionFault => {
                // The stall left the controller in DISABLE, which refuses moves (error J)...
                let stalled = light.status().await.expect("status");
                assert!(stalled.fault.is_some(), "{stalled:?}");
                // ...and reconnecting brings it back to READY with its reference kept.
                let after = light
                    .reconnect()
                    .await
                    .expect("reconnect re-enables the controller");
                assert!(after.referenced && after.fault.is_none(), "{after:?}");
                light
                    .start_move(0.0)
                    .await
                    .expect("the retried move is accepted, not refused in DISABLE");
                assert!(sim.fault_counts().stalls > 0);
                return;
            }
            Err(e) => panic!("unexpected error: {e}"),
        }
    }
    panic!("no stalled move in 40 moves at a 50 % stall rate");
}

#[tokio::test(start_paused = true)]
async fn smc100_stop_reaches_a_moving_axis() {
    trace();
    let sim = sim_with(|_| {}, 1.0);
    let (light, detector) = arms(sim_port(&sim, "arms"));
    light.home().await.expect("home");
    detector.home().await.expect("home");
    light.start_move(90.0).await.expect("start");
    tokio::time::sleep(Duration::from_millis(500)).await;
    light.stop().await.expect("stop");
    let err = light.wait_arrived(90.0).await.expect_err("stopped short");
    assert_eq!(err.kind(), ErrorKind::MotionFault, "{err}");
    assert!(sim.pose().light_deg < 80.0);
}

#[tokio::test(start_paused = true)]
async fn smc100_garbled_and_dropped_replies_never_give_a_wrong_success() {
    trace();
    let sim = sim_with(
        |f| {
            f.garble_rate = 0.05;
            f.drop_rate = 0.05;
            f.seed = 7;
        },
        1.0,
    );
    let (light, _) = arms(sim_port(&sim, "arms"));
    let mut ok = 0;
    for _ in 0..3 {
        if light.home().await.is_ok() {
            break;
        }
    }
    for target in [10.0, -20.0, 35.0, 5.0, -60.0, 12.5] {
        match light.move_to(target).await {
            Ok(read) => {
                ok += 1;
                assert!((read - target).abs() <= 0.005);
                assert!(
                    (sim.pose().light_deg - target).abs() <= 0.006,
                    "claimed {read}, really {}",
                    sim.pose().light_deg
                );
            }
            Err(e) => {
                eprintln!("move to {target} failed: {e}");
                assert!(e.kind() != ErrorKind::OutOfRange, "{e}");
            }
        }
    }
    assert!(
        ok >= 3,
        "retries should carry most moves through 5% faults ({ok}/6)"
    );
}

#[tokio::test(start_paused = true)]
async fn smc100_disconnect_then_reconnect_reverifies() {
    trace();
    let sim = sim_with(
        |f| {
            f.disconnect_after_s = Some(30.0);
            f.reconnect_after_s = Some(10.0);
        },
        1.0,
    );
    let (light, _) = arms(sim_port(&sim, "arms"));
    light.home().await.expect("home");
    light.move_to(20.0).await.expect("move");
    tokio::time::sleep(Duration::from_secs(31)).await;
    let err = light.position_deg().await.expect_err("link down");
    assert_eq!(err.kind(), ErrorKind::Disconnected, "{err}");
    // Still down: reconnecting fails with a typed error.
    assert!(light.reconnect().await.is_err());
    tokio::time::sleep(Duration::from_secs(10)).await;
    match light.reconnect().await {
        Ok(status) => assert!((status.position_deg - 20.0).abs() <= 0.005, "{status:?}"),
        Err(e) => assert_eq!(e.kind(), ErrorKind::NotReferenced, "{e}"),
    }
}

#[tokio::test(start_paused = true)]
async fn zaber_homes_moves_and_verifies_against_the_emulator() {
    trace();
    let sim = sim_with(|_| {}, 1.0);
    let (tilt, rotation) = stage(sim_port(&sim, "stage"));
    tilt.home().await.expect("home tilt");
    rotation.home().await.expect("home rotation");
    tilt.move_to(20.0).await.expect("tilt");
    rotation.move_to(-90.0).await.expect("rotation");
    let pose = sim.pose();
    assert!((pose.tilt_deg - 20.0).abs() <= 0.005, "{pose:?}");
    assert!((pose.rotation_deg - -90.0).abs() <= 0.005, "{pose:?}");
    assert_eq!(
        tilt.start_move(95.0).await.expect_err("limit").kind(),
        ErrorKind::OutOfRange
    );
    let status = tilt.status().await.expect("status");
    assert!(
        status.referenced && !status.moving && status.fault.is_none(),
        "{status:?}"
    );
}

#[tokio::test(start_paused = true)]
async fn zaber_stall_is_a_motion_fault() {
    trace();
    let sim = sim_with(|f| f.stall_rate = 1.0, 1.0);
    let (tilt, _) = stage(sim_port(&sim, "stage"));
    let _ = tilt.home().await;
    let err = tilt.move_to(30.0).await.expect_err("stalls");
    assert!(
        matches!(err.kind(), ErrorKind::MotionFault | ErrorKind::NotReferenced),
        "{err}"
    );
}

#[tokio::test(start_paused = true)]
async fn fw102c_turns_and_reads_back_against_the_emulator() {
    trace();
    let sim = sim_with(|_| {}, 1.0);
    let wheel = Fw102c::new("wheel", sim_port(&sim, "wheel"), 0.4);
    assert_eq!(wheel.position_count().await.expect("pcount"), 6);
    wheel.go_to(3).await.expect("to 3");
    assert_eq!(wheel.position().await.expect("pos"), 3);
    assert_eq!(sim.band().band_nm, Some(650.0));
    assert_eq!(
        wheel.go_to(7).await.expect_err("6 positions").kind(),
        ErrorKind::OutOfRange
    );
    let err = wheel
        .exchange("nonsense", Duration::from_millis(500), false)
        .await
        .expect_err("unknown");
    assert_eq!(err.kind(), ErrorKind::Rejected, "{err}");
}

pub(crate) fn meter(sim: &gonio_simulator::SimInstrument) -> Pm100 {
    let s = sim.clone();
    let opener: gonio_driver::pm100::PipeOpener = Arc::new(move || {
        s.usb_device("meter")
            .map(|d| Arc::new(SimPipe(d)) as Arc<dyn UsbPipe>)
            .map_err(|_| gonio_driver::transport::UsbError::NoDevice)
    });
    let dev = sim.usb_device("meter").expect("usb device");
    assert_eq!((dev.vendor_id(), dev.product_id()), (0x1313, 0x8072));
    Pm100::new("meter", Arc::new(SimPipe(dev)), Some(opener))
}

#[tokio::test(start_paused = true)]
async fn pm100_configures_and_reads_the_scene_power() {
    trace();
    let sim = sim_with(|_| {}, 1.0);
    let m = meter(&sim);
    assert!(m.identify().await.expect("idn").contains("PM100"));
    // The wheel sits at position 1 (450 nm): the meter's responsivity correction must use that wavelength for
    // its reading to equal the optical power.
    assert_eq!(sim.band().band_nm, Some(450.0));
    m.configure(DetectorConfig {
        wavelength_nm: 450.0,
        averaging: 10,
        range: PowerRange::Auto,
    })
    .await
    .expect("configure");
    let r = m.read_power().await.expect("reading");
    let truth = sim.detector_power_w();
    assert!(!r.overload);
    assert!(
        (r.power_w - truth).abs() <= 0.05 * truth + 1e-9,
        "read {} W, scene {} W",
        r.power_w,
        truth
    );
    assert!(r.range_w >= r.power_w);
    // A bad setting is caught (here by the sensor's limits, asked before anything is set), not silently
    // accepted.
    let err = m
        .configure(DetectorConfig {
            wavelength_nm: 1.0e7,
            averaging: 1,
            range: PowerRange::Auto,
        })
        .await
        .expect_err("absurd wavelength");
    assert_eq!(err.kind(), ErrorKind::OutOfRange, "{err}");
    // One the meter itself refuses (averaging beyond its limit) through SYST:ERR?.
    let err = m
        .configure(DetectorConfig {
            wavelength_nm: 550.0,
            averaging: 2_000_000,
            range: PowerRange::Auto,
        })
        .await
        .expect_err("absurd averaging");
    assert_eq!(err.kind(), ErrorKind::Rejected, "{err}");
}

#[tokio::test(start_paused = true)]
async fn pm100_overload_is_flagged() {
    trace();
    let sim = sim_with(|f| f.saturate = true, 1.0);
    let m = meter(&sim);
    m.configure(DetectorConfig {
        wavelength_nm: 550.0,
        averaging: 1,
        range: PowerRange::Fixed { full_scale_w: 5.0e-8 },
    })
    .await
    .expect("configure");
    let r = m.read_power().await.expect("reading");
    assert!(r.overload, "{r:?}");
}

#[tokio::test(start_paused = true)]
async fn pm100_disconnect_and_reopen() {
    trace();
    let sim = sim_with(
        |f| {
            f.disconnect_after_s = Some(5.0);
            f.reconnect_after_s = Some(5.0);
        },
        1.0,
    );
    let m = meter(&sim);
    m.identify().await.expect("idn");
    tokio::time::sleep(Duration::from_secs(6)).await;
    let err = m.identify().await.expect_err("gone");
    assert_eq!(err.kind(), ErrorKind::Disconnected, "{err}");
    tokio::time::sleep(Duration::from_secs(5)).await;
    m.reconnect().await.expect("reopened");
    m.identify().await.expect("idn again");
}

/// Real pseudo-terminals, opened by path with `serialport` (the code path of a real port), real time; the
/// simulator runs 20x faster than real time so that moves are short.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn every_serial_driver_through_a_pseudo_terminal() {
    trace();
    let sim = sim_with(|_| {}, 20.0);
    let (arms_path, _a) = pty_bridge(&sim, "arms");
    let (stage_path, _s) = pty_bridge(&sim, "stage");
    let (wheel_path, _w) = pty_bridge(&sim, "wheel");

    let (light, detector) = arms(pty_port("arms", &arms_path, 57_600, true));
    light.home().await.expect("home light over the pty");
    detector.home().await.expect("home detector over the pty");
    light.move_to(15.0).await.expect("move light over the pty");
    assert!((sim.pose().light_deg - 15.0).abs() <= 0.005);
    // Reconnect through the same path: the port is released and reopened, the axis re-verified.
    let status = light.reconnect().await.expect("reopen the pty");
    assert!((status.position_deg - 15.0).abs() <= 0.005);

    let (tilt, _) = stage(pty_port("stage", &stage_path, 115_200, false));
    tilt.home().await.expect("home tilt over the pty");
    tilt.move_to(-10.0).await.expect("tilt over the pty");
    assert!((sim.pose().tilt_deg - -10.0).abs() <= 0.005);

    let (wheel_path, wheel_bridge) = (wheel_path, _w);
    let wheel = Fw102c::new("wheel", pty_port("wheel", &wheel_path, 115_200, false), 0.4);
    wheel.go_to(2).await.expect("wheel over the pty");
    assert_eq!(wheel.position().await.expect("pos"), 2);

    // The far end goes away (the master side of the pty closes, as when a USB-serial adapter is unplugged):
    // the next request says "disconnected", not "timeout".
    wheel_bridge.abort();
    let _ = wheel_bridge.await;
    tokio::time::sleep(Duration::from_millis(100)).await;
    let err = wheel.position().await.expect_err("far end gone");
    assert_eq!(err.kind(), ErrorKind::Disconnected, "{err}");
}

#[tokio::test(start_paused = true)]
async fn zaber_and_wheel_under_garbled_and_dropped_replies_never_give_a_wrong_success() {
    trace();
    for seed in [3, 11] {
        let sim = sim_with(
            |f| {
                f.garble_rate = 0.05;
                f.drop_rate = 0.05;
                f.seed = seed;
            },
            1.0,
        );
        let (tilt, _) = stage(sim_port(&sim, "stage"));
        let wheel = Fw102c::new("wheel", sim_port(&sim, "wheel"), 0.4);
        let _ = tilt.home().await;
        let mut ok = 0;
        for target in [10.0, -20.0, 35.0, 5.0] {
            match tilt.move_to(target).await {
                Ok(read) => {
                    ok += 1;
                    assert!((read - target).abs() <= 0.005);
                    assert!(
                        (sim.pose().tilt_deg - target).abs() <= 0.005,
                        "claimed {read}, really {}",
                        sim.pose().tilt_deg
                    );
                }
                Err(e) => eprintln!("seed {seed}: tilt to {target}: {e}"),
            }
        }
        for p in [2u8, 5, 1] {
            match wheel.go_to(p).await {
                Ok(()) => {
                    ok += 1;
                    // The emulator counts the instant of arrival (when it sends the prompt) as still turning;
                    // look a moment later.
                    tokio::time::sleep(Duration::from_millis(10)).await;
                    let want = [
                        None,
                        Some(450.0),
                        Some(550.0),
                        Some(650.0),
                        Some(500.0),
                        Some(600.0),
                    ][usize::from(p)];
                    assert_eq!(
                        sim.band().band_nm,
                        want,
                        "wheel claimed position {p} at t = {} s",
                        sim.now_s()
                    );
                }
                Err(e) => eprintln!("seed {seed}: wheel to {p}: {e}"),
            }
        }
        assert!(
            ok >= 4,
            "seed {seed}: retries should carry most requests through 5% faults ({ok}/7)"
        );
    }
}

#[tokio::test(start_paused = true)]
async fn late_replies_end_in_a_bounded_timeout() {
    trace();
    // Every reply comes 2 s late: far beyond the reply deadline. Each request gives up (after its bounded retries)
    // with a timeout instead of waiting, and the late replies never satisfy a later request.
    let sim = sim_with(|f| f.delay_ms = 2000.0, 1.0);
    let (light, _) = arms(sim_port(&sim, "arms"));
    let started = tokio::time::Instant::now();
    let err = light.position_deg().await.expect_err("too late");
    assert_eq!(err.kind(), ErrorKind::Timeout, "{err}");
    assert!(
        started.elapsed() < Duration::from_secs(5),
        "bounded: {:?}",
        started.elapsed()
    );
    let wheel = Fw102c::new("wheel", sim_port(&sim, "wheel"), 0.4);
    assert_eq!(
        wheel.position().await.expect_err("too late").kind(),
        ErrorKind::Timeout
    );
}

#[tokio::test(start_paused = true)]
async fn zaber_and_wheel_disconnect_then_reconnect() {
    trace();
    let sim = sim_with(
        |f| {
            f.disconnect_after_s = Some(20.0);
            f.reconnect_after_s = Some(10.0);
        },
        1.0,
    );
    let (tilt, _) = stage(sim_port(&sim, "stage"));
    let wheel = Fw102c::new("wheel", sim_port(&sim, "wheel"), 0.4);
    tilt.home().await.expect("home");
    tilt.move_to(12.0).await.expect("move");
    wheel.go_to(2).await.expect("wheel");
    tokio::time::sleep(Duration::from_secs(21)).await;
    assert_eq!(
        tilt.position_deg().await.expect_err("down").kind(),
        ErrorKind::Disconnected
    );
    assert_eq!(
        wheel.position().await.expect_err("down").kind(),
        ErrorKind::Disconnected
    );
    tokio::time::sleep(Duration::from_secs(10)).await;
    match tilt.reconnect().await {
        Ok(status) => assert!((status.position_deg - 12.0).abs() <= 0.005, "{status:?}"),
        Err(e) => assert_eq!(e.kind(), ErrorKind::NotReferenced, "{e}"),
    }
    wheel.reconnect().await.expect("wheel back");
}
