//! The meter's and the source's noise figures against the instrument file: the dark and noise of every range
//! (for the record), the head's dark current (`detector.dark_current_a`) and the source's white relative noise
//! (`source.relative_noise`).
//!
//! - Amplifier noise (`detector.amplifier_noise_a_per_rthz`): right after, through the blank [`measure_meter`]
//!   leaves in the beam, the smallest range at averaging 1 (crate::selftest's `amplifier`).
//! - Dark current: the blank in the beam, the meter on its smallest range; the mean reading (W at the set
//!   wavelength) times the file's responsivity there is the current the head delivers in the dark. Room light
//!   leaking past the baffles (ambient light) adds to it and cannot be told from it in a test of minutes (it
//!   varies over tens of minutes, the dark current not at all): the figure is "dark + ambient", and the verdict
//!   fails a figure below the claim by more than the tolerance, or above it by more than the tolerance plus
//!   [`AMBIENT_ALLOWANCE`] of the claim.
//! - Relative noise: the holder empty, the detector on the direct beam, the meter at averaging 1 on a range
//!   (and a set wavelength) that puts the beam at most [`MAX_FILL`] of full scale; [`NOISE_READINGS`] readings
//!   in a row. The differences of consecutive readings remove the slow drift (and the source's warm-up and
//!   wander); their variance is twice the reading's. The meter's own noise at that level (shot noise of the
//!   current, Johnson noise of the range's feedback resistor, the converter's quantisation: [`meter_floor_w2`])
//!   is subtracted (gonio_instrument::meter_noise, the figures the simulated meter uses too); at the direct beam
//!   it is a few percent of the source's at most.
//! - Flicker (`source.flicker_rel`): right after, the same beam, range and set wavelength at the file's
//!   averaging (what a campaign reads with), read back to back for [`FLICKER_WINDOW_S`] with each reading's
//!   time. About the straight line through them (the drift references follow) the readings scatter by the
//!   lamp's slow fluctuation and by their own white noise; half the variance of consecutive differences is the
//!   white part (the flicker barely changes in one reading's time) and is subtracted ([`flicker_rel`]). A
//!   two-minute record sees fluctuations faster than about a minute: slower ones are the drift's, which the
//!   campaign's references and their curvature cover. One record of a 1/f fluctuation estimates its size to
//!   some percent at best, so the verdict allows [`FLICKER_ALLOWANCE`] either way ([`flicker_check`]).

use gonio_driver::{DetectorConfig, PowerRange};
use gonio_instrument::meter_noise;
use gonio_instrument::responsivity::Responsivity;
use gonio_scheduler::kinematics::Pose;

use super::fit::mean_std;
use super::report::{Check, against, info, line};
use crate::motion::{Device, Motion, MotionError};

/// Readings per meter range for its dark and noise.
const READINGS_PER_RANGE: usize = 20;
/// Direct-beam readings for the source's relative noise: the spread of N - 1 differences is known to about
/// 1 / sqrt(2 (N - 1)), 2.5 % here.
pub const NOISE_READINGS: usize = 800;
/// Ambient light a dark reading may hold on top of the claimed dark current, as a fraction of the claim
/// (realistic.toml's room light is 40 % of its head's dark current, varying by 20 %).
pub const AMBIENT_ALLOWANCE: f64 = 0.6;
/// How long the flicker's record lasts (s of instrument time).
pub const FLICKER_WINDOW_S: f64 = 120.0;
/// The flicker's verdict: the measured figure may differ from the claim by this factor (relative) either way.
/// Four seeds of realistic.toml's lamp (flicker over 0.01-10 Hz) measure 0.89-0.99 of its rms (the straight
/// line takes part of the slowest decade); a lamp whose flicker reaches further down scatters more.
pub const FLICKER_ALLOWANCE: f64 = 0.3;
/// The direct beam's largest share of the range's full scale: its noise and drift must not overload it.
pub const MAX_FILL: f64 = 0.75;

