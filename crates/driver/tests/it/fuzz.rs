//! Every reply parser fed arbitrary bytes: never a panic, and never a value out of a malformed reply.

use gonio_driver::fw102c::{Answer, parse_answer, parse_int};
use gonio_driver::pm100::{parse_scpi_error, parse_scpi_number};
use gonio_driver::smc100::{parse_number, parse_reply, parse_te, parse_ts};
use gonio_driver::usbtmc::decode_in_header;
use gonio_driver::zaber::{Message, checksum, parse_message};
use proptest::prelude::*;

proptest! {
    #![proptest_config(ProptestConfig { cases: 2000, ..ProptestConfig::default() })]

    #[test]
    fn smc100_parsers_never_panic(bytes in proptest::collection::vec(any::<u8>(), 0..40)) {
        if let Some((addr, cc, value)) = parse_reply(&bytes) {
            // Whatever was accepted really has the documented shape.
            prop_assert!((1..=31).contains(&addr));
            prop_assert!(cc.iter().all(u8::is_ascii_uppercase));
            let text = std::str::from_utf8(&bytes).expect("accepted lines are text");
            prop_assert!(text.starts_with(&addr.to_string()));
            prop_assert!(text.ends_with(value));
            if let Some(ts) = parse_ts(value) {
                prop_assert_eq!(value.len(), 6);
                let _ = ts.state.describe();
            }
            if let Some(x) = parse_number(value) { prop_assert!(x.is_finite()); }
            if let Some(c) = parse_te(value) { prop_assert_eq!(value.len(), 1); prop_assert!(c == '@' || c.is_ascii_uppercase()); }
        }
    }

    #[test]
    fn smc100_ts_rejects_all_but_six_hex_digits(s in "[0-9A-Fa-f]{0,8}|.{0,8}") {
        let hex = s.len() == 6 && s.bytes().all(|b| b.is_ascii_hexdigit());
        if !hex {
            prop_assert!(parse_ts(&s).is_none());
        }
    }

    #[test]
    fn zaber_parser_never_panics_and_checks_checksums(bytes in proptest::collection::vec(any::<u8>(), 0..60)) {
        if let Ok(Message::Reply(r)) = parse_message(&bytes) {
            prop_assert!(!r.data.is_empty());
            let text = std::str::from_utf8(&bytes).expect("accepted lines are text");
            prop_assert!(text.starts_with('@'));
        }
    }

    #[test]
    fn zaber_single_byte_corruption_of_a_checksummed_reply_is_caught(pos in 1usize..20, byte in 0x20u8..0x7f) {
        let body = "01 1 42 OK IDLE -- 12345";
        let line = format!("@{body}:{:02X}", checksum(body.as_bytes()));
        let mut bytes = line.into_bytes();
        let at = pos.min(body.len());
        prop_assume!(bytes[at] != byte);
        bytes[at] = byte;
        // Either the line no longer parses, or (never) it parses to the same values: a flipped byte is never
        // accepted as a valid reply.
        prop_assert!(parse_message(&bytes).is_err());
    }

    #[test]
    fn usbtmc_header_never_panics(bytes in proptest::collection::vec(any::<u8>(), 0..32)) {
        if let Ok(h) = decode_in_header(&bytes) {
            prop_assert!(bytes.len() >= 12);
            prop_assert_eq!(bytes[0], 2);
            prop_assert!(h.btag != 0);
            prop_assert_eq!(bytes[2], !bytes[1]);
        }
    }

    #[test]
    fn scpi_and_wheel_parsers_never_panic(s in ".{0,40}", bytes in proptest::collection::vec(any::<u8>(), 0..40)) {
        if let Some(x) = parse_scpi_number(&s) { prop_assert!(x.is_finite()); }
        let _ = parse_scpi_error(&s);
        match parse_answer("pos?", &bytes) {
            Some(Answer::Lines(lines)) => {
                if let Some(n) = parse_int(&lines) { prop_assert!(n < 1000); }
            }
            Some(Answer::Error(_)) | None => {}
        }
    }
}

