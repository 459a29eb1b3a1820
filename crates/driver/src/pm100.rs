//! Thorlabs PM100-family optical power meters (PM100USB, PM100D, PM100A, PM400, ...) over USBTMC with SCPI,
//! written from the Thorlabs PM100 SCPI command reference and the USBTMC 1.0 specification.
//!
//! Configuration is followed by `SYST:ERR?` until the queue reads code 0 (`0,"No error"` or, as real meters
//! write it, `+0,"No error"`); any error there is a rejection. The wavelength is checked against the sensor's
//! limits (`SENS:CORR:WAV? MIN` / `MAX`) first. Readings are `MEAS:POW?` (W) with the range from
//! `SENS:POW:RANG?`. A reading at or beyond the range's full scale is flagged as overload, never passed off as
//! a value; so are the over-range answers, which differ between models and firmware versions.
//!
//! Protocol notes, and where each comes from:
//! - Over range, `MEAS:POW?` answers `INFINITY` or `-INFINITY` (Thorlabs' SCPI command references for the
//!   PM100D2, PM101, PM103 and PM400), or SCPI 1999's overflow value `9.9E37`; `+INF`, `-INF` and `NAN` are
//!   taken as overload too ([`classify_reading`]).
//! - `SYST:ERR?` answers `+0,"No error"` on real devices (published transcripts); the sign is optional.
//! - `SENS:CORR:WAV? MIN` / `MAX` answer the sensor head's limits: PM100 SCPI reference.
//! - The USB product ids of the family: Thorlabs' TLPMX examples ([`PRODUCTS`]). Unconfirmed: which model
//!   each of 0x8070, 0x8071, 0x8075, 0x8076, 0x8077, 0x807A, 0x807B and 0x8099 is (named "Thorlabs power
//!   meter" here).

use std::sync::Arc;
use std::time::{Duration, SystemTime};

use tokio::sync::Mutex;
use tokio::time::Instant;

use crate::error::DriverError;
use crate::traits::{Detector, DetectorConfig, PowerRange, PowerReading};
use crate::transport::BoxFuture;
use crate::transport::usb::{UsbError, UsbPipe};
use crate::usbtmc::{Usbtmc, UsbtmcError};

/// Thorlabs' USB vendor id and the power meters' product ids (normal mode).
pub const THORLABS_VID: u16 = 0x1313;
pub const PRODUCTS: [(u16, &str); 14] = [
    (0x8070, "Thorlabs power meter"),
    (0x8071, "Thorlabs power meter"),
    (0x8072, "PM100USB"),
    (0x8075, "Thorlabs power meter"),
    (0x8076, "Thorlabs power meter"),
    (0x8077, "Thorlabs power meter"),
    (0x8078, "PM100D"),
    (0x8079, "PM100A"),
    (0x807A, "Thorlabs power meter"),
    (0x807B, "Thorlabs power meter"),
    (0x807D, "PM400"),
    (0x8099, "Thorlabs power meter"),
    (0x80B0, "PM200"),
    (0x80BB, "PM5020"),
];

const QUERY_TIMEOUT: Duration = Duration::from_millis(1000);
const ATTEMPTS: usize = 2;
/// SCPI's "overflow" value (IEEE 488.2 / SCPI 1999, 9.9E37).
const SCPI_OVERFLOW: f64 = 9.9e37;
/// One sample takes about 3 ms on the PM100.
const SAMPLE_S: f64 = 0.003;

/// Parse an SCPI number (`+1.234567E-03`); finite only. Never panics.
pub fn parse_scpi_number(text: &str) -> Option<f64> {
    let t = text.trim();
    if t.is_empty()
        || t.len() > 32
        || !t
            .bytes()
            .all(|b| b.is_ascii_digit() || matches!(b, b'.' | b'-' | b'+' | b'e' | b'E'))
    {
        return None;
    }
    t.parse::<f64>().ok().filter(|x| x.is_finite())
}

/// What a `MEAS:POW?` answer says, given the range's full scale (W): `Some((power_w, overload))`, with
/// `power_w` NaN when the meter gave no value (over range); `None` when the text is not a reading at all.
/// Never panics.
pub fn classify_reading(text: &str, range_w: f64) -> Option<(f64, bool)> {
    let t = text.trim();
    if let Some(p) = parse_scpi_number(t) {
        return Some(if p.abs() >= SCPI_OVERFLOW {
            (f64::NAN, true)
        } else {
            (p, p >= range_w)
        });
    }
    let word = t.strip_prefix(['+', '-']).unwrap_or(t);
    ["INF", "INFINITY", "NAN", "NAN(IND)"]
        .iter()
        .any(|w| word.eq_ignore_ascii_case(w))
        .then_some((f64::NAN, true))
}

