//! `[simulator.actual]`: the hardware as it really is where it differs from what the instrument file claims.
//!
//! A lab's instrument file says what the devices should do; the devices on the bench may do otherwise (a
//! wheel slower than its data sheet, an arm that cannot reach its configured speed, a settle time longer than
//! written). `gonio selftest` finds such differences; to test it, a simulated instrument can be given them here,
//! by the same keys as the tables they correct:
//!
//! ```toml
//! [simulator.actual.filter_wheel]
//! seconds_per_position = 0.8
//! [simulator.actual.axes.detector]     # the axis's name
//! max_speed_deg_s = 10.0
//! [simulator.actual.axes.light]
//! settle_s = 0.2
//! [simulator.actual.detector]
//! dark_current_a = 1.0e-10
//! [simulator.actual.source]
//! relative_noise = 3.0e-4
//! [simulator.actual.devices.arms]       # the device's name
//! reply_latency_ms = 10.0
//! position_sampled_ms = 6.0              # when it takes what it reports, after the query was sent
//! ```
//!
//! The simulated devices run the actual values ([`InstrumentFile::actual_instrument`]); the engine plans with
//! the file's. Like the imperfections, the actual values are the simulator's hidden truth: they reach a
//! dry-run's run.json, never the engine, the drivers or the self-test.

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};

use crate::{Instrument, InstrumentFile};

/// `[simulator.actual]` (module doc). Every field absent: the hardware is as the file says.
#[derive(Debug, Clone, Default, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Actual {
    #[serde(default)]
    pub filter_wheel: Option<ActualWheel>,
    /// By axis name.
    #[serde(default)]
    pub axes: BTreeMap<String, ActualAxis>,
    #[serde(default)]
    pub detector: Option<ActualDetector>,
    #[serde(default)]
    pub source: Option<ActualSource>,
    /// By device name.
    #[serde(default)]
    pub devices: BTreeMap<String, ActualDevice>,
}

/// `[simulator.actual.devices.<name>]`.
#[derive(Debug, Clone, Default, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct ActualDevice {
    /// What the device really takes to answer a query beyond its reply's time on the line (ms).
    pub reply_latency_ms: Option<f64>,
    /// When the device really takes the position it reports (and acts on any command), after the host sent it
    /// (ms): at most its reply latency.
    pub position_sampled_ms: Option<f64>,
}

/// `[simulator.actual.detector]`.
#[derive(Debug, Clone, Default, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct ActualDetector {
    /// The head's real dark current (A).
    pub dark_current_a: Option<f64>,
}

/// `[simulator.actual.source]`.
#[derive(Debug, Clone, Default, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct ActualSource {
    /// The source's real white relative noise (1 sigma, a fraction).
    pub relative_noise: Option<f64>,
}

/// `[simulator.actual.filter_wheel]`.
#[derive(Debug, Clone, Default, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct ActualWheel {
    /// Time to turn by one position (s) at the configured speed.
    pub seconds_per_position: Option<f64>,
}

/// `[simulator.actual.axes.<name>]`.
#[derive(Debug, Clone, Default, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct ActualAxis {
    /// The fastest the axis really moves (deg/s), whatever speed it is commanded.
    pub max_speed_deg_s: Option<f64>,
    /// The largest acceleration it really reaches (deg/s^2).
    pub accel_deg_s2: Option<f64>,
    /// How long its vibrations really take to die down after an arrival (s).
    pub settle_s: Option<f64>,
    /// Its real mechanical backlash (deg).
    pub backlash_deg: Option<f64>,
}

impl Actual {
    /// True when nothing differs from the file.
    pub fn is_empty(&self) -> bool {
        self.filter_wheel
            .as_ref()
            .is_none_or(|w| w.seconds_per_position.is_none())
            && self.axes.values().all(|a| a == &ActualAxis::default())
            && self.detector.as_ref().is_none_or(|d| d.dark_current_a.is_none())
            && self.source.as_ref().is_none_or(|s| s.relative_noise.is_none())
            && self.devices.values().all(|d| d == &ActualDevice::default())
    }

    /// Every value names an axis the file has and is a positive (zero for settle and backlash), finite
    /// number; the message names the key as the file spells it.
    pub fn validate(&self, instrument: &Instrument) -> Result<(), crate::InvalidInstrument> {
        self.check(instrument).map_err(crate::InvalidInstrument)
    }

