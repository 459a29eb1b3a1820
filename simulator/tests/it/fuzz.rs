//! The device emulators' command parsers fed random input: random bytes, and sequences of the protocols' own
//! words in random order (so that the parsers get past their first check). Never a panic; every byte the device
//! sends is a documented reply (or nothing): the SMC100 answers only queries, `<addr><CC><value>`, and keeps
//! errors for `TE`; the Zaber devices answer `@DD A [ID] OK|RJ IDLE|BUSY FLAG data` with the documented
//! rejection reasons, or alerts `!DD A ...`; the FW102C echoes, answers or says one of its two `Command error`s,
//! then prompts; the PM100 answers only queries and queues documented SCPI errors; its USBTMC endpoint halts on
//! a bad header and works again after a clear. Axes never leave their limit switches whatever they are told.
//!
//! Cases: `GONIO_FUZZ_CASES` (default: a fast tier); e.g. `GONIO_FUZZ_CASES=100000 cargo test --release
//! -p gonio-simulator --test it fuzz` for a large run.

use std::sync::{Arc, Mutex};
use std::time::Duration;

use gonio_instrument::{Faults, InstrumentFile};
use gonio_simulator::SimInstrument;
use gonio_simulator::faults::FaultInjector;
use gonio_simulator::fw102c::Fw102c;
use gonio_simulator::motion::{AxisMotion, AxisParams};
use gonio_simulator::scene::UniformScene;
use gonio_simulator::session::{Output, SerialEmulator};
use gonio_simulator::smc100::Smc100Chain;
use gonio_simulator::zaber::{ZaberChain, lrc};
use proptest::prelude::*;

fn cases(default: u32) -> u32 {
    std::env::var("GONIO_FUZZ_CASES")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(default)
}

/// Input: a mix of random bytes and protocol words.
fn input(words: &'static [&'static str]) -> impl Strategy<Value = Vec<u8>> {
    let token = prop_oneof![
        3 => prop::sample::select(words).prop_map(|w| w.as_bytes().to_vec()),
        1 => proptest::collection::vec(any::<u8>(), 1..6),
        1 => "-?[0-9]{1,12}(\\.[0-9]{0,8})?(e-?[0-9]{1,3})?".prop_map(String::into_bytes),
    ];
    proptest::collection::vec(token, 0..40).prop_map(|t| t.concat())
}

/// The device's axes as the simulator builds them (power-up at zero), with their motion state.
fn axes_of(device: &str) -> Vec<(gonio_instrument::Axis, Arc<Mutex<AxisMotion>>)> {
    let file = InstrumentFile::simulated();
    file.instrument
        .axes
        .iter()
        .filter(|a| a.device == device)
        .map(|a| {
            let (lo, hi) = (
                a.controller_from_physical_deg(a.min_deg),
                a.controller_from_physical_deg(a.max_deg),
            );
            let params = AxisParams {
                hw_min_deg: lo.min(hi),
                hw_max_deg: lo.max(hi),
                backlash_deg: a.backlash_deg,
                encoder_resolution_deg: a.encoder_resolution_deg,
            };
            (a.clone(), Arc::new(Mutex::new(AxisMotion::new(params, 0.0))))
        })
        .collect()
}

fn no_faults(device: &str) -> gonio_simulator::faults::DeviceFaults {
    Arc::new(FaultInjector::new(Faults::default())).for_device(device)
}

/// Feed `bytes` in random-sized pieces at increasing times; collect what the device says.
fn feed(emu: &mut dyn SerialEmulator, bytes: &[u8], cuts: &[usize]) -> Vec<Output> {
    let mut out = Vec::new();
    let mut t = 0.0;
    let mut rest = bytes;
    let mut cuts = cuts.iter().cycle();
    while !rest.is_empty() {
        let n = cuts.next().copied().unwrap_or(1).clamp(1, rest.len());
        let (now, later) = rest.split_at(n);
        out.extend(emu.receive(now, t));
        t += 0.01;
        if let Some(next) = emu.next_event_s(t) {
            out.extend(emu.poll_events(next.max(t)));
        }
        rest = later;
    }
    out
}