/// Parse a `SYST:ERR?` answer: `code,"text"`.
pub fn parse_scpi_error(text: &str) -> Option<(i32, String)> {
    let (code, msg) = text.trim().split_once(',')?;
    let code: i32 = code.trim().parse().ok()?;
    let msg = msg.trim();
    let msg = msg
        .strip_prefix('"')
        .and_then(|m| m.strip_suffix('"'))
        .unwrap_or(msg);
    Some((code, msg.to_string()))
}

/// Reopens the USB device after it vanished.
pub type PipeOpener = Arc<dyn Fn() -> Result<Arc<dyn UsbPipe>, UsbError> + Send + Sync>;

/// One power meter.
pub struct Pm100 {
    name: String,
    tmc: Mutex<Usbtmc>,
    opener: Option<PipeOpener>,
    averaging: std::sync::Mutex<u32>,
    /// The last configuration applied. A meter that vanished and came back has its power-up settings (another
    /// wavelength correction would make every reading silently wrong): it is applied again before any reading.
    config: std::sync::Mutex<Option<DetectorConfig>>,
    /// Set when the device was reopened and [`Pm100::config`] not yet applied to it again.
    needs_restore: std::sync::atomic::AtomicBool,
}

impl std::fmt::Debug for Pm100 {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Pm100")
            .field("name", &self.name)
            .finish_non_exhaustive()
    }
}

impl Pm100 {
    /// A meter on an open pipe; `opener` (optional) reopens the device after a disconnect.
    pub fn new(name: impl Into<String>, pipe: Arc<dyn UsbPipe>, opener: Option<PipeOpener>) -> Pm100 {
        let name = name.into();
        Pm100 {
            tmc: Mutex::new(Usbtmc::new(name.clone(), pipe)),
            name,
            opener,
            averaging: std::sync::Mutex::new(1),
            config: std::sync::Mutex::new(None),
            needs_restore: std::sync::atomic::AtomicBool::new(false),
        }
    }

    /// Open a real meter by USB ids (blocking enumeration runs on the blocking pool).
    pub async fn open_usb(
        name: impl Into<String>,
        vid: u16,
        pid: u16,
        serial: Option<String>,
    ) -> Result<Pm100, DriverError> {
        let name = name.into();
        let opener: PipeOpener = Arc::new(move || {
            crate::transport::usb::RusbPipe::open(vid, pid, serial.as_deref())
                .map(|p| Arc::new(p) as Arc<dyn UsbPipe>)
        });
        let o = Arc::clone(&opener);
        let pipe = tokio::task::spawn_blocking(move || o())
            .await
            .map_err(|e| DriverError::Unavailable {
                device: name.clone(),
                detail: e.to_string(),
            })?
            .map_err(|e| DriverError::Unavailable {
                device: name.clone(),
                detail: format!("USB {vid:04x}:{pid:04x}: {e}"),
            })?;
        Ok(Pm100::new(name, pipe, Some(opener)))
    }

    /// Open a meter served on a Unix socket (`gonio sim --link-dir`; see [`crate::transport::usb_socket`]);
    /// reconnecting connects again.
    pub async fn open_socket(
        name: impl Into<String>,
        path: std::path::PathBuf,
    ) -> Result<Pm100, DriverError> {
        let name = name.into();
        let opener: PipeOpener = Arc::new(move || {
            crate::transport::usb_socket::SocketUsbPipe::open(&path).map(|p| Arc::new(p) as Arc<dyn UsbPipe>)
        });
        let o = Arc::clone(&opener);
        let pipe = tokio::task::spawn_blocking(move || o())
            .await
            .map_err(|e| DriverError::Unavailable {
                device: name.clone(),
                detail: e.to_string(),
            })?
            .map_err(|e| DriverError::Unavailable {
                device: name.clone(),
                detail: format!("USB socket: {e}"),
            })?;
        Ok(Pm100::new(name, pipe, Some(opener)))
    }

