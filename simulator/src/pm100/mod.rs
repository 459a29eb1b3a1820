//! Thorlabs PM100USB optical power meter: SCPI over USBTMC, as a USB device with bulk and control pipes.
//!
//! Split by job: [`usbtmc`] (the USB side: bulk and control pipes, framing), [`scpi`] (header matching,
//! number formats), `function` (the measurement function the command tree and the command set both speak),
//! [`commands`] (the command set: IEEE 488.2 common commands, status registers, sense settings, measurement
//! functions), [`physics`] (photocurrent, noise, ranges).
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
//! range in use (or of the largest range under auto-range) is an overload.
//!
//! Protocol notes, and where each comes from:
//! - Over range, `MEAS:POW?` answers `INFINITY` (`-INFINITY` below the negative full scale) and bit 3 (POWer)
//!   of `STAT:QUES:COND?` is set: Thorlabs' SCPI command references for the PM100D2, PM101, PM103 and PM400.
//!   Older material and SCPI 1999 give the overflow value 9.9E37 instead: `[simulator.quirks]
//!   pm100_overrange` picks the variant (default `infinity`).
//! - Queries taking `MIN`/`MAX` (`SENS:CORR:WAV?`, `SENS:POW:RANG?`, `SENS:CURR:RANG?`, `SENS:AVER?`,
//!   `SENS:CORR:BEAM?`) answer the limits; the wavelength limits are the sensor's (`[instrument.detector]
//!   sensor_wavelength_nm`): PM100 SCPI reference.
//! - The IEEE 488.2 common commands (`*IDN? *RST *CLS *OPC *OPC? *WAI *TST? *STB? *SRE *SRE? *ESE *ESE? *ESR?`)
//!   and the status byte / standard event status register: IEEE 488.2 (mandatory for a USB488 device, which
//!   GET_CAPABILITIES announces) and the PM100 manual's command list.
//! - `MEAS`/`CONF`/`READ?`/`FETC?` with the functions `POW`, `CURR`, `PDEN` (W/cm² over the beam diameter of
//!   `SENS:CORR:BEAM`) and `FREQ`; `CONF?` names the function: PM100 SCPI reference.
//! - `SYST:ERR?` answers `+0,"No error"` (signed code) on real devices: published transcripts of real meters.
//!
//! Still unconfirmed (no real-device record found): what `MEAS:ENER?`, `VOLT`, `TEMP` and `RES` (functions of
//! pyroelectric, thermopile and thermistor heads) answer with a photodiode head (here: error -241 "Hardware
//! missing"); the default beam diameter (here 1 mm); the largest `SENS:AVER:COUN` (here 1 000 000); the
//! `FREQ` reading of a CW source (here 0).

use std::collections::VecDeque;
use std::sync::{Arc, Mutex};
use std::time::Duration;

use gonio_instrument::{Detector, Device, Instrument, Pm100Overrange, SimulatorSettings};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

use crate::faults::DeviceFaults;
use crate::world::World;

mod commands;
mod function;
mod physics;
mod scpi;
mod usbtmc;

use crate::responsivity::Responsivity;

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
pub const SAMPLE_S: f64 = gonio_instrument::meter_noise::SAMPLE_S;
/// The value a reading takes in overload under `pm100_overrange = "scpi-overflow"`.
pub const OVERLOAD_W: f64 = 9.9e37;
/// Bit 3 of the SCPI questionable status registers: the power reading is over range.
pub const QUES_POWER_OVERRANGE: u16 = 1 << 3;
/// How long the device takes to clear its buffers after INITIATE_CLEAR (s).
const CLEAR_S: f64 = 0.001;

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