/// Every axis stays between its limit switches, sampled over a long time after the input.
fn within_limit_switches(
    axes: &[(gonio_instrument::Axis, Arc<Mutex<AxisMotion>>)],
) -> Result<(), TestCaseError> {
    for (axis, motion) in axes {
        let mut m = motion.lock().unwrap_or_else(|e| e.into_inner());
        let p = *m.params();
        for k in 0..200 {
            let t = 0.5 * f64::from(k);
            let x = m.motor_deg(t);
            prop_assert!(
                x >= p.hw_min_deg - 1e-9 && x <= p.hw_max_deg + 1e-9,
                "{} at {} (switches {}..{}) at t = {}",
                axis.name,
                x,
                p.hw_min_deg,
                p.hw_max_deg,
                t
            );
        }
    }
    Ok(())
}

/// Split the device's output into CRLF-terminated lines; anything after the last CRLF is returned apart.
fn crlf_lines(out: &[Output]) -> (Vec<String>, Vec<u8>) {
    let bytes: Vec<u8> = out.iter().flat_map(|o| o.bytes.iter().copied()).collect();
    let mut lines = Vec::new();
    let mut rest = bytes.as_slice();
    while let Some(i) = rest.windows(2).position(|w| w == b"\r\n") {
        lines.push(String::from_utf8_lossy(&rest[..i]).into_owned());
        rest = &rest[i + 2..];
    }
    (lines, rest.to_vec())
}

const SMC_WORDS: &[&str] = &[
    "1", "2", "3", "0", "99", "TS", "TE", "TP", "TH", "ID", "VE", "PW", "PA", "PR", "OR", "RS", "PT", "ST",
    "MM", "VA", "AC", "SL", "SR", "?", "0", "1", "-", ".", " ", "\r\n", "\r\n", "\n", "1e308", "-1e12", "TB",
    "ZT", "ZX", "SE", "KP", "HT", "BA", "SB", "RA", "RB", "DV", "##",
];
/// Codes a reply line may carry: the queries, and the parameters `ZT` lists.
const SMC_QUERIES: &[&str] = &[
    "TS", "TE", "TP", "TH", "ID", "VE", "PW", "PA", "PR", "PT", "MM", "VA", "AC", "SL", "SR", "TB", "RA",
    "RB", "ZX", "SE", "BA", "BH", "FD", "FE", "FF", "HT", "JM", "JR", "KD", "KI", "KP", "KV", "OH", "OT",
    "QI", "SA", "SB", "SC", "SU",
];

const ZABER_WORDS: &[&str] = &[
    "/",
    "/",
    "0",
    "1",
    "2",
    "3",
    " ",
    " ",
    "move",
    "abs",
    "rel",
    "vel",
    "min",
    "max",
    "home",
    "stop",
    "estop",
    "get",
    "set",
    "pos",
    "maxspeed",
    "accel",
    "limit.min",
    "limit.max",
    "comm.alert",
    "comm.checksum",
    "warnings",
    "clear",
    "tools",
    "echo",
    "system.serial",
    "version",
    "device.id",
    ":",
    "\r",
    "\n",
    "\r\n",
    "\x08",
    "\x7f",
];
const ZABER_REJECTIONS: &[&str] = &["BADCOMMAND", "BADDATA", "BADAXIS"];

const FW_WORDS: &[&str] = &[
    "pos", "pos?", "pcount", "pcount?", "speed", "speed?", "sensors", "trig", "baud", "save", "*idn?", "=",
    "1", "3", "6", "12", "0", "\r", "\r", "\n", " ",
];