    fn check(&self, instrument: &Instrument) -> Result<(), String> {
        let positive = |key: String, v: Option<f64>, zero_ok: bool| -> Result<(), String> {
            match v {
                Some(x) if !x.is_finite() || x < 0.0 || (x == 0.0 && !zero_ok) => Err(format!(
                    "{key} = {x}: must be a finite number {}",
                    if zero_ok { ">= 0" } else { "> 0" }
                )),
                _ => Ok(()),
            }
        };
        if let Some(w) = &self.filter_wheel {
            if instrument.filter_wheel.is_none() {
                return Err("[simulator.actual.filter_wheel]: the instrument has no filter wheel".into());
            }
            positive(
                "simulator.actual.filter_wheel.seconds_per_position".into(),
                w.seconds_per_position,
                false,
            )?;
        }
        for (name, a) in &self.axes {
            if !instrument.axes.iter().any(|x| &x.name == name) {
                let names: Vec<&str> = instrument.axes.iter().map(|x| x.name.as_str()).collect();
                return Err(format!(
                    "[simulator.actual.axes.{name}]: no axis named {name:?}; the axes are {}",
                    names.join(", ")
                ));
            }
            let key = |k: &str| format!("simulator.actual.axes.{name}.{k}");
            positive(key("max_speed_deg_s"), a.max_speed_deg_s, false)?;
            positive(key("accel_deg_s2"), a.accel_deg_s2, false)?;
            positive(key("settle_s"), a.settle_s, true)?;
            positive(key("backlash_deg"), a.backlash_deg, true)?;
        }
        for (name, d) in &self.devices {
            if instrument.device(name).is_none() {
                let names: Vec<&str> = instrument.devices.iter().map(|x| x.name.as_str()).collect();
                return Err(format!(
                    "[simulator.actual.devices.{name}]: no device named {name:?}; the devices are {}",
                    names.join(", ")
                ));
            }
            positive(
                format!("simulator.actual.devices.{name}.reply_latency_ms"),
                d.reply_latency_ms,
                true,
            )?;
            let key = format!("simulator.actual.devices.{name}.position_sampled_ms");
            positive(key.clone(), d.position_sampled_ms, true)?;
            let latency_ms = d
                .reply_latency_ms
                .or(instrument.device(name).and_then(|x| x.reply_latency_ms))
                .unwrap_or(0.0);
            if let Some(ms) = d.position_sampled_ms
                && ms > latency_ms
            {
                return Err(format!(
                    "{key} = {ms}: a device cannot take what it reports after it answers (its reply latency is \
                     {latency_ms} ms)"
                ));
            }
        }
        if let Some(d) = &self.detector {
            positive(
                "simulator.actual.detector.dark_current_a".into(),
                d.dark_current_a,
                true,
            )?;
        }
        if let Some(s) = &self.source {
            positive(
                "simulator.actual.source.relative_noise".into(),
                s.relative_noise,
                true,
            )?;
        }
        Ok(())
    }
}

impl InstrumentFile {
    /// The instrument as the simulated hardware really is: the file's `[instrument]` with `[simulator.actual]`
    /// applied (module doc). Equal to `self.instrument` when nothing differs.
    pub fn actual_instrument(&self) -> Instrument {
        let mut inst = self.instrument.clone();
        self.simulator.actual.apply_to(&mut inst);
        inst
    }
}