    fn map(&self, request: &str, e: UsbtmcError, timeout: Duration) -> DriverError {
        let device = self.name.clone();
        match e {
            UsbtmcError::Usb(UsbError::NoDevice) => DriverError::Disconnected {
                device,
                detail: "USB device gone".into(),
            },
            UsbtmcError::Usb(UsbError::Access(d)) => DriverError::Unavailable { device, detail: d },
            UsbtmcError::Usb(UsbError::Timeout { .. }) | UsbtmcError::Timeout => DriverError::Timeout {
                device,
                request: request.into(),
                timeout,
            },
            other => DriverError::Protocol {
                device,
                request: request.into(),
                detail: other.to_string(),
            },
        }
    }

    /// One SCPI query; on a timeout or a bad frame the I/O is cleared (INITIATE_CLEAR) and the query asked once
    /// more (SCPI queries here have no side effects beyond taking a new reading).
    pub async fn query(&self, command: &str, timeout: Duration) -> Result<String, DriverError> {
        let mut tmc = self.tmc.lock().await;
        let mut last = None;
        for attempt in 1..=ATTEMPTS {
            match tmc.query(command, Instant::now() + timeout).await {
                Ok(v) => return Ok(v),
                Err(e @ UsbtmcError::Usb(UsbError::NoDevice | UsbError::Access(_))) => {
                    return Err(self.map(command, e, timeout));
                }
                Err(e) => {
                    tracing::warn!(meter = %self.name, command, attempt, error = %e, "query failed; clearing the I/O");
                    if let Err(ce) = tmc.clear().await {
                        tracing::warn!(meter = %self.name, error = %ce, "INITIATE_CLEAR failed");
                    }
                    last = Some(e);
                }
            }
        }
        Err(self.map(command, last.unwrap_or(UsbtmcError::Timeout), timeout))
    }

    /// One SCPI command (no reply).
    pub async fn write(&self, command: &str) -> Result<(), DriverError> {
        let mut tmc = self.tmc.lock().await;
        tmc.write(command.as_bytes(), Instant::now() + QUERY_TIMEOUT)
            .await
            .map_err(|e| self.map(command, e, QUERY_TIMEOUT))
    }

    /// Drain the SCPI error queue (bounded); returns the errors found.
    pub async fn errors(&self) -> Result<Vec<(i32, String)>, DriverError> {
        let mut found = Vec::new();
        for _ in 0..16 {
            let a = self.query("SYST:ERR?", QUERY_TIMEOUT).await?;
            let (code, text) = parse_scpi_error(&a).ok_or_else(|| DriverError::Protocol {
                device: self.name.clone(),
                request: "SYST:ERR?".into(),
                detail: format!("{a:?}"),
            })?;
            if code == 0 {
                return Ok(found);
            }
            found.push((code, text));
        }
        Ok(found)
    }

    async fn number(&self, command: &str, timeout: Duration) -> Result<f64, DriverError> {
        let a = self.query(command, timeout).await?;
        parse_scpi_number(&a).ok_or_else(|| DriverError::Protocol {
            device: self.name.clone(),
            request: command.into(),
            detail: format!("not a number: {a:?}"),
        })
    }

