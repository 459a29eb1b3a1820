//! Thorlabs PM100USB optical power meter: SCPI over USBTMC, as a USB device with bulk and control pipes.
//!
//! USBTMC (USB Test & Measurement Class 1.0) framing on the device side:
//! - Bulk-OUT transfers start with a 12-byte header: MsgID (1 DEV_DEP_MSG_OUT, 2 REQUEST_DEV_DEP_MSG_IN), bTag,
//!   ~bTag, 0, transfer size (u32 LE), attributes (OUT: bit0 EOM), TermChar, 0, 0; the payload follows, padded to a
//!   multiple of 4. A transfer announcing more payload than one `bulk_out` call carried continues in the next
//!   call(s). A header that fails its checks (bTag 0, wrong inverse, unknown MsgID, zero REQUEST size) halts the
//!   Bulk-OUT endpoint: every later Bulk-OUT transfer fails with a pipe error until `clear_halt`.
//! - Each REQUEST_DEV_DEP_MSG_IN is answered with one Bulk-IN transfer: header (MsgID 2, the request's bTag and
//!   inverse, transfer size, EOM in bit0 of the attributes when it carries the last byte of the response), data,
//!   padding. A response longer than the requested size spans several transfers (EOM only on the last). A
//!   `bulk_in` smaller than the transfer returns its first part; the rest stays for the next `bulk_in`.
//! - With nothing to send, Bulk-IN NAKs: the host's read times out.
//! - Class requests: INITIATE_ABORT_BULK_OUT/IN, CHECK_ABORT_BULK_OUT/IN_STATUS, INITIATE_CLEAR,
//!   CHECK_CLEAR_STATUS, GET_CAPABILITIES, with the USBTMC status bytes.
//!
//! SCPI: case-insensitive, short or long forms, optional nodes, `;`-separated commands, newline-terminated
//! (CR LF accepted). Unanswered responses accumulate: two queries without a read give both answers, as the
//! manual warns. Errors go to the queue read by `SYST:ERR?`.
//!
//! Reading physics: the scene's optical power -> photocurrent (responsivity at the band's wavelength) + dark
//! current; with noise on, shot and Johnson noise per sample, each sample quantised by a 16-bit converter on the
//! range, averaged over `SENS:AVER:COUN` samples of 3 ms each (the reply is ready that much simulated time later).
//! The current is converted back to watts with the responsivity at the wavelength the meter is SET to, so a
//! wrong `SENS:CORR:WAV` gives a wrong reading, as on the real meter. A current beyond the full scale of the
//! range in use (or of the largest range under auto-range) is an overload: the reading is the SCPI
//! over-range value 9.9E37.

use std::collections::VecDeque;
use std::sync::{Arc, Mutex};
use std::time::Duration;

use gonio_instrument::{Detector, Device, Instrument, SimulatorSettings};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr_lite::standard_normal;

use crate::faults::DeviceFaults;
use crate::instrument::World;
use crate::scene::{Band, Pose};

/// USB identity.
pub const VENDOR_ID: u16 = 0x1313;
pub const PRODUCT_ID_PM100USB: u16 = 0x8072;
pub const BULK_OUT_EP: u8 = 0x02;
pub const BULK_IN_EP: u8 = 0x81;

/// USBTMC message ids.
pub const DEV_DEP_MSG_OUT: u8 = 1;
pub const REQUEST_DEV_DEP_MSG_IN: u8 = 2;
pub const DEV_DEP_MSG_IN: u8 = 2;

/// USBTMC class requests.
pub const INITIATE_ABORT_BULK_OUT: u8 = 1;
pub const CHECK_ABORT_BULK_OUT_STATUS: u8 = 2;
pub const INITIATE_ABORT_BULK_IN: u8 = 3;
pub const CHECK_ABORT_BULK_IN_STATUS: u8 = 4;
pub const INITIATE_CLEAR: u8 = 5;
pub const CHECK_CLEAR_STATUS: u8 = 6;
pub const GET_CAPABILITIES: u8 = 7;

/// USBTMC status bytes.
pub const STATUS_SUCCESS: u8 = 0x01;
pub const STATUS_PENDING: u8 = 0x02;
pub const STATUS_FAILED: u8 = 0x80;
pub const STATUS_TRANSFER_NOT_IN_PROGRESS: u8 = 0x81;

/// Time per averaged sample (s).
pub const SAMPLE_S: f64 = 0.003;
/// The value a reading takes in overload.
pub const OVERLOAD_W: f64 = 9.9e37;
/// How long the device takes to clear its buffers after INITIATE_CLEAR (s).
const CLEAR_S: f64 = 0.001;
const ELEMENTARY_CHARGE_C: f64 = 1.602_176_634e-19;
const BOLTZMANN_J_K: f64 = 1.380_649e-23;
const TEMPERATURE_K: f64 = 295.0;
/// Full-scale voltage of the transimpedance amplifier (sets the feedback resistor of each range).
const FULL_SCALE_V: f64 = 2.0;
const ADC_COUNTS: f64 = 65_536.0;

/// Minimal normal deviates without another dependency.
mod rand_distr_lite {
    use rand::Rng;

