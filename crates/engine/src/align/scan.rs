//! One scan through a beam on the instrument: the meter read at each position of one axis, coarse over the whole
//! profile, then fine across each edge, and the centre (crate::align::centre) with its uncertainty.

use gonio_instrument::AxisRole;
use gonio_scheduler::kinematics::Pose;

use super::AlignError;
use super::centre::{CentreError, Located, centre, edge, plateau_and_base, rough_edges};
use crate::motion::{Device, Motion};

/// Scan widths and steps (deg). The coarse scan must hold the whole profile; the fine scans cover each edge.
pub(crate) const DETECTOR_HALF_WIDTH_DEG: f64 = 1.5;
const COARSE_STEP_DEG: f64 = 0.1;
/// The reflection rises by `2 cos(theta_i)` times the tilt: the detector's width over that.
pub(crate) fn tilt_half_width_deg(theta_i_deg: f64) -> f64 {
    DETECTOR_HALF_WIDTH_DEG / (2.0 * theta_i_deg.to_radians().cos()).max(0.5)
}
/// Readings on each fine edge scan.
const FINE_POINTS: i32 = 17;

/// Read the meter at each position of `role` (the others as `at` puts them): (position deg, power W).
pub(super) async fn read_along(
    motion: &mut Motion<'_>,
    scan_name: &str,
    role: AxisRole,
    positions: &[f64],
    at: &(dyn Fn(f64) -> Pose + Sync),
) -> Result<Vec<(f64, f64)>, AlignError> {
    let det = motion.rig().detector().clone();
    let largest = meter_ranges_w(motion).iter().copied().fold(0.0, f64::max);
    let mut out = Vec::with_capacity(positions.len());
    for &x in positions {
        motion.move_to(&at(x)).await?;
        let r = motion
            .device(Device::Detector, "read the meter", || det.read_power())
            .await?;
        if r.overload && r.range_w >= largest {
            return Err(AlignError::Saturated {
                scan: scan_name.to_string(),
                power_w: r.power_w,
            });
        }
        out.push((motion.current().get(role), r.power_w));
    }
    Ok(out)
}

/// What one scan found: the profile's centre and its two half-height edges (deg), its plateau and baseline (W),
/// the width of an edge from 15 % to 85 % of the way up (deg: from the coarse readings, or the narrower window a
/// sharp edge needed for enough fine readings on it) and the readings taken.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Profile {
    pub centre: Located,
    pub low: Located,
    pub high: Located,
    pub plateau_w: f64,
    pub base_w: f64,
    pub edge_width_deg: f64,
    pub readings: usize,
}

