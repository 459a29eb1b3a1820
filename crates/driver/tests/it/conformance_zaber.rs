//! Zaber: rejections of an unhomed device (the manual's `@01 0 RJ IDLE WR BADDATA`), both answers to a bad
//! checksum, flags in priority order, hexadecimal numbers, under both simulator variants.

use std::sync::Arc;
use std::sync::atomic::{AtomicUsize, Ordering};

use gonio_driver::transport::LinePort;
use gonio_driver::zaber::{Flag, ZaberAxis, ZaberChain};
use gonio_driver::{Axis, ErrorKind};
use gonio_instrument::ZaberBadChecksum;

use crate::common::{demanding_quirks, manual_quirks, sim_axis, sim_file, sim_port, trace};
use crate::scripted::{peer, zparse, zreply};

#[tokio::test(start_paused = true)]
async fn a_bad_checksum_rejected_by_every_device_is_sent_again_even_when_sent_once() {
    trace();
    // The line of the first `home` reached the chain corrupted: both devices reject it (the manual's first
    // answer), with its message id; the second copy is taken.
    let homes = Arc::new(AtomicUsize::new(0));
    let h = Arc::clone(&homes);
    let (stream, log) = peer(b'\n', move |line| {
        let (d, a, id, cmd) = zparse(line);
        match cmd.as_str() {
            "home" if h.fetch_add(1, Ordering::SeqCst) == 0 => vec![
                (0, zreply(&format!("01 0 {id} RJ IDLE -- BADDATA"))),
                (0, zreply(&format!("02 0 {id} RJ IDLE -- BADDATA"))),
            ],
            "home" => vec![(0, zreply(&format!("{d:02} {a} {id} OK BUSY WR 0")))],
            "get pos" => vec![(0, zreply(&format!("{d:02} {a} {id} OK IDLE -- 0")))],
            "warnings" => vec![(0, zreply(&format!("{d:02} {a} {id} OK IDLE -- 00")))],
            _ => vec![(0, zreply(&format!("{d:02} {a} {id} OK IDLE -- 0")))],
        }
    });
    let port = Arc::new(LinePort::from_stream("stage", Box::new(stream)));
    let axis = ZaberAxis::new(ZaberChain::new("stage", port), sim_axis("tilt")).expect("axis");
    axis.home().await.expect("homed after the resend");
    assert_eq!(homes.load(Ordering::SeqCst), 2, "{:?}", log.lock().unwrap());
}

#[tokio::test(start_paused = true)]
async fn a_bad_checksum_that_is_ignored_times_out_and_a_query_is_retried() {
    trace();
    let first = Arc::new(AtomicUsize::new(0));
    let f = Arc::clone(&first);
    let (stream, _) = peer(b'\n', move |line| {
        let (d, a, id, cmd) = zparse(line);
        if f.fetch_add(1, Ordering::SeqCst) == 0 {
            return vec![]; // the manual's second answer: ignored
        }
        match cmd.as_str() {
            "get pos" => vec![(0, zreply(&format!("{d:02} {a} {id} OK IDLE -- 0x2710")))],
            _ => vec![(0, zreply(&format!("{d:02} {a} {id} OK IDLE -- 0")))],
        }
    });
    let port = Arc::new(LinePort::from_stream("stage", Box::new(stream)));
    let chain = ZaberChain::new("stage", port);
    let r = chain.request(1, 1, "get pos", true).await.expect("retried");
    assert_eq!((r.flag, r.data.as_str()), (Flag::Ok, "0x2710"));
    // A position written in hexadecimal is read.
    let axis = ZaberAxis::new(chain, sim_axis("tilt")).expect("axis");
    let deg = axis.position_deg().await.expect("hex position");
    assert!((deg - 10000.0 * 0.000234375).abs() < 1e-9, "{deg}");
}

#[tokio::test(start_paused = true)]
async fn unhomed_moves_are_not_referenced_even_behind_a_higher_priority_flag() {
    trace();
    // The manual's exchange: an unhomed device refuses a relative move with `RJ IDLE WR BADDATA`.
    let (stream, _) = peer(b'\n', |line| {
        let (d, a, id, cmd) = zparse(line);
        match cmd.as_str() {
            c if c.starts_with("move") && a == 1 => {
                vec![(0, zreply(&format!("{d:02} {a} {id} RJ IDLE WR BADDATA")))]
            }
            // Axis 2: a stall flag (FS) shows first; WR is only in the list.
            c if c.starts_with("move") => vec![(0, zreply(&format!("{d:02} {a} {id} RJ IDLE FS BADDATA")))],
            "warnings" => vec![(0, zreply(&format!("{d:02} {a} {id} OK IDLE FS 02 FS WR")))],
            _ => vec![(0, zreply(&format!("{d:02} {a} {id} OK IDLE WR 0")))],
        }
    });
    let port = Arc::new(LinePort::from_stream("stage", Box::new(stream)));
    let chain = ZaberChain::new("stage", port);
    let tilt = ZaberAxis::new(Arc::clone(&chain), sim_axis("tilt")).expect("tilt");
    let err = tilt.start_move(10.0).await.expect_err("unhomed");
    assert_eq!(err.kind(), ErrorKind::NotReferenced, "{err}");
    let rotation = ZaberAxis::new(chain, sim_axis("rotation")).expect("rotation");
    let err = rotation.start_move(10.0).await.expect_err("unhomed behind FS");
    assert_eq!(err.kind(), ErrorKind::NotReferenced, "{err}");
}

#[tokio::test(start_paused = true)]
async fn correct_under_both_bad_checksum_variants() {
    trace();
    // Both answers the manual gives, each set explicitly, with the other devices as the manuals describe them
    // and as recorded.
    for (variant, others) in [
        (ZaberBadChecksum::RejectAll, manual_quirks()),
        (ZaberBadChecksum::Ignore, manual_quirks()),
        (ZaberBadChecksum::RejectAll, demanding_quirks()),
        (ZaberBadChecksum::Ignore, demanding_quirks()),
    ] {
        let sim = sim_file(
            |f| {
                f.simulator.quirks = others;
                f.simulator.quirks.zaber_bad_checksum = variant;
            },
            1.0,
        );
        let chain = ZaberChain::new("stage", sim_port(&sim, "stage"));
        let tilt = ZaberAxis::new(Arc::clone(&chain), sim_axis("tilt")).expect("tilt");
        let err = tilt.start_move(5.0).await.expect_err("unhomed");
        assert_eq!(err.kind(), ErrorKind::NotReferenced, "{variant:?}: {err}");
        tilt.home().await.expect("home");
        let read = tilt.move_to(5.0).await.expect("move");
        assert!((read - 5.0).abs() <= 0.005, "{variant:?}: {read}");
        // A corrupted line, written by hand: the chain's answer (rejections or silence) does not disturb the
        // next request.
        let _ = chain
            .port()
            .send_priority(
                b"/1 1 get pos:00\n",
                tokio::time::Instant::now() + std::time::Duration::from_secs(1),
            )
            .await;
        let read = tilt
            .position_deg()
            .await
            .expect("position after a corrupted line");
        assert!((read - 5.0).abs() <= 0.005, "{variant:?}: {read}");
    }
}