proptest! {
    #![proptest_config(ProptestConfig { cases: cases(2000), failure_persistence: None, ..ProptestConfig::default() })]

    #[test]
    fn smc100_answers_only_queries_in_the_documented_form(
        bytes in prop_oneof![input(SMC_WORDS), proptest::collection::vec(any::<u8>(), 0..300)],
        cuts in proptest::collection::vec(1usize..40, 1..8),
    ) {
        let axes = axes_of("arms");
        let mut chain = Smc100Chain::new("arms", axes.clone(), no_faults("arms"));
        let out = feed(&mut chain, &bytes, &cuts);
        let (lines, rest) = crlf_lines(&out);
        prop_assert!(rest.is_empty(), "unterminated output {:?}", rest);
        for line in &lines {
            // The address as the command gave it (the emulator echoes it, leading zero included).
            let addr: String = line.chars().take_while(char::is_ascii_digit).collect();
            let n = addr.parse::<u8>().ok();
            prop_assert!(n == Some(1) || n == Some(2), "reply from address {:?}: {:?}", addr, line);
            let code = line.get(addr.len()..addr.len() + 2).unwrap_or_default();
            prop_assert!(SMC_QUERIES.contains(&code), "not a query reply: {:?}", line);
            prop_assert!(!line.bytes().any(|b| b == 0x11 || b == 0x13), "XON/XOFF in {:?}", line);
        }
        // Whatever happened, `TE` reports a documented error letter (or '@'), and the controller still answers.
        // (A line left unterminated by the input is ended first: its own error, if any, is what TE reports.)
        // (Asked well after any reset or configuration save that makes a controller deaf for a while.)
        let _ = chain.receive(b"\r\n", 99.0);
        for addr in ["1", "2"] {
            let out = chain.receive(format!("{addr}TE\r\n").as_bytes(), 200.0);
            let (lines, _) = crlf_lines(&out);
            prop_assert_eq!(lines.len(), 1, "{:?}", lines);
            let te = lines[0].strip_prefix(&format!("{addr}TE")).unwrap_or_default();
            prop_assert!(te == "@" || (te.len() == 1 && te.bytes().all(|b| b.is_ascii_uppercase())), "TE {:?}", te);
        }
        within_limit_switches(&axes)?;
    }

    #[test]
    fn zaber_replies_are_well_formed_with_documented_rejections(
        bytes in prop_oneof![input(ZABER_WORDS), proptest::collection::vec(any::<u8>(), 0..300)],
        cuts in proptest::collection::vec(1usize..40, 1..8),
    ) {
        let axes = axes_of("stage");
        let clock = gonio_simulator::clock::SimClock::new(1.0);
        let mut chain = ZaberChain::new("stage", axes.clone(), no_faults("stage"), clock);
        let out = feed(&mut chain, &bytes, &cuts);
        let (lines, rest) = crlf_lines(&out);
        prop_assert!(rest.is_empty(), "unterminated output {:?}", rest);
        for line in &lines {
            // A checksum, when the device was told to add one, must be right.
            let body = match line.rsplit_once(':') {
                Some((body, cs)) if cs.len() == 2 && cs.bytes().all(|b| b.is_ascii_hexdigit()) => {
                    let lead_less = body.get(1..).unwrap_or_default();
                    prop_assert_eq!(
                        u8::from_str_radix(cs, 16).ok(),
                        Some(lrc(lead_less.as_bytes())),
                        "bad checksum on {:?}", line
                    );
                    body
                }
                _ => line.as_str(),
            };
            let words: Vec<&str> = body.split(' ').collect();
            match body.as_bytes().first() {
                Some(b'@') => {
                    // @DD A [ID] FL STATUS WW data
                    let fl_at = words.iter().position(|w| *w == "OK" || *w == "RJ");
                    prop_assert!(fl_at == Some(2) || fl_at == Some(3), "no reply flag where due: {:?}", line);
                    let fl_at = fl_at.unwrap_or(2);
                    prop_assert!(
                        matches!(words.get(fl_at + 1), Some(&"IDLE") | Some(&"BUSY")),
                        "status: {:?}", line
                    );
                    prop_assert!(words.get(fl_at + 2).is_some_and(|w| w.len() == 2), "warning flag: {:?}", line);
                    if words[fl_at] == "RJ" {
                        let reason = words.get(fl_at + 3).copied().unwrap_or_default();
                        prop_assert!(ZABER_REJECTIONS.contains(&reason), "undocumented rejection {:?}", line);
                    }
                }
                Some(b'!') => {
                    prop_assert!(
                        matches!(words.get(2), Some(&"IDLE") | Some(&"BUSY")) && words.len() == 4,
                        "alert: {:?}", line
                    );
                }
                _ => prop_assert!(false, "neither a reply nor an alert: {:?}", line),
            }
        }
        within_limit_switches(&axes)?;
    }

    #[test]
    fn fw102c_echoes_answers_or_errs_then_prompts(
        bytes in prop_oneof![input(FW_WORDS), proptest::collection::vec(any::<u8>(), 0..300)],
        cuts in proptest::collection::vec(1usize..40, 1..8),
    ) {
        let file = InstrumentFile::simulated();
        let mut wheel = Fw102c::new("wheel", file.instrument.filter_wheel.as_ref());
        let out = feed(&mut wheel, &bytes, &cuts);
        // One exchange per CR received: echo, at most one reply line, the prompt.
        let commands = bytes.iter().filter(|b| **b == b'\r').count();
        let prompts = out.iter().filter(|o| o.bytes == b"> ").count();
        prop_assert_eq!(prompts, commands);
        let mut i = 0;
        while i < out.len() {
            let echo = &out[i];
            prop_assert!(echo.bytes.ends_with(b"\r"), "echo {:?}", String::from_utf8_lossy(&echo.bytes));
            i += 1;
            if out.get(i).is_some_and(|o| o.bytes != b"> ") {
                let reply = String::from_utf8_lossy(&out[i].bytes).into_owned();
                let reply = reply.trim_end_matches('\r');
                let known = reply.starts_with("THORLABS")
                    || reply.parse::<u32>().is_ok()
                    || reply == "Command error CMD_NOT_DEFINED"
                    || reply == "Command error CMD_ARG_INVALID";
                prop_assert!(known, "reply {:?}", reply);
                i += 1;
            }
            prop_assert_eq!(out.get(i).map(|o| o.bytes.as_slice()), Some(&b"> "[..]));
            i += 1;
        }
        // Prompts come in time order, never before their command could run.
        for w in out.windows(2) {
            prop_assert!(w[1].at_s >= w[0].at_s);
        }
    }
}

