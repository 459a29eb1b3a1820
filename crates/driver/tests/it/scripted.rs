//! The serial drivers against scripted in-memory peers: written from the manuals, independent of the simulator.

use std::sync::{Arc, Mutex};
use std::time::Duration;

use gonio_driver::fw102c::Fw102c;
use gonio_driver::smc100::{Smc100Axis, Smc100Chain};
use gonio_driver::transport::{LinePort, PortOpener};
use gonio_driver::zaber::{ZaberAxis, ZaberChain, checksum};
use gonio_driver::{Axis, ErrorKind, FilterWheel};
use tokio::io::{AsyncReadExt, AsyncWriteExt, DuplexStream};

use crate::common::{sim_axis, trace};

pub(crate) type Log = Arc<Mutex<Vec<String>>>;

/// A scripted device: for every received line (terminated by `term`), `handler` returns chunks to send back,
/// each after its delay. Every line is logged as it arrives.
pub(crate) fn peer(
    term: u8,
    mut handler: impl FnMut(&str) -> Vec<(u64, String)> + Send + 'static,
) -> (DuplexStream, Log) {
    let (host, dev) = tokio::io::duplex(4096);
    let (mut rx, tx) = tokio::io::split(dev);
    let tx = Arc::new(tokio::sync::Mutex::new(tx));
    let log: Log = Arc::default();
    let log2 = Arc::clone(&log);
    tokio::spawn(async move {
        let mut buf = Vec::new();
        let mut chunk = [0u8; 256];
        loop {
            let n = match rx.read(&mut chunk).await {
                Ok(0) | Err(_) => return,
                Ok(n) => n,
            };
            buf.extend_from_slice(&chunk[..n]);
            while let Some(at) = buf.iter().position(|b| *b == term) {
                let line: Vec<u8> = buf.drain(..=at).collect();
                let text = String::from_utf8_lossy(&line)
                    .trim_end_matches(['\r', '\n'])
                    .to_string();
                if text.is_empty() {
                    continue;
                }
                log2.lock().unwrap().push(text.clone());
                let replies = handler(&text);
                let tx = Arc::clone(&tx);
                // Replies go out from their own task so that a slow answer does not stop the device listening.
                let write = async move {
                    for (delay_ms, out) in replies {
                        if delay_ms > 0 {
                            tokio::time::sleep(Duration::from_millis(delay_ms)).await;
                        }
                        if tx.lock().await.write_all(out.as_bytes()).await.is_err() {
                            return;
                        }
                    }
                };
                tokio::spawn(write);
            }
        }
    });
    (host, log)
}

/// A minimal SMC100 controller set by hand from the manual: addresses 1 and 2, READY, positions given.
fn smc_peer(ts: &'static str, tp: &'static str) -> impl FnMut(&str) -> Vec<(u64, String)> + Send + 'static {
    move |line: &str| {
        let addr = &line[..1];
        let cmd = &line[1..];
        match cmd {
            "TS" => vec![(0, format!("{addr}TS{ts}\r\n"))],
            "TP" => vec![(0, format!("{addr}TP{tp}\r\n"))],
            "TE" => vec![(0, format!("{addr}TE@\r\n"))],
            c if c.starts_with("PT") => vec![(0, format!("{addr}PT0.5\r\n"))],
            _ => vec![],
        }
    }
}

fn smc_axis(stream: DuplexStream, name: &str) -> Smc100Axis {
    let port = Arc::new(LinePort::from_stream("arms", Box::new(stream)));
    Smc100Axis::new(Smc100Chain::new("arms", port), sim_axis(name))
}

#[tokio::test(start_paused = true)]
async fn smc100_stale_lines_are_discarded_and_replies_matched_by_address() {
    trace();
    let (stream, _log) = peer(b'\n', |line| match line {
        // A stale reply for the other controller and a junk line arrive before the real answer.
        "1TP" => vec![
            (0, "2TP99.00000\r\n".into()),
            (0, "garbage\r\n".into()),
            (0, "1TP12.50000\r\n".into()),
        ],
        _ => vec![],
    });
    let axis = smc_axis(stream, "light");
    assert_eq!(axis.position_deg().await.expect("position"), 12.5);
}

