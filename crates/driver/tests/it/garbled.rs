//! Issue 8: a byte garbled inside a well-formed number (`1TP12.3450` read as `1TP12.3480`, a Zaber position
//! without checksum) parses like a good reply. Every position the drivers act on must come out either right (after
//! a re-read) or as a typed error, never wrong. Scripted peers corrupt exactly the replies chosen here; the last
//! test runs the drivers against the simulator's own fault injection and compares with its ground truth.

use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};

use gonio_driver::fw102c::Fw102c;
use gonio_driver::smc100::{Smc100Axis, Smc100Chain};
use gonio_driver::transport::LinePort;
use gonio_driver::zaber::{ZaberAxis, ZaberChain, checksum};
use gonio_driver::{Axis, ErrorKind, FilterWheel};

use crate::common::{sim_axis, sim_port, sim_with, trace};
use crate::scripted::{Log, peer, zparse, zreply};

/// Characters a corrupted byte may become in these tests: the ones that keep a number well formed.
const NUMERIC: &[u8] = b"0123456789.-";

/// `text` with the byte at `at` replaced by `with`.
fn corrupt(text: &str, at: usize, with: u8) -> String {
    let mut b = text.as_bytes().to_vec();
    b[at] = with;
    String::from_utf8(b).expect("ASCII")
}

/// An SMC100 at address 1, READY and at rest at `truth` (as the controller prints it). `garble(k)` may replace the
/// value of the k-th TP reply of the conversation (0-based).
fn resting_smc(
    truth: &'static str,
    garble: impl Fn(usize) -> Option<String> + Send + 'static,
) -> (Smc100Axis, Arc<Smc100Chain>, Log) {
    let tp_count = AtomicUsize::new(0);
    let (stream, log) = peer(b'\n', move |line| match line {
        "1TS" => vec![(0, "1TS000033\r\n".into())],
        "1TE" => vec![(0, "1TE@\r\n".into())],
        "1TP" => {
            let k = tp_count.fetch_add(1, Ordering::SeqCst);
            let value = garble(k).unwrap_or_else(|| truth.to_string());
            vec![(0, format!("1TP{value}\r\n"))]
        }
        l if l.starts_with("1PT") => vec![(0, "1PT0.5\r\n".into())],
        _ => vec![],
    });
    let chain = Smc100Chain::new("arms", Arc::new(LinePort::from_stream("arms", Box::new(stream))));
    let axis = Smc100Axis::new(Arc::clone(&chain), sim_axis("light"));
    (axis, chain, log)
}

#[tokio::test(start_paused = true)]
async fn smc100_one_garbled_character_in_a_position_is_caught_by_the_second_read() {
    trace();
    let truth = "12.3450";
    let resolution = sim_axis("light").encoder_resolution_deg;
    // The hazard: one read of a reply garbled into another well-formed number is believed.
    let (_, chain, _) = resting_smc(truth, |k| (k == 0).then(|| "72.3450".to_string()));
    assert_eq!(chain.number(1, "TP", "").await.expect("one read"), 72.345);
    // Every character of the first or the second reply of the pair, into every character that keeps it numeric.
    let mut cases = 0;
    for which in 0..2 {
        for at in 0..truth.len() {
            for &with in NUMERIC {
                if truth.as_bytes()[at] == with {
                    continue;
                }
                let bad = corrupt(truth, at, with);
                let (axis, _, _) = resting_smc(truth, move |k| (k == which).then(|| bad.clone()));
                let read = axis.position_deg().await;
                let read = read.unwrap_or_else(|e| panic!("{which}/{at}/{}: {e}", with as char));
                // Within the encoder resolution: a change below it (the last digit by a few counts) is not
                // "wrong", it is what the encoder itself cannot tell apart.
                assert!(
                    (read - 12.345).abs() <= resolution + 1e-9,
                    "reply {which}, byte {at} -> {:?}: read {read}",
                    with as char
                );
                cases += 1;
            }
        }
    }
    assert_eq!(cases, 2 * 7 * 11);
}

