//! SMC100: a controller that loses input sent in bursts or too soon after a set command, and the TS that gets no
//! reply after power-up or homing; the real replies' formats (VE, TP with ten decimals).

use std::sync::{Arc, Mutex};
use std::time::Duration;

use gonio_driver::Axis;
use gonio_driver::smc100::{MAX_SET_GAP, SET_GAP, Smc100Axis, Smc100Chain, parse_number, parse_reply};
use gonio_driver::transport::LinePort;
use tokio::time::Instant;

use crate::common::{sim_axis, sim_file, sim_port, trace};
use crate::scripted::peer;

/// Arrival time (ms since the start) and text of every line the scripted controller saw, and whether it took it.
type Seen = Arc<Mutex<Vec<(u64, String, bool)>>>;

/// A scripted controller at READY, position 0, that loses a line arriving within 60 ms of a set command (as the
/// recorded real-hardware drivers' pacing implies) and gives no reply to the first TS.
fn strict_controller() -> (tokio::io::DuplexStream, Seen) {
    let seen: Seen = Arc::default();
    let s = Arc::clone(&seen);
    let start = Instant::now();
    let mut busy_until = start;
    let mut first_ts = true;
    let mut target = String::from("0");
    let (stream, _) = peer(b'\n', move |line: &str| {
        let now = Instant::now();
        let ms = (now - start).as_millis() as u64;
        let taken = now >= busy_until;
        s.lock().unwrap().push((ms, line.to_string(), taken));
        if !taken {
            return vec![];
        }
        let (addr, cmd) = line.split_at(1);
        let reply = match cmd.get(..2).unwrap_or_default() {
            "TS" if std::mem::take(&mut first_ts) => return vec![],
            "TS" => format!("{addr}TS000033"),
            "TP" | "TH" => format!("{addr}TP{target}"),
            "TE" => format!("{addr}TE@"),
            "PT" => format!("{addr}PT0.1"),
            "PA" => {
                target = cmd[2..].to_string();
                busy_until = now + Duration::from_millis(60);
                return vec![];
            }
            _ => {
                busy_until = now + Duration::from_millis(60);
                return vec![];
            }
        };
        vec![(0, format!("{reply}\r\n"))]
    });
    (stream, seen)
}

#[tokio::test(start_paused = true)]
async fn commands_go_out_one_at_a_time_and_paced_after_set_commands() {
    trace();
    let (stream, seen) = strict_controller();
    let port = Arc::new(LinePort::from_stream("arms", Box::new(stream)));
    let chain = Smc100Chain::new("arms", port);
    // The first TS gets no reply: the query is asked again.
    let ts = chain.ts(1).await.expect("TS after one lost");
    assert!(matches!(ts.state, gonio_driver::smc100::State::Ready(0x33)));
    let axis = Smc100Axis::new(Arc::clone(&chain), sim_axis("light"));
    axis.start_move(5.0).await.expect("PA then TE, paced");
    let seen = seen.lock().unwrap().clone();
    let lines: Vec<&str> = seen.iter().map(|(_, l, _)| l.as_str()).collect();
    assert_eq!(
        lines,
        ["1TS", "1TS", "1TP", "1TP", "1PA5.000000", "1TE"],
        "{seen:?}"
    );
    assert!(seen.iter().all(|(_, _, taken)| *taken), "nothing lost: {seen:?}");
    // TE went out no sooner than the pause after PA.
    let pa = seen[4].0;
    let te = seen[5].0;
    assert!(
        te >= pa + SET_GAP.as_millis() as u64,
        "PA at {pa} ms, TE at {te} ms"
    );
}