#[tokio::test(start_paused = true)]
async fn smc100_arrival_needs_ready_and_the_read_back_within_tolerance() {
    trace();
    let (stream, log) = peer(b'\n', smc_peer("000033", "10.00100"));
    let axis = smc_axis(stream, "light");
    axis.start_move(10.0).await.expect("PA accepted");
    assert_eq!(axis.wait_arrived(10.0).await.expect("arrived"), 10.001);
    assert!(
        log.lock().unwrap().iter().any(|l| l == "1PA10.000000"),
        "{:?}",
        log.lock().unwrap()
    );
    // READY but 0.5 deg off: not arrived, and the error says where it is.
    let (stream, _) = peer(b'\n', smc_peer("000033", "9.50000"));
    let axis = smc_axis(stream, "light");
    let err = axis.wait_arrived(10.0).await.expect_err("not there");
    assert_eq!(err.kind(), ErrorKind::MotionFault);
    assert!(err.to_string().contains("9.5"), "{err}");
}

#[tokio::test(start_paused = true)]
async fn smc100_disable_after_a_stall_is_terminal_with_the_device_reason() {
    trace();
    let (stream, _) = peer(b'\n', smc_peer("00203D", "3.20000"));
    let axis = smc_axis(stream, "detector");
    let err = axis.wait_arrived(10.0).await.expect_err("stalled");
    assert_eq!(err.kind(), ErrorKind::MotionFault);
    let msg = err.to_string();
    assert!(
        msg.contains("DISABLE from moving") && msg.contains("following error"),
        "{msg}"
    );
    // NOT REFERENCED is terminal too.
    let (stream, _) = peer(b'\n', smc_peer("00000A", "0.00000"));
    let err = smc_axis(stream, "detector")
        .wait_arrived(10.0)
        .await
        .expect_err("not referenced");
    assert_eq!(err.kind(), ErrorKind::NotReferenced);
}

#[tokio::test(start_paused = true)]
async fn smc100_rejections_carry_the_te_code() {
    trace();
    let (stream, _) = peer(b'\n', |line| match line {
        "1TE" => vec![(0, "1TEH\r\n".into())],
        "1TP" => vec![(0, "1TP0.00000\r\n".into())],
        _ => vec![],
    });
    let axis = smc_axis(stream, "light");
    let err = axis.start_move(5.0).await.expect_err("not referenced");
    assert_eq!(err.kind(), ErrorKind::NotReferenced);
    let (stream, _) = peer(b'\n', |line| match line {
        "1TE" => vec![(0, "1TEM\r\n".into())],
        "1TP" => vec![(0, "1TP0.00000\r\n".into())],
        _ => vec![],
    });
    let err = smc_axis(stream, "light")
        .start_move(5.0)
        .await
        .expect_err("moving");
    assert_eq!(err.kind(), ErrorKind::Rejected);
    assert!(err.to_string().contains("MOVING"), "{err}");
    // Out of the configured travel: refused before anything is sent.
    let (stream, log) = peer(b'\n', smc_peer("000033", "0"));
    let err = smc_axis(stream, "light")
        .start_move(150.0)
        .await
        .expect_err("limits");
    assert_eq!(err.kind(), ErrorKind::OutOfRange);
    assert!(log.lock().unwrap().is_empty());
}

#[tokio::test(start_paused = true)]
async fn smc100_stop_overtakes_a_request_in_flight() {
    trace();
    // The controller takes 200 ms to answer TS; a stop for address 2 is sent meanwhile.
    let (stream, log) = peer(b'\n', |line| match line {
        "1TS" => vec![(200, "1TS000028\r\n".into())],
        _ => vec![],
    });
    let port = Arc::new(LinePort::from_stream("arms", Box::new(stream)));
    let chain = Smc100Chain::new("arms", port);
    let a1 = Smc100Axis::new(Arc::clone(&chain), sim_axis("light"));
    let a2 = Smc100Axis::new(Arc::clone(&chain), sim_axis("detector"));
    let slow = tokio::spawn(async move { a1.read_status().await.map(|s| s.moving) });
    tokio::time::sleep(Duration::from_millis(20)).await;
    a2.stop().await.expect("stop sent");
    tokio::time::sleep(Duration::from_millis(5)).await;
    // (The status exchange asks TS alone and waits for its reply before the TP reads, as a paced host does;
    // the stop goes out at once and once more after the set-command pause, both before TS is answered.)
    assert_eq!(
        *log.lock().unwrap(),
        vec!["1TS".to_string(), "2ST".to_string(), "2ST".to_string()],
        "stop written while TS pending"
    );
    assert!(!slow.is_finished());
    // The slow exchange still completes (its TP is not answered: it ends in a bounded timeout, not a hang).
    let r = slow.await.expect("task");
    assert_eq!(r.expect_err("TP unanswered").kind(), ErrorKind::Timeout);
}