/// The file's responsivity, or why there is none to convert with.
pub(super) fn responsivity(motion: &Motion<'_>) -> Result<Responsivity, String> {
    Responsivity::from_detector(&motion.rig().file().instrument.detector).map_err(|e| e.0)
}

async fn configure(motion: &Motion<'_>, config: DetectorConfig) -> Result<(), MotionError> {
    let det = motion.rig().detector();
    motion
        .device(Device::Detector, "configure the meter", || det.configure(config))
        .await
}

/// `n` readings (W) with the meter set to `nm`, averaging 1, on the fixed range of full scale `range_w`; None
/// when one is an overload.
pub(super) async fn readings_at_averaging_1(
    motion: &Motion<'_>,
    nm: f64,
    range_w: f64,
    n: usize,
) -> Result<Option<Vec<f64>>, MotionError> {
    configure(
        motion,
        DetectorConfig {
            wavelength_nm: nm,
            averaging: 1,
            range: PowerRange::Fixed {
                full_scale_w: range_w,
            },
        },
    )
    .await?;
    readings(motion, n).await
}

/// `n` readings (W); None when one is an overload.
async fn readings(motion: &Motion<'_>, n: usize) -> Result<Option<Vec<f64>>, MotionError> {
    let det = motion.rig().detector();
    let mut values = Vec::with_capacity(n);
    for _ in 0..n {
        let r = motion
            .device(Device::Detector, "read the meter", || det.read_power())
            .await?;
        if r.overload || !r.power_w.is_finite() {
            return Ok(None);
        }
        values.push(r.power_w);
    }
    Ok(Some(values))
}

/// What [`measure_meter`] found, and where it left the meter.
pub(super) struct MeterNoise {
    pub checks: Vec<Check>,
    pub not_measured: Vec<String>,
    /// The blank is in the beam and the meter set to this wavelength (nm); None without a blank.
    pub blank_at_nm: Option<f64>,
}

/// The meter's dark and noise on each range with the blank in the beam, and the head's dark current from the
/// smallest range (module doc). The blank stays in the beam.
pub(super) async fn measure_meter(motion: &Motion<'_>, tolerance: f64) -> Result<MeterNoise, MotionError> {
    let rig = motion.rig();
    let inst = &rig.file().instrument;
    let mut missing = Vec::new();
    let blank = inst
        .filter_wheel
        .as_ref()
        .and_then(|w| w.positions.iter().find(|p| p.blank))
        .map(|p| p.position);
    let dark = match (rig.wheel(), blank) {
        (Some(w), Some(p)) => {
            motion
                .device(Device::Wheel, "the blank into the beam", || w.go_to(p))
                .await?;
            true
        }
        _ => {
            missing.push(
                "detector.dark_current_a: no blank on the wheel, so the readings below include whatever light \
                 reaches the meter"
                    .to_string(),
            );
            false
        }
    };
    let nm = inst.bands_nm().first().copied().unwrap_or(550.0);
    let mut out = Vec::new();
    let mut smallest = None;
    for (i, range_w) in inst.detector.ranges_w.iter().enumerate() {
        configure(
            motion,
            DetectorConfig {
                wavelength_nm: nm,
                averaging: inst.detector.averaging,
                range: PowerRange::Fixed {
                    full_scale_w: *range_w,
                },
            },
        )
        .await?;
        let Some(values) = readings(motion, READINGS_PER_RANGE).await? else {
            missing.push(format!(
                "detector.ranges_w[{i}]: the dark overloads the {range_w:e} W range"
            ));
            continue;
        };
        if let Some((mean, std)) = mean_std(&values) {
            if i == 0 {
                smallest = Some(mean);
            }
            out.push(info(
                format!("detector.ranges_w[{i}].dark_w"),
                &format!("dark on the {range_w:e} W range"),
                "W",
                mean,
            ));
            out.push(info(
                format!("detector.ranges_w[{i}].noise_w"),
                &format!("noise (1 sigma) on the {range_w:e} W range"),
                "W",
                std,
            ));
        }
    }
    match (dark, smallest, responsivity(motion)) {
        (true, Some(mean_w), Ok(r)) => out.push(dark_current_check(
            inst.detector.dark_current_a,
            mean_w * r.at(nm),
            tolerance,
        )),
        (true, Some(_), Err(e)) => missing.push(format!("detector.dark_current_a: {e}")),
        (true, None, _) => missing.push("detector.dark_current_a: no dark on the smallest range".into()),
        (false, _, _) => {}
    }
    Ok(MeterNoise {
        checks: out,
        not_measured: missing,
        blank_at_nm: dark.then_some(nm),
    })
}

