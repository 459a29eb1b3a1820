//! USBTMC framing and session behaviour against the documentation's byte vectors and a scripted device.

use std::sync::Arc;
use std::time::Duration;

use gonio_driver::transport::usb::{MEMORY_EP_IN, MEMORY_EP_OUT, MemoryPipe, MemoryState, UsbError, UsbPipe};
use gonio_driver::usbtmc::{self, FrameError, Usbtmc, UsbtmcError, decode_in_header, next_btag};
use tokio::time::Instant;

use crate::common::trace;

/// A Bulk-IN DEV_DEP_MSG_IN transfer, built by hand from the specification's table (not with the driver's code).
fn in_frame(btag: u8, data: &[u8], eom: bool) -> Vec<u8> {
    let n = data.len() as u32;
    let mut v = vec![2, btag, !btag, 0];
    v.extend_from_slice(&n.to_le_bytes());
    v.extend_from_slice(&[if eom { 1 } else { 0 }, 0, 0, 0]);
    v.extend_from_slice(data);
    while v.len() % 4 != 0 {
        v.push(0);
    }
    v
}

#[test]
fn meas_pow_frame_matches_the_reference_bytes() {
    let frame = usbtmc::encode_dev_dep_msg_out(1, b"MEAS:POW?\n", true);
    assert_eq!(
        frame,
        [
            0x01, 0x01, 0xFE, 0x00, 0x0A, 0x00, 0x00, 0x00, 0x01, 0x00, 0x00, 0x00, 0x4D, 0x45, 0x41, 0x53,
            0x3A, 0x50, 0x4F, 0x57, 0x3F, 0x0A, 0x00, 0x00
        ]
    );
    let req = usbtmc::encode_request_dev_dep_msg_in(2, 1024, None);
    assert_eq!(
        req,
        [
            0x02, 0x02, 0xFD, 0x00, 0x00, 0x04, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00
        ]
    );
    // TermChar enabled: bit 1 of the attributes, then the character.
    let req = usbtmc::encode_request_dev_dep_msg_in(3, 64, Some(b'\n'));
    assert_eq!(
        req,
        [
            0x02, 0x03, 0xFC, 0x00, 0x40, 0x00, 0x00, 0x00, 0x02, 0x0A, 0x00, 0x00
        ]
    );
    // Padding to a multiple of four for every payload length.
    for n in 0..9 {
        let f = usbtmc::encode_dev_dep_msg_out(7, &vec![b'x'; n], false);
        assert_eq!(f.len(), 12 + n.div_ceil(4) * 4);
        assert_eq!(f[8], 0, "EOM clear");
    }
}

#[test]
fn btag_sequence_wraps_without_zero() {
    assert_eq!(next_btag(0), 1);
    assert_eq!(next_btag(1), 2);
    assert_eq!(next_btag(254), 255);
    assert_eq!(next_btag(255), 1);
}

#[test]
fn in_headers_are_checked() {
    let f = in_frame(9, b"1.5E-3\n", true);
    let h = decode_in_header(&f).expect("valid");
    assert_eq!((h.btag, h.transfer_size, h.eom), (9, 7, true));
    assert_eq!(decode_in_header(&f[..11]), Err(FrameError::Short(11)));
    let mut bad = f.clone();
    bad[2] = 0;
    assert!(matches!(
        decode_in_header(&bad),
        Err(FrameError::TagInverse { .. })
    ));
    let mut bad = f.clone();
    bad[0] = 1;
    assert_eq!(decode_in_header(&bad), Err(FrameError::MsgId(1)));
    let zero = in_frame(0, b"", true);
    assert_eq!(decode_in_header(&zero), Err(FrameError::ZeroTag));
}

/// A scripted USBTMC device: answers every REQUEST_DEV_DEP_MSG_IN with `reply(message)` split per `chunk`.
fn device(mut reply: impl FnMut(&[u8]) -> Vec<u8> + Send + 'static) -> MemoryPipe {
    let mut pending: Vec<u8> = Vec::new();
    MemoryPipe::new().with_responder(move |out: &[u8], state: &mut MemoryState| {
        let size = u32::from_le_bytes([out[4], out[5], out[6], out[7]]) as usize;
        match out[0] {
            1 => pending = reply(&out[12..12 + size]),
            2 => {
                let n = pending.len().min(size);
                let rest = pending.split_off(n);
                let data = std::mem::replace(&mut pending, rest);
                state
                    .in_queue
                    .push_back(Ok(in_frame(out[1], &data, pending.is_empty())));
            }
            _ => {}
        }
    })
}