// ---------------------------------------------------------------- at scale: near-valid replies, hostile devices
//
// The blocks below run `GONIO_FUZZ_CASES` cases (default: a fast tier for `cargo test`); for a large run, e.g.
// `GONIO_FUZZ_CASES=200000 cargo test --release -p gonio-driver --test it fuzz`.

use std::sync::{Arc, Mutex};
use std::time::Duration;

use gonio_driver::fw102c::Fw102c;
use gonio_driver::pm100::Pm100;
use gonio_driver::smc100::{Smc100Axis, Smc100Chain};
use gonio_driver::transport::usb::{BoxFuture, UsbError, UsbPipe};
use gonio_driver::transport::{LinePort, PortOpener};
use gonio_driver::usbtmc::{encode_request_dev_dep_msg_in, next_btag};
use gonio_driver::zaber::{ZaberAxis, ZaberChain};
use gonio_driver::{Axis, Detector, DetectorConfig, DriverError, FilterWheel, PowerRange};
use tokio::io::{AsyncReadExt, AsyncWriteExt};

use crate::common::sim_axis;

/// Cases per property: `GONIO_FUZZ_CASES`, else `default`.
fn cases(default: u32) -> u32 {
    std::env::var("GONIO_FUZZ_CASES")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(default)
}

/// Up to three random edits (replace, insert, delete a byte) of a valid message.
fn mutated(valid: &'static [&'static str]) -> impl Strategy<Value = Vec<u8>> {
    let edit = (0u8..3, any::<prop::sample::Index>(), any::<u8>());
    (prop::sample::select(valid), proptest::collection::vec(edit, 1..4)).prop_map(|(v, edits)| {
        let mut bytes = v.as_bytes().to_vec();
        for (kind, at, byte) in edits {
            let i = at.index(bytes.len() + 1);
            match kind {
                0 if i < bytes.len() => bytes[i] = byte,
                1 => bytes.insert(i, byte),
                _ if i < bytes.len() => {
                    bytes.remove(i);
                }
                _ => bytes.push(byte),
            }
        }
        bytes
    })
}

const SMC_REPLIES: &[&str] = &[
    "1TS000033",
    "2TS00200F",
    "1TP12.3456",
    "2TH-45.5",
    "1TE@",
    "1TEH",
    "1PT0.512",
    "2VA20",
];
const ZABER_REPLIES: &[&str] = &[
    "@01 1 42 OK IDLE -- 12345",
    "@01 0 OK BUSY WR 0",
    "@02 1 07 RJ IDLE -- BADDATA",
    "!01 1 IDLE --",
    "@01 1 42 OK IDLE -- 12345:3E",
];
const SCPI_NUMBERS: &[&str] = &[
    "1.234567E-06",
    "-3.2E-09",
    "9.9E37",
    "5.000000E-04",
    "0",
    "+4.5e+2",
];