/// The dark current's verdict (module doc): ambient light only adds.
fn dark_current_check(claimed_a: f64, measured_a: f64, tolerance: f64) -> Check {
    let low = claimed_a * (1.0 - tolerance);
    let high = claimed_a * (1.0 + tolerance + AMBIENT_ALLOWANCE);
    line(
        "detector.dark_current_a".into(),
        "dark current + ambient light (blank, smallest range)",
        "A",
        claimed_a,
        measured_a,
        (low..=high).contains(&measured_a),
    )
}

/// The variance (W^2) the meter itself adds to one sample of `power_w` on a range of `full_scale_w`, set to a
/// wavelength where the head delivers `a_per_w` (module doc).
pub fn meter_floor_w2(power_w: f64, full_scale_w: f64, a_per_w: f64) -> f64 {
    let current_a2 =
        meter_noise::shot_a2(power_w * a_per_w) + meter_noise::johnson_a2(full_scale_w * a_per_w);
    let lsb_w = meter_noise::lsb(full_scale_w);
    current_a2 / (a_per_w * a_per_w) + lsb_w * lsb_w / 12.0
}

/// The set wavelength and range that put a beam read as `power_w` at `band_nm` highest below [`MAX_FILL`] of
/// full scale: the meter reports `power_w R(band) / R(set)`. None when no range holds it.
fn best_setting(
    r: &Responsivity,
    band_nm: f64,
    power_w: f64,
    ranges_w: &[f64],
    sensor_nm: [f64; 2],
) -> Option<(f64, f64)> {
    let mut best: Option<(f64, f64, f64)> = None;
    let candidates = std::iter::once(band_nm).chain(
        r.wavelengths_nm()
            .into_iter()
            .filter(|nm| (sensor_nm[0]..=sensor_nm[1]).contains(nm)),
    );
    for nm in candidates {
        let reads_w = power_w * r.at(band_nm) / r.at(nm);
        for &range_w in ranges_w {
            let fill = reads_w / range_w;
            if fill <= MAX_FILL && best.is_none_or(|b| fill > b.2) {
                best = Some((nm, range_w, fill));
            }
        }
    }
    best.map(|(nm, range_w, _)| (nm, range_w))
}

/// The source's white relative noise on the direct beam at `pose` (module doc) and the meter's setting it was
/// read with (set wavelength nm, range W), or why it is not measured.
pub(super) async fn source_noise(
    motion: &mut Motion<'_>,
    pose: &Pose,
    band_nm: f64,
    tolerance: f64,
) -> Result<Result<(Check, (f64, f64)), String>, MotionError> {
    let inst = motion.rig().file().instrument.clone();
    let r = match responsivity(motion) {
        Ok(r) => r,
        Err(e) => return Ok(Err(e)),
    };
    motion.move_to(pose).await?;
    configure(
        motion,
        DetectorConfig {
            wavelength_nm: band_nm,
            averaging: 1,
            range: PowerRange::Auto,
        },
    )
    .await?;
    let Some(first) = readings(motion, 5).await? else {
        return Ok(Err("the direct beam overloads the meter".into()));
    };
    let power_w = first.iter().sum::<f64>() / first.len() as f64;
    let ranges = &inst.detector.ranges_w;
    let Some((nm, range_w)) = best_setting(&r, band_nm, power_w, ranges, inst.detector.sensor_wavelength_nm)
    else {
        return Ok(Err(format!(
            "no range holds the direct beam ({power_w:e} W) below {MAX_FILL} of full scale"
        )));
    };
    tracing::info!(
        set_nm = nm,
        range_w,
        readings = NOISE_READINGS,
        "self-test: the source's relative noise on the direct beam"
    );
    let Some(values) = readings_at_averaging_1(motion, nm, range_w, NOISE_READINGS).await? else {
        return Ok(Err(format!("the direct beam overloads the {range_w:e} W range")));
    };
    let Some(measured) = relative_noise(&values, range_w, r.at(nm), inst.detector.noise) else {
        return Ok(Err("no direct beam to measure the noise on".into()));
    };
    let claimed = inst.source.relative_noise;
    let check = against(
        "source.relative_noise".into(),
        "source's white relative noise (direct beam, differences of consecutive readings)",
        "1",
        claimed,
        measured,
        tolerance,
    );
    Ok(Ok((check, (nm, range_w))))
}