// ---- the PM100: SCPI over USBTMC through the simulator's USB device

const SCPI_WORDS: &[&str] = &[
    "*IDN?",
    "*RST",
    "*CLS",
    "*OPC?",
    "*TST?",
    "SYST:ERR?",
    "SYSTem:ERRor?",
    "SENS:CORR:WAV",
    "SENS:POW:RANG",
    "SENS:POW:RANG:AUTO",
    "SENS:POW:UNIT",
    "SENS:AVER:COUN",
    "CONF:POW",
    "MEAS:POW?",
    "READ?",
    "FETC?",
    "INIT",
    "ABOR",
    " ",
    " ",
    ";",
    ";",
    "?",
    "ON",
    "OFF",
    "W",
    "DBM",
    "MIN",
    "MAX",
    "550",
    "1e9",
    "-3",
    "2",
    "\n",
];
/// The SCPI error codes the meter documents (and queue overflow).
const SCPI_ERRORS: &[i32] = &[0, -104, -109, -113, -222, -224, -350, -420];

fn dev_dep_msg_out(tag: u8, payload: &[u8]) -> Vec<u8> {
    let mut t = vec![1, tag, !tag, 0];
    t.extend_from_slice(&(payload.len() as u32).to_le_bytes());
    t.extend_from_slice(&[1, 0, 0, 0]);
    t.extend_from_slice(payload);
    while t.len() % 4 != 0 {
        t.push(0);
    }
    t
}

fn request_in(tag: u8, max: u32) -> Vec<u8> {
    let mut t = vec![2, tag, !tag, 0];
    t.extend_from_slice(&max.to_le_bytes());
    t.extend_from_slice(&[0, 0, 0, 0]);
    t
}

struct Meter {
    dev: gonio_simulator::SimUsbDevice,
    tag: u8,
}

impl Meter {
    fn next_tag(&mut self) -> u8 {
        self.tag = if self.tag == 255 { 1 } else { self.tag + 1 };
        self.tag
    }

    async fn send(&mut self, text: &[u8]) -> Result<usize, gonio_simulator::UsbSimError> {
        let tag = self.next_tag();
        let ep = self.dev.bulk_out_endpoint();
        self.dev
            .bulk_out(ep, &dev_dep_msg_out(tag, text), Duration::from_secs(1))
            .await
    }

    /// One response, or None when the meter has nothing to say (its Bulk-IN NAKs until the timeout).
    async fn read(&mut self) -> Option<String> {
        let tag = self.next_tag();
        let ep = self.dev.bulk_out_endpoint();
        self.dev
            .bulk_out(ep, &request_in(tag, 4096), Duration::from_secs(1))
            .await
            .ok()?;
        let t = self
            .dev
            // Long enough for the slowest reading (10^6 averaged samples of 3 ms): free on the paused clock.
            .bulk_in(self.dev.bulk_in_endpoint(), 8192, Duration::from_secs(4000))
            .await
            .ok()?;
        Some(
            String::from_utf8_lossy(t.get(12..).unwrap_or_default())
                .trim_end_matches('\0')
                .to_string(),
        )
    }