proptest! {
    #![proptest_config(ProptestConfig { cases: cases(3000), failure_persistence: None, ..ProptestConfig::default() })]

    #[test]
    fn near_valid_smc100_replies_parse_to_their_documented_shape_or_not_at_all(bytes in mutated(SMC_REPLIES)) {
        if let Some((addr, cc, value)) = parse_reply(&bytes) {
            prop_assert!((1..=31).contains(&addr));
            prop_assert!(cc.iter().all(u8::is_ascii_uppercase));
            if let Some(ts) = parse_ts(value) {
                prop_assert_eq!(value.len(), 6);
                prop_assert!(!ts.state.describe().is_empty());
            }
            if let Some(x) = parse_number(value) {
                prop_assert!(x.is_finite());
            }
        }
    }

    #[test]
    fn near_valid_zaber_replies_never_panic_and_keep_their_shape(bytes in mutated(ZABER_REPLIES)) {
        if let Ok(Message::Reply(r)) = parse_message(&bytes) {
            prop_assert!(!r.data.is_empty());
            prop_assert_eq!(bytes.first(), Some(&b'@'));
        }
    }

    #[test]
    fn near_valid_scpi_numbers_are_finite_or_refused(bytes in mutated(SCPI_NUMBERS)) {
        let text = String::from_utf8_lossy(&bytes);
        if let Some(x) = parse_scpi_number(&text) {
            prop_assert!(x.is_finite());
        }
        let _ = parse_scpi_error(&text);
    }

    #[test]
    fn near_valid_usbtmc_headers_are_checked(
        btag in 1u8..=255,
        size in 0u32..64,
        edits in proptest::collection::vec((0usize..16, any::<u8>()), 1..3),
    ) {
        let mut t = vec![2, btag, !btag, 0];
        t.extend_from_slice(&size.to_le_bytes());
        t.extend_from_slice(&[1, 0, 0, 0]);
        t.extend(std::iter::repeat_n(b'x', size as usize));
        for (at, byte) in edits {
            if let Some(b) = t.get_mut(at) {
                *b = byte;
            }
        }
        if let Ok(h) = decode_in_header(&t) {
            prop_assert_eq!(t[0], 2);
            prop_assert_eq!(t[2], !t[1]);
            prop_assert_eq!(h.btag, t[1]);
            prop_assert!(h.btag != 0);
        }
    }
}

// ---- hostile devices: the whole driver, against a peer that answers garbage

/// What a hostile device answers to each line: random bytes, or a plausible line with random content.
fn hostile_replies(
    prefixes: &'static [&'static str],
    end: &'static str,
) -> impl Strategy<Value = Vec<Vec<u8>>> {
    let random = proptest::collection::vec(any::<u8>(), 0..40);
    // Valid replies (to whichever command) are in the lists; a tail of hex digits and numbers makes more of
    // them parse, printable noise makes them fail later.
    let tail = prop_oneof![
        Just(String::new()),
        "[0-9]{1,2}",
        "[0-9A-F.-]{0,9}",
        "[ -~]{0,16}"
    ];
    let plausible = (prop::sample::select(prefixes), tail)
        .prop_map(move |(p, tail)| format!("{p}{tail}{end}").into_bytes());
    proptest::collection::vec(
        prop_oneof![1 => random, 3 => plausible, 1 => Just(Vec::new())],
        1..12,
    )
}

/// A byte-stream device that answers every received line (ended by `term`) with the next reply, cycling.
/// Each (re)connection gets a fresh device.
fn hostile_port(name: &str, term: u8, replies: Vec<Vec<u8>>) -> Arc<LinePort> {
    let replies = Arc::new(replies);
    let opener = PortOpener::Stream(Arc::new(move || {
        let (host, dev) = tokio::io::duplex(4096);
        let replies = Arc::clone(&replies);
        tokio::spawn(async move {
            let (mut rx, mut tx) = tokio::io::split(dev);
            let mut next = 0usize;
            let mut chunk = [0u8; 256];
            let mut line = Vec::new();
            loop {
                let n = match rx.read(&mut chunk).await {
                    Ok(0) | Err(_) => return,
                    Ok(n) => n,
                };
                for &b in &chunk[..n] {
                    if b != term {
                        line.push(b);
                        continue;
                    }
                    let reply = with_message_id(&replies[next % replies.len()], &line);
                    line.clear();
                    next += 1;
                    if tx.write_all(&reply).await.is_err() {
                        return;
                    }
                }
            }
        });
        Ok(Box::new(host) as _)
    }));
    Arc::new(LinePort::open(name, opener).expect("open the hostile port"))
}