/// A scan of `role` about `nominal` (deg, within `half_width`): coarse, then fine across each edge.
pub(crate) async fn scan(
    motion: &mut Motion<'_>,
    name: &str,
    role: AxisRole,
    nominal: f64,
    half_width: f64,
    at: &(dyn Fn(f64) -> Pose + Sync),
) -> Result<Profile, AlignError> {
    let fail = |cause| AlignError::Scan {
        scan: name.to_string(),
        cause,
    };
    let steps =
        (half_width / COARSE_STEP_DEG * if role == AxisRole::SampleTilt { 2.0 } else { 1.0 }).round() as i32;
    let step = half_width / f64::from(steps);
    let coarse_x: Vec<f64> = (-steps..=steps).map(|k| nominal + f64::from(k) * step).collect();
    let coarse = read_along(motion, name, role, &coarse_x, at).await?;
    let (plateau, base) =
        plateau_and_base(&coarse).ok_or_else(|| fail(CentreError::NoBeam { max_w: 0.0 }))?;
    // A beam is there when its top stands well above the ends: ten times their scatter (consecutive
    // differences of the three readings at each end) and ten times a floor of a thousandth of the meter's
    // smallest range.
    let floor = meter_ranges_w(motion)
        .iter()
        .copied()
        .fold(f64::INFINITY, f64::min)
        * 1e-3;
    if plateau - base <= 10.0 * floor.max(end_scatter(&coarse)) || plateau.is_nan() {
        return Err(fail(CentreError::NoBeam { max_w: plateau }));
    }
    if base.max(0.0) * 100.0 > plateau {
        return Err(fail(CentreError::NotInside { side: "low or high" }));
    }
    let level = |f: f64| base + f * (plateau - base);
    let (l, r) = rough_edges(&coarse, level(0.5)).map_err(fail)?;
    // Each edge's width from the coarse profile (15 % to 85 %), at least two coarse steps.
    let width = match (
        rough_edges(&coarse, level(0.15)),
        rough_edges(&coarse, level(0.85)),
    ) {
        (Ok((l15, r15)), Ok((l85, r85))) => ((l85 - l15).abs().max((r15 - r85).abs())).max(2.0 * step),
        _ => 2.0 * step,
    };
    let mut n = coarse.len();
    let mut found = Vec::with_capacity(2);
    // The narrowest window an edge needed (a sharp edge is narrowed until enough readings fall on it).
    let mut fine_width = width;
    for (x0, side) in [(l, "low"), (r, "high")] {
        // A sharp edge (a top-hat beam) may hold too few readings at the first fine step: narrow the window
        // about the edge's latest crossing and read again, a few times at most.
        let (mut x0, mut width) = (x0, width);
        let mut attempt = 0;
        let located = loop {
            let fine_step = 1.5 * width / f64::from(FINE_POINTS - 1);
            let half = (FINE_POINTS - 1) / 2;
            let xs: Vec<f64> = (-half..=half).map(|k| x0 + f64::from(k) * fine_step).collect();
            let pts = read_along(motion, name, role, &xs, at).await?;
            n += pts.len();
            match edge(&pts, plateau, base, side) {
                Ok(e) => break e,
                Err(CentreError::FewEdgePoints { .. }) if attempt < 4 => {
                    attempt += 1;
                    width /= 4.0;
                    if let Some(x) = crossing(&pts, level(0.5)) {
                        x0 = x;
                    }
                }
                Err(e) => return Err(fail(e)),
            }
        };
        found.push(located);
        fine_width = fine_width.min(width);
    }
    let (left, right) = (found[0], found[1]);
    // The read-back positions are quantised to the axis's encoder resolution: a centre from some ten readings
    // per edge is not known better than a tenth of it (and a noiseless simulation claims no better).
    let resolution = motion
        .rig()
        .file()
        .instrument
        .axis(role)
        .map_or(0.0, |a| a.encoder_resolution_deg);
    let mut c = centre(left, right);
    c.u = c.u.max(0.1 * resolution).max(1e-6);
    Ok(Profile {
        centre: c,
        low: left,
        high: right,
        plateau_w: plateau,
        base_w: base,
        edge_width_deg: fine_width,
        readings: n,
    })
}

/// The readings' scatter at the ends of a scan (W): the rms of consecutive differences over the first and the
/// last three readings, over sqrt(2).
fn end_scatter(samples: &[(f64, f64)]) -> f64 {
    let n = samples.len();
    if n < 6 {
        return 0.0;
    }
    let d: Vec<f64> = [0, 1, n - 3, n - 2]
        .iter()
        .map(|&i| samples[i + 1].1 - samples[i].1)
        .collect();
    (d.iter().map(|v| v * v).sum::<f64>() / (2.0 * d.len() as f64)).sqrt()
}

/// Where readings sorted by position first cross `level` (linear interpolation), either way.
fn crossing(samples: &[(f64, f64)], level: f64) -> Option<f64> {
    samples.windows(2).find_map(|w| {
        let ((x0, p0), (x1, p1)) = (w[0], w[1]);
        ((p0 - level) * (p1 - level) <= 0.0 && p1 != p0).then(|| x0 + (level - p0) * (x1 - x0) / (p1 - p0))
    })
}

/// The meter's ranges (full scale, W) as the instrument file gives them.
pub(crate) fn meter_ranges_w<'m>(motion: &'m Motion<'_>) -> &'m [f64] {
    &motion.rig().file().instrument.detector.ranges_w
}