/// Meter settings (reset by `*RST` and by a power cycle).
#[derive(Debug, Clone)]
struct Settings {
    wavelength_nm: f64,
    auto_range: bool,
    /// Index into the ranges.
    range: usize,
    unit_dbm: bool,
    averaging: u32,
    /// Beam diameter for power density (mm).
    beam_mm: f64,
    function: function::Function,
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
    /// IEEE 488.2 registers: standard event status, its enable, the service request enable.
    esr: u8,
    ese: u8,
    sre: u8,
    /// SCPI status: questionable condition, event, enable; operation event, enable.
    ques_cond: u16,
    ques_event: u16,
    ques_enable: u16,
    oper_event: u16,
    oper_enable: u16,
    /// Extra delay (simulated s) for the next response only: the gadget's "reply late" fault.
    next_reply_delay_s: f64,
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
    overrange: Pm100Overrange,
    /// The meter's and photodiode's hidden errors (crate::imperfections::detector); `None` on the ideal
    /// instrument.
    imperfections: Option<crate::imperfections::DetectorTruth>,
    /// What the imperfections did to the last reading (recorded only on an imperfect instrument).
    last_effects: Mutex<Option<crate::imperfections::MeterEffects>>,
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
        imperfections: Option<crate::imperfections::DetectorTruth>,
    ) -> Result<Pm100, String> {
        let detector = inst.detector.clone();
        let responsivity = Responsivity::from_detector(&detector).map_err(|e| e.0)?;
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
            overrange: sim.quirks.pm100_overrange,
            imperfections,
            last_effects: Mutex::new(None),
            state,
            notify: tokio::sync::Notify::new(),
        })
    }

    /// What the imperfections did to the last reading (hidden truth); `None` on the ideal instrument.
    pub fn last_effects(&self) -> Option<crate::imperfections::MeterEffects> {
        *self.last_effects.lock().unwrap_or_else(|e| e.into_inner())
    }

    fn power_up_settings(detector: &Detector) -> Settings {
        Settings {
            wavelength_nm: 633.0,
            auto_range: true,
            range: detector.ranges_w.len().saturating_sub(1),
            unit_dbm: false,
            averaging: detector.averaging.max(1),
            beam_mm: commands::DEFAULT_BEAM_MM,
            function: function::Function::Power,
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
            // Power-on (PON, bit 7) is set at power-up.
            esr: 0x80,
            ese: 0,
            sre: 0,
            ques_cond: 0,
            ques_event: 0,
            ques_enable: 0,
            oper_event: 0,
            oper_enable: 0,
            next_reply_delay_s: 0.0,
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
        // IEEE 488.2 event bits: command error (CME, bit 5), execution error (EXE, 4), device-dependent (DDE,
        // 3), query error (QYE, 2), by the SCPI error class.
        st.esr |= match code {
            -199..=-100 => 0x20,
            -299..=-200 => 0x10,
            -399..=-300 => 0x08,
            -499..=-400 => 0x04,
            _ => 0,
        };
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
        let delay = self.faults.reply_delay_s() + std::mem::take(&mut st.next_reply_delay_s);
        if let crate::faults::ReplyFate::Drop = self.faults.reply(Vec::from([0u8])) {
            // The reply is lost: the host's read will time out. (USB is CRC-protected: no garbling.)
            return;
        }
        st.responses.push_back(Pending {
            ready_at_s: ready_at + delay,
            bytes,
        });
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

    /// The meter lost its bus power (its USB cable was pulled, or its gadget unbound): every setting, queued
    /// message and halt is gone; it comes back in its power-up state, as a bus-powered PM100USB does.
    pub fn power_cycle(&self) {
        let now = self.meter.now();
        tracing::info!(meter = %self.meter.name, "PM100 power cycled: power-up state");
        let mut st = self.meter.lock();
        *st = Pm100::power_up_state(&self.meter.detector, self.meter.seed.wrapping_add(1), now);
        drop(st);
        self.meter.notify.notify_waiters();
    }

    /// Answer the next query `delay_s` simulated seconds late (a fault: a reply past the host's timeout).
    pub fn delay_next_reply(&self, delay_s: f64) {
        if delay_s.is_finite() && delay_s >= 0.0 {
            tracing::info!(meter = %self.meter.name, delay_s, "PM100: next reply delayed (fault)");
            self.meter.lock().next_reply_delay_s = delay_s;
        }
    }
}