impl Actual {
    /// Set every value this table states on `inst` (the simulator applies it after the hidden timing draws:
    /// a stated value is the hardware's, whatever was drawn).
    pub fn apply_to(&self, inst: &mut Instrument) {
        let actual = self;
        if let (Some(w), Some(a)) = (inst.filter_wheel.as_mut(), actual.filter_wheel.as_ref())
            && let Some(s) = a.seconds_per_position
        {
            w.seconds_per_position = s;
        }
        for axis in &mut inst.axes {
            let Some(a) = actual.axes.get(&axis.name) else {
                continue;
            };
            if let Some(v) = a.max_speed_deg_s {
                axis.max_speed_deg_s = v;
            }
            if let Some(v) = a.accel_deg_s2 {
                axis.accel_deg_s2 = v;
            }
            if let Some(v) = a.settle_s {
                axis.settle_s = v;
            }
            if let Some(v) = a.backlash_deg {
                axis.backlash_deg = v;
            }
        }
        if let Some(v) = actual.detector.as_ref().and_then(|d| d.dark_current_a) {
            inst.detector.dark_current_a = v;
        }
        if let Some(v) = actual.source.as_ref().and_then(|s| s.relative_noise) {
            inst.source.relative_noise = v;
        }
        for device in &mut inst.devices {
            if let Some(v) = actual.devices.get(&device.name).and_then(|d| d.reply_latency_ms) {
                device.reply_latency_ms = Some(v);
            }
            if let Some(v) = actual
                .devices
                .get(&device.name)
                .and_then(|d| d.position_sampled_ms)
            {
                device.position_sampled_ms = Some(v);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn simulated_with(extra: &str) -> Result<InstrumentFile, crate::InstrumentError> {
        let text = format!("{}\n{extra}", crate::SIMULATED_INSTRUMENT_TOML);
        InstrumentFile::parse(&text, "test.toml")
    }

    #[test]
    fn the_actual_hardware_overrides_the_files_claims_by_the_same_keys() {
        let file = simulated_with(
            "[simulator.actual.filter_wheel]\nseconds_per_position = 2.0\n\
             [simulator.actual.axes.detector]\nmax_speed_deg_s = 10.0\nsettle_s = 0.4\n\
             [simulator.actual.detector]\ndark_current_a = 1.0e-10\n\
             [simulator.actual.source]\nrelative_noise = 3.0e-4\n\
             [simulator.actual.devices.arms]\nreply_latency_ms = 10.0\n",
        )
        .expect("valid");
        let actual = file.actual_instrument();
        assert_eq!(
            actual.filter_wheel.as_ref().map(|w| w.seconds_per_position),
            Some(2.0)
        );
        let det = actual
            .axes
            .iter()
            .find(|a| a.name == "detector")
            .expect("detector");
        assert_eq!((det.max_speed_deg_s, det.settle_s), (10.0, 0.4));
        assert_eq!(actual.detector.dark_current_a, 1.0e-10);
        assert_eq!(actual.source.relative_noise, 3.0e-4);
        assert_eq!(actual.device("arms").and_then(|d| d.reply_latency_ms), Some(10.0));
        assert_eq!(
            file.instrument.device("arms").and_then(|d| d.reply_latency_ms),
            None
        );
        let claimed = file
            .instrument
            .axes
            .iter()
            .find(|a| a.name == "detector")
            .expect("detector");
        assert_eq!(
            det.accel_deg_s2, claimed.accel_deg_s2,
            "what is not listed stays as claimed"
        );
        assert_ne!(file.instrument, actual, "the file itself keeps its claims");
        assert!(!file.simulator.actual.is_empty());
        let plain = InstrumentFile::simulated();
        assert!(plain.simulator.actual.is_empty());
        assert_eq!(plain.actual_instrument(), plain.instrument);
    }

    #[test]
    fn wrong_actual_tables_are_refused_naming_the_key() {
        for (extra, says) in [
            (
                "[simulator.actual.axes.elbow]\nsettle_s = 1.0\n",
                "no axis named \"elbow\"",
            ),
            (
                "[simulator.actual.axes.light]\nmax_speed_deg_s = 0.0\n",
                "simulator.actual.axes.light.max_speed_deg_s",
            ),
            (
                "[simulator.actual.axes.light]\nsettle_s = -1.0\n",
                "simulator.actual.axes.light.settle_s",
            ),
            (
                "[simulator.actual.filter_wheel]\nseconds_per_position = nan\n",
                "seconds_per_position",
            ),
            ("[simulator.actual.axes.light]\ntop_speed = 3.0\n", "top_speed"),
            (
                "[simulator.actual.detector]\ndark_current_a = -1e-9\n",
                "simulator.actual.detector.dark_current_a",
            ),
            (
                "[simulator.actual.source]\nrelative_noise = inf\n",
                "simulator.actual.source.relative_noise",
            ),
            (
                "[simulator.actual.devices.elbow]\nreply_latency_ms = 1.0\n",
                "no device named \"elbow\"",
            ),
            (
                "[simulator.actual.devices.arms]\nreply_latency_ms = -1.0\n",
                "simulator.actual.devices.arms.reply_latency_ms",
            ),
        ] {
            let e = simulated_with(extra).expect_err(extra).to_string();
            assert!(e.contains(says), "{extra}: {e}");
        }
        // The file's own claim is checked as the devices' other keys are.
        for (key, bads) in [
            ("reply_latency_ms", ["-1.0", "nan", "1000.0"]),
            ("position_sampled_ms", ["-1000.0", "nan", "1000.0"]),
        ] {
            for bad in bads {
                let text = crate::SIMULATED_INSTRUMENT_TOML
                    .replace("name = \"arms\"\n", &format!("name = \"arms\"\n{key} = {bad}\n"));
                let e = InstrumentFile::parse(&text, "test.toml")
                    .expect_err(bad)
                    .to_string();
                assert!(e.contains(key) && e.contains("\"arms\""), "{bad}: {e}");
            }
        }
    }
}