#[tokio::test(start_paused = true)]
async fn a_move_starts_from_where_the_last_came_to_rest_without_reading_it_again() {
    trace();
    let (stream, seen) = strict_controller();
    let port = Arc::new(LinePort::from_stream("arms", Box::new(stream)));
    let chain = Smc100Chain::new("arms", port);
    let _ = chain.ts(1).await;
    let axis = Smc100Axis::new(Arc::clone(&chain), sim_axis("light"));
    let lines_from = |k: usize| -> Vec<String> {
        seen.lock().unwrap()[k..]
            .iter()
            .map(|(_, l, _)| l.clone())
            .collect()
    };
    // Nothing known of where the axis is: the start is read (twice) before the PA.
    let before = seen.lock().unwrap().len();
    axis.start_move(5.0).await.expect("first move");
    assert_eq!(lines_from(before), ["1TP", "1TP", "1PA5.000000", "1TE"]);
    axis.wait_arrived(5.0).await.expect("arrived");
    // Seen over and read back: the next move starts from there, PA alone (two reads fewer, ~25 ms a leg on a
    // real controller).
    let before = seen.lock().unwrap().len();
    axis.start_move(7.0).await.expect("second move");
    assert_eq!(lines_from(before), ["1PA7.000000", "1TE"]);
    axis.wait_arrived(7.0).await.expect("arrived");
    // A stop forgets it: whatever moved since, the start is read again.
    let before = seen.lock().unwrap().len();
    axis.stop().await.expect("stop");
    axis.start_move(3.0).await.expect("move after a stop");
    let lines = lines_from(before);
    assert_eq!(lines.first().map(String::as_str), Some("1ST"), "{lines:?}");
    let after_stop: Vec<String> = lines.into_iter().skip_while(|l| l == "1ST").collect();
    assert_eq!(after_stop, ["1TP", "1TP", "1PA3.000000", "1TE"]);
}

/// Home and move both arms, then read their status: under the variant `f` sets.
async fn both_arms_work(f: impl FnOnce(&mut gonio_instrument::InstrumentFile)) -> Arc<Smc100Chain> {
    both_arms_work_at(f, 1.0).await
}

/// [`both_arms_work`] with the simulated controllers `scale` times faster than tokio's clock, and the pause
/// after a set command scaled as the daemon's rig scales it.
async fn both_arms_work_at(
    f: impl FnOnce(&mut gonio_instrument::InstrumentFile),
    scale: f64,
) -> Arc<Smc100Chain> {
    let sim = sim_file(f, scale);
    let chain = Smc100Chain::with_set_gap("arms", sim_port(&sim, "arms"), SET_GAP.div_f64(scale));
    let light = Smc100Axis::new(Arc::clone(&chain), sim_axis("light"));
    let detector = Smc100Axis::new(Arc::clone(&chain), sim_axis("detector"));
    light.home().await.expect("home light");
    detector.home().await.expect("home detector");
    let read = light.move_to(25.0).await.expect("light to 25");
    assert!((read - 25.0).abs() <= 0.005, "{read}");
    detector.move_to(-40.0).await.expect("detector to -40");
    let pose = sim.pose();
    assert!((pose.light_deg - 25.0).abs() <= 0.005 && (pose.detector_deg + 40.0).abs() <= 0.005);
    let st = detector.status().await.expect("status");
    assert!(st.referenced && !st.moving && st.fault.is_none(), "{st:?}");
    chain
}