/// A reply template with `{id}` replaced by the message id of a Zaber command line (`/<dev> <axis> <id> ...`)
/// and `{echo}` by the command itself (the FW102C echoes it), so that a hostile reply can get past those checks
/// into the parsing of its content.
fn with_message_id(reply: &[u8], command: &[u8]) -> Vec<u8> {
    let text = String::from_utf8_lossy(reply);
    let text = text.replace(
        "{echo}",
        String::from_utf8_lossy(command).trim_end_matches(['\r', '\n']),
    );
    if !text.contains("{id}") {
        return text.into_bytes();
    }
    let id = String::from_utf8_lossy(command)
        .trim_start_matches('/')
        .split([' ', ':'])
        .nth(2)
        .unwrap_or("0")
        .to_string();
    text.replace("{id}", &id).into_bytes()
}

/// Run driver operations on the paused clock: each must end (Ok or Err) well within a simulated day.
fn bounded<T>(what: &str, fut: impl std::future::Future<Output = T>) -> Result<T, TestCaseError> {
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .start_paused(true)
        .build()
        .map_err(|e| TestCaseError::fail(format!("runtime: {e}")))?;
    rt.block_on(async { tokio::time::timeout(Duration::from_secs(86_400), fut).await })
        .map_err(|_| TestCaseError::fail(format!("{what}: no end within a simulated day (a hang)")))
}

fn finite_or_error(what: &str, r: &Result<f64, DriverError>) -> Result<(), TestCaseError> {
    if let Ok(x) = r {
        prop_assert!(x.is_finite(), "{}: accepted {}", what, x);
    }
    Ok(())
}

/// A USB meter that answers garbage: random transfers, or a valid USBTMC header (matching the request's bTag)
/// around random text, so that the SCPI layer is reached too.
#[derive(Debug)]
struct HostilePipe {
    replies: Vec<(bool, Vec<u8>)>,
    state: Mutex<(usize, u8)>,
}

impl UsbPipe for HostilePipe {
    fn bulk_out<'a>(&'a self, data: &'a [u8], _timeout: Duration) -> BoxFuture<'a, Result<usize, UsbError>> {
        Box::pin(async move {
            if data.first() == Some(&2)
                && let Some(tag) = data.get(1)
            {
                self.state.lock().unwrap_or_else(|e| e.into_inner()).1 = *tag;
            }
            Ok(data.len())
        })
    }
    fn bulk_in(&self, max_len: usize, _timeout: Duration) -> BoxFuture<'_, Result<Vec<u8>, UsbError>> {
        Box::pin(async move {
            let (framed, payload) = {
                let mut st = self.state.lock().unwrap_or_else(|e| e.into_inner());
                st.0 += 1;
                let (framed, p) = &self.replies[st.0 % self.replies.len()];
                if p.is_empty() {
                    return Err(UsbError::Timeout { transferred: 0 });
                }
                let tag = st.1;
                let mut out = p.clone();
                if *framed {
                    let mut t = vec![2, tag, !tag, 0];
                    t.extend_from_slice(&(p.len() as u32).to_le_bytes());
                    t.extend_from_slice(&[1, 0, 0, 0]);
                    t.extend_from_slice(p);
                    while t.len() % 4 != 0 {
                        t.push(0);
                    }
                    out = t;
                }
                (framed, out)
            };
            let _ = framed;
            Ok(payload.into_iter().take(max_len).collect())
        })
    }
    fn control_in(
        &self,
        _rt: u8,
        _rq: u8,
        _value: u16,
        _index: u16,
        max_len: usize,
        _timeout: Duration,
    ) -> BoxFuture<'_, Result<Vec<u8>, UsbError>> {
        Box::pin(async move {
            let mut st = self.state.lock().unwrap_or_else(|e| e.into_inner());
            st.0 += 1;
            let (_, p) = &self.replies[st.0 % self.replies.len()];
            Ok(p.iter().copied().take(max_len).collect())
        })
    }
    fn clear_halt(&self, _endpoint: u8) -> BoxFuture<'_, Result<(), UsbError>> {
        Box::pin(async { Ok(()) })
    }
    fn bulk_out_endpoint(&self) -> u8 {
        0x02
    }
    fn bulk_in_endpoint(&self) -> u8 {
        0x81
    }
    fn interface_number(&self) -> u8 {
        0
    }
}

