//! `[simulator.quirks]`: where the vendors' documents, the recorded behaviour of real devices and firmware
//! versions disagree, which variant the simulated devices show. Every default is the manuals' behaviour, so the
//! ideal instrument (config/instruments/simulated.toml, or a file without the table) is the instrument its
//! manuals describe and a host written against them gets every reply. The recorded variants that demand more of
//! a host are set explicitly where they are wanted: config/instruments/realistic.toml takes them all, each with
//! the report that justifies it, and the drivers and soaks are tested under them.

use serde::{Deserialize, Serialize};

/// What the simulated PM100 answers for a reading beyond the range's full scale.
#[derive(Debug, Clone, Copy, Default, Serialize, Deserialize, PartialEq, Eq)]
#[serde(rename_all = "kebab-case")]
pub enum Pm100Overrange {
    /// `INFINITY` (`-INFINITY` below the negative full scale, which the simulated photodiode never reaches):
    /// what Thorlabs' SCPI command references for the PM100D2, PM101, PM103 and PM400 document, so the default.
    #[default]
    Infinity,
    /// `9.9E37`, SCPI 1999's overflow value, which older Thorlabs material gives: a number a plain float parser
    /// takes, so a host that does not check it reads an over-range as a huge power.
    ScpiOverflow,
}

/// What the simulated Zaber devices do with a message whose checksum is wrong: the firmware-6 ASCII manual
/// says both. The default is the rejection, because the vendor's own host library expects it: Zaber Motion
/// Library maps `RJ ... BADDATA` to its `BadDataException` (simulator/src/zaber/mod.rs), so the rejection is
/// the behaviour Zaber builds its hosts against, and it is the one a host can observe and act on (an ignored
/// message shows only as a timeout). `ignore` remains for hosts that must survive the other reading.
#[derive(Debug, Clone, Copy, Default, Serialize, Deserialize, PartialEq, Eq)]
#[serde(rename_all = "kebab-case")]
pub enum ZaberBadChecksum {
    /// Every device on the chain answers `RJ ... BADDATA` (several replies to one message, none addressed to
    /// the host's request in the usual way): the default (see the type's documentation).
    #[default]
    RejectAll,
    /// The message is ignored: no reply at all.
    Ignore,
}

/// The variants; see the module documentation.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields, default)]
pub struct Quirks {
    pub pm100_overrange: Pm100Overrange,
    /// SMC100: how long (ms) a set command keeps the controller busy; a command line arriving while it is busy
    /// (within this after a set command, or before a query's reply has crossed the line) is lost, with no
    /// reply and no error. Host drivers written against real controllers pace their commands by 60 ms to
    /// 0.5 s. 0 (the default) takes every line, as the manual describes.
    pub smc100_min_command_gap_ms: f64,
    /// SMC100: the first `TS` after power-up or reset, and the first right after a homing completes, get no
    /// reply (reported by a real-hardware driver as undocumented). Off by default: the manual answers every `TS`.
    pub smc100_drop_first_ts: bool,
    /// FW102C: right after the port opens, NUL bytes and a `Command error CMD_NOT_DEFINED` (with its prompt)
    /// arrive before any reply (reported by users of real wheels). Off by default: the manual describes none.
    pub fw102c_noise_at_open: bool,
    pub zaber_bad_checksum: ZaberBadChecksum,
}

impl Default for Quirks {
    fn default() -> Quirks {
        Quirks {
            pm100_overrange: Pm100Overrange::Infinity,
            smc100_min_command_gap_ms: 0.0,
            smc100_drop_first_ts: false,
            fw102c_noise_at_open: false,
            zaber_bad_checksum: ZaberBadChecksum::RejectAll,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn defaults_are_the_manuals_behaviour_and_each_variant_parses() {
        let q: Quirks = toml::from_str("").expect("empty");
        assert_eq!(q, Quirks::default());
        assert_eq!(q.pm100_overrange, Pm100Overrange::Infinity);
        assert_eq!(q.smc100_min_command_gap_ms, 0.0);
        assert!(!q.smc100_drop_first_ts);
        assert!(!q.fw102c_noise_at_open);
        assert_eq!(q.zaber_bad_checksum, ZaberBadChecksum::RejectAll);
        let q: Quirks = toml::from_str(
            "pm100_overrange = \"scpi-overflow\"\nsmc100_min_command_gap_ms = 60.0\nsmc100_drop_first_ts = true\n\
             fw102c_noise_at_open = true",
        )
        .expect("variants");
        assert_eq!(q.pm100_overrange, Pm100Overrange::ScpiOverflow);
        assert_eq!(q.smc100_min_command_gap_ms, 60.0);
        assert!(q.smc100_drop_first_ts && q.fw102c_noise_at_open);
        assert_eq!(q.zaber_bad_checksum, ZaberBadChecksum::RejectAll);
        let q: Quirks = toml::from_str("zaber_bad_checksum = \"ignore\"").expect("ignore");
        assert_eq!(q.zaber_bad_checksum, ZaberBadChecksum::Ignore);
        assert!(toml::from_str::<Quirks>("pm100_overrange = \"nan\"").is_err());
        assert!(toml::from_str::<Quirks>("smc100_gap = 1.0").is_err());
    }

    /// The two instrument files the project ships: the ideal one takes the manuals' behaviour (the defaults),
    /// the realistic one every recorded variant that demands more of a host.
    #[test]
    fn the_shipped_instruments_take_the_manuals_and_the_recorded_variants() {
        let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../config/instruments");
        let ideal = crate::InstrumentFile::load(&dir.join("simulated.toml")).expect("simulated.toml");
        assert_eq!(ideal.simulator.quirks, Quirks::default());
        let real = crate::InstrumentFile::load(&dir.join("realistic.toml")).expect("realistic.toml");
        let q = &real.simulator.quirks;
        assert_eq!(q.smc100_min_command_gap_ms, 60.0);
        assert!(q.smc100_drop_first_ts && q.fw102c_noise_at_open);
    }
}
