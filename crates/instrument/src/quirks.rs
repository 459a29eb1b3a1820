//! `[simulator.quirks]`: where the vendors' documents, the recorded behaviour of real devices and firmware
//! versions disagree, which variant the simulated devices show. Every default is the variant that demands the
//! most of a host; the drivers are tested under every variant.

use serde::{Deserialize, Serialize};

/// What the simulated PM100 answers for a reading beyond the range's full scale.
#[derive(Debug, Clone, Copy, Default, Serialize, Deserialize, PartialEq, Eq)]
#[serde(rename_all = "kebab-case")]
pub enum Pm100Overrange {
    /// `INFINITY` (`-INFINITY` below the negative full scale, which the simulated photodiode never reaches):
    /// the PM100D2, PM101, PM103 and PM400 SCPI references. Not a number a plain float parser takes: the
    /// default.
    #[default]
    Infinity,
    /// `9.9E37`, SCPI 1999's overflow value.
    ScpiOverflow,
}

/// What the simulated Zaber devices do with a message whose checksum is wrong: the firmware-6 ASCII manual
/// says both.
#[derive(Debug, Clone, Copy, Default, Serialize, Deserialize, PartialEq, Eq)]
#[serde(rename_all = "kebab-case")]
pub enum ZaberBadChecksum {
    /// Every device on the chain answers `RJ ... BADDATA` (several replies to one message, none addressed to
    /// the host's request in the usual way): the default.
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
    /// 0.5 s. 0 takes every line as the manual describes.
    pub smc100_min_command_gap_ms: f64,
    /// SMC100: the first `TS` after power-up or reset, and the first right after a homing completes, get no
    /// reply (reported by a real-hardware driver as undocumented).
    pub smc100_drop_first_ts: bool,
    /// FW102C: right after the port opens, NUL bytes and a `Command error CMD_NOT_DEFINED` (with its prompt)
    /// arrive before any reply (reported by users of real wheels).
    pub fw102c_noise_at_open: bool,
    pub zaber_bad_checksum: ZaberBadChecksum,
}

impl Default for Quirks {
    fn default() -> Quirks {
        Quirks {
            pm100_overrange: Pm100Overrange::Infinity,
            smc100_min_command_gap_ms: 60.0,
            smc100_drop_first_ts: true,
            fw102c_noise_at_open: true,
            zaber_bad_checksum: ZaberBadChecksum::RejectAll,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn defaults_are_the_demanding_variants_and_each_parses() {
        let q: Quirks = toml::from_str("").expect("empty");
        assert_eq!(q, Quirks::default());
        assert_eq!(q.pm100_overrange, Pm100Overrange::Infinity);
        assert!(q.smc100_drop_first_ts && q.smc100_min_command_gap_ms >= 60.0 && q.fw102c_noise_at_open);
        let q: Quirks = toml::from_str(
            "pm100_overrange = \"scpi-overflow\"\nsmc100_min_command_gap_ms = 0.0\nsmc100_drop_first_ts = false",
        )
        .expect("variants");
        assert_eq!(q.pm100_overrange, Pm100Overrange::ScpiOverflow);
        assert_eq!(q.smc100_min_command_gap_ms, 0.0);
        assert!(!q.smc100_drop_first_ts);
        assert_eq!(q.zaber_bad_checksum, ZaberBadChecksum::RejectAll);
        let q: Quirks = toml::from_str("zaber_bad_checksum = \"ignore\"").expect("ignore");
        assert_eq!(q.zaber_bad_checksum, ZaberBadChecksum::Ignore);
        assert!(toml::from_str::<Quirks>("pm100_overrange = \"nan\"").is_err());
    }
}