/// The source's flicker on the direct beam where [`source_noise`] left the meter (module doc), or why it is not
/// measured. `nm` and `range_w`: that setting.
pub(super) async fn source_flicker(
    motion: &mut Motion<'_>,
    nm: f64,
    range_w: f64,
) -> Result<Result<Check, String>, MotionError> {
    let inst = motion.rig().file().instrument.clone();
    configure(
        motion,
        DetectorConfig {
            wavelength_nm: nm,
            averaging: inst.detector.averaging,
            range: PowerRange::Fixed {
                full_scale_w: range_w,
            },
        },
    )
    .await?;
    tracing::info!(
        window_s = FLICKER_WINDOW_S,
        averaging = inst.detector.averaging,
        "self-test: the source's flicker on the direct beam"
    );
    let det = motion.rig().detector();
    let clock = motion.clock();
    let t0 = clock.now_s();
    let mut samples = Vec::new();
    loop {
        let t = clock.now_s();
        if t - t0 >= FLICKER_WINDOW_S {
            break;
        }
        let r = motion
            .device(Device::Detector, "read the meter", || det.read_power())
            .await?;
        if r.overload || !r.power_w.is_finite() {
            return Ok(Err(format!("the direct beam overloads the {range_w:e} W range")));
        }
        samples.push((0.5 * (t + clock.now_s()), r.power_w));
    }
    let Some((measured, white)) = flicker_rel(&samples) else {
        return Ok(Err(format!(
            "too few readings in {FLICKER_WINDOW_S} s ({}) or no direct beam",
            samples.len()
        )));
    };
    Ok(Ok(flicker_check(
        inst.source.flicker_rel,
        measured,
        white,
        samples.len(),
    )))
}

/// The flicker of `samples` (time s, W): the relative standard deviation about their least-squares straight
/// line, less the white part (half the variance of consecutive differences); and that white part's relative
/// standard deviation. None with fewer than 20 samples or without a positive mean.
pub fn flicker_rel(samples: &[(f64, f64)]) -> Option<(f64, f64)> {
    if samples.len() < 20 {
        return None;
    }
    let n = samples.len() as f64;
    let (mt, mv) = samples
        .iter()
        .fold((0.0, 0.0), |(a, b), (t, v)| (a + t / n, b + v / n));
    if mv.is_nan() || mv <= 0.0 {
        return None;
    }
    let stt: f64 = samples.iter().map(|(t, _)| (t - mt).powi(2)).sum();
    let stv: f64 = samples.iter().map(|(t, v)| (t - mt) * (v - mv)).sum();
    let slope = if stt > 0.0 { stv / stt } else { 0.0 };
    let about_line = samples
        .iter()
        .map(|(t, v)| (v - mv - slope * (t - mt)).powi(2))
        .sum::<f64>()
        / (n - 2.0);
    let white = samples.windows(2).map(|w| (w[1].1 - w[0].1).powi(2)).sum::<f64>() / (2.0 * (n - 1.0));
    Some(((about_line - white).max(0.0).sqrt() / mv, white.sqrt() / mv))
}