#[tokio::test(start_paused = true)]
async fn smc100_disconnect_is_reported_and_reconnect_reverifies() {
    trace();
    let make: Arc<Mutex<Vec<DuplexStream>>> = Arc::default();
    let (first, _) = peer(b'\n', smc_peer("000033", "1.00000"));
    let (second, _) = peer(b'\n', smc_peer("00000A", "0.00000")); // came back unreferenced (power cycle)
    let (third, _) = peer(b'\n', smc_peer("000032", "0.00000"));
    make.lock().unwrap().extend([third, second, first]);
    let m = Arc::clone(&make);
    let opener = PortOpener::Stream(Arc::new(move || {
        m.lock()
            .unwrap()
            .pop()
            .map(|s| Box::new(s) as _)
            .ok_or_else(|| std::io::Error::other("no more streams"))
    }));
    let port = Arc::new(LinePort::open("arms", opener).expect("open"));
    let axis = Smc100Axis::new(Smc100Chain::new("arms", Arc::clone(&port)), sim_axis("light"));
    assert_eq!(axis.position_deg().await.expect("first link"), 1.0);
    let err = axis
        .reconnect()
        .await
        .expect_err("unreferenced after the power cycle");
    assert_eq!(err.kind(), ErrorKind::NotReferenced);
    let status = axis.reconnect().await.expect("third link is fine");
    assert!(status.referenced && !status.moving);
}

#[tokio::test(start_paused = true)]
async fn link_lost_is_disconnected() {
    trace();
    let (host, dev) = tokio::io::duplex(64);
    drop(dev);
    let axis = smc_axis(host, "light");
    let err = axis.position_deg().await.expect_err("gone");
    assert_eq!(err.kind(), ErrorKind::Disconnected);
}

/// A Zaber reply line with a checksum, as a device configured to send them would.
pub(crate) fn zreply(body: &str) -> String {
    format!("@{body}:{:02X}\r\n", checksum(body.as_bytes()))
}

/// Extract (device, axis, id, command) from `/d a id cmd:CC` after checking the checksum.
pub(crate) fn zparse(line: &str) -> (u8, u8, u8, String) {
    let body = line.strip_prefix('/').expect("starts with /");
    let (body, cs) = body.rsplit_once(':').expect("has a checksum");
    let sum = body.bytes().fold(0u8, |s, b| s.wrapping_add(b));
    assert_eq!(
        sum.wrapping_add(u8::from_str_radix(cs, 16).expect("hex")),
        0,
        "bad checksum in {line}"
    );
    let mut t = body.splitn(4, ' ');
    let d = t.next().unwrap().parse().unwrap();
    let a = t.next().unwrap().parse().unwrap();
    let id = t.next().unwrap().parse().unwrap();
    (d, a, id, t.next().unwrap_or("").to_string())
}

#[tokio::test(start_paused = true)]
async fn zaber_ids_checksums_alerts_and_garbage() {
    trace();
    let mut first = true;
    let (stream, log) = peer(b'\n', move |line| {
        let (d, a, id, cmd) = zparse(line);
        match cmd.as_str() {
            "get pos" if first => {
                first = false;
                // Garbled (bad checksum), then an alert, then a reply for another id: all must be skipped;
                // the request then times out and is retried with a new id.
                let mut bad = zreply(&format!("{d:02} {a} {id} OK IDLE -- 1000"));
                bad.replace_range(10..11, "9");
                vec![
                    (0, bad),
                    (0, format!("!{d:02} {a} IDLE --\r\n")),
                    (0, zreply(&format!("{d:02} {a} {} OK IDLE -- 5", (id + 1) % 100))),
                ]
            }
            "get pos" => vec![
                (0, "#01 1 info line\r\n".into()),
                (0, zreply(&format!("{d:02} {a} {id} OK IDLE -- 42667"))),
            ],
            "move abs 999999999" => vec![(0, zreply(&format!("{d:02} {a} {id} RJ IDLE -- BADDATA")))],
            _ => vec![],
        }
    });
    let port = Arc::new(LinePort::from_stream("stage", Box::new(stream)));
    let axis = ZaberAxis::new(ZaberChain::new("stage", port), sim_axis("tilt")).expect("axis");
    let deg = axis.position_deg().await.expect("position after a retry");
    assert!((deg - 42667.0 * 0.000234375).abs() < 1e-12);
    let ids: Vec<u8> = log.lock().unwrap().iter().map(|l| zparse(l).2).collect();
    assert_eq!(ids, vec![0, 1], "the retry used a fresh id");
}

