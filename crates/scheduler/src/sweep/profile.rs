//! Profiles of speed along requested arcs (`follow = { ... }` in `[[plan.sweeps]]`): made from the readings of a
//! first pass over the same arcs, and applied to the pieces the path check left.
//!
//! The first pass's readings that lie on a requested arc (their geometry within [`ON_ARC_DEG`] of the arc's at
//! their swept angle) are averaged per band in bins `resolution_deg` wide, empty bins interpolated from their
//! neighbours; [`follow::speed_profile_curves`] turns the bands' curves into pieces of one speed (the slowest
//! any band needs). Averaging in bins is what makes the BRDF's bend measurable from noisy readings: the
//! relative noise of a bin's mean, divided by the bin width squared, is the noise of the bend. Noise makes the
//! profile slower than needed, never faster; a first pass swept fast smears a narrow lobe and makes its bend
//! look smaller, so the first pass should be swept at a speed whose own smearing is small at the lobe (its
//! readings' arcs a fraction of the resolution).
//!
//! Where a path piece runs beyond the stretch the first pass covered, it is swept at the profile's slowest
//! speed; a piece of one speed shorter than [`MIN_PIECE_DEG`] joins its slower neighbour.

use serde::{Deserialize, Serialize};

use super::follow::{self, FollowPiece, FollowRequest};
use super::path::{Piece, swept_role};
use super::spec::{MIN_PIECE_DEG, SweepRequest};
use super::sweep_reading_period_s;
use super::walk::sweep_time_s;
use crate::kinematics::Geometry;
use crate::plan::FollowSpec;
use crate::timing::{DETECTOR_SAMPLE_S, TimeModel};

/// A reading lies on an arc when both its directions are within this of the arc's at its swept angle (degrees).
pub const ON_ARC_DEG: f64 = 0.05;

/// Defaults of `follow = { ... }`: the floor is the top speed over this; the shortest piece and the bins (deg).
pub const DEFAULT_FLOOR_DIVISOR: f64 = 64.0;
pub const DEFAULT_MIN_PIECE_DEG: f64 = 2.0;
pub const DEFAULT_RESOLUTION_DEG: f64 = 0.5;
/// How far beyond the profile's ends its end pieces' speeds carry on (deg): [`split_piece`].
const EDGE_DEG: f64 = 1.0;

/// One reading of the first pass.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PassReading {
    /// The geometry at the middle of the arc the reading covered.
    pub geometry: Geometry,
    /// The signed swept angle there (degrees).
    pub s_deg: f64,
    pub band_nm: f64,
    /// The BRDF or the signal: only its variation along the arc matters.
    pub value: f64,
}

/// The pieces of constant speed of one requested arc (`[[plan.sweeps]]` entry, held angle, plane).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ArcProfile {
    pub entry: usize,
    pub held_deg: f64,
    pub plane_phi_deg: f64,
    pub pieces: Vec<FollowPiece>,
}

impl ArcProfile {
    /// Whether this is the profile of request `r`.
    pub fn matches(&self, r: &SweepRequest) -> bool {
        self.entry == r.entry
            && (self.held_deg - r.held_deg).abs() < 1e-9
            && (self.plane_phi_deg - r.plane_phi_deg).abs() < 1e-9
    }

    /// The slowest speed of the profile (deg/s).
    pub fn slowest_deg_s(&self) -> f64 {
        self.pieces
            .iter()
            .map(|p| p.speed_deg_s)
            .fold(f64::INFINITY, f64::min)
    }
}

/// The request the profile of `r` is computed for, from its entry's `follow` table and the time model of the
/// swept axis (its acceleration, and what a piece costs besides its motion: `walk::sweep_time_s`).
pub fn follow_request(r: &SweepRequest, spec: &FollowSpec, time: &TimeModel) -> FollowRequest {
    let model = time.axes.iter().flatten().find(|m| m.role == swept_role(r.arm));
    let period = sweep_reading_period_s(r.averaging);
    let (accel_deg_s2, per_piece_s) = model.map_or((f64::INFINITY, 0.0), |m| {
        let motion = m.leg.start_return_s;
        (
            m.accel_deg_s2,
            sweep_time_s(m, motion, period) - motion + m.leg.set_velocity_s,
        )
    });
    FollowRequest {
        integration_s: f64::from(r.averaging) * DETECTOR_SAMPLE_S,
        tolerance_rel: spec.tolerance_rel,
        top_speed_deg_s: r.speed_deg_s,
        min_speed_deg_s: spec
            .min_speed_deg_s
            .unwrap_or(r.speed_deg_s / DEFAULT_FLOOR_DIVISOR),
        min_piece_deg: spec.min_piece_deg.unwrap_or(DEFAULT_MIN_PIECE_DEG),
        relative_to: spec.relative_to.unwrap_or_default(),
        accel_deg_s2,
        per_piece_s,
    }
}

