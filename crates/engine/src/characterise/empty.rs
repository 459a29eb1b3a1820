//! The characterisation's steps with the holder empty (crate::characterise's module doc, steps 1-5): raw
//! readings only; [`super::finish`] turns them into the calibration once the sample's overlaps are in too.

use gonio_scheduler::kinematics::Pose;
use serde::Serialize;

use super::meter::{Meter, OVERLAP_AVERAGING, auto, fixed, mean_and_u, overlap_range, wheel_to};
use super::ranges::{Overlap, RangeDark, near_range_boundary};
use super::signature::alpha_deg;
use super::{CharacteriseError, CharacteriseOptions, WATCH_INTERVAL_S};
use crate::motion::Motion;

/// Samples averaged per signature reading (about 0.6 s): the signature's floor is a few counts of the smallest
/// range.
const SIGNATURE_AVERAGING: u32 = 200;
/// Readings per signature point and per dark.
const SIGNATURE_REPEATS: usize = 3;
/// Single-sample darks for the noise.
const NOISE_READINGS: usize = 40;
/// Positions of the fine pass over the beam's edge.
const FINE_POSITIONS: i32 = 160;
/// The walk out of the beam: step and farthest offset from the facing angle (deg).
const WALK_STEP_DEG: f64 = 0.02;
const WALK_MAX_DEG: f64 = 3.0;
/// Angles from the beam's forward direction the signature is read at (deg), kept where the arms can go.
const SIGNATURE_ALPHA_DEG: [f64; 16] = [
    3.0, 3.5, 4.0, 5.0, 6.0, 8.0, 10.0, 13.0, 17.0, 22.0, 30.0, 45.0, 60.0, 90.0, 120.0, 150.0,
];

/// The direct beam in one band (raw reading; `range` the fixed range it was read on, if it was).
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct DirectBeam {
    pub band_nm: f64,
    pub power_w: f64,
    pub range: Option<usize>,
    /// When it was read (instrument time s since the procedure started).
    pub t_s: f64,
}

/// One band's signature readings, raw: at each angle the lit reading and the dark at its time, (mean W, u W).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct RawSignature {
    pub band_nm: f64,
    pub alpha_deg: Vec<f64>,
    pub lit_w: Vec<(f64, f64)>,
    pub dark_w: Vec<(f64, f64)>,
    /// When each lit reading was taken (instrument time s since the procedure started): the source's drift
    /// from the direct beam's reading to it is taken out (crate::characterise::finish).
    pub t_s: Vec<f64>,
    /// Standard deviation of one single-sample dark reading (W).
    pub noise_one_sample_w: f64,
}

/// What the empty-holder steps read.
#[derive(Debug, Clone, Serialize)]
pub struct EmptyHolder {
    pub direct: Vec<DirectBeam>,
    /// The band the overlaps and the watch used.
    pub overlap_nm: f64,
    /// The watch's readings (instrument time s, W).
    pub drift_readings: Vec<(f64, f64)>,
    pub darks: Vec<RangeDark>,
    /// The walk out of the beam and the fine pass over its edge (deg from the facing angle, W).
    pub walk: Vec<(f64, f64)>,
    pub fine: Vec<(f64, f64)>,
    pub overlaps: Vec<Overlap>,
    pub signature: Vec<RawSignature>,
    pub not_done: Vec<String>,
}

/// The open bands of the wheel (position, nm) and its blank position.
fn wheel_bands(motion: &Motion<'_>) -> (Vec<(u8, f64)>, Option<u8>) {
    let inst = &motion.rig().file().instrument;
    let Some(w) = &inst.filter_wheel else {
        return (Vec::new(), None);
    };
    let bands = w
        .positions
        .iter()
        .filter(|p| !p.blank && p.transmission > 0.0)
        .filter_map(|p| p.band_nm.map(|nm| (p.position, nm)))
        .collect();
    (bands, w.positions.iter().find(|p| p.blank).map(|p| p.position))
}