    async fn query(&mut self, q: &str) -> Option<String> {
        self.send(format!("{q}\n").as_bytes()).await.ok()?;
        self.read().await
    }
}

fn meter_sim() -> SimInstrument {
    SimInstrument::new(
        &InstrumentFile::simulated(),
        Arc::new(UniformScene { power_w: 1e-5 }),
        1.0,
    )
    .expect("simulated instrument")
}

fn paused<T>(f: impl std::future::Future<Output = T>) -> T {
    tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .start_paused(true)
        .build()
        .expect("runtime")
        .block_on(f)
}

proptest! {
    #![proptest_config(ProptestConfig { cases: cases(2000) / 8 + 1, failure_persistence: None, ..ProptestConfig::default() })]

    #[test]
    fn pm100_answers_only_queries_and_queues_documented_errors(
        text in input(SCPI_WORDS).prop_filter("one program message", |t| !t.contains(&b'\n')),
    ) {
        paused(async {
            let sim = meter_sim();
            let mut m = Meter { dev: sim.usb_device("meter").expect("meter"), tag: 0 };
            m.send(&text).await.map_err(|e| TestCaseError::fail(format!("refused {e}")))?;
            let response = m.read().await;
            if !text.contains(&b'?') {
                prop_assert!(response.is_none(), "a response to a message with no query: {:?}", response);
            }
            // Drain the error queue: documented codes, `code,"text"`, ending with 0.
            for _ in 0..40 {
                let e = m.query("SYST:ERR?").await;
                prop_assert!(e.is_some(), "no answer to SYST:ERR?");
                let e = e.unwrap_or_default();
                let code = e.split(',').next().and_then(|c| c.trim().parse::<i32>().ok());
                prop_assert!(code.is_some_and(|c| SCPI_ERRORS.contains(&c)), "error {:?}", e);
                prop_assert!(e.contains('"'), "error text {:?}", e);
                if code == Some(0) {
                    break;
                }
            }
            let idn = m.query("*IDN?").await.unwrap_or_default();
            prop_assert!(idn.starts_with("Thorlabs,PM100USB"), "{}", idn);
            Ok(())
        })?;
    }

    #[test]
    fn pm100_usbtmc_framing_halts_on_garbage_and_recovers_after_a_clear(
        transfers in proptest::collection::vec(proptest::collection::vec(any::<u8>(), 0..64), 1..6),
    ) {
        paused(async {
            let sim = meter_sim();
            let mut m = Meter { dev: sim.usb_device("meter").expect("meter"), tag: 0 };
            let ep = m.dev.bulk_out_endpoint();
            for t in &transfers {
                let _ = m.dev.bulk_out(ep, t, Duration::from_secs(1)).await;
            }
            // Whatever state the garbage left: abort any transfer, clear the halt, then the meter answers.
            let _ = m.dev.clear_halt(ep).await;
            let _ = m.dev.clear_halt(m.dev.bulk_in_endpoint()).await;
            // A partial transfer still expecting bytes swallows what follows: a clear (INITIATE_CLEAR) ends it.
            let _ = m.dev.control_in(0xA1, 5, 0, 0, 1, Duration::from_secs(1)).await;
            for _ in 0..10 {
                let s = m.dev.control_in(0xA1, 6, 0, 0, 2, Duration::from_secs(1)).await;
                if s.as_ref().map(|s| s.first() == Some(&1)).unwrap_or(true) {
                    break;
                }
                tokio::time::sleep(Duration::from_millis(5)).await;
            }
            let _ = m.dev.clear_halt(ep).await;
            let mut idn = None;
            for _ in 0..3 {
                idn = m.query("*IDN?").await.filter(|s| s.starts_with("Thorlabs"));
                if idn.is_some() {
                    break;
                }
            }
            prop_assert!(idn.is_some(), "the meter never answered again after {:?}", transfers);
            Ok(())
        })?;
    }
}