/// The first pass's curves along `r` (one per band with readings in at least three bins), on one grid of bins
/// about `resolution_deg` wide spanning the readings found on the arc.
pub fn curves_on_arc(
    r: &SweepRequest,
    readings: &[PassReading],
    resolution_deg: f64,
) -> Vec<Vec<(f64, f64)>> {
    let on: Vec<&PassReading> = readings
        .iter()
        .filter(|p| {
            p.s_deg.is_finite()
                && p.value.is_finite()
                && p.value > 0.0
                && (r.from_deg..=r.to_deg).contains(&p.s_deg)
                && on_arc(r, p)
        })
        .collect();
    let (lo, hi) = on.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), p| {
        (lo.min(p.s_deg), hi.max(p.s_deg))
    });
    if !(resolution_deg > 0.0 && hi > lo) {
        return Vec::new();
    }
    let bins = ((hi - lo) / resolution_deg).ceil().max(1.0) as usize;
    if bins < 3 {
        return Vec::new();
    }
    let width = (hi - lo) / bins as f64;
    let mut bands: Vec<f64> = on.iter().map(|p| p.band_nm).collect();
    bands.sort_by(f64::total_cmp);
    bands.dedup_by(|a, b| (*a - *b).abs() < 1e-9 || (a.is_nan() && b.is_nan()));
    let centre = |k: usize| lo + (k as f64 + 0.5) * width;
    bands
        .iter()
        .filter_map(|band| {
            let mut sum = vec![(0.0, 0usize); bins];
            for p in on.iter().filter(|p| same_band(p.band_nm, *band)) {
                let k = (((p.s_deg - lo) / width) as usize).min(bins - 1);
                sum[k].0 += p.value;
                sum[k].1 += 1;
            }
            let filled: Vec<(usize, f64)> = sum
                .iter()
                .enumerate()
                .filter(|(_, (_, n))| *n > 0)
                .map(|(k, (v, n))| (k, v / *n as f64))
                .collect();
            (filled.len() >= 3).then(|| {
                fill(&filled, bins)
                    .into_iter()
                    .enumerate()
                    .map(|(k, v)| (centre(k), v))
                    .collect()
            })
        })
        .collect()
}

/// A first-pass reading lies on the arc `r`, or, on an isotropic sample, on the arc turned about the normal (a
/// stretch the path check measured turned: `SweepRequest::turned`).
fn on_arc(r: &SweepRequest, p: &PassReading) -> bool {
    let near = |q: &SweepRequest| q.geometry_at(p.s_deg).max_direction_angle_deg(&p.geometry) <= ON_ARC_DEG;
    near(r) || (r.isotropic && near(&r.turned()))
}

fn same_band(a: f64, b: f64) -> bool {
    (a - b).abs() < 1e-9 || (a.is_nan() && b.is_nan())
}

/// Values at every bin from the filled ones (sorted by bin): linear between filled neighbours, the nearest
/// filled value beyond the ends.
fn fill(filled: &[(usize, f64)], bins: usize) -> Vec<f64> {
    (0..bins)
        .map(|k| {
            let after = filled.partition_point(|(j, _)| *j < k);
            match (
                after.checked_sub(1).map(|i| filled[i]),
                filled.get(after).copied(),
            ) {
                (_, Some((j, v))) if j == k => v,
                (Some((a, va)), Some((b, vb))) => va + (vb - va) * (k - a) as f64 / (b - a) as f64,
                (Some((_, v)), None) | (None, Some((_, v))) => v,
                (None, None) => f64::NAN,
            }
        })
        .collect()
}

/// Why an arc has no speed profile.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ProfileError {
    #[error(
        "the first pass has no readings along the {arm} sweep at {held_deg} deg in the plane at {plane_phi_deg} deg \
         from {from_deg} to {to_deg} deg (at least three bins of {resolution_deg} deg are needed)"
    )]
    NoReadings {
        arm: &'static str,
        held_deg: f64,
        plane_phi_deg: f64,
        from_deg: f64,
        to_deg: f64,
        resolution_deg: f64,
    },
    #[error(
        "no speed profile from the first pass along the {arm} sweep at {held_deg} deg in the plane at {plane_phi_deg} deg"
    )]
    NoProfile {
        arm: &'static str,
        held_deg: f64,
        plane_phi_deg: f64,
    },
}