/// The flicker's verdict: within [`FLICKER_ALLOWANCE`] of the claim either way, give or take what the readings'
/// white noise (`white_rel` each, `readings` of them) leaves in the estimate: three of its standard deviations,
/// a variance difference known to about sqrt(5 / readings) of the white variance.
fn flicker_check(claimed: f64, measured: f64, white_rel: f64, readings: usize) -> Check {
    let floor = white_rel * 3f64.sqrt() * (5.0 / readings.max(1) as f64).powf(0.25);
    let pass = measured <= claimed * (1.0 + FLICKER_ALLOWANCE) + floor
        && measured >= claimed / (1.0 + FLICKER_ALLOWANCE) - floor;
    line(
        "source.flicker_rel".into(),
        "source's flicker (direct beam, two minutes about a straight line)",
        "1",
        claimed,
        measured,
        pass,
    )
}

/// The mean of `values` and one reading's white variance: half the variance of consecutive differences, in
/// which a slow drift cancels; and how many differences it rests on. None for fewer than three readings.
pub fn white_variance(values: &[f64]) -> Option<(f64, f64, usize)> {
    let (mean, _) = mean_std(values)?;
    let diffs: Vec<f64> = values.windows(2).map(|w| w[1] - w[0]).collect();
    let (_, diff_std) = mean_std(&diffs)?;
    Some((mean, 0.5 * diff_std * diff_std, diffs.len()))
}