    pub async fn do_configure(&self, config: DetectorConfig) -> Result<(), DriverError> {
        if !(config.wavelength_nm.is_finite() && config.wavelength_nm > 0.0) {
            return Err(DriverError::OutOfRange {
                device: self.name.clone(),
                what: "wavelength (nm)".into(),
                value: config.wavelength_nm,
                min: 0.0,
                max: f64::INFINITY,
            });
        }
        if config.averaging == 0 {
            return Err(DriverError::OutOfRange {
                device: self.name.clone(),
                what: "averaging".into(),
                value: 0.0,
                min: 1.0,
                max: f64::INFINITY,
            });
        }
        // Start from an empty error queue so that what we read afterwards is ours.
        let stale = self.errors().await?;
        if !stale.is_empty() {
            tracing::warn!(meter = %self.name, ?stale, "errors queued before configuration");
        }
        // The sensor head's wavelength limits: a wavelength outside them is refused before anything is set.
        let min_nm = self.number("SENS:CORR:WAV? MIN", QUERY_TIMEOUT).await?;
        let max_nm = self.number("SENS:CORR:WAV? MAX", QUERY_TIMEOUT).await?;
        if !(min_nm..=max_nm).contains(&config.wavelength_nm) {
            return Err(DriverError::OutOfRange {
                device: self.name.clone(),
                what: "wavelength (nm) for the sensor".into(),
                value: config.wavelength_nm,
                min: min_nm,
                max: max_nm,
            });
        }
        let mut commands = vec![
            "SENS:POW:UNIT W".to_string(),
            format!("SENS:CORR:WAV {}", config.wavelength_nm),
            format!("SENS:AVER:COUN {}", config.averaging),
        ];
        match config.range {
            // Through the largest range first: a meter under auto-range may answer SENS:POW:RANG? with the range
            // last set by hand (the simulated PM100 does), and a reading is held against that for overload.
            PowerRange::Auto => {
                commands.push("SENS:POW:RANG MAX".into());
                commands.push("SENS:POW:RANG:AUTO ON".into());
            }
            PowerRange::Fixed { full_scale_w } => {
                commands.push("SENS:POW:RANG:AUTO OFF".into());
                commands.push(format!("SENS:POW:RANG {full_scale_w:E}"));
            }
        }
        commands.push("CONF:POW".into());
        for c in &commands {
            self.write(c).await?;
        }
        // -420 (Query UNTERMINATED) is a read requested with no query pending: what a lost reply leaves behind
        // once this driver has asked again. None of the commands above is a query, so it refuses none of them.
        let (unterminated, errors): (Vec<_>, Vec<_>) = self
            .errors()
            .await?
            .into_iter()
            .partition(|(code, _)| *code == -420);
        if !unterminated.is_empty() {
            tracing::warn!(meter = %self.name, ?unterminated, "ignored: left by a lost reply, not by the configuration");
        }
        if !errors.is_empty() {
            let reason = errors
                .iter()
                .map(|(c, t)| format!("{c},\"{t}\""))
                .collect::<Vec<_>>()
                .join("; ");
            return Err(DriverError::Rejected {
                device: self.name.clone(),
                request: commands.join("; "),
                reason,
            });
        }
        let wav = self.number("SENS:CORR:WAV?", QUERY_TIMEOUT).await?;
        if (wav - config.wavelength_nm).abs() > 0.5 {
            return Err(DriverError::Rejected {
                device: self.name.clone(),
                request: format!("SENS:CORR:WAV {}", config.wavelength_nm),
                reason: format!("the meter reports {wav} nm"),
            });
        }
        if let Ok(mut g) = self.averaging.lock() {
            *g = config.averaging;
        }
        if let Ok(mut g) = self.config.lock() {
            *g = Some(config);
        }
        self.needs_restore
            .store(false, std::sync::atomic::Ordering::SeqCst);
        tracing::info!(meter = %self.name, wavelength_nm = config.wavelength_nm, averaging = config.averaging, range = ?config.range, "configured");
        Ok(())
    }

    /// Apply the last configuration again if the device came back from a disconnect since it was applied.
    async fn restore_config(&self) -> Result<(), DriverError> {
        if !self.needs_restore.load(std::sync::atomic::Ordering::SeqCst) {
            return Ok(());
        }
        let config = self.config.lock().ok().and_then(|g| *g);
        match config {
            Some(config) => {
                self.do_configure(config).await?;
                tracing::info!(meter = %self.name, "configuration restored after reconnect");
            }
            None => self
                .needs_restore
                .store(false, std::sync::atomic::Ordering::SeqCst),
        }
        Ok(())
    }

    pub async fn do_read_power(&self) -> Result<PowerReading, DriverError> {
        // Never read with power-up settings after a reconnect whose restore did not complete.
        self.restore_config().await?;
        let n = self.averaging.lock().map(|g| *g).unwrap_or(1);
        let timeout = Duration::from_secs_f64(f64::from(n) * SAMPLE_S * 2.0) + QUERY_TIMEOUT;
        // The reading decides a point's value, yet it is not read twice as the serial drivers read positions: each
        // MEAS:POW? is a new measurement (two differ by the noise), and USB data packets carry a CRC16 that the
        // host controller checks, so bytes arrive as sent or not at all. What is checked here: the USBTMC framing
        // (bTag, transfer size, EOM), the number's syntax, and the range for overload.
        let a = self.query("MEAS:POW?", timeout).await?;
        let timestamp = SystemTime::now();
        let range_w = self.number("SENS:POW:RANG?", QUERY_TIMEOUT).await?;
        let t = a.trim();
        let (power_w, overload) = classify_reading(t, range_w).ok_or_else(|| DriverError::Protocol {
            device: self.name.clone(),
            request: "MEAS:POW?".into(),
            detail: format!("not a number: {a:?}"),
        })?;
        if overload {
            tracing::warn!(meter = %self.name, reply = %t, range_w, "reading at or beyond full scale (overload)");
        }
        Ok(PowerReading {
            power_w,
            range_w,
            overload,
            timestamp,
        })
    }