    /// A standard normal deviate (Box-Muller).
    pub fn standard_normal(rng: &mut impl Rng) -> f64 {
        let u1: f64 = rng.random::<f64>().max(f64::MIN_POSITIVE);
        let u2: f64 = rng.random::<f64>();
        (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
    }
}

/// Errors of the in-process USB device, as libusb reports them.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum UsbSimError {
    #[error("USB transfer timed out after {transferred} bytes")]
    Timeout { transferred: usize },
    #[error("USB endpoint {endpoint:#04x} is halted (pipe error)")]
    Pipe { endpoint: u8 },
    #[error("USB device is gone")]
    NoDevice,
    #[error("invalid USB request: {0}")]
    InvalidParam(String),
}

/// Photodiode responsivity (A/W) as a function of wavelength.
#[derive(Debug, Clone)]
enum Responsivity {
    Constant(f64),
    Table(Vec<(f64, f64)>),
}

impl Responsivity {
    fn from_detector(d: &Detector) -> Result<Responsivity, String> {
        match &d.responsivity_a_per_w {
            None => Ok(Responsivity::Constant(0.5)),
            Some(toml::Value::Float(x)) if *x > 0.0 => Ok(Responsivity::Constant(*x)),
            Some(toml::Value::Integer(x)) if *x > 0 => Ok(Responsivity::Constant(*x as f64)),
            Some(toml::Value::Table(t)) => {
                let mut pts = Vec::new();
                for (k, v) in t {
                    let nm: f64 = k.trim().parse().map_err(|_| {
                        format!(
                            "[instrument.detector] responsivity_a_per_w: key {k:?} is not a wavelength in nm"
                        )
                    })?;
                    let r = v
                        .as_float()
                        .or_else(|| v.as_integer().map(|i| i as f64))
                        .filter(|r| *r > 0.0)
                        .ok_or_else(|| {
                            format!("[instrument.detector] responsivity_a_per_w: value at {k} nm must be > 0")
                        })?;
                    pts.push((nm, r));
                }
                pts.sort_by(|a, b| a.0.total_cmp(&b.0));
                if pts.is_empty() {
                    return Err("[instrument.detector] responsivity_a_per_w: empty table".into());
                }
                Ok(Responsivity::Table(pts))
            }
            Some(v) => Err(format!(
                "[instrument.detector] responsivity_a_per_w: expected a number > 0 or a table, got {v}"
            )),
        }
    }

    /// Linear interpolation, constant beyond the table's ends.
    fn at(&self, nm: f64) -> f64 {
        match self {
            Responsivity::Constant(r) => *r,
            Responsivity::Table(pts) => {
                let (Some(first), Some(last)) = (pts.first(), pts.last()) else {
                    return 0.5;
                };
                if nm <= first.0 {
                    return first.1;
                }
                if nm >= last.0 {
                    return last.1;
                }
                for w in pts.windows(2) {
                    let (a, b) = (w[0], w[1]);
                    if nm <= b.0 {
                        let f = (nm - a.0) / (b.0 - a.0);
                        return a.1 + f * (b.1 - a.1);
                    }
                }
                last.1
            }
        }
    }
}

/// Meter settings (reset by `*RST` and by a power cycle).
#[derive(Debug, Clone)]
struct Settings {
    wavelength_nm: f64,
    auto_range: bool,
    /// Index into the ranges.
    range: usize,
    unit_dbm: bool,
    averaging: u32,
}

#[derive(Debug, Clone, Copy)]
struct OutTransfer {
    btag: u8,
    remaining: usize,
    /// Padding bytes still to come after the payload.
    pad: usize,
    eom: bool,
    received: usize,
}

#[derive(Debug, Clone, Copy)]
struct InRequest {
    btag: u8,
    max: usize,
}

/// Bytes of the response message, available from `ready_at_s` on.
#[derive(Debug, Clone)]
struct Pending {
    ready_at_s: f64,
    bytes: Vec<u8>,
}

#[derive(Debug)]
struct MeterState {
    settings: Settings,
    errors: VecDeque<(i32, &'static str)>,
    /// Bulk-OUT transfer in progress (header seen, payload incomplete).
    out: Option<OutTransfer>,
    last_out_btag: u8,
    /// SCPI text received so far (until EOM and a newline).
    message: Vec<u8>,
    request: Option<InRequest>,
    last_in_btag: u8,
    responses: VecDeque<Pending>,
    /// Bytes of the Bulk-IN transfer being read out.
    in_fifo: VecDeque<u8>,
    in_sent: usize,
    halted_out: bool,
    halted_in: bool,
    clear_until_s: Option<f64>,
    powered_up_at_s: f64,
    rng: ChaCha8Rng,
}

/// The power meter: shared by every handle opened on it.
#[derive(Debug)]
pub struct Pm100 {
    name: String,
    product_id: u16,
    serial: String,
    detector: Detector,
    responsivity: Responsivity,
    world: Arc<World>,
    faults: DeviceFaults,
    seed: u64,
    state: Mutex<MeterState>,
    notify: tokio::sync::Notify,
}

impl Pm100 {
    pub(crate) fn new(
        dev: &Device,
        inst: &Instrument,
        sim: &SimulatorSettings,
        world: Arc<World>,
        faults: DeviceFaults,
    ) -> Result<Pm100, String> {
        let detector = inst.detector.clone();
        let responsivity = Responsivity::from_detector(&detector)?;
        let seed = sim.seed ^ 0x504d_3130_3055_5342;
        let state = Mutex::new(Self::power_up_state(&detector, seed, 0.0));
        Ok(Pm100 {
            name: dev.name.clone(),
            product_id: dev.usb_product_id.unwrap_or(PRODUCT_ID_PM100USB),
            serial: dev.usb_serial.clone().unwrap_or_else(|| "P2000001".into()),
            detector,
            responsivity,
            world,
            faults,
            seed,
            state,
            notify: tokio::sync::Notify::new(),
        })
    }