#[tokio::test(start_paused = true)]
async fn correct_under_every_simulator_variant() {
    trace();
    // Every combination, each set explicitly: the manual's controller (no pause needed, every TS answered), the
    // recorded one (60 ms, the first TS lost), one needing a longer pause than ours (200 ms), and each with and
    // without the lost first TS.
    for gap_ms in [0.0, 60.0, 200.0] {
        for drop_first_ts in [false, true] {
            let chain = both_arms_work(|f| {
                f.simulator.quirks.smc100_min_command_gap_ms = gap_ms;
                f.simulator.quirks.smc100_drop_first_ts = drop_first_ts;
            })
            .await;
            let gap = chain.set_gap();
            if gap_ms > SET_GAP.as_millis() as f64 {
                assert!(
                    gap >= Duration::from_millis(200),
                    "gap {gap_ms} ms, drop {drop_first_ts}: the pause widened to what the controller needs: {gap:?}"
                );
            } else {
                assert_eq!(
                    gap, SET_GAP,
                    "gap {gap_ms} ms, drop {drop_first_ts}: no need to widen"
                );
            }
        }
    }
    // The same controller 40 times faster: the pause widens in the controller's time, not to real
    // milliseconds (which would be 40 times what it needs).
    for drop_first_ts in [false, true] {
        let chain = both_arms_work_at(
            |f| {
                f.simulator.quirks.smc100_min_command_gap_ms = 200.0;
                f.simulator.quirks.smc100_drop_first_ts = drop_first_ts;
            },
            40.0,
        )
        .await;
        assert!(
            chain.set_gap() >= Duration::from_millis(5) && chain.set_gap() <= MAX_SET_GAP.div_f64(40.0),
            "widened within the scaled bounds: {:?}",
            chain.set_gap()
        );
    }
}

#[test]
fn real_reply_formats_parse() {
    // Recorded from a real SMC100CC.
    let (addr, cc, value) = parse_reply(b"1VE SMC_CC - Controller-driver version  3. 1. 2").expect("VE");
    assert_eq!((addr, &cc), (1, b"VE"));
    assert_eq!(value, " SMC_CC - Controller-driver version  3. 1. 2");
    let (_, cc, value) = parse_reply(b"1TP12.3456789012").expect("TP");
    assert_eq!(&cc, b"TP");
    assert_eq!(parse_number(value), Some(12.3456789012));
    assert_eq!(parse_number("-0.0000000001"), Some(-1e-10));
}

/// The daemon's dry-run set-up at a large time scale (the driver's pause scaled as the rig scales it), on a
/// real clock with every core busy: the paced driver loses no line to the controller's input pacing, and
/// every status read and move succeeds at the first attempt.
#[test]
fn paced_exchanges_hold_at_large_time_scales_under_load() {
    trace();
    let _load = gonio_testkit::CpuLoad::start();
    for scale in [40.0, 200.0] {
        let rt = tokio::runtime::Builder::new_multi_thread()
            .worker_threads(2)
            .enable_all()
            .build()
            .expect("runtime");
        rt.block_on(async {
            // The recorded controller (60 ms pause, first TS lost), set explicitly.
            let sim = sim_file(
                |f| {
                    f.simulator.quirks.smc100_min_command_gap_ms = 60.0;
                    f.simulator.quirks.smc100_drop_first_ts = true;
                },
                scale,
            );
            let chain = Smc100Chain::with_set_gap("arms", sim_port(&sim, "arms"), SET_GAP.div_f64(scale));
            let light = Smc100Axis::new(Arc::clone(&chain), sim_axis("light"));
            let detector = Smc100Axis::new(Arc::clone(&chain), sim_axis("detector"));
            light.home().await.expect("home light");
            detector.home().await.expect("home detector");
            let lost_after_homing = sim.lost_input_lines();
            for i in 0..40 {
                let at = f64::from(i % 7) * 5.0 - 15.0;
                light
                    .move_to(at)
                    .await
                    .unwrap_or_else(|e| panic!("x{scale}: light to {at}: {e}"));
                detector
                    .move_to(at + 60.0)
                    .await
                    .unwrap_or_else(|e| panic!("x{scale}: detector: {e}"));
                for axis in [&light, &detector] {
                    let st = axis
                        .status()
                        .await
                        .unwrap_or_else(|e| panic!("x{scale}: status: {e}"));
                    assert!(
                        st.referenced && !st.moving && st.fault.is_none(),
                        "x{scale}: {st:?}"
                    );
                }
            }
            assert_eq!(
                sim.lost_input_lines(),
                lost_after_homing,
                "x{scale}: lines lost to pacing"
            );
            assert_eq!(
                chain.set_gap(),
                SET_GAP.div_f64(scale),
                "x{scale}: the pause never had to widen"
            );
        });
    }
}