#[tokio::test(start_paused = true)]
async fn query_round_trip_with_btags_in_sequence() {
    trace();
    let pipe = device(|m| {
        if m == b"*IDN?\n" {
            b"Thorlabs,PM100USB,P000,1.0\n".to_vec()
        } else {
            b"?\n".to_vec()
        }
    });
    let state = Arc::clone(&pipe.state);
    let mut tmc = Usbtmc::new("meter", Arc::new(pipe));
    let answer = tmc
        .query("*IDN?\n", Instant::now() + Duration::from_secs(1))
        .await
        .expect("reply");
    assert_eq!(answer, "Thorlabs,PM100USB,P000,1.0");
    let s = state.lock().unwrap();
    assert_eq!(s.out_log.len(), 2);
    assert_eq!(&s.out_log[0][..4], &[1, 1, 0xFE, 0]);
    assert_eq!(&s.out_log[1][..4], &[2, 2, 0xFD, 0]);
}

#[tokio::test(start_paused = true)]
async fn long_reply_spans_several_requests_until_eom() {
    trace();
    let long: Vec<u8> = (0..100).map(|i| b'a' + (i % 26) as u8).chain(*b"\n").collect();
    let expected = long.clone();
    let pipe = device(move |_| long.clone());
    let state = Arc::clone(&pipe.state);
    let mut tmc = Usbtmc::new("meter", Arc::new(pipe));
    tmc.max_chunk = 16;
    tmc.write(b"X?\n", Instant::now() + Duration::from_secs(1))
        .await
        .expect("write");
    let got = tmc
        .read(Instant::now() + Duration::from_secs(1))
        .await
        .expect("read");
    assert_eq!(got, expected);
    // 101 bytes in chunks of 16: 7 requests, each with its own, increasing bTag.
    let s = state.lock().unwrap();
    let tags: Vec<u8> = s.out_log.iter().skip(1).map(|f| f[1]).collect();
    assert_eq!(tags, vec![2, 3, 4, 5, 6, 7, 8]);
}

#[tokio::test(start_paused = true)]
async fn reply_split_across_bulk_in_transfers_is_reassembled() {
    trace();
    let pipe = MemoryPipe::new().with_responder(|out, state| {
        if out[0] == 2 {
            // One DEV_DEP_MSG_IN delivered as three Bulk-IN transfers (header+4, 4, rest+padding).
            let f = in_frame(out[1], b"1.234E-05\n", true);
            state.in_queue.push_back(Ok(f[..16].to_vec()));
            state.in_queue.push_back(Ok(f[16..20].to_vec()));
            state.in_queue.push_back(Ok(f[20..].to_vec()));
        }
    });
    let mut tmc = Usbtmc::new("meter", Arc::new(pipe));
    let v = tmc
        .query("MEAS:POW?\n", Instant::now() + Duration::from_secs(1))
        .await
        .expect("reply");
    assert_eq!(v, "1.234E-05");
}

#[tokio::test(start_paused = true)]
async fn stale_reply_with_an_old_btag_is_discarded() {
    trace();
    let pipe = MemoryPipe::new().with_responder(|out, state| {
        if out[0] == 2 {
            // An answer to an earlier request (bTag one lower) arrives first, then the real one.
            let old = if out[1] == 1 { 255 } else { out[1] - 1 };
            state.in_queue.push_back(Ok(in_frame(old, b"OLD\n", true)));
            state.in_queue.push_back(Ok(in_frame(out[1], b"NEW\n", true)));
        }
    });
    let mut tmc = Usbtmc::new("meter", Arc::new(pipe));
    let v = tmc
        .query("X?\n", Instant::now() + Duration::from_secs(1))
        .await
        .expect("reply");
    assert_eq!(v, "NEW");
}

#[tokio::test(start_paused = true)]
async fn partial_transfer_on_timeout_is_never_a_reply_and_the_transfer_is_aborted() {
    trace();
    let pipe = MemoryPipe::new().with_responder(|out, state| {
        if out[0] == 2 {
            // The header promises 10 bytes, 4 arrive, then the transfer times out having moved some bytes.
            let f = in_frame(out[1], b"1.23456789", true);
            state.in_queue.push_back(Ok(f[..16].to_vec()));
            state
                .in_queue
                .push_back(Err(UsbError::Timeout { transferred: 2 }));
            // INITIATE_ABORT_BULK_IN: SUCCESS; CHECK_ABORT_BULK_IN_STATUS: PENDING with data queued, then SUCCESS.
            state.control_replies.extend([
                vec![0x01, out[1]],
                vec![0x02, 0x01, 0, 0, 0, 0, 0, 0],
                vec![0x01, 0, 0, 0, 10, 0, 0, 0],
            ]);
        }
    });
    let state = Arc::clone(&pipe.state);
    let mut tmc = Usbtmc::new("meter", Arc::new(pipe));
    let err = tmc
        .query("MEAS:POW?\n", Instant::now() + Duration::from_secs(1))
        .await
        .expect_err("no reply");
    assert_eq!(err, UsbtmcError::Timeout);
    let s = state.lock().unwrap();
    let reqs: Vec<(u8, u8, u16, u16)> = s
        .control_log
        .iter()
        .map(|c| (c.request_type, c.request, c.value, c.index))
        .collect();
    assert_eq!(
        reqs,
        vec![
            (0xA2, 3, 2, u16::from(MEMORY_EP_IN)),
            (0xA2, 4, 0, u16::from(MEMORY_EP_IN)),
            (0xA2, 4, 0, u16::from(MEMORY_EP_IN))
        ]
    );
}