    pub async fn do_identify(&self) -> Result<String, DriverError> {
        self.query("*IDN?", QUERY_TIMEOUT).await
    }

    pub async fn do_reconnect(&self) -> Result<(), DriverError> {
        {
            let mut tmc = self.tmc.lock().await;
            match tmc.clear().await {
                Ok(()) => {}
                Err(UsbtmcError::Usb(UsbError::NoDevice)) | Err(UsbtmcError::Usb(UsbError::Access(_))) => {
                    let opener = self.opener.clone().ok_or_else(|| DriverError::Unavailable {
                        device: self.name.clone(),
                        detail: "the device is gone and cannot be reopened".into(),
                    })?;
                    let pipe = tokio::task::spawn_blocking(move || opener())
                        .await
                        .map_err(|e| DriverError::Unavailable {
                            device: self.name.clone(),
                            detail: e.to_string(),
                        })?
                        .map_err(|e| DriverError::Unavailable {
                            device: self.name.clone(),
                            detail: e.to_string(),
                        })?;
                    *tmc = Usbtmc::new(self.name.clone(), pipe);
                    self.needs_restore
                        .store(true, std::sync::atomic::Ordering::SeqCst);
                    tracing::info!(meter = %self.name, "USB device reopened");
                }
                Err(e) => {
                    tracing::warn!(meter = %self.name, error = %e, "INITIATE_CLEAR failed; trying to talk anyway")
                }
            }
        }
        let idn = self.do_identify().await?;
        tracing::info!(meter = %self.name, %idn, "re-verified after reconnect");
        self.restore_config().await
    }
}

impl Detector for Pm100 {
    fn name(&self) -> &str {
        &self.name
    }
    fn configure(&self, config: DetectorConfig) -> BoxFuture<'_, Result<(), DriverError>> {
        Box::pin(self.do_configure(config))
    }
    fn read_power(&self) -> BoxFuture<'_, Result<PowerReading, DriverError>> {
        Box::pin(self.do_read_power())
    }
    fn identify(&self) -> BoxFuture<'_, Result<String, DriverError>> {
        Box::pin(self.do_identify())
    }
    fn reconnect(&self) -> BoxFuture<'_, Result<(), DriverError>> {
        Box::pin(self.do_reconnect())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn scpi_numbers_and_errors() {
        assert_eq!(parse_scpi_number("+1.234000E-03\n"), Some(1.234e-3));
        assert_eq!(parse_scpi_number("9.9E37"), Some(9.9e37));
        assert_eq!(parse_scpi_number("1e999"), None);
        assert_eq!(parse_scpi_number("abc"), None);
        assert_eq!(parse_scpi_error("0,\"No error\""), Some((0, "No error".into())));
        assert_eq!(
            parse_scpi_error("-113,\"Undefined header\""),
            Some((-113, "Undefined header".into()))
        );
        assert_eq!(parse_scpi_error("No error"), None);
        // Real meters sign the code.
        assert_eq!(
            parse_scpi_error("+0,\"No error\"\n"),
            Some((0, "No error".into()))
        );
    }

    #[test]
    fn over_range_answers_of_every_model_are_overload() {
        for t in [
            "INFINITY",
            "-INFINITY",
            "+INF",
            "inf",
            "-inf",
            "infinity",
            "NAN",
            "9.9E37",
            "-9.9E37\n",
        ] {
            let (p, overload) = classify_reading(t, 5e-3).unwrap_or_else(|| panic!("{t:?} refused"));
            assert!(overload && p.is_nan(), "{t:?}");
        }
        assert_eq!(classify_reading("+1.000000E-03", 5e-3), Some((1e-3, false)));
        assert_eq!(classify_reading("5.000000E-03", 5e-3), Some((5e-3, true)));
        assert_eq!(classify_reading("INFINITE", 5e-3), None);
        assert_eq!(classify_reading("", 5e-3), None);
        assert_eq!(classify_reading("-", 5e-3), None);
    }

    #[test]
    fn every_product_id_of_the_family_is_known() {
        for pid in [
            0x8070u16, 0x8071, 0x8072, 0x8075, 0x8076, 0x8077, 0x8078, 0x8079, 0x807A, 0x807B, 0x807D,
            0x8099, 0x80B0, 0x80BB,
        ] {
            assert!(PRODUCTS.iter().any(|(p, _)| *p == pid), "{pid:#06x}");
        }
    }
}
