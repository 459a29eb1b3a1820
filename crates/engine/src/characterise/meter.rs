//! The meter and the wheel as the characterisation drives them: a reading under a given configuration, the
//! way back to auto-range, the wheel to a position, and the one overlap reading (A-B-B-A) every step uses.

use gonio_driver::{DetectorConfig, PowerRange, PowerReading};

use super::CharacteriseError;
use super::ranges::Overlap;
use crate::motion::{Device, Motion};

/// Samples averaged per overlap and dark reading (about 0.3 s each): enough that the flicker and the converter's
/// resolution leave each ratio a few 1e-5 uncertain.
pub const OVERLAP_AVERAGING: u32 = 100;

/// The meter's state between readings: what it was last configured to.
#[derive(Debug, Default)]
pub struct Meter {
    configured: Option<DetectorConfig>,
}

/// Auto-range at `nm`, averaging `averaging` samples.
pub fn auto(nm: f64, averaging: u32) -> DetectorConfig {
    DetectorConfig {
        wavelength_nm: nm,
        averaging,
        range: PowerRange::Auto,
    }
}

/// The fixed range of full scale `full_scale_w` at `nm`, averaging [`OVERLAP_AVERAGING`] samples.
pub fn fixed(nm: f64, full_scale_w: f64) -> DetectorConfig {
    DetectorConfig {
        wavelength_nm: nm,
        averaging: OVERLAP_AVERAGING,
        range: PowerRange::Fixed { full_scale_w },
    }
}

impl Meter {
    /// One reading under `config` (the meter configured first when it is not already).
    pub async fn read(
        &mut self,
        motion: &Motion<'_>,
        config: DetectorConfig,
    ) -> Result<PowerReading, CharacteriseError> {
        let det = motion.rig().detector().clone();
        if self.configured != Some(config) {
            motion
                .device(Device::Detector, "configure the meter", || det.configure(config))
                .await?;
            self.configured = Some(config);
        }
        Ok(motion
            .device(Device::Detector, "read the meter", || det.read_power())
            .await?)
    }

    /// The light where the detector is, read on range `r` and on `r + 1` in the order A-B-B-A (a linear drift
    /// cancels): `None` when a reading is overloaded or not positive.
    pub async fn overlap(
        &mut self,
        motion: &Motion<'_>,
        nm: f64,
        r: usize,
        ranges_w: &[f64],
    ) -> Result<Option<Overlap>, CharacteriseError> {
        let (Some(&lo_fs), Some(&hi_fs)) = (ranges_w.get(r), ranges_w.get(r + 1)) else {
            return Ok(None);
        };
        let a1 = self.read(motion, fixed(nm, lo_fs)).await?;
        let b1 = self.read(motion, fixed(nm, hi_fs)).await?;
        let b2 = self.read(motion, fixed(nm, hi_fs)).await?;
        let a2 = self.read(motion, fixed(nm, lo_fs)).await?;
        if [a1, b1, b2, a2]
            .iter()
            .any(|m| m.overload || m.power_w.is_nan() || m.power_w <= 0.0)
        {
            return Ok(None);
        }
        let (low, high) = (0.5 * (a1.power_w + a2.power_w), 0.5 * (b1.power_w + b2.power_w));
        // Each mean's spread between its two readings, and the converter's step of each range (16 bits).
        let q = |w: f64, fs: f64| fs / 65536.0 / (w * 12f64.sqrt());
        let spread =
            ((a1.power_w / a2.power_w).ln().powi(2) + (b1.power_w / b2.power_w).ln().powi(2)).sqrt() / 2.0;
        let u = spread.hypot(q(low, lo_fs)).hypot(q(high, hi_fs)).max(1e-6);
        Ok(Some(Overlap {
            range: r,
            low_w: low,
            high_w: high,
            ln_ratio_u: u,
        }))
    }
}

/// The range whose overlap with the next a reading of `level_w` serves: filled to between 0.15 and 0.95 of its
/// full scale.
pub fn overlap_range(level_w: f64, ranges_w: &[f64]) -> Option<usize> {
    (0..ranges_w.len().saturating_sub(1))
        .find(|&r| level_w >= 0.15 * ranges_w[r] && level_w <= 0.95 * ranges_w[r])
}

pub async fn wheel_to(motion: &Motion<'_>, position: u8) -> Result<(), CharacteriseError> {
    if let Some(w) = motion.rig().wheel() {
        motion
            .device(
                Device::Wheel,
                &format!("filter wheel to position {position}"),
                || w.go_to(position),
            )
            .await?;
    }
    Ok(())
}

/// Mean and its standard uncertainty.
pub fn mean_and_u(values: &[f64]) -> (f64, f64) {
    let n = values.len().max(1) as f64;
    let mean = values.iter().sum::<f64>() / n;
    let var = values.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (n - 1.0).max(1.0);
    (mean, (var / n).sqrt())
}