#[tokio::test(start_paused = true)]
async fn halted_endpoint_is_cleared_before_reuse() {
    trace();
    let pipe = device(|_| b"OK\n".to_vec());
    pipe.state.lock().unwrap().halted.push(MEMORY_EP_OUT);
    let state = Arc::clone(&pipe.state);
    let mut tmc = Usbtmc::new("meter", Arc::new(pipe));
    let err = tmc
        .write(b"*CLS\n", Instant::now() + Duration::from_secs(1))
        .await
        .expect_err("halted");
    assert_eq!(err, UsbtmcError::Usb(UsbError::Pipe));
    assert_eq!(state.lock().unwrap().cleared, vec![MEMORY_EP_OUT]);
    // After the clear the pipe works again.
    assert_eq!(
        tmc.query("X?\n", Instant::now() + Duration::from_secs(1))
            .await
            .expect("works"),
        "OK"
    );
}

#[tokio::test(start_paused = true)]
async fn clear_sequence_follows_the_specification() {
    trace();
    let pipe = MemoryPipe::new();
    {
        let mut s = pipe.state.lock().unwrap();
        // INITIATE_CLEAR: SUCCESS; CHECK_CLEAR_STATUS: PENDING with bytes to drain, PENDING, SUCCESS.
        s.control_replies
            .extend([vec![0x01], vec![0x02, 0x01], vec![0x02, 0x00], vec![0x01, 0x00]]);
        s.in_queue.push_back(Ok(in_frame(9, b"leftover\n", true)));
    }
    let state = Arc::clone(&pipe.state);
    let mut tmc = Usbtmc::new("meter", Arc::new(pipe));
    tmc.clear().await.expect("cleared");
    let s = state.lock().unwrap();
    let reqs: Vec<(u8, u8, u16)> = s
        .control_log
        .iter()
        .map(|c| (c.request_type, c.request, c.index))
        .collect();
    assert_eq!(reqs, vec![(0xA1, 5, 0), (0xA1, 6, 0), (0xA1, 6, 0), (0xA1, 6, 0)]);
    assert!(s.in_queue.is_empty(), "the queued data was drained");
    assert_eq!(s.cleared, vec![MEMORY_EP_OUT], "Bulk-OUT halt cleared at the end");
}

#[tokio::test(start_paused = true)]
async fn abort_bulk_out_after_a_write_timeout() {
    trace();
    let pipe = MemoryPipe::new();
    {
        let mut s = pipe.state.lock().unwrap();
        s.out_errors.push_back(UsbError::Timeout { transferred: 4 });
        s.control_replies.extend([
            vec![0x01, 1],
            vec![0x02, 0, 0, 0, 0, 0, 0, 0],
            vec![0x01, 0, 0, 0, 4, 0, 0, 0],
        ]);
    }
    let state = Arc::clone(&pipe.state);
    let mut tmc = Usbtmc::new("meter", Arc::new(pipe));
    let err = tmc
        .write(b"CONF:POW\n", Instant::now() + Duration::from_secs(1))
        .await
        .expect_err("timeout");
    assert_eq!(err, UsbtmcError::Timeout);
    let s = state.lock().unwrap();
    let reqs: Vec<(u8, u8, u16, u16)> = s
        .control_log
        .iter()
        .map(|c| (c.request_type, c.request, c.value, c.index))
        .collect();
    assert_eq!(
        reqs,
        vec![
            (0xA2, 1, 1, u16::from(MEMORY_EP_OUT)),
            (0xA2, 2, 0, u16::from(MEMORY_EP_OUT)),
            (0xA2, 2, 0, u16::from(MEMORY_EP_OUT))
        ]
    );
    assert_eq!(s.cleared, vec![MEMORY_EP_OUT]);
}

#[tokio::test(start_paused = true)]
async fn vanished_device_is_reported_as_such() {
    let pipe = device(|_| b"x\n".to_vec());
    pipe.state.lock().unwrap().gone = true;
    let mut tmc = Usbtmc::new("meter", Arc::new(pipe) as Arc<dyn UsbPipe>);
    let err = tmc
        .query("X?\n", Instant::now() + Duration::from_secs(1))
        .await
        .expect_err("gone");
    assert_eq!(err, UsbtmcError::Usb(UsbError::NoDevice));
}