#[tokio::test(start_paused = true)]
async fn smc100_arrival_read_back_is_never_a_garbled_value_within_tolerance() {
    trace();
    // `12.3480` is 0.003 deg from the truth: inside the 0.005 deg arrival tolerance, so a single read would
    // have reported a wrong arrival position. Whichever TP reply of the move it hits (the start pair, the
    // read-back pair), the move must report the true position.
    for k in 0..6 {
        let (axis, _, log) = resting_smc("12.3450", move |i| (i == k).then(|| "12.3480".into()));
        axis.start_move(12.345).await.expect("PA accepted");
        let read = axis.wait_arrived(12.345).await.expect("arrived");
        assert!(
            (read - 12.345).abs() <= 0.0005 + 1e-9,
            "TP reply #{k} garbled: arrival reported at {read}; sent {:?}",
            log.lock().unwrap()
        );
    }
}

#[tokio::test(start_paused = true)]
async fn smc100_reads_that_never_agree_are_a_protocol_error() {
    trace();
    // Every other TP reply garbled: the two reads of a pair never agree.
    let (axis, _, _) = resting_smc("12.3450", |k| (k % 2 == 1).then(|| "19.3450".into()));
    let err = axis.position_deg().await.expect_err("no agreement");
    assert_eq!(err.kind(), ErrorKind::Protocol, "{err}");
    assert!(err.to_string().contains("never agreed"), "{err}");
    let err = axis
        .wait_arrived(12.345)
        .await
        .expect_err("no trustworthy read-back");
    assert_eq!(err.kind(), ErrorKind::Protocol, "{err}");
}

/// How a scripted Zaber device handles reply checksums.
#[derive(Clone, Copy, PartialEq)]
enum ZChecksums {
    /// Off until `set comm.checksum 1` (the factory default).
    OnRequest,
    /// Refuses the setting and never sends checksums.
    Never,
}

/// A Zaber device 1 whose axis 1 rests at `steps`, IDLE. `garble(k, reply)` may replace the k-th `get pos`
/// reply line (complete, with its checksum if any) by another.
fn resting_zaber(
    steps: i64,
    mode: ZChecksums,
    garble: impl Fn(usize, &str) -> Option<String> + Send + 'static,
) -> (ZaberAxis, Log) {
    let on = Mutex::new(false);
    let pos_count = AtomicUsize::new(0);
    let (stream, log) = peer(b'\n', move |line| {
        let (d, a, id, cmd) = zparse(line);
        let frame = |body: String| {
            if *on.lock().unwrap() {
                zreply(&body)
            } else {
                format!("@{body}\r\n")
            }
        };
        match cmd.as_str() {
            "set comm.checksum 1" if mode == ZChecksums::OnRequest && a == 0 => {
                *on.lock().unwrap() = true;
                vec![(0, frame(format!("{d:02} 0 {id} OK IDLE -- 0")))]
            }
            "set comm.checksum 1" => vec![(0, frame(format!("{d:02} {a} {id} RJ IDLE -- BADCOMMAND")))],
            "get pos" => {
                let k = pos_count.fetch_add(1, Ordering::SeqCst);
                let good = frame(format!("{d:02} {a} {id} OK IDLE -- {steps}"));
                vec![(0, garble(k, &good).unwrap_or(good))]
            }
            _ => vec![],
        }
    });
    let port = Arc::new(LinePort::from_stream("stage", Box::new(stream)));
    let axis = ZaberAxis::new(ZaberChain::new("stage", port), sim_axis("tilt")).expect("axis");
    (axis, log)
}

/// The reply line `reply` with the `digit`-th digit of its position (the last field) replaced by `with`; the
/// checksum, if any, is left as it was.
fn garble_position(reply: &str, digit: usize, with: u8) -> Option<String> {
    let end = reply.find([':', '\r'])?;
    let start = reply[..end].rfind(' ')? + 1;
    let at = start + digit;
    (at < end && reply.as_bytes()[at] != with).then(|| corrupt(reply, at, with))
}