#[tokio::test(start_paused = true)]
async fn zaber_rejection_and_fault_flags_are_errors() {
    trace();
    let (stream, _) = peer(b'\n', |line| {
        let (d, a, id, cmd) = zparse(line);
        match cmd.as_str() {
            "get pos" => vec![(0, zreply(&format!("{d:02} {a} {id} OK IDLE FS 1000")))],
            "warnings" => vec![(0, zreply(&format!("{d:02} {a} {id} OK IDLE FS 02 FS WL")))],
            "warnings clear" => vec![(0, zreply(&format!("{d:02} {a} {id} OK IDLE FS 02 FS WL")))],
            c if c.starts_with("move abs") => {
                vec![(0, zreply(&format!("{d:02} {a} {id} RJ IDLE WR BADCOMMAND")))]
            }
            _ => vec![],
        }
    });
    let port = Arc::new(LinePort::from_stream("stage", Box::new(stream)));
    let axis = ZaberAxis::new(ZaberChain::new("stage", port), sim_axis("rotation")).expect("axis");
    let err = axis.wait_arrived(10.0).await.expect_err("stalled");
    assert_eq!(err.kind(), ErrorKind::MotionFault);
    assert!(
        err.to_string().contains("FS (stalled and stopped)") && err.to_string().contains("WL"),
        "{err}"
    );
    let err = axis.start_move(10.0).await.expect_err("not referenced");
    assert_eq!(err.kind(), ErrorKind::NotReferenced);
}

