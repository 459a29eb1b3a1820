//! The meter's command set: the IEEE 488.2 common commands with the status byte and the standard event
//! status register, the SCPI status registers, the sense settings (with their `MIN`/`MAX` limits) and the
//! measurement functions.

use gonio_instrument::Pm100Overrange;

use super::function::Function;
use super::scpi::{Cmd, Num, match_header, parse_num, query_limit, sci};
use super::{MeterState, OVERLOAD_W, Pm100, QUES_POWER_OVERRANGE, SAMPLE_S};

/// Beam diameter at power-up for power density (mm). Unconfirmed: no record of the real default.
pub(super) const DEFAULT_BEAM_MM: f64 = 1.0;
/// Limits of the beam diameter (mm). Unconfirmed.
const BEAM_MM: (f64, f64) = (0.01, 100.0);
/// Largest `SENS:AVER:COUN`. Unconfirmed.
const MAX_AVERAGING: f64 = 1_000_000.0;
/// Wavelength at power-up and for `DEF` (nm).
const DEFAULT_WAVELENGTH_NM: f64 = 633.0;

/// A query's response and when it is ready (simulated seconds), or nothing; or an SCPI error.
type Reply = Result<Option<(String, f64)>, (i32, &'static str)>;

/// A status register value 0..=max from a numeric parameter.
fn register(arg: &str, max: u16) -> Result<u16, (i32, &'static str)> {
    match parse_num(arg)? {
        Num::Value(x) if (0.0..=f64::from(max)).contains(&x) => Ok(x.round() as u16),
        Num::Value(_) => Err((-222, "Data out of range")),
        Num::Min | Num::Default => Ok(0),
        Num::Max => Ok(max),
    }
}

/// A numeric setting within [lo, hi]: the value, or the limit named.
fn setting(arg: &str, lo: f64, hi: f64, default: f64) -> Result<f64, (i32, &'static str)> {
    let x = match parse_num(arg)? {
        Num::Value(x) => x,
        Num::Min => lo,
        Num::Max => hi,
        Num::Default => default,
    };
    if (lo..=hi).contains(&x) {
        Ok(x)
    } else {
        Err((-222, "Data out of range"))
    }
}

/// A query that may name a limit: the current value, or the limit.
fn limit_query(arg: &str, current: f64, lo: f64, hi: f64, default: f64) -> Result<f64, (i32, &'static str)> {
    Ok(match query_limit(arg)? {
        None => current,
        Some(Num::Min) => lo,
        Some(Num::Max) => hi,
        Some(_) => default,
    })
}

impl Pm100 {
    /// One command or query.
    pub(super) fn execute_unit(&self, st: &mut MeterState, unit: &str, now: f64) -> Reply {
        let (header, arg) = match unit.split_once(|c: char| c.is_ascii_whitespace()) {
            Some((h, a)) => (h, a.trim()),
            None => (unit, ""),
        };
        let query = header.ends_with('?');
        let header = header.trim_end_matches('?');
        if header.starts_with('*') {
            return self.common(st, &header.to_ascii_uppercase(), query, arg, now);
        }
        let at_now = |s: String| Ok(Some((s, now)));
        let ranges = &self.detector.ranges_w;
        let (r_lo, r_hi) = (
            ranges.first().copied().unwrap_or(0.0),
            ranges.last().copied().unwrap_or(0.0),
        );
        let r_set = self.responsivity.at(st.settings.wavelength_nm);
        let [wl_lo, wl_hi] = self.detector.sensor_wavelength_nm;
        let cmd = match_header(header).ok_or((-113, "Undefined header"))?;
        match (cmd, query) {
            (Cmd::SystSensIdn, true) => at_now("S120C,12345678,01-Jan-2024,1,18,289".into()),
            (Cmd::SystErr, true) => {
                let (code, text) = st.errors.pop_front().unwrap_or((0, "No error"));
                at_now(format!("{code:+},\"{text}\""))
            }
            (Cmd::SystVers, true) => at_now("1999.0".into()),
            (Cmd::Wavelength, true) => {
                let nm = limit_query(
                    arg,
                    st.settings.wavelength_nm,
                    wl_lo,
                    wl_hi,
                    DEFAULT_WAVELENGTH_NM,
                )?;
                at_now(sci(nm))
            }
            (Cmd::Wavelength, false) => {
                st.settings.wavelength_nm = setting(arg, wl_lo, wl_hi, DEFAULT_WAVELENGTH_NM)?;
                Ok(None)
            }
            (Cmd::RangeAuto | Cmd::CurrentRangeAuto, true) => {
                at_now(if st.settings.auto_range { "1" } else { "0" }.into())
            }
            (Cmd::RangeAuto | Cmd::CurrentRangeAuto, false) => {
                st.settings.auto_range = match arg.to_ascii_uppercase().as_str() {
                    "ON" | "1" => true,
                    "OFF" | "0" => false,
                    "" => return Err((-109, "Missing parameter")),
                    _ => return Err((-224, "Illegal parameter value")),
                };
                Ok(None)
            }
            (Cmd::Range, true) => {
                let current = ranges.get(st.settings.range).copied().unwrap_or(0.0);
                at_now(sci(limit_query(arg, current, r_lo, r_hi, r_hi)?))
            }
            (Cmd::CurrentRange, true) => {
                let current = ranges.get(st.settings.range).copied().unwrap_or(0.0);
                at_now(sci(limit_query(arg, current, r_lo, r_hi, r_hi)? * r_set))
            }
            (Cmd::Range | Cmd::CurrentRange, false) => {
                let per_w = if cmd == Cmd::CurrentRange { r_set } else { 1.0 };
                let w = match parse_num(arg)? {
                    Num::Min => r_lo,
                    Num::Max | Num::Default => r_hi,
                    Num::Value(x) if per_w > 0.0 => x / per_w,
                    Num::Value(_) => return Err((-221, "Settings conflict")),
                };
                if w <= 0.0 {
                    return Err((-222, "Data out of range"));
                }
                // The smallest range that holds the requested value; the largest when none does.
                st.settings.range = ranges
                    .iter()
                    .position(|r| *r >= w * (1.0 - 1e-9))
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
            (Cmd::Average, true) => {
                let current = f64::from(st.settings.averaging);
                let n = limit_query(arg, current, 1.0, MAX_AVERAGING, 1.0)?;
                at_now(format!("{}", n.round() as u64))
            }
            (Cmd::Average, false) => {
                st.settings.averaging = setting(arg, 1.0, MAX_AVERAGING, 1.0)?.round() as u32;
                Ok(None)
            }
            (Cmd::BeamDiameter, true) => {
                let mm = limit_query(arg, st.settings.beam_mm, BEAM_MM.0, BEAM_MM.1, DEFAULT_BEAM_MM)?;
                at_now(sci(mm))
            }
            (Cmd::BeamDiameter, false) => {
                st.settings.beam_mm = setting(arg, BEAM_MM.0, BEAM_MM.1, DEFAULT_BEAM_MM)?;
                Ok(None)
            }
            (Cmd::Responsivity, true) => at_now(sci(r_set)),
            (Cmd::Conf(f), false) => {
                if !f.photodiode() {
                    return Err((-241, "Hardware missing"));
                }
                st.settings.function = f;
                Ok(None)
            }
            (Cmd::ConfQuery, true) => at_now(st.settings.function.name().into()),
            (Cmd::ConfQuery, false) => {
                st.settings.function = Function::Power;
                Ok(None)
            }
            (Cmd::Meas(f), true) => {
                if !f.photodiode() {
                    return Err((-241, "Hardware missing"));
                }
                st.settings.function = f;
                self.measure(st, now)
            }
            (Cmd::Read | Cmd::Fetch, true) => self.measure(st, now),
            (Cmd::Init | Cmd::Abort, false) => Ok(None),
            (Cmd::QuesCond, true) => at_now(st.ques_cond.to_string()),
            (Cmd::QuesEvent, true) => at_now(std::mem::take(&mut st.ques_event).to_string()),
            (Cmd::QuesEnable, true) => at_now(st.ques_enable.to_string()),
            (Cmd::QuesEnable, false) => {
                st.ques_enable = register(arg, 0x7FFF)?;
                Ok(None)
            }
            (Cmd::OperCond, true) => at_now("0".into()),
            (Cmd::OperEvent, true) => at_now(std::mem::take(&mut st.oper_event).to_string()),
            (Cmd::OperEnable, true) => at_now(st.oper_enable.to_string()),
            (Cmd::OperEnable, false) => {
                st.oper_enable = register(arg, 0x7FFF)?;
                Ok(None)
            }
            (Cmd::StatPreset, false) => {
                st.ques_enable = 0;
                st.oper_enable = 0;
                Ok(None)
            }
            _ => Err((-113, "Undefined header")),
        }
    }

    /// IEEE 488.2 common commands (`header` upper-case, without the `?`).
    fn common(&self, st: &mut MeterState, header: &str, query: bool, arg: &str, now: f64) -> Reply {
        let at_now = |s: String| Ok(Some((s, now)));
        match (header, query) {
            ("*IDN", true) => at_now(format!("Thorlabs,PM100USB,{},1.7.0", self.serial)),
            ("*RST", false) => {
                st.settings = Self::power_up_settings(&self.detector);
                Ok(None)
            }
            ("*CLS", false) => {
                st.errors.clear();
                st.esr = 0;
                st.ques_event = 0;
                st.oper_event = 0;
                Ok(None)
            }
            // Every operation completes before the next command is taken: OPC at once.
            ("*OPC", false) => {
                st.esr |= 0x01;
                Ok(None)
            }
            ("*OPC", true) => at_now("1".into()),
            ("*WAI", false) => Ok(None),
            ("*TST", true) => at_now("0".into()),
            ("*ESR", true) => at_now(std::mem::take(&mut st.esr).to_string()),
            ("*ESE", true) => at_now(st.ese.to_string()),
            ("*ESE", false) => {
                st.ese = register(arg, 255)? as u8;
                Ok(None)
            }
            ("*SRE", true) => at_now(st.sre.to_string()),
            ("*SRE", false) => {
                // Bit 6 (RQS/MSS) cannot be enabled (IEEE 488.2 11.3.2.3).
                st.sre = (register(arg, 255)? as u8) & !0x40;
                Ok(None)
            }
            ("*STB", true) => at_now(Self::status_byte(st).to_string()),
            _ => Err((-113, "Undefined header")),
        }
    }

    /// The IEEE 488.2 status byte: error queue not empty (bit 2), questionable summary (3), message available
    /// (4), standard event summary (5), master summary (6), operation summary (7).
    fn status_byte(st: &MeterState) -> u8 {
        let mut stb = 0u8;
        if !st.errors.is_empty() {
            stb |= 0x04;
        }
        if st.ques_event & st.ques_enable != 0 {
            stb |= 0x08;
        }
        if !st.responses.is_empty() || !st.in_fifo.is_empty() {
            stb |= 0x10;
        }
        if st.esr & st.ese != 0 {
            stb |= 0x20;
        }
        if st.oper_event & st.oper_enable != 0 {
            stb |= 0x80;
        }
        if stb & st.sre != 0 {
            stb |= 0x40;
        }
        stb
    }

    /// Take one reading of the configured function; the reply is ready after the averaging time (which starts
    /// the imperfect meter's reading delay after the request).
    fn measure(&self, st: &mut MeterState, now: f64) -> Reply {
        let n = st.settings.averaging.max(1);
        let start = now
            + self
                .imperfections
                .as_ref()
                .map_or(0.0, |t| t.reading_delay_s.max(0.0));
        let done = start + f64::from(n) * SAMPLE_S;
        let r_set = self.responsivity.at(st.settings.wavelength_nm);
        let Some(current_a) = self.reading_a(st, start, n, r_set) else {
            // Questionable condition bit 3 (POWer over range); its positive transition latches the event.
            if st.ques_cond & QUES_POWER_OVERRANGE == 0 {
                st.ques_event |= QUES_POWER_OVERRANGE;
            }
            st.ques_cond |= QUES_POWER_OVERRANGE;
            let text = match self.overrange {
                Pm100Overrange::Infinity => "INFINITY".to_string(),
                Pm100Overrange::ScpiOverflow => sci(OVERLOAD_W),
            };
            return Ok(Some((text, done)));
        };
        st.ques_cond &= !QUES_POWER_OVERRANGE;
        let power_w = if r_set > 0.0 { current_a / r_set } else { 0.0 };
        let value = match st.settings.function {
            Function::Current => current_a,
            Function::PowerDensity => {
                // W/cm² over the beam's cross-section.
                let radius_cm = st.settings.beam_mm / 20.0;
                power_w / (std::f64::consts::PI * radius_cm * radius_cm)
            }
            // A CW source has no pulse frequency to count.
            Function::Frequency => 0.0,
            _ if st.settings.unit_dbm => 10.0 * (power_w.max(1e-30) / 1e-3).log10(),
            _ => power_w,
        };
        Ok(Some((sci(value), done)))
    }
}