#[tokio::test(start_paused = true)]
async fn zaber_garbled_position_is_caught_by_checksum_or_second_read() {
    trace();
    let steps: i64 = 52_672;
    let truth = 52_672.0 * 0.000234375;
    for mode in [ZChecksums::OnRequest, ZChecksums::Never] {
        // The first reply (before checksums are on) and the second (after, when the device takes the setting),
        // each digit into each other digit.
        for k in 0..2 {
            for digit in 0..5 {
                for with in b'0'..=b'9' {
                    let (axis, log) = resting_zaber(steps, mode, move |i, r| {
                        (i == k).then(|| garble_position(r, digit, with)).flatten()
                    });
                    let read = axis.position_deg().await;
                    let read = read.unwrap_or_else(|e| panic!("reply {k}, digit {digit}: {e}"));
                    // Within the encoder resolution (one microstep here), as for the SMC100.
                    assert!(
                        (read - truth).abs() <= 0.000234375 + 1e-9,
                        "reply {k}, digit {digit} -> {}: read {read}",
                        with as char
                    );
                    let asked = log
                        .lock()
                        .unwrap()
                        .iter()
                        .any(|l| zparse(l).3 == "set comm.checksum 1");
                    assert!(asked, "the driver asks the device for checksums");
                }
            }
        }
    }
}

#[tokio::test(start_paused = true)]
async fn zaber_with_checksums_on_drops_a_garbled_reply_and_asks_again() {
    trace();
    let steps: i64 = 52_672;
    // Checksums on from the start: a digit changed in the data no longer matches the checksum.
    let (stream, log) = {
        let count = AtomicUsize::new(0);
        peer(b'\n', move |line| {
            let (d, a, id, cmd) = zparse(line);
            assert_eq!(cmd, "get pos", "no other command is needed");
            let good = zreply(&format!("{d:02} {a} {id} OK IDLE -- {steps}"));
            if count.fetch_add(1, Ordering::SeqCst) == 0 {
                vec![(0, good.replacen("52672", "58672", 1))]
            } else {
                vec![(0, good)]
            }
        })
    };
    let port = Arc::new(LinePort::from_stream("stage", Box::new(stream)));
    let axis = ZaberAxis::new(ZaberChain::new("stage", port), sim_axis("tilt")).expect("axis");
    let read = axis.position_deg().await.expect("position");
    assert!((read - 52_672.0 * 0.000234375).abs() < 1e-9, "{read}");
    assert_eq!(log.lock().unwrap().len(), 2, "one garbled reply, one retry");
    // (The checksum the test device uses is the protocol's.)
    assert_eq!(checksum(b"1"), 0xCF);
}

#[tokio::test(start_paused = true)]
async fn zaber_without_checksums_and_reads_that_never_agree_is_a_protocol_error() {
    trace();
    // Every reply garbled, each differently: no two reads agree.
    let (axis, _) = resting_zaber(52_672, ZChecksums::Never, |k, r| {
        garble_position(r, 0, b'1' + (k % 4) as u8)
    });
    let err = axis.position_deg().await.expect_err("no agreement");
    assert_eq!(err.kind(), ErrorKind::Protocol, "{err}");
}

#[tokio::test(start_paused = true)]
async fn fw102c_a_garbled_position_cannot_confirm_a_turn_that_did_not_happen() {
    trace();
    // A wheel stuck at position 2: it takes `pos=N` but does not turn. The first `pos?` after the turn is
    // garbled into the requested position.
    let pos_queries = Arc::new(AtomicUsize::new(0));
    let q = Arc::clone(&pos_queries);
    let (stream, _) = peer(b'\r', move |line| {
        let echo = format!("{line}\r");
        match line {
            "pcount?" => vec![(0, echo), (0, "6\r> ".into())],
            "pos?" => {
                // Query 0 comes before the turn, query 1 is the first after it.
                let answer = if q.fetch_add(1, Ordering::SeqCst) == 1 {
                    "3"
                } else {
                    "2"
                };
                vec![(0, echo), (0, format!("{answer}\r> "))]
            }
            l if l.starts_with("pos=") => vec![(0, echo), (0, "> ".into())],
            // Set once per opening of the port: speed and the position sensors off.
            "speed=1" | "sensors=0" => vec![(0, echo), (0, "> ".into())],
            _ => vec![(0, echo), (0, "Command error CMD_NOT_DEFINED\r> ".into())],
        }
    });
    let wheel = Fw102c::new(
        "wheel",
        Arc::new(LinePort::from_stream("wheel", Box::new(stream))),
        0.4,
    );
    let err = wheel.go_to(3).await.expect_err("the wheel did not turn");
    assert_eq!(err.kind(), ErrorKind::MotionFault, "{err}");
    assert!(err.to_string().contains("position 2"), "{err}");
    assert!(
        pos_queries.load(Ordering::SeqCst) >= 3,
        "the garbled answer was read again"
    );
}