#[tokio::test(start_paused = true)]
async fn fw102c_echo_prompt_and_error_text() {
    trace();
    let pos = Arc::new(Mutex::new(1u8));
    let p = Arc::clone(&pos);
    let (stream, _) = peer(b'\r', move |line| {
        let echo = format!("{line}\r");
        match line {
            "pcount?" => vec![(0, echo), (0, "6\r> ".into())],
            "pos?" => vec![(0, echo), (0, format!("{}\r> ", p.lock().unwrap()))],
            l if l.starts_with("pos=") => {
                let n: u8 = l[4..].parse().unwrap_or(0);
                *p.lock().unwrap() = n;
                // The prompt comes when the wheel has turned.
                vec![(0, echo), (900, "> ".into())]
            }
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
    wheel.go_to(4).await.expect("turned");
    assert_eq!(wheel.position().await.expect("pos"), 4);
    let err = wheel.go_to(9).await.expect_err("only 6 positions");
    assert_eq!(err.kind(), ErrorKind::OutOfRange);
    let err = wheel
        .exchange("bogus?", Duration::from_millis(500), true)
        .await
        .expect_err("unknown command");
    assert_eq!(err.kind(), ErrorKind::Rejected);
    assert!(err.to_string().contains("CMD_NOT_DEFINED"));
}

#[tokio::test(start_paused = true)]
async fn zaber_reply_continued_in_info_lines_is_joined() {
    trace();
    let (stream, _) = peer(b'\n', |line| {
        let (d, a, id, cmd) = zparse(line);
        match cmd.as_str() {
            "warnings" => vec![
                (0, zreply(&format!("{d:02} {a} {id} OK IDLE FS 03 FS\\"))),
                (0, format!("#{d:02} {a} {id} cont 1 WL\\\r\n")),
                (0, format!("#{d:02} {a} {id} cont 2 NI\r\n")),
            ],
            _ => vec![],
        }
    });
    let port = Arc::new(LinePort::from_stream("stage", Box::new(stream)));
    let axis = ZaberAxis::new(ZaberChain::new("stage", port), sim_axis("tilt")).expect("axis");
    assert_eq!(axis.warnings().await.expect("joined"), vec!["FS", "WL", "NI"]);
}

#[tokio::test(start_paused = true)]
async fn smc100_pa_retry_after_a_lost_te_is_recognised_as_in_progress() {
    trace();
    // The first TE reply is lost; the retried PA meets a MOVING controller (TE M) whose set-point is our target.
    let mut te_calls = 0;
    let (stream, log) = peer(b'\n', move |line| match line {
        "1TP" => vec![(0, "1TP0.00000\r\n".into())],
        "1TE" => {
            te_calls += 1;
            if te_calls == 1 {
                vec![]
            } else {
                vec![(0, "1TEM\r\n".into())]
            }
        }
        "1TH" => vec![(0, "1TH25.00000\r\n".into())],
        _ => vec![],
    });
    let axis = smc_axis(stream, "light");
    axis.start_move(25.0)
        .await
        .expect("in progress counts as started");
    let sent = log.lock().unwrap().clone();
    assert_eq!(
        sent.iter().filter(|l| l.starts_with("1PA")).count(),
        2,
        "{sent:?}"
    );
    // A different set-point means the axis is busy with something else: a real rejection.
    let (stream, _) = peer(b'\n', |line| match line {
        "1TP" => vec![(0, "1TP0.00000\r\n".into())],
        "1TE" => vec![(0, "1TEM\r\n".into())],
        "1TH" => vec![(0, "1TH-5.00000\r\n".into())],
        _ => vec![],
    });
    assert_eq!(
        smc_axis(stream, "light")
            .start_move(25.0)
            .await
            .expect_err("busy")
            .kind(),
        ErrorKind::Rejected
    );
}

/// A position report is one query, and says how many bytes its request and its reply took on the line (what
/// the engine dates a report by while an arm sweeps): counted here on the wire itself.
#[tokio::test(start_paused = true)]
async fn a_position_report_is_one_query_with_the_sizes_of_its_exchange() {
    trace();
    let (stream, log) = peer(b'\n', |line| match line {
        "1TP" => vec![(0, "1TP12.34567\r\n".into())],
        _ => vec![],
    });
    let axis = smc_axis(stream, "light");
    let r = axis.position_report().await.expect("report");
    assert_eq!(r.position_deg, 12.34567);
    assert_eq!(*log.lock().unwrap(), vec!["1TP".to_string()], "a single TP");
    assert_eq!(
        (r.request_bytes, r.reply_bytes),
        ("1TP\r\n".len(), "1TP12.34567\r\n".len())
    );

    let sent: Arc<Mutex<Vec<String>>> = Arc::default();
    let replied = Arc::clone(&sent);
    let (stream, log) = peer(b'\n', move |line| {
        let (d, a, id, cmd) = zparse(line);
        match cmd.as_str() {
            "get pos" => {
                let reply = zreply(&format!("{d:02} {a} {id} OK BUSY -- -42667"));
                replied.lock().unwrap().push(reply.clone());
                vec![(0, reply)]
            }
            _ => vec![(0, zreply(&format!("{d:02} {a} {id} OK IDLE -- 0")))],
        }
    });
    let port = Arc::new(LinePort::from_stream("stage", Box::new(stream)));
    let axis = ZaberAxis::new(ZaberChain::new("stage", port), sim_axis("tilt")).expect("axis");
    let r = axis.position_report().await.expect("report");
    assert!(
        (r.position_deg + 42667.0 * 0.000234375).abs() < 1e-12,
        "{}",
        r.position_deg
    );
    let log = log.lock().unwrap();
    let request = log.iter().rfind(|l| l.contains("get pos")).expect("get pos sent");
    assert_eq!(r.request_bytes, request.len() + 1, "{request} and its newline");
    let reply = sent.lock().unwrap().last().cloned().expect("replied");
    assert_eq!(r.reply_bytes, reply.len(), "{reply:?}");
}

#[tokio::test(start_paused = true)]
async fn smc100_a_speed_the_controller_holds_is_not_written_again() {
    trace();
    let (stream, log) = peer(b'\n', smc_peer("000033", "10.00000"));
    let axis = smc_axis(stream, "light");
    let sets = |log: &Log| -> Vec<String> {
        log.lock()
            .unwrap()
            .iter()
            .filter(|l| l[1..].starts_with("VA") || l[1..].starts_with("AC"))
            .cloned()
            .collect()
    };
    // Nothing is known at first: both written, each a set command with its pause.
    axis.set_speed(2.5, 80.0).await.expect("speed");
    assert_eq!(sets(&log), ["1VA2.500000", "1AC80.000000"]);
    // The same again: nothing sent. A new speed at the same acceleration: VA alone.
    axis.set_speed(2.5, 80.0).await.expect("speed");
    axis.set_speed(20.0, 80.0).await.expect("speed");
    assert_eq!(sets(&log), ["1VA2.500000", "1AC80.000000", "1VA20.000000"]);
    // Homing is where a power-cycled controller is met again: what it holds is not known after it.
    axis.home().await.expect("already referenced");
    axis.set_speed(20.0, 80.0).await.expect("speed");
    assert_eq!(
        sets(&log),
        [
            "1VA2.500000",
            "1AC80.000000",
            "1VA20.000000",
            "1VA20.000000",
            "1AC80.000000"
        ]
    );
}