    fn power_up_settings(detector: &Detector) -> Settings {
        Settings {
            wavelength_nm: 633.0,
            auto_range: true,
            range: detector.ranges_w.len().saturating_sub(1),
            unit_dbm: false,
            averaging: detector.averaging.max(1),
        }
    }

    fn power_up_state(detector: &Detector, seed: u64, t_s: f64) -> MeterState {
        MeterState {
            settings: Self::power_up_settings(detector),
            errors: VecDeque::new(),
            out: None,
            last_out_btag: 0,
            message: Vec::new(),
            request: None,
            last_in_btag: 0,
            responses: VecDeque::new(),
            in_fifo: VecDeque::new(),
            in_sent: 0,
            halted_out: false,
            halted_in: false,
            clear_until_s: None,
            powered_up_at_s: t_s,
            rng: ChaCha8Rng::seed_from_u64(seed),
        }
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, MeterState> {
        self.state.lock().unwrap_or_else(|e| e.into_inner())
    }

    fn now(&self) -> f64 {
        self.world.clock.now_s()
    }

    /// Is a handle opened at `opened_s` still valid at `now`? (A disconnect in between invalidates it.)
    fn handle_alive(&self, opened_s: f64, now: f64) -> bool {
        let inj = self.faults.injector();
        if !inj.link_up(now) {
            return false;
        }
        // A disconnect since the handle was opened invalidates it (the device re-enumerated meanwhile).
        match inj.latest_outage_start_s(now) {
            Some(start) => opened_s >= start,
            None => true,
        }
    }

    // ---------------------------------------------------------------- SCPI

    fn push_error(st: &mut MeterState, code: i32, text: &'static str) {
        tracing::debug!(code, text, "PM100: SCPI error queued");
        if st.errors.len() >= 30 {
            st.errors.pop_back();
            st.errors.push_back((-350, "Queue overflow"));
        } else {
            st.errors.push_back((code, text));
        }
    }

    /// Execute one complete program message (up to a newline); queue the response.
    fn execute_message(&self, st: &mut MeterState, text: &str, now: f64) {
        tracing::debug!(meter = %self.name, msg = text, "PM100 SCPI message");
        let mut responses: Vec<String> = Vec::new();
        let mut ready_at = now;
        for unit in text.split(';') {
            let unit = unit.trim();
            if unit.is_empty() {
                continue;
            }
            match self.execute_unit(st, unit, now) {
                Ok(Some((resp, done))) => {
                    responses.push(resp);
                    ready_at = ready_at.max(done);
                }
                Ok(None) => {}
                Err((code, msg)) => Self::push_error(st, code, msg),
            }
        }
        if responses.is_empty() {
            return;
        }
        let mut bytes = responses.join(";").into_bytes();
        bytes.push(b'\n');
        let delay = self.faults.reply_delay_s();
        if let crate::faults::ReplyFate::Drop = self.faults.reply(Vec::from([0u8])) {
            // The reply is lost: the host's read will time out. (USB is CRC-protected: no garbling.)
            return;
        }
        st.responses.push_back(Pending {
            ready_at_s: ready_at + delay,
            bytes,
        });
    }

    /// One command or query. Ok(Some((response, ready_at))) for queries.
    #[allow(clippy::type_complexity)]
    fn execute_unit(
        &self,
        st: &mut MeterState,
        unit: &str,
        now: f64,
    ) -> Result<Option<(String, f64)>, (i32, &'static str)> {
        let (header, arg) = match unit.split_once(|c: char| c.is_ascii_whitespace()) {
            Some((h, a)) => (h, a.trim()),
            None => (unit, ""),
        };
        let query = header.ends_with('?');
        let header = header.trim_end_matches('?');
        let at_now = |s: String| Ok(Some((s, now)));
        let parse_num = |a: &str| -> Result<f64, (i32, &'static str)> {
            if a.is_empty() {
                return Err((-109, "Missing parameter"));
            }
            a.parse::<f64>()
                .ok()
                .filter(|x| x.is_finite())
                .ok_or((-104, "Data type error"))
        };
        let ranges = &self.detector.ranges_w;
        let r_set = |st: &MeterState| self.responsivity.at(st.settings.wavelength_nm);
        // Common commands.
        if header.starts_with('*') {
            return match (header.to_ascii_uppercase().as_str(), query) {
                ("*IDN", true) => at_now(format!("Thorlabs,PM100USB,{},1.7.0", self.serial)),
                ("*OPC", true) => at_now("1".into()),
                ("*RST", false) => {
                    st.settings = Self::power_up_settings(&self.detector);
                    Ok(None)
                }
                ("*CLS", false) => {
                    st.errors.clear();
                    Ok(None)
                }
                ("*TST", true) => at_now("0".into()),
                ("*OPC" | "*WAI", false) => Ok(None),
                _ => Err((-113, "Undefined header")),
            };
        }
        let cmd = match_header(header).ok_or((-113, "Undefined header"))?;
        match (cmd, query) {
            (Cmd::SystSensIdn, true) => at_now("S120C,12345678,01-Jan-2024,1,18,289".into()),
            (Cmd::SystErr, true) => {
                let (code, text) = st.errors.pop_front().unwrap_or((0, "No error"));
                at_now(format!("{code},\"{text}\""))
            }
            (Cmd::Wavelength, true) => at_now(sci(st.settings.wavelength_nm)),
            (Cmd::Wavelength, false) => {
                let nm = parse_num(arg)?;
                if !(400.0..=1100.0).contains(&nm) {
                    return Err((-222, "Data out of range"));
                }
                st.settings.wavelength_nm = nm;
                Ok(None)
            }
            (Cmd::RangeAuto, true) => at_now(if st.settings.auto_range { "1" } else { "0" }.into()),
            (Cmd::RangeAuto, false) => {
                st.settings.auto_range = match arg.to_ascii_uppercase().as_str() {
                    "ON" | "1" => true,
                    "OFF" | "0" => false,
                    "" => return Err((-109, "Missing parameter")),
                    _ => return Err((-224, "Illegal parameter value")),
                };
                Ok(None)
            }
            (Cmd::Range, true) => at_now(sci(ranges.get(st.settings.range).copied().unwrap_or(0.0))),
            (Cmd::Range, false) => {
                let w = match arg.to_ascii_uppercase().as_str() {
                    "MIN" | "MINIMUM" => ranges.first().copied().unwrap_or(0.0),
                    "MAX" | "MAXIMUM" => ranges.last().copied().unwrap_or(0.0),
                    _ => parse_num(arg)?,
                };
                if w <= 0.0 {
                    return Err((-222, "Data out of range"));
                }
                // The smallest range that holds the requested power; the largest when none does.
                st.settings.range = ranges
                    .iter()
                    .position(|r| *r >= w)
                    .unwrap_or(ranges.len().saturating_sub(1));
                st.settings.auto_range = false;
                Ok(None)
            }
            (Cmd::Unit, true) => at_now(if st.settings.unit_dbm { "DBM" } else { "W" }.into()),
            (Cmd::Unit, false) => {
                st.settings.unit_dbm = match arg.to_ascii_uppercase().as_str() {
                    "W" => false,
                    "DBM" => true,
                    "" => return Err((-109, "Missing parameter")),
                    _ => return Err((-224, "Illegal parameter value")),
                };
                Ok(None)
            }
            (Cmd::Average, true) => at_now(st.settings.averaging.to_string()),
            (Cmd::Average, false) => {
                let n = parse_num(arg)?;
                if !(1.0..=1_000_000.0).contains(&n) {
                    return Err((-222, "Data out of range"));
                }
                st.settings.averaging = n.round() as u32;
                Ok(None)
            }
            (Cmd::ConfPower, false) | (Cmd::Init, false) | (Cmd::Abort, false) => Ok(None),
            (Cmd::ConfPower, true) => at_now("POW".into()),
            (Cmd::MeasPower, true) | (Cmd::Read, true) | (Cmd::Fetch, true) => {
                let n = st.settings.averaging.max(1);
                let done = now + f64::from(n) * SAMPLE_S;
                let w = self.reading_w(st, now, n, r_set(st));
                let value = if st.settings.unit_dbm && w < OVERLOAD_W {
                    10.0 * (w.max(1e-30) / 1e-3).log10()
                } else {
                    w
                };
                Ok(Some((sci(value), done)))
            }
            _ => Err((-113, "Undefined header")),
        }
    }

    /// Simulate one averaged reading starting at `t0` (W, or OVERLOAD_W).
    fn reading_w(&self, st: &mut MeterState, t0: f64, n: u32, r_set: f64) -> f64 {
        let d = &self.detector;
        let ranges = &d.ranges_w;
        let world = &self.world;
        let sample_times = |k: u32| t0 + (f64::from(k) + 0.5) * SAMPLE_S;
        // Axes and wheel at rest over the window: one scene evaluation serves every sample.
        let (p_first, b_first) = (world.pose(sample_times(0)), world.band(sample_times(0)));
        let (p_last, b_last) = (world.pose(sample_times(n - 1)), world.band(sample_times(n - 1)));
        let steady = p_first == p_last && b_first == b_last;
        let optical_at = |k: u32| -> (f64, Band) {
            let t = sample_times(k);
            let (pose, band): (Pose, Band) = if steady {
                (p_first, b_first)
            } else {
                (world.pose(t), world.band(t))
            };
            let p = world.scene.detector_power_w(&pose, &band, t);
            (if p.is_finite() { p.max(0.0) } else { 0.0 }, band)
        };
        // Current of each sample.
        let current = |p: f64, band: &Band| {
            let r_band = band.band_nm.map(|nm| self.responsivity.at(nm)).unwrap_or(0.0);
            p * r_band + d.dark_current_a
        };
        let currents: Vec<f64> = if steady && !d.noise {
            // At rest and without noise every sample is the same.
            let (p, band) = optical_at(n / 2);
            vec![current(p, &band); n as usize]
        } else if steady {
            // At rest, only the source changes from sample to sample: the scene computes the geometry once.
            let times: Vec<f64> = (0..n).map(sample_times).collect();
            let mut powers = Vec::with_capacity(times.len());
            world
                .scene
                .detector_power_series_w(&p_first, &b_first, &times, &mut powers);
            powers.iter().map(|p| current(p.max(0.0), &b_first)).collect()
        } else {
            (0..n)
                .map(|k| {
                    let (p, band) = optical_at(k);
                    current(p, &band)
                })
                .collect()
        };
        let mean_i = currents.iter().sum::<f64>() / f64::from(n);
        // Range in use: auto picks the smallest whose full-scale current holds the signal.
        let full_scale_i = |idx: usize| ranges.get(idx).copied().unwrap_or(0.0) * r_set;
        let range = if st.settings.auto_range {
            ranges
                .iter()
                .position(|r| r * r_set >= mean_i.abs())
                .unwrap_or(ranges.len().saturating_sub(1))
        } else {
            st.settings.range
        };
        let fs = full_scale_i(range);
        let saturate = self.faults.injector().saturate_reading(&self.name);
        if saturate || mean_i > fs {
            tracing::info!(meter = %self.name, current_a = mean_i, full_scale_a = fs, "PM100 overload");
            return OVERLOAD_W;
        }
        let mut i = mean_i;
        if d.noise && fs > 0.0 {
            // Each sample: shot noise of its current and Johnson noise of the range's feedback resistor, then
            // the 16-bit converter over the range; the reading is the mean of the quantised samples.
            let bandwidth_hz = 1.0 / (2.0 * SAMPLE_S);
            let r_feedback = FULL_SCALE_V / fs;
            let johnson_var = 4.0 * BOLTZMANN_J_K * TEMPERATURE_K * bandwidth_hz / r_feedback;
            let lsb = fs / ADC_COUNTS;
            let mut sum = 0.0;
            for c in &currents {
                let shot_var = 2.0 * ELEMENTARY_CHARGE_C * c.abs() * bandwidth_hz;
                let sample = c + (shot_var + johnson_var).sqrt() * standard_normal(&mut st.rng);
                sum += (sample / lsb).round() * lsb;
            }
            i = sum / f64::from(n);
        }
        if r_set > 0.0 { i / r_set } else { 0.0 }
    }

    // ---------------------------------------------------------------- USBTMC

    fn bulk_out(&self, opened_s: f64, endpoint: u8, data: &[u8]) -> Result<usize, UsbSimError> {
        let now = self.now();
        if !self.handle_alive(opened_s, now) {
            return Err(UsbSimError::NoDevice);
        }
        if endpoint != BULK_OUT_EP {
            return Err(UsbSimError::InvalidParam(format!(
                "endpoint {endpoint:#04x} is not the Bulk-OUT endpoint"
            )));
        }
        let mut st = self.lock();
        if st.halted_out {
            return Err(UsbSimError::Pipe { endpoint });
        }
        tracing::trace!(meter = %self.name, len = data.len(), "PM100 Bulk-OUT");
        let mut rest = data;
        while !rest.is_empty() {
            if let Some(mut t) = st.out {
                let take = t.remaining.min(rest.len());
                st.message.extend_from_slice(&rest[..take]);
                t.remaining -= take;
                t.received += take;
                rest = &rest[take..];
                let pad = t.pad.min(rest.len());
                t.pad -= pad;
                rest = &rest[pad..];
                if t.remaining == 0 {
                    st.out = None;
                    if t.eom {
                        self.message_complete(&mut st, now);
                    }
                } else {
                    st.out = Some(t);
                }
                continue;
            }
            let Some(h) = rest.get(..12) else {
                return self.halt_out(&mut st, "short header");
            };
            let (msg_id, btag, inv) = (h[0], h[1], h[2]);
            if btag == 0 || inv != !btag {
                return self.halt_out(&mut st, "bTag check failed");
            }
            let size = u32::from_le_bytes([h[4], h[5], h[6], h[7]]) as usize;
            match msg_id {
                DEV_DEP_MSG_OUT => {
                    let pad = (4 - size % 4) % 4;
                    st.last_out_btag = btag;
                    st.out = Some(OutTransfer {
                        btag,
                        remaining: size,
                        pad,
                        eom: h[8] & 1 == 1,
                        received: 0,
                    });
                    if size == 0 {
                        let eom = h[8] & 1 == 1;
                        st.out = None;
                        if eom {
                            self.message_complete(&mut st, now);
                        }
                    }
                    rest = &rest[12..];
                }
                REQUEST_DEV_DEP_MSG_IN => {
                    if size == 0 {
                        return self.halt_out(&mut st, "REQUEST_DEV_DEP_MSG_IN for 0 bytes");
                    }
                    st.request = Some(InRequest { btag, max: size });
                    st.last_in_btag = btag;
                    if st.responses.is_empty() && st.in_fifo.is_empty() {
                        // Reading with no query pending.
                        Self::push_error(&mut st, -420, "Query UNTERMINATED");
                    }
                    rest = &[];
                }
                _ => return self.halt_out(&mut st, "unsupported MsgID"),
            }
        }
        drop(st);
        self.notify.notify_waiters();
        Ok(data.len())
    }

    fn halt_out(&self, st: &mut MeterState, why: &str) -> Result<usize, UsbSimError> {
        tracing::debug!(meter = %self.name, why, "PM100: Bulk-OUT halted");
        st.halted_out = true;
        st.out = None;
        Err(UsbSimError::Pipe {
            endpoint: BULK_OUT_EP,
        })
    }

    fn message_complete(&self, st: &mut MeterState, now: f64) {
        let msg = std::mem::take(&mut st.message);
        let text = String::from_utf8_lossy(&msg).into_owned();
        // Newline ends a program message; a final one without newline is taken as ended by EOM (EOI).
        for line in text.split('\n') {
            let line = line.trim_end_matches('\r');
            if !line.trim().is_empty() {
                self.execute_message(st, line, now);
            }
        }
    }

    /// Build the next Bulk-IN transfer if a request is pending and response bytes are ready.
    fn fill_in_fifo(st: &mut MeterState, now: f64) {
        if !st.in_fifo.is_empty() {
            return;
        }
        let Some(req) = st.request else { return };
        let Some(front) = st.responses.front() else { return };
        if front.ready_at_s > now {
            return;
        }
        let Some(mut resp) = st.responses.pop_front() else {
            return;
        };
        let n = req.max.min(resp.bytes.len());
        let rest = resp.bytes.split_off(n);
        let eom = rest.is_empty();
        if !eom {
            st.responses.push_front(Pending {
                ready_at_s: resp.ready_at_s,
                bytes: rest,
            });
        }
        let mut t = vec![DEV_DEP_MSG_IN, req.btag, !req.btag, 0];
        t.extend_from_slice(&(n as u32).to_le_bytes());
        t.extend_from_slice(&[u8::from(eom), 0, 0, 0]);
        t.extend_from_slice(&resp.bytes);
        while t.len() % 4 != 0 {
            t.push(0);
        }
        st.in_fifo.extend(t);
        st.in_sent = 0;
        st.request = None;
    }

    fn in_ready_at(st: &MeterState) -> Option<f64> {
        if !st.in_fifo.is_empty() {
            return Some(0.0);
        }
        st.request?;
        st.responses.front().map(|r| r.ready_at_s)
    }

    async fn bulk_in(
        &self,
        opened_s: f64,
        endpoint: u8,
        max_len: usize,
        timeout: Duration,
    ) -> Result<Vec<u8>, UsbSimError> {
        if endpoint != BULK_IN_EP {
            return Err(UsbSimError::InvalidParam(format!(
                "endpoint {endpoint:#04x} is not the Bulk-IN endpoint"
            )));
        }
        if max_len == 0 {
            return Err(UsbSimError::InvalidParam("bulk_in of 0 bytes".into()));
        }
        let deadline = tokio::time::Instant::now() + timeout;
        loop {
            let now = self.now();
            if !self.handle_alive(opened_s, now) {
                return Err(UsbSimError::NoDevice);
            }
            let notified = self.notify.notified();
            let wake = {
                let mut st = self.lock();
                if st.halted_in {
                    return Err(UsbSimError::Pipe { endpoint });
                }
                Self::fill_in_fifo(&mut st, now);
                if !st.in_fifo.is_empty() {
                    let n = max_len.min(st.in_fifo.len());
                    let out: Vec<u8> = st.in_fifo.drain(..n).collect();
                    st.in_sent += n;
                    tracing::trace!(meter = %self.name, len = out.len(), "PM100 Bulk-IN");
                    return Ok(out);
                }
                Self::in_ready_at(&st)
            };
            let disconnect = self.faults.injector().next_disconnect_s(now);
            let wake = match (wake, disconnect) {
                (Some(a), Some(b)) => Some(a.min(b)),
                (a, b) => a.or(b),
            };
            let wake_instant = wake
                .map(|t| self.world.clock.instant_at(t).min(deadline))
                .unwrap_or(deadline);
            tokio::select! {
                _ = tokio::time::sleep_until(wake_instant) => {}
                _ = notified => {}
            }
            if tokio::time::Instant::now() >= deadline {
                // Last look: the data may have become ready exactly at the deadline.
                let mut st = self.lock();
                Self::fill_in_fifo(&mut st, self.now());
                if st.in_fifo.is_empty() {
                    return Err(UsbSimError::Timeout { transferred: 0 });
                }
            }
        }
    }

    fn control_in(
        &self,
        opened_s: f64,
        request_type: u8,
        request: u8,
        value: u16,
        index: u16,
        max_len: usize,
    ) -> Result<Vec<u8>, UsbSimError> {
        let now = self.now();
        if !self.handle_alive(opened_s, now) {
            return Err(UsbSimError::NoDevice);
        }
        let mut st = self.lock();
        let btag = (value & 0xFF) as u8;
        let endpoint = (index & 0xFF) as u8;
        let reply: Vec<u8> = match (request_type, request) {
            (0xA2, INITIATE_ABORT_BULK_OUT) if endpoint == BULK_OUT_EP => {
                let status = match st.out {
                    Some(t) if t.btag == btag => {
                        st.out = None;
                        st.message.clear();
                        STATUS_SUCCESS
                    }
                    Some(_) => STATUS_TRANSFER_NOT_IN_PROGRESS,
                    None if st.last_out_btag == btag && !st.message.is_empty() => {
                        st.message.clear();
                        STATUS_SUCCESS
                    }
                    None => STATUS_FAILED,
                };
                vec![status, btag]
            }
            (0xA2, CHECK_ABORT_BULK_OUT_STATUS) if endpoint == BULK_OUT_EP => {
                let n = st.out.map(|t| t.received).unwrap_or(0) as u32;
                let mut v = vec![STATUS_SUCCESS, 0, 0, 0];
                v.extend_from_slice(&n.to_le_bytes());
                v
            }
            (0xA2, INITIATE_ABORT_BULK_IN) if endpoint == BULK_IN_EP => {
                let in_progress = !st.in_fifo.is_empty() || st.request.is_some();
                let status = if !in_progress {
                    STATUS_FAILED
                } else if st.last_in_btag != btag {
                    STATUS_TRANSFER_NOT_IN_PROGRESS
                } else {
                    st.in_fifo.clear();
                    st.request = None;
                    st.responses.clear();
                    STATUS_SUCCESS
                };
                vec![status, btag]
            }
            (0xA2, CHECK_ABORT_BULK_IN_STATUS) if endpoint == BULK_IN_EP => {
                let more = u8::from(!st.in_fifo.is_empty());
                let mut v = vec![STATUS_SUCCESS, more, 0, 0];
                v.extend_from_slice(&(st.in_sent as u32).to_le_bytes());
                v
            }
            (0xA1, INITIATE_CLEAR) => {
                st.out = None;
                st.message.clear();
                st.request = None;
                st.responses.clear();
                st.in_fifo.clear();
                st.clear_until_s = Some(now + CLEAR_S);
                vec![STATUS_SUCCESS]
            }
            (0xA1, CHECK_CLEAR_STATUS) => match st.clear_until_s {
                Some(t) if now < t => vec![STATUS_PENDING, 0],
                _ => {
                    st.clear_until_s = None;
                    vec![STATUS_SUCCESS, u8::from(!st.in_fifo.is_empty())]
                }
            },
            (0xA1, GET_CAPABILITIES) => {
                let mut v = vec![0u8; 0x18];
                v[0] = STATUS_SUCCESS;
                // bcdUSBTMC 1.00
                v[2] = 0x00;
                v[3] = 0x01;
                // USB488 subclass: bcdUSB488 1.00, 488.2 interface, SCPI device.
                v[12] = 0x00;
                v[13] = 0x01;
                v[14] = 0x04;
                v[15] = 0x08;
                v
            }
            _ => {
                // Unsupported requests are answered with a STALL of the control pipe.
                return Err(UsbSimError::Pipe { endpoint: 0 });
            }
        };
        tracing::debug!(meter = %self.name, request, status = reply.first().copied(), "PM100 control request");
        let mut reply = reply;
        reply.truncate(max_len);
        Ok(reply)
    }

    fn clear_halt(&self, opened_s: f64, endpoint: u8) -> Result<(), UsbSimError> {
        if !self.handle_alive(opened_s, self.now()) {
            return Err(UsbSimError::NoDevice);
        }
        let mut st = self.lock();
        match endpoint {
            BULK_OUT_EP => {
                st.halted_out = false;
                st.out = None;
            }
            BULK_IN_EP => st.halted_in = false,
            _ => return Err(UsbSimError::InvalidParam(format!("no endpoint {endpoint:#04x}"))),
        }
        Ok(())
    }

    /// Power the meter up again if it was unplugged since it last powered up (a fault reconnect).
    fn reopen(&self, now: f64) {
        let mut st = self.lock();
        if let Some(start) = self.faults.injector().latest_outage_start_s(now)
            && st.powered_up_at_s <= start
        {
            tracing::info!(meter = %self.name, "PM100 re-enumerated after disconnect: power-up state");
            *st = Self::power_up_state(&self.detector, self.seed.wrapping_add(1), now);
        }
    }
}

/// SCPI commands the meter knows.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Cmd {
    SystSensIdn,
    SystErr,
    Wavelength,
    RangeAuto,
    Range,
    Unit,
    Average,
    ConfPower,
    MeasPower,
    Read,
    Fetch,
    Init,
    Abort,
}

/// Command tree patterns: nodes separated by ':', `[...]` optional, upper-case part = short form.
const PATTERNS: &[(&str, Cmd)] = &[
    ("SYSTem:SENSor:IDN", Cmd::SystSensIdn),
    ("SYSTem:ERRor[:NEXT]", Cmd::SystErr),
    ("[SENSe]:CORRection:WAVelength", Cmd::Wavelength),
    ("[SENSe]:POWer[:DC]:RANGe:AUTO", Cmd::RangeAuto),
    ("[SENSe]:POWer[:DC]:RANGe[:UPPer]", Cmd::Range),
    ("[SENSe]:POWer[:DC]:UNIT", Cmd::Unit),
    ("[SENSe]:AVERage[:COUNt]", Cmd::Average),
    ("CONFigure[:SCALar]:POWer", Cmd::ConfPower),
    ("CONFigure", Cmd::ConfPower),
    ("MEASure[:SCALar]:POWer", Cmd::MeasPower),
    ("MEASure", Cmd::MeasPower),
    ("READ", Cmd::Read),
    ("FETCh", Cmd::Fetch),
    ("INITiate[:IMMediate]", Cmd::Init),
    ("ABORt", Cmd::Abort),
];

/// Does `word` name the node `long` (short form = its upper-case prefix), with an optional numeric suffix 1?
fn node_matches(word: &str, long: &str) -> bool {
    let word = word.strip_suffix('1').filter(|w| !w.is_empty()).unwrap_or(word);
    let short: String = long.chars().take_while(|c| c.is_ascii_uppercase()).collect();
    word.eq_ignore_ascii_case(&short) || word.eq_ignore_ascii_case(long)
}

fn match_pattern(words: &[&str], nodes: &[(&str, bool)]) -> bool {
    match (words.first(), nodes.first()) {
        (None, None) => true,
        (None, Some(_)) => nodes.iter().all(|(_, optional)| *optional),
        (Some(_), None) => false,
        (Some(w), Some((long, optional))) => {
            (node_matches(w, long) && match_pattern(&words[1..], &nodes[1..]))
                || (*optional && match_pattern(words, &nodes[1..]))
        }
    }
}

fn match_header(header: &str) -> Option<Cmd> {
    let header = header.strip_prefix(':').unwrap_or(header);
    let words: Vec<&str> = header.split(':').collect();
    if words.iter().any(|w| w.is_empty()) {
        return None;
    }
    PATTERNS.iter().find_map(|(pattern, cmd)| {
        let nodes: Vec<(&str, bool)> = pattern
            .split(':')
            .filter(|n| !n.is_empty())
            .map(|n| {
                let optional = n.starts_with('[') || n.ends_with(']');
                (n.trim_matches(|c| c == '[' || c == ']'), optional)
            })
            .collect();
        // "[:NEXT]" splits as "[" + "NEXT]": the filter above drops the empty piece.
        match_pattern(&words, &nodes).then_some(*cmd)
    })
}

/// SCPI NR3 format: `d.dddddde±XX`.
fn sci(x: f64) -> String {
    if x == 0.0 || !x.is_finite() {
        return "0.000000E+00".into();
    }
    let exp = x.abs().log10().floor() as i32;
    let mut mant = x / 10f64.powi(exp);
    let mut exp = exp;
    if (mant.abs() * 1e6).round() >= 1e7 {
        mant /= 10.0;
        exp += 1;
    }
    format!("{mant:.6}E{}{:02}", if exp < 0 { '-' } else { '+' }, exp.abs())
}

/// A handle on the simulated USB power meter, as a USB device would be opened on the bus.
#[derive(Debug, Clone)]
pub struct SimUsbDevice {
    meter: Arc<Pm100>,
    opened_s: f64,
}

impl SimUsbDevice {
    pub(crate) fn open(meter: Arc<Pm100>, now_s: f64) -> SimUsbDevice {
        meter.reopen(now_s);
        SimUsbDevice {
            meter,
            opened_s: now_s,
        }
    }