/// Regression against the simulator's own fault injection: with a quarter of all replies garbled, every
/// position the drivers return (read-backs after moves, positions read at rest) is the simulator's true encoder
/// position to within its resolution. Errors are allowed (typed), wrong values are not.
#[tokio::test(start_paused = true)]
async fn positions_under_heavy_garbling_are_right_or_typed_errors() {
    trace();
    let sim = sim_with(
        |f| {
            f.garble_rate = 0.25;
            f.drop_rate = 0.0;
            f.seed = 21;
        },
        1.0,
    );
    let light = Smc100Axis::new(
        Smc100Chain::new("arms", sim_port(&sim, "arms")),
        sim_axis("light"),
    );
    let tilt = ZaberAxis::new(
        ZaberChain::new("stage", sim_port(&sim, "stage")),
        sim_axis("tilt"),
    )
    .expect("axis");
    for _ in 0..5 {
        if light.home().await.is_ok() {
            break;
        }
    }
    for _ in 0..5 {
        if tilt.home().await.is_ok() {
            break;
        }
    }
    let (mut checked, mut errors) = (0, 0);
    let resolution = sim_axis("light").encoder_resolution_deg;
    let step = sim_axis("tilt").encoder_resolution_deg;
    for target in [10.0, -20.0, 35.5, 5.25, -60.0, 12.5, 0.75, 44.0] {
        for (name, axis, truth, tol) in [
            ("light", &light as &dyn Axis, 0usize, resolution),
            ("tilt", &tilt as &dyn Axis, 2, step),
        ] {
            let true_deg = |sim: &gonio_simulator::SimInstrument| {
                let p = sim.pose();
                [p.light_deg, p.detector_deg, p.tilt_deg][truth]
            };
            match axis.move_to(target).await {
                Ok(read) => {
                    checked += 1;
                    assert!(
                        (read - true_deg(&sim)).abs() <= tol + 1e-9,
                        "{name}: read back {read}, really {}",
                        true_deg(&sim)
                    );
                }
                Err(e) => {
                    errors += 1;
                    assert!(
                        matches!(
                            e.kind(),
                            ErrorKind::Protocol | ErrorKind::Timeout | ErrorKind::MotionFault
                        ),
                        "{name}: {e}"
                    );
                    // The axis may still be on its way: compare positions at rest only.
                    tokio::time::sleep(std::time::Duration::from_secs(10)).await;
                }
            }
            for _ in 0..4 {
                match axis.position_deg().await {
                    Ok(read) => {
                        checked += 1;
                        assert!(
                            (read - true_deg(&sim)).abs() <= tol + 1e-9,
                            "{name}: position {read}, really {}",
                            true_deg(&sim)
                        );
                    }
                    Err(e) => {
                        errors += 1;
                        assert!(
                            matches!(e.kind(), ErrorKind::Protocol | ErrorKind::Timeout),
                            "{name}: {e}"
                        );
                    }
                }
            }
        }
    }
    let garbled = sim.fault_counts().garbled;
    eprintln!("{checked} positions checked, {errors} typed errors, {garbled} replies garbled");
    assert!(garbled >= 30, "the test must actually garble replies ({garbled})");
    assert!(checked >= 60, "most requests get through ({checked} of 80)");
}