/// The profile of request `r` from the first pass's `readings`, or why there is none. `time`: the instrument's
/// time model, for what a piece of one speed costs ([`follow_request`]).
pub fn arc_profile(
    r: &SweepRequest,
    readings: &[PassReading],
    spec: &FollowSpec,
    time: &TimeModel,
) -> Result<ArcProfile, ProfileError> {
    let resolution = spec.resolution_deg.unwrap_or(DEFAULT_RESOLUTION_DEG);
    let curves = curves_on_arc(r, readings, resolution);
    if curves.is_empty() {
        return Err(ProfileError::NoReadings {
            arm: r.arm.name(),
            held_deg: r.held_deg,
            plane_phi_deg: r.plane_phi_deg,
            from_deg: r.from_deg,
            to_deg: r.to_deg,
            resolution_deg: resolution,
        });
    }
    let mut pieces = follow::speed_profile_curves(&curves, &follow_request(r, spec, time));
    // The profile runs between the first and the last bin's centre; the first pass covered half a bin more
    // at each end.
    let half_bin = (curves[0][1].0 - curves[0][0].0) / 2.0;
    if let Some(p) = pieces.first_mut() {
        p.from_deg -= half_bin;
    }
    if let Some(p) = pieces.last_mut() {
        p.to_deg += half_bin;
    }
    if pieces.is_empty() {
        return Err(ProfileError::NoProfile {
            arm: r.arm.name(),
            held_deg: r.held_deg,
            plane_phi_deg: r.plane_phi_deg,
        });
    }
    Ok(ArcProfile {
        entry: r.entry,
        held_deg: r.held_deg,
        plane_phi_deg: r.plane_phi_deg,
        pieces,
    })
}