/// The white relative noise of `values` (module doc): consecutive differences, less the meter's own noise when
/// the file says the meter has it (`noise`). None without a positive mean.
pub fn relative_noise(values: &[f64], range_w: f64, a_per_w: f64, meter_noise: bool) -> Option<f64> {
    let (mean, white_w2, _) = white_variance(values)?;
    if mean <= 0.0 {
        return None;
    }
    let floor = if meter_noise {
        meter_floor_w2(mean, range_w, a_per_w)
    } else {
        0.0
    };
    Some((white_w2 - floor).max(0.0).sqrt() / mean)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_setting_puts_the_beam_highest_below_the_fill() {
        let r = Responsivity::Table(vec![(400.0, 0.1), (550.0, 0.3), (750.0, 0.45)]);
        // 5e-4 W at 550 nm would fill the 5e-4 W range: read at 750 nm it is 3.3e-4 W, 67 % of it.
        let got = best_setting(&r, 550.0, 5.0e-4, &[5.0e-5, 5.0e-4, 5.0e-3], [400.0, 1100.0]);
        assert_eq!(got, Some((750.0, 5.0e-4)));
        // Outside the sensor's limits a wavelength is not offered: read at 400 nm it is 1.5e-3 W, 30 % of the
        // 5e-3 W range (at 550 nm 10 %).
        let got = best_setting(&r, 550.0, 5.0e-4, &[5.0e-5, 5.0e-4, 5.0e-3], [400.0, 700.0]);
        assert_eq!(got, Some((400.0, 5.0e-3)));
        let got = best_setting(&r, 550.0, 5.0e-4, &[5.0e-5, 5.0e-4, 5.0e-3], [500.0, 700.0]);
        assert_eq!(got, Some((550.0, 5.0e-3)));
        assert_eq!(best_setting(&r, 550.0, 1.0, &[5.0e-4], [400.0, 1100.0]), None);
    }

    #[test]
    fn the_relative_noise_ignores_a_slow_drift_and_subtracts_the_meters_own() {
        // A deterministic +-1 pattern of relative size 1e-4 on a ramp of 1 % over the series.
        let n = 1000;
        let values: Vec<f64> = (0..n)
            .map(|k| {
                let drift = 1.0 + 0.01 * k as f64 / n as f64;
                let white = if (k * 7919) % 13 < 6 { 1.0 } else { -1.0 };
                1.0e-4 * drift * (1.0 + 1.0e-4 * white)
            })
            .collect();
        let plain = relative_noise(&values, 5.0e-4, 0.3, false).expect("a beam");
        // The pattern's consecutive differences are not those of white noise; what matters is that the ramp
        // (1e-5 per reading of 1e-4 W x 1e-2 / 1000) adds nothing and the floor only lowers the figure.
        let ramp_free: Vec<f64> = (0..n)
            .map(|k| {
                let white = if (k * 7919) % 13 < 6 { 1.0 } else { -1.0 };
                1.0e-4 * (1.0 + 1.0e-4 * white)
            })
            .collect();
        let flat = relative_noise(&ramp_free, 5.0e-4, 0.3, false).expect("a beam");
        assert!((plain / flat - 1.0).abs() < 0.01, "{plain} vs {flat}");
        let less = relative_noise(&values, 5.0e-4, 0.3, true).expect("a beam");
        assert!(less < plain && less > 0.9 * plain, "{less} vs {plain}");
        assert_eq!(relative_noise(&[0.0; 10], 5.0e-4, 0.3, true), None);
    }

    #[test]
    fn the_flicker_is_the_scatter_about_a_line_less_the_white_noise() {
        // Two minutes at 30 ms a reading: a ramp of 1 %, a slow sine of rms 2e-4 (period 20 s) and white noise of
        // 1e-4 (uniform, from a xorshift generator).
        let n = 4000;
        let mut state = 0x2545_f491_4f6c_dd1d_u64;
        let mut next_white = move || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            let u = (state >> 11) as f64 / (1u64 << 53) as f64;
            1e-4 * 3f64.sqrt() * (2.0 * u - 1.0)
        };
        let whites: Vec<f64> = (0..n).map(|_| next_white()).collect();
        let samples: Vec<(f64, f64)> = (0..n)
            .map(|k| {
                let t = 0.03 * k as f64;
                let sine = 2e-4 * std::f64::consts::SQRT_2 * (std::f64::consts::TAU * t / 20.0).sin();
                (t, 1e-4 * (1.0 + 0.01 * t / 120.0 + sine + whites[k]))
            })
            .collect();
        let (flicker, white) = flicker_rel(&samples).expect("a beam");
        assert!((flicker / 2e-4 - 1.0).abs() < 0.05, "{flicker}");
        assert!((white / 1e-4 - 1.0).abs() < 0.05, "{white}");
        // Without the sine: no flicker is claimed beyond the white noise's leftovers.
        let flat: Vec<(f64, f64)> = (0..n)
            .map(|k| (0.03 * k as f64, 1e-4 * (1.0 + whites[k])))
            .collect();
        let (none, _) = flicker_rel(&flat).expect("a beam");
        assert!(none < 1e-5, "{none}");
        assert_eq!(flicker_rel(&samples[..10]), None);
    }

    #[test]
    fn the_flicker_passes_within_its_allowance_either_way() {
        use super::super::report::Verdict::{Fail, Pass};
        let c = |claimed: f64, measured: f64| flicker_check(claimed, measured, 3e-5, 4000).verdict;
        assert_eq!(c(2e-4, 2e-4), Pass);
        assert_eq!(c(2e-4, 2.5e-4), Pass);
        assert_eq!(c(2e-4, 1.6e-4), Pass);
        assert_eq!(c(2e-4, 4e-4), Fail, "a lamp twice as unsteady as claimed");
        assert_eq!(
            c(2e-4, 0.5e-4),
            Fail,
            "a claim four times what is there pads every budget"
        );
        // No flicker claimed: the white noise's leftovers pass, a real flicker does not.
        assert_eq!(c(0.0, 5e-6), Pass);
        assert_eq!(c(0.0, 1e-4), Fail);
    }

    #[test]
    fn the_dark_current_allows_ambient_light_above_the_claim_only() {
        let c = |m: f64| dark_current_check(5.0e-11, m, 0.1).verdict;
        use super::super::report::Verdict::{Fail, Pass};
        assert_eq!(c(5.0e-11), Pass);
        assert_eq!(c(7.0e-11), Pass, "dark + realistic ambient");
        assert_eq!(c(4.4e-11), Fail, "below the claim");
        assert_eq!(c(1.2e-10), Fail, "twice the claim with ambient light");
    }
}