/// The empty-holder steps, the light arm at `light_deg` and the detector facing the beam at `facing_deg`.
pub async fn read_empty_holder(
    motion: &mut Motion<'_>,
    meter: &mut Meter,
    light_deg: f64,
    facing_deg: f64,
    options: CharacteriseOptions,
    t0: f64,
) -> Result<EmptyHolder, CharacteriseError> {
    let clock = motion.clock();
    let file = motion.rig().file().clone();
    let inst = &file.instrument;
    let ranges_w = inst.detector.ranges_w.clone();
    let (bands, blank) = wheel_bands(motion);
    let mut not_done = Vec::new();
    let facing = Pose::new(light_deg, facing_deg, 0.0, 0.0);
    motion.move_to(&facing).await?;

    // 2. The direct beam per band; the overlaps use the band with the most power (the highest levels).
    let single_band = inst.bands_nm().first().copied().unwrap_or(550.0);
    let mut direct: Vec<(u8, DirectBeam, bool)> = Vec::new();
    let targets: Vec<(u8, f64)> = if bands.is_empty() {
        vec![(0, single_band)]
    } else {
        bands.clone()
    };
    for &(position, nm) in &targets {
        wheel_to(motion, position).await?;
        let mut r = meter.read(motion, auto(nm, OVERLAP_AVERAGING)).await?;
        let mut range = None;
        // Within 1 % of a range's full scale the range auto-ranging took cannot be told from the value: read
        // on the upper range, fixed.
        if let Some(upper) = near_range_boundary(r.power_w, &ranges_w).filter(|_| !r.overload) {
            r = meter.read(motion, fixed(nm, ranges_w[upper])).await?;
            range = Some(upper);
        }
        let beam = DirectBeam {
            band_nm: nm,
            power_w: r.power_w,
            range,
            t_s: clock.now_s() - t0,
        };
        direct.push((position, beam, r.overload));
    }
    let Some(&(brightest_position, brightest, _)) = direct
        .iter()
        .filter(|(_, _, overload)| !overload)
        .max_by(|a, b| a.1.power_w.total_cmp(&b.1.power_w))
    else {
        return Err(CharacteriseError::Saturated {
            power_w: direct.first().map_or(f64::NAN, |d| d.1.power_w),
        });
    };
    let overlap_nm = brightest.band_nm;
    wheel_to(motion, brightest_position).await?;

    // 1. The warm-up watch (after the band is chosen: it follows one band).
    let mut drift_readings = Vec::new();
    let watch_end = clock.now_s() + options.warmup_watch_s.max(0.0);
    loop {
        let r = meter.read(motion, auto(overlap_nm, OVERLAP_AVERAGING)).await?;
        drift_readings.push((clock.now_s() - t0, r.power_w));
        if clock.now_s() + WATCH_INTERVAL_S > watch_end {
            break;
        }
        clock.sleep_s(WATCH_INTERVAL_S).await;
    }

    // 3. Darks per range, each beside range 0's (the ambient light moves slowly between them).
    let mut darks = Vec::new();
    match blank {
        Some(b) => {
            wheel_to(motion, b).await?;
            let mut zero = Vec::new();
            let mut diffs: Vec<Vec<f64>> = vec![Vec::new(); ranges_w.len()];
            for _ in 0..4 {
                for r in 1..ranges_w.len() {
                    let d0 = meter.read(motion, fixed(overlap_nm, ranges_w[0])).await?.power_w;
                    let dr = meter.read(motion, fixed(overlap_nm, ranges_w[r])).await?.power_w;
                    zero.push(d0);
                    diffs[r].push(dr - d0);
                }
            }
            let (z, _) = mean_and_u(&zero);
            darks.push(RangeDark {
                range: 0,
                mean_w: z,
                u_w: 0.0,
            });
            for (r, d) in diffs.iter().enumerate().skip(1) {
                let (m, u) = mean_and_u(d);
                // A reading is quantised to the range's converter step; without noise to spread it, that step
                // over sqrt(12) bounds how well a mean knows the offset.
                let step = ranges_w[r] / 65536.0;
                darks.push(RangeDark {
                    range: r,
                    mean_w: z + m,
                    u_w: u.hypot(step / 12f64.sqrt()),
                });
            }
            wheel_to(motion, brightest_position).await?;
        }
        None => not_done.push(
            "ranges: the filter wheel has no blank position to read darks through, so the offsets and the \
             overlaps' zero are unknown"
                .to_string(),
        ),
    }

    // 4. Walk out of the beam, then a fine pass over the edge it crossed for the overlaps.
    let mut walk: Vec<(f64, f64)> = Vec::new();
    let steps = (WALK_MAX_DEG / WALK_STEP_DEG).round() as i32;
    let smallest = ranges_w.first().copied().unwrap_or(0.0);
    for k in 0..=steps {
        let offset = f64::from(k) * WALK_STEP_DEG;
        let pose = Pose::new(light_deg, facing_deg - offset, 0.0, 0.0);
        if motion.safe_move(&pose).is_err() {
            break;
        }
        motion.move_to(&pose).await?;
        let r = meter.read(motion, auto(overlap_nm, 10)).await?;
        walk.push((offset, r.power_w));
        if r.power_w < 0.1 * smallest {
            break;
        }
    }
    let peak = walk.iter().map(|w| w.1).fold(0.0, f64::max);
    let mut overlaps = Vec::new();
    let mut fine = Vec::new();
    if !darks.is_empty() {
        // The fine pass goes the walk's way (so that the axis's backlash is always taken up the same way): at
        // each position the light is read on the range it fills to between 0.15 and 0.95 of full scale, and on
        // the next. The edge may be a few hundredths of a degree (a top-hat beam) or a degree (a Gaussian
        // one): the pass takes [`FINE_POSITIONS`] steps over it, no finer than the encoder's resolution.
        let start = walk
            .iter()
            .rev()
            .find(|w| w.1 >= 0.97 * peak)
            .map_or(0.0, |w| w.0);
        let end = walk.last().map_or(0.0, |w| w.0);
        let detector_axis = inst.axis(gonio_instrument::AxisRole::DetectorArm);
        let resolution = detector_axis.map_or(0.0, |a| a.encoder_resolution_deg);
        let step = ((end - start) / f64::from(FINE_POSITIONS))
            .max(resolution)
            .max(1e-4);
        // A move shorter than the axis's arrival tolerance may leave it where it is: each position is
        // approached from this far back, the same way every time.
        let run_up = 4.0 * detector_axis.map_or(0.005, |a| a.tolerance_deg.max(a.backlash_deg));
        let mut offset = start;
        while offset <= end {
            motion
                .move_to(&Pose::new(light_deg, facing_deg - offset + run_up, 0.0, 0.0))
                .await?;
            motion
                .move_to(&Pose::new(light_deg, facing_deg - offset, 0.0, 0.0))
                .await?;
            let level = meter.read(motion, auto(overlap_nm, 10)).await?.power_w;
            fine.push((offset, level));
            offset += step;
            if let Some(r) = overlap_range(level, &ranges_w)
                && let Some(o) = meter.overlap(motion, overlap_nm, r, &ranges_w).await?
            {
                overlaps.push(o);
            }
        }
    }

    // 5. The signature per band, each point with the dark before and after it, then the darks' noise.
    let mut signature = Vec::new();
    match blank {
        None => not_done.push(
            "signature: the filter wheel has no blank position to read each point's dark through".to_string(),
        ),
        Some(b) => {
            let alphas: Vec<f64> = SIGNATURE_ALPHA_DEG
                .iter()
                .copied()
                .filter(|&a| {
                    motion
                        .safe_move(&Pose::new(light_deg, facing_deg - a, 0.0, 0.0))
                        .is_ok()
                })
                .collect();
            // Each angle as a campaign computes it, from the arms' nominal angles
            // (crate::characterise::signature::alpha_deg), not from the facing angle found: the table is then
            // looked up the way it was read.
            let nominal_alphas: Vec<f64> = alphas
                .iter()
                .map(|a| alpha_deg(light_deg, facing_deg - a))
                .collect();
            let mut raw: Vec<RawSignature> = bands
                .iter()
                .map(|&(_, nm)| RawSignature {
                    band_nm: nm,
                    alpha_deg: nominal_alphas.clone(),
                    lit_w: Vec::new(),
                    dark_w: Vec::new(),
                    t_s: Vec::new(),
                    noise_one_sample_w: f64::NAN,
                })
                .collect();
            for &a in &alphas {
                motion
                    .move_to(&Pose::new(light_deg, facing_deg - a, 0.0, 0.0))
                    .await?;
                // The dark before and after the bands, each band's taken at its own time between them: the
                // ambient light moves by about as much as the far signature in the seconds the bands take.
                let before = darks_now(motion, meter, b, &bands).await?;
                let mut lit = Vec::new();
                for &(position, nm) in &bands {
                    wheel_to(motion, position).await?;
                    let t = clock.now_s();
                    let mut v = Vec::new();
                    for _ in 0..SIGNATURE_REPEATS {
                        v.push(meter.read(motion, auto(nm, SIGNATURE_AVERAGING)).await?.power_w);
                    }
                    lit.push((0.5 * (t + clock.now_s()), mean_and_u(&v)));
                }
                let after = darks_now(motion, meter, b, &bands).await?;
                for (k, (t, value)) in lit.iter().enumerate() {
                    let (t0, (d0, u0)) = before[k];
                    let (t1, (d1, u1)) = after[k];
                    let w = if t1 > t0 { (t - t0) / (t1 - t0) } else { 0.5 };
                    raw[k].lit_w.push(*value);
                    raw[k].t_s.push(t - t0);
                    raw[k]
                        .dark_w
                        .push((d0 + w * (d1 - d0), ((1.0 - w) * u0).hypot(w * u1)));
                }
            }
            // The darks' noise per band (the meter converts current to power at the band's wavelength):
            // single-sample readings on the blank.
            for (k, &(_, nm)) in bands.iter().enumerate() {
                let mut noise = Vec::new();
                for _ in 0..NOISE_READINGS {
                    noise.push(meter.read(motion, auto(nm, 1)).await?.power_w);
                }
                let (_, u_mean) = mean_and_u(&noise);
                raw[k].noise_one_sample_w = u_mean * (noise.len() as f64).sqrt();
            }
            signature = raw;
            wheel_to(motion, brightest_position).await?;
        }
    }

    // The direct beam once more at the end: the drift over the whole step.
    motion.move_to(&facing).await?;
    let r = meter.read(motion, auto(overlap_nm, OVERLAP_AVERAGING)).await?;
    drift_readings.push((clock.now_s() - t0, r.power_w));
    Ok(EmptyHolder {
        direct: direct.into_iter().map(|d| d.1).collect(),
        overlap_nm,
        drift_readings,
        darks,
        walk,
        fine,
        overlaps,
        signature,
        not_done,
    })
}

/// The dark in every band through the blank position `blank`: per band (instrument time s, (mean W, u W)).
async fn darks_now(
    motion: &Motion<'_>,
    meter: &mut Meter,
    blank: u8,
    bands: &[(u8, f64)],
) -> Result<Vec<(f64, (f64, f64))>, CharacteriseError> {
    wheel_to(motion, blank).await?;
    let clock = motion.clock();
    let mut out = Vec::with_capacity(bands.len());
    for &(_, nm) in bands {
        let t = clock.now_s();
        let mut v = Vec::new();
        for _ in 0..SIGNATURE_REPEATS {
            v.push(meter.read(motion, auto(nm, SIGNATURE_AVERAGING)).await?.power_w);
        }
        out.push((0.5 * (t + clock.now_s()), mean_and_u(&v)));
    }
    Ok(out)
}