/// A path piece cut where the profile's speed changes: the sub-pieces and their speeds, in increasing angle.
pub fn split_piece(r: &SweepRequest, piece: &Piece, profile: &ArcProfile) -> Vec<(Piece, f64)> {
    let (a, b) = (piece.from_deg, piece.to_deg);
    let slowest = profile.slowest_deg_s();
    // Beyond the profile (the first pass's readings stop short of the arc's ends by up to a bin or so), its end
    // piece's speed carries on for EDGE_DEG: a sliver at another speed would be a move of its own, for a
    // fraction of a degree; farther out, where the first pass saw nothing, the slowest.
    let (first, last) = (profile.pieces.first(), profile.pieces.last());
    let speed_at = |s: f64| {
        profile
            .pieces
            .iter()
            .find(|p| p.from_deg <= s && s <= p.to_deg)
            .or(first.filter(|p| s < p.from_deg && p.from_deg - s <= EDGE_DEG))
            .or(last.filter(|p| s > p.to_deg && s - p.to_deg <= EDGE_DEG))
            .map_or(slowest, |p| p.speed_deg_s)
    };
    let mut cuts: Vec<f64> = vec![a];
    let edges = [
        first.map(|p| p.from_deg - EDGE_DEG),
        last.map(|p| p.to_deg + EDGE_DEG),
    ];
    cuts.extend(
        profile
            .pieces
            .iter()
            .flat_map(|p| [p.from_deg, p.to_deg])
            .chain(edges.into_iter().flatten())
            .filter(|x| *x > a && *x < b),
    );
    cuts.push(b);
    cuts.sort_by(f64::total_cmp);
    cuts.dedup_by(|x, y| (*x - *y).abs() < 1e-9);
    // (from, to, speed), equal neighbours joined.
    let mut runs: Vec<(f64, f64, f64)> = Vec::new();
    for w in cuts.windows(2) {
        let v = speed_at((w[0] + w[1]) / 2.0);
        match runs.last_mut() {
            Some(last) if last.2 == v => last.1 = w[1],
            _ => runs.push((w[0], w[1], v)),
        }
    }
    // Too short to be a move of its own: into the slower neighbour, at the slower speed.
    while runs.len() > 1 {
        let Some(i) = (0..runs.len()).find(|&i| runs[i].1 - runs[i].0 < MIN_PIECE_DEG) else {
            break;
        };
        let j = match (i.checked_sub(1), (i + 1 < runs.len()).then_some(i + 1)) {
            (Some(l), Some(n)) => {
                if runs[l].2 <= runs[n].2 {
                    l
                } else {
                    n
                }
            }
            (Some(l), None) => l,
            (None, Some(n)) => n,
            (None, None) => break,
        };
        let (lo, hi) = (i.min(j), i.max(j));
        runs[lo] = (runs[lo].0, runs[hi].1, runs[lo].2.min(runs[hi].2));
        runs.remove(hi);
    }
    let role = swept_role(r.arm);
    let (x0, x1) = (piece.from_pose.get(role), piece.to_pose.get(role));
    let pose_at = |s: f64| {
        let mut pose = piece.from_pose;
        if b > a {
            pose.set(role, x0 + (x1 - x0) * (s - a) / (b - a));
        }
        pose
    };
    runs.into_iter()
        .map(|(from, to, v)| {
            let sub = Piece {
                from_deg: from,
                to_deg: to,
                from_pose: if from == a { piece.from_pose } else { pose_at(from) },
                to_pose: if to == b { piece.to_pose } else { pose_at(to) },
                turned: piece.turned,
            };
            (sub, v)
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::kinematics::Pose;
    use crate::plan::SweptArm;

    fn request() -> SweepRequest {
        SweepRequest {
            entry: 0,
            arm: SweptArm::Detector,
            held_deg: 30.0,
            plane_phi_deg: 0.0,
            from_deg: -80.0,
            to_deg: 80.0,
            speed_deg_s: 20.0,
            averaging: 10,
            isotropic: false,
        }
    }

    fn time() -> TimeModel {
        TimeModel::new(&gonio_instrument::InstrumentFile::simulated().instrument)
    }

    fn follow(tolerance_rel: f64) -> FollowSpec {
        FollowSpec {
            first_pass: "first".to_string(),
            tolerance_rel,
            min_speed_deg_s: None,
            min_piece_deg: None,
            resolution_deg: None,
            relative_to: None,
        }
    }

    /// A gloss lobe at the specular direction (30 deg) a few degrees wide on a diffuse floor.
    fn lobe(s: f64) -> f64 {
        0.1 + 5.0 * (-((s - 30.0) / 3.0).powi(2)).exp()
    }

    /// Readings of `r` every `step` degrees in two bands (the second a third lower), between `from` and `to`.
    fn pass(r: &SweepRequest, from: f64, to: f64, step: f64) -> Vec<PassReading> {
        let n = ((to - from) / step).round() as usize;
        (0..=n)
            .flat_map(|i| {
                let s = from + i as f64 * step;
                [(450.0, 1.0), (650.0, 1.0 / 3.0)].map(|(band_nm, k)| PassReading {
                    geometry: r.geometry_at(s),
                    s_deg: s,
                    band_nm,
                    value: k * lobe(s),
                })
            })
            .collect()
    }

    #[test]
    fn the_first_pass_is_binned_per_band_along_its_own_arc_only() {
        let r = request();
        // Readings every 0.07 deg: no reading falls on a bin's edge.
        let mine = pass(&r, -60.0, 70.0, 0.07);
        let mut readings = mine.clone();
        // Another incidence's arc, and a reading off every arc: left out.
        let other = SweepRequest { held_deg: 45.0, ..r };
        readings.extend(
            pass(&other, -60.0, 70.0, 1.0)
                .into_iter()
                .map(|p| PassReading { value: 1e3, ..p }),
        );
        readings.push(PassReading {
            geometry: Geometry::new(30.0, 0.0, 40.0, 90.0),
            s_deg: 40.0,
            band_nm: 450.0,
            value: 1e3,
        });
        let curves = curves_on_arc(&r, &readings, 0.5);
        assert_eq!(curves.len(), 2);
        let grid = &curves[0];
        let (lo, hi) = (-60.0, mine.last().unwrap().s_deg);
        assert_eq!(grid.len(), 260);
        let width = (hi - lo) / 260.0;
        assert!(
            (grid[0].0 - (lo + width / 2.0)).abs() < 1e-9 && (grid[259].0 - (hi - width / 2.0)).abs() < 1e-9
        );
        for (c, band) in curves.iter().zip([450.0, 650.0]) {
            for (s, v) in c {
                // Each bin's value: the mean of the band's readings within half a bin of its centre.
                let inside: Vec<f64> = mine
                    .iter()
                    .filter(|p| p.band_nm == band && (p.s_deg - s).abs() < width / 2.0)
                    .map(|p| p.value)
                    .collect();
                let mean = inside.iter().sum::<f64>() / inside.len() as f64;
                assert!((v / mean - 1.0).abs() < 1e-12, "at {s}: {v} against {mean}");
            }
        }
    }

    #[test]
    fn empty_bins_are_interpolated_and_too_few_readings_give_no_curve() {
        let r = request();
        let mut readings = pass(&r, -20.0, 20.0, 0.05);
        readings.retain(|p| !(0.0..5.0).contains(&p.s_deg));
        let curves = curves_on_arc(&r, &readings, 0.5);
        let at = |s: f64| {
            curves[0]
                .iter()
                .find(|(x, _)| (x - s).abs() < 0.26)
                .map(|p| p.1)
                .unwrap()
        };
        let (a, b) = (at(-0.25), at(5.25));
        assert!((at(2.25) - (a + (b - a) * 5.0 / 11.0)).abs() < 1e-9);
        assert!(curves_on_arc(&r, &pass(&r, 0.0, 1.0, 0.5), 0.5).is_empty());
        assert!(curves_on_arc(&r, &[], 0.5).is_empty());
        let err = arc_profile(&r, &[], &follow(1e-3), &time())
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("no readings along the detector sweep at 30 deg"),
            "{err}"
        );
    }

    #[test]
    fn the_profile_slows_down_at_the_lobe_only() {
        let r = request();
        let profile = arc_profile(&r, &pass(&r, -80.0, 80.0, 0.02), &follow(1e-4), &time()).expect("profile");
        let at = |s: f64| {
            profile
                .pieces
                .iter()
                .find(|p| p.from_deg <= s && s <= p.to_deg)
                .unwrap()
        };
        assert_eq!(at(-40.0).speed_deg_s, 20.0);
        assert!(at(30.0).speed_deg_s < 5.0, "{:?}", at(30.0));
        assert!(at(30.0).speed_deg_s >= 20.0 / DEFAULT_FLOOR_DIVISOR);
        assert!(
            profile.pieces.iter().all(|p| p.smearing_rel <= 1e-4),
            "{profile:?}"
        );
        // The flanks bend (relative to the value) more than the top.
        assert!(profile.slowest_deg_s() <= at(30.0).speed_deg_s);
        assert!(
            profile
                .pieces
                .iter()
                .any(|p| p.speed_deg_s == profile.slowest_deg_s())
        );
        assert!(profile.matches(&r) && !profile.matches(&SweepRequest { held_deg: 45.0, ..r }));
    }

    #[test]
    fn a_path_piece_is_cut_where_the_speed_changes_with_its_poses_on_the_line() {
        let r = request();
        let piece = Piece {
            from_deg: -10.0,
            to_deg: 60.0,
            from_pose: Pose::new(-30.0, -10.0, 0.0, 0.0),
            to_pose: Pose::new(-30.0, 60.0, 0.0, 0.0),
            turned: false,
        };
        let p = |from_deg: f64, to_deg: f64, speed_deg_s: f64| FollowPiece {
            from_deg,
            to_deg,
            speed_deg_s,
            smearing_rel: 0.0,
        };
        let profile = ArcProfile {
            entry: 0,
            held_deg: 30.0,
            plane_phi_deg: 0.0,
            // The first pass covered -50 to 50: beyond, the slowest speed.
            pieces: vec![
                p(-50.0, 20.0, 20.0),
                p(20.0, 20.05, 10.0),
                p(20.05, 40.0, 2.0),
                p(40.0, 50.0, 20.0),
            ],
        };
        let cut = split_piece(&r, &piece, &profile);
        let spans: Vec<(f64, f64, f64)> = cut.iter().map(|(q, v)| (q.from_deg, q.to_deg, *v)).collect();
        // The 0.05-degree piece joins its slower neighbour; beyond the first pass (50), the end piece's speed
        // for a degree, then the slowest.
        assert_eq!(
            spans,
            vec![
                (-10.0, 20.0, 20.0),
                (20.0, 40.0, 2.0),
                (40.0, 51.0, 20.0),
                (51.0, 60.0, 2.0)
            ]
        );
        // A path that ends just past the first pass's end is no sliver at another speed.
        let short = Piece {
            to_deg: 50.3,
            to_pose: Pose::new(-30.0, 50.3, 0.0, 0.0),
            ..piece
        };
        let last = split_piece(&r, &short, &profile).pop().expect("pieces");
        assert_eq!((last.0.from_deg, last.0.to_deg, last.1), (40.0, 50.3, 20.0));
        for (q, _) in &cut {
            assert!((q.from_pose.detector_deg - q.from_deg).abs() < 1e-9);
            assert!((q.to_pose.detector_deg - q.to_deg).abs() < 1e-9);
            assert_eq!(q.from_pose.light_deg, -30.0);
        }
        assert_eq!(cut[0].0.from_pose, piece.from_pose);
        assert_eq!(cut[3].0.to_pose, piece.to_pose);
    }
}