proptest! {
    #![proptest_config(ProptestConfig {
        cases: cases(3000) / 30 + 1,
        failure_persistence: None,
        ..ProptestConfig::default()
    })]

    #[test]
    fn smc100_axis_against_a_hostile_controller_ends_every_operation(
        replies in hostile_replies(
            &["1TS", "1TP", "1TE", "1PT", "1TS000033", "1TS00003", "1TS00000A", "1TS000028", "1TP10", "1TE@", "2TS", "1ID"],
            "\r\n",
        ),
    ) {
        bounded("smc100", async {
            let port = hostile_port("arms", b'\n', replies);
            let chain = Smc100Chain::new("arms", port);
            let axis = Smc100Axis::new(chain.clone(), sim_axis("light"));
            let _ = axis.status().await;
            finite_or_error("position", &axis.position_deg().await)?;
            let _ = axis.home().await;
            finite_or_error("move", &axis.move_to(10.0).await)?;
            let _ = axis.stop().await;
            let _ = chain.stop_all(&[1, 2]).await;
            let _ = axis.reconnect().await;
            Ok::<(), TestCaseError>(())
        })??;
    }

    #[test]
    fn zaber_axis_against_a_hostile_device_ends_every_operation(
        replies in hostile_replies(
            &["@01 1 ", "@01 1 {id} OK IDLE -- ", "@01 1 {id} OK BUSY -- ", "@01 1 {id} OK IDLE WR ",
              "@01 1 {id} RJ IDLE -- ", "!01 1 IDLE -- ", "@01 1 {id} OK IDLE -- 0", "@01 1 {id} OK IDLE FS 5",
              "@02 0 {id} OK IDLE -- "],
            "\r\n",
        ),
    ) {
        bounded("zaber", async {
            let port = hostile_port("stage", b'\n', replies);
            let chain = ZaberChain::new("stage", port);
            let Ok(axis) = ZaberAxis::new(chain.clone(), sim_axis("tilt")) else {
                return Ok(());
            };
            let _ = axis.status().await;
            finite_or_error("position", &axis.position_deg().await)?;
            let _ = axis.home().await;
            finite_or_error("move", &axis.move_to(10.0).await)?;
            let _ = axis.stop().await;
            let _ = chain.stop_all().await;
            let _ = axis.reconnect().await;
            Ok::<(), TestCaseError>(())
        })??;
    }

    #[test]
    fn fw102c_against_a_hostile_wheel_ends_every_operation(
        replies in hostile_replies(
            &["pos=3\r> ", "{echo}\r", "{echo}\r", "{echo}\r6\r> ", "pos?\r3\r> ", "pcount?\r6\r> ", "*idn?\r",
              "> ", "Command error "],
            "\r> ",
        ),
    ) {
        bounded("fw102c", async {
            let port = hostile_port("wheel", b'\r', replies);
            let wheel = Fw102c::new("wheel", port, 0.4);
            if let Ok(n) = wheel.position_count().await {
                prop_assert!(n == 6 || n == 12, "position count {}", n);
            }
            if let Ok(p) = wheel.position().await {
                prop_assert!((1..=12).contains(&p), "position {}", p);
            }
            let _ = wheel.go_to(3).await;
            let _ = wheel.identify().await;
            let _ = wheel.reconnect().await;
            Ok::<(), TestCaseError>(())
        })??;
    }

    #[test]
    fn pm100_against_a_hostile_meter_ends_every_operation(
        replies in proptest::collection::vec(
            (any::<bool>(), prop_oneof![
                proptest::collection::vec(any::<u8>(), 0..40),
                "[ -~]{0,24}\n".prop_map(String::into_bytes),
                prop::sample::select(vec!["1.5E-06\n", "0,\"No error\"\n", "-222,\"Data out of range\"\n",
                    "9.9E37\n", "5.0E-04\n", "Thorlabs,PM100USB,1,1\n"]).prop_map(|s| s.as_bytes().to_vec()),
            ]),
            1..10,
        ),
    ) {
        let pipe = Arc::new(HostilePipe { replies, state: Mutex::new((0, 0)) });
        bounded("pm100", async {
            let meter = Pm100::new("meter", pipe, None);
            let _ = meter
                .configure(DetectorConfig { wavelength_nm: 550.0, averaging: 2, range: PowerRange::Auto })
                .await;
            if let Ok(r) = meter.read_power().await {
                prop_assert!(r.overload || (r.power_w.is_finite() && r.range_w.is_finite()), "{:?}", r);
            }
            let _ = meter.identify().await;
            Ok::<(), TestCaseError>(())
        })??;
    }
}