    pub fn vendor_id(&self) -> u16 {
        VENDOR_ID
    }

    pub fn product_id(&self) -> u16 {
        self.meter.product_id
    }

    pub fn serial_number(&self) -> String {
        self.meter.serial.clone()
    }

    pub fn bulk_out_endpoint(&self) -> u8 {
        BULK_OUT_EP
    }

    pub fn bulk_in_endpoint(&self) -> u8 {
        BULK_IN_EP
    }

    /// One Bulk-OUT transfer; returns the bytes accepted.
    pub async fn bulk_out(
        &self,
        endpoint: u8,
        data: &[u8],
        _timeout: Duration,
    ) -> Result<usize, UsbSimError> {
        self.meter.bulk_out(self.opened_s, endpoint, data)
    }

    /// One Bulk-IN transfer of at most `max_len` bytes; waits up to `timeout` for the device to have data.
    pub async fn bulk_in(
        &self,
        endpoint: u8,
        max_len: usize,
        timeout: Duration,
    ) -> Result<Vec<u8>, UsbSimError> {
        self.meter
            .bulk_in(self.opened_s, endpoint, max_len, timeout)
            .await
    }

    /// A control transfer from the device (class requests of USBTMC).
    pub async fn control_in(
        &self,
        request_type: u8,
        request: u8,
        value: u16,
        index: u16,
        max_len: usize,
        _timeout: Duration,
    ) -> Result<Vec<u8>, UsbSimError> {
        self.meter
            .control_in(self.opened_s, request_type, request, value, index, max_len)
    }

