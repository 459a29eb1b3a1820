//! `[simulator.imperfections.source]`: magnitudes of how the source's power really varies. The models are
//! documented in simulator/src/imperfections/source.rs; they multiply the instrument file's own smooth
//! drift and white noise (`[instrument.source] drift_per_hour`, `relative_noise`).

use serde::{Deserialize, Serialize};

use super::{ImperfectionsError, check};

/// `[simulator.imperfections.source]`: relative quantities as plain fractions.
#[derive(Debug, Clone, Default, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct SourceImperfections {
    /// How far below its settled power the source starts when the run begins (fraction): the power is
    /// `1 - warmup_fraction exp(-t / warmup_time_s)` of the settled value.
    #[serde(default)]
    pub warmup_fraction: f64,
    /// The warm-up's time constant (s; needed when `warmup_fraction` > 0).
    #[serde(default)]
    pub warmup_time_s: f64,
    /// Standard deviation of the relative random walk after one hour (fraction per sqrt(hour)).
    #[serde(default)]
    pub random_walk_per_rthour: f64,
    /// Relative rms of the flicker: fluctuations with a 1/f spectrum between 0.01 and 10 Hz.
    #[serde(default)]
    pub flicker_rms: f64,
}

impl SourceImperfections {
    pub fn is_ideal(&self) -> bool {
        self.warmup_fraction == 0.0 && self.random_walk_per_rthour == 0.0 && self.flicker_rms == 0.0
    }

    pub fn validate(&self) -> Result<(), ImperfectionsError> {
        const G: &str = "source";
        for (key, value, limit, why) in [
            (
                "warmup_fraction",
                self.warmup_fraction,
                0.5,
                "a source that dim is still off",
            ),
            (
                "warmup_time_s",
                self.warmup_time_s,
                86_400.0,
                "a day-long warm-up is a drift",
            ),
            (
                "random_walk_per_rthour",
                self.random_walk_per_rthour,
                0.1,
                "a source that unstable is broken",
            ),
            (
                "flicker_rms",
                self.flicker_rms,
                0.05,
                "a source that unstable is broken",
            ),
        ] {
            check(G, key, value, limit, why)?;
        }
        if self.warmup_fraction > 0.0 && self.warmup_time_s <= 0.0 {
            return Err(ImperfectionsError::Needed {
                group: G,
                key: "warmup_time_s",
                needed_by: "warmup_fraction",
                value: self.warmup_time_s,
            });
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn off_by_default_and_warm_up_needs_its_time() {
        assert!(SourceImperfections::default().is_ideal());
        let s = SourceImperfections {
            warmup_fraction: 0.01,
            ..Default::default()
        };
        let msg = s.validate().expect_err("time needed").to_string();
        assert!(
            msg.contains("[simulator.imperfections.source] warmup_time_s"),
            "{msg}"
        );
        let s = SourceImperfections {
            flicker_rms: f64::NAN,
            ..Default::default()
        };
        assert!(s.validate().expect_err("nan").to_string().contains("flicker_rms"));
    }
}