#[test]
fn the_usbtmc_request_encoder_round_trips_through_the_checker() {
    // The hostile meter above keys its framed replies on the request's bTag: make sure requests carry it where
    // the checker reads it (byte 1, inverse in byte 2).
    let mut tag = 0u8;
    for _ in 0..300 {
        tag = next_btag(tag);
        let r = encode_request_dev_dep_msg_in(tag, 64, None);
        assert_eq!((r[0], r[1], r[2]), (2, tag, !tag));
    }
}

/// A wheel whose answers are well formed but inconsistent: every `pcount?` says 6 or 12, every `pos?` any
/// position 1..12, `pos=N` is obeyed or refused, in the order `choices` says (cycling). What a wheel with
/// garbled digits or a swapped unit looks like to the driver.
fn inconsistent_wheel(choices: Vec<u8>) -> Arc<LinePort> {
    let choices = Arc::new(choices);
    let opener = PortOpener::Stream(Arc::new(move || {
        let (host, dev) = tokio::io::duplex(4096);
        let choices = Arc::clone(&choices);
        tokio::spawn(async move {
            let (mut rx, mut tx) = tokio::io::split(dev);
            let (mut next, mut line, mut chunk) = (0usize, Vec::new(), [0u8; 256]);
            loop {
                let n = match rx.read(&mut chunk).await {
                    Ok(0) | Err(_) => return,
                    Ok(n) => n,
                };
                for &b in &chunk[..n] {
                    if b != b'\r' {
                        line.push(b);
                        continue;
                    }
                    let cmd = String::from_utf8_lossy(&line).to_string();
                    line.clear();
                    let c = choices[next % choices.len()];
                    next += 1;
                    let answer = match cmd.as_str() {
                        "pcount?" => format!("{}\r", if c % 2 == 0 { 6 } else { 12 }),
                        "pos?" => format!("{}\r", 1 + c % 12),
                        "*idn?" => "THORLABS FW102C/FW212C Filter Wheel version 1.07\r".to_string(),
                        _ if c % 5 == 0 => "Command error CMD_ARG_INVALID\r".to_string(),
                        _ => String::new(),
                    };
                    if tx
                        .write_all(format!("{cmd}\r{answer}> ").as_bytes())
                        .await
                        .is_err()
                    {
                        return;
                    }
                }
            }
        });
        Ok(Box::new(host) as _)
    }));
    Arc::new(LinePort::open("wheel", opener).expect("open the wheel port"))
}

proptest! {
    #![proptest_config(ProptestConfig {
        cases: cases(3000) / 10 + 1,
        failure_persistence: None,
        ..ProptestConfig::default()
    })]

    #[test]
    fn fw102c_against_an_inconsistent_wheel_never_panics(
        choices in proptest::collection::vec(any::<u8>(), 1..16),
        target in 1u8..=12,
    ) {
        bounded("fw102c", async {
            let wheel = Fw102c::new("wheel", inconsistent_wheel(choices), 0.4);
            for _ in 0..4 {
                // Success or an error that says what went wrong; never a panic or a hang.
                if let Err(e) = wheel.go_to(target).await {
                    prop_assert!(!e.to_string().is_empty());
                }
            }
            Ok::<(), TestCaseError>(())
        })??;
    }
}