    /// Clear a halted endpoint (CLEAR_FEATURE ENDPOINT_HALT).
    pub async fn clear_halt(&self, endpoint: u8) -> Result<(), UsbSimError> {
        self.meter.clear_halt(self.opened_s, endpoint)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn scpi_headers_match_short_and_long_forms_case_insensitively() {
        assert_eq!(match_header("SENS:CORR:WAV"), Some(Cmd::Wavelength));
        assert_eq!(match_header("sense:correction:wavelength"), Some(Cmd::Wavelength));
        assert_eq!(match_header("CORR:WAV"), Some(Cmd::Wavelength));
        assert_eq!(match_header(":SENS1:POW:DC:RANG:AUTO"), Some(Cmd::RangeAuto));
        assert_eq!(match_header("SENS:POW:RANG"), Some(Cmd::Range));
        assert_eq!(match_header("POW:RANG:UPP"), Some(Cmd::Range));
        assert_eq!(match_header("MEAS:POW"), Some(Cmd::MeasPower));
        assert_eq!(match_header("meas:scal:pow"), Some(Cmd::MeasPower));
        assert_eq!(match_header("SYST:ERR"), Some(Cmd::SystErr));
        assert_eq!(match_header("SYST:ERR:NEXT"), Some(Cmd::SystErr));
        assert_eq!(match_header("SYST:SENS:IDN"), Some(Cmd::SystSensIdn));
        // Neither short nor long form.
        assert_eq!(match_header("SENS:CORR:WAVE"), None);
        assert_eq!(match_header("CORRE:WAV"), None);
        assert_eq!(match_header("SENS::WAV"), None);
    }

    #[test]
    fn nr3_format() {
        assert_eq!(sci(633.0), "6.330000E+02");
        assert_eq!(sci(1.234e-7), "1.234000E-07");
        assert_eq!(sci(9.9999999e-5), "1.000000E-04");
        assert_eq!(sci(0.0), "0.000000E+00");
    }

    #[test]
    fn responsivity_interpolates_linearly_and_clamps() {
        let r = Responsivity::Table(vec![(400.0, 0.1), (500.0, 0.3)]);
        assert!((r.at(450.0) - 0.2).abs() < 1e-12);
        assert_eq!(r.at(300.0), 0.1);
        assert_eq!(r.at(900.0), 0.3);
    }
}
