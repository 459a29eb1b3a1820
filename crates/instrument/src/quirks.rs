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

/// The variants; see the module documentation.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields, default)]
pub struct Quirks {
    pub pm100_overrange: Pm100Overrange,
}

impl Default for Quirks {
    fn default() -> Quirks {
        Quirks {
            pm100_overrange: Pm100Overrange::Infinity,
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
        let q: Quirks = toml::from_str("pm100_overrange = \"scpi-overflow\"").expect("variants");
        assert_eq!(q.pm100_overrange, Pm100Overrange::ScpiOverflow);
        assert!(toml::from_str::<Quirks>("pm100_overrange = \"nan\"").is_err());
    }
}
