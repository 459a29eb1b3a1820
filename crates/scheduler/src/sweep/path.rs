//! The path check: which parts of a requested arc the instrument may sweep, and with which axis solution.
//!
//! A sweep holds every axis but one. For each axis solution ("family") of the request's geometry the swept
//! axis's physical angle is linear in the signed swept angle, `x(s) = x_ref + sigma (s - s_ref)` with
//! `sigma = +-1`, because the arm turns in the plane that holds the normal. The arc is scanned every
//! [`SCAN_STEP_DEG`] at most, each sample given to the first family under which it passes every rule (the static
//! rules of `crate::constraints`, the swept axis's limits, the arm separation with the backlash overshoot margin
//! the point plans keep, and the side of the arms the plan chose). A maximal run of samples of one family is a
//! piece; its ends are refined by bisection to [`EDGE_TOLERANCE_DEG`] towards the failing neighbour, so that a
//! piece ends within that of the first forbidden angle, never beyond it. Every sample's geometry is also checked
//! against the forward kinematics of its pose: a family that is not linear (an out-of-plane tilt) is not used.
//!
//! A forbidden zone narrower than the scan step between two samples could be missed; the zones of the rules are
//! degrees wide (the retro-reflection block, the separation) or half-planes (limits, grazing), so the step keeps
//! the check exact for any instrument file with `retro_block_deg` and `min_arm_separation_deg` above it.

use std::collections::BTreeMap;

use gonio_instrument::{AxisRole, Instrument};

use super::spec::{MIN_PIECE_DEG, SweepRequest};
use crate::constraints::{ANGLE_TOLERANCE_DEG, Constraints, Reason};
use crate::kinematics::{Kinematics, Pose};
use crate::plan::SweptArm;
use crate::timing::TimeModel;

/// Largest distance between two checked samples of an arc (degrees).
pub const SCAN_STEP_DEG: f64 = 0.05;

/// A piece's ends lie within this of the boundary of what is allowed (degrees).
pub const EDGE_TOLERANCE_DEG: f64 = 1e-6;

/// Signed reference angles tried to find the axis solutions of a request (any valid one serves), besides
/// [`ARC_REFERENCES`] angles spread over the request's own arc (a solution whose swept axis leaves its limits
/// at every fixed reference angle may still reach part of the arc).
const REFERENCE_ANGLES_DEG: [f64; 7] = [45.0, 30.0, 60.0, 15.0, 75.0, -45.0, -75.0];

/// Reference angles taken along the requested arc, both ends included.
const ARC_REFERENCES: usize = 17;

/// An axis solution along which the swept axis is linear in the swept angle.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Family {
    /// The pose at the reference angle `s_ref`.
    pose: Pose,
    s_ref: f64,
    sigma: f64,
    /// A solution of the arc turned half a turn about the normal (`SweepRequest::turned`; isotropic only).
    turned: bool,
}

/// One sweepable piece of a requested arc.
#[derive(Debug, Clone, PartialEq)]
pub struct Piece {
    /// Signed swept angle at the piece's ends, `from_deg < to_deg`.
    pub from_deg: f64,
    pub to_deg: f64,
    /// The pose at `from_deg` (every axis but the swept one holds it through the piece).
    pub from_pose: Pose,
    /// The pose at `to_deg`.
    pub to_pose: Pose,
    /// The piece measures the request turned half a turn about the normal (`SweepRequest::turned`): an
    /// isotropic sample's stretch swept without turning the sample.
    pub turned: bool,
}

/// What the check of one requested arc found.
#[derive(Debug, Clone, PartialEq)]
pub struct PathVerdict {
    pub pieces: Vec<Piece>,
    /// Degrees of the requested arc not swept, by the reason of the first rule that failed there.
    pub skipped_deg: BTreeMap<Reason, f64>,
}

/// The role a sweep moves.
pub fn swept_role(arm: SweptArm) -> AxisRole {
    match arm {
        SweptArm::Detector => AxisRole::DetectorArm,
        SweptArm::Light => AxisRole::LightArm,
    }
}

/// Everything the check needs besides the request.
#[derive(Debug)]
pub struct PathContext<'a> {
    pub instrument: &'a Instrument,
    pub kinematics: &'a Kinematics,
    pub constraints: &'a Constraints,
    pub time: &'a TimeModel,
    /// The side of the arms (`light < detector`) the plan keeps.
    pub light_below_detector: bool,
}

impl PathContext<'_> {
    /// The axis solutions of `r`; of an isotropic request, also those of the arc turned about the normal, the
    /// ones that hold the sample rotation nearest the plane's azimuth first: a stretch beyond the other arm is
    /// then measured turned, the sample held, rather than after turning the sample half a turn (the move between
    /// the stretches of an in-plane arc becomes the light arm's alone).
    fn families(&self, r: &SweepRequest) -> Vec<Family> {
        let mut out = self.families_of(r, false);
        if r.isotropic {
            out.extend(self.families_of(&r.turned(), true));
            let off = |f: &Family| {
                let d = (f.pose.rotation_deg - r.plane_phi_deg).rem_euclid(360.0);
                d.min(360.0 - d)
            };
            // Stable: among families as near, the request's own come first.
            out.sort_by(|a, b| off(a).total_cmp(&off(b)));
        }
        out
    }

    fn families_of(&self, r: &SweepRequest, turned: bool) -> Vec<Family> {
        let role = swept_role(r.arm);
        let hint = Pose::new(0.0, 0.0, 0.0, r.plane_phi_deg);
        let mut out: Vec<Family> = Vec::new();
        let along =
            (0..ARC_REFERENCES).map(|k| r.from_deg + r.length_deg() * k as f64 / (ARC_REFERENCES - 1) as f64);
        for s_ref in REFERENCE_ANGLES_DEG.into_iter().chain(along) {
            let (wi, wo) = r.geometry_at(s_ref).directions();
            let Ok(poses) = self.kinematics.solutions(&wi, &wo, &hint) else {
                continue;
            };
            for pose in poses {
                let Some(sigma) = self.slope(r, &pose, s_ref) else {
                    continue;
                };
                // The same family found from another reference angle: same held axes, same line.
                let same = |f: &Family| {
                    let x = f.pose.get(role) + f.sigma * (s_ref - f.s_ref);
                    f.sigma == sigma
                        && (x - pose.get(role)).abs() < 1e-6
                        && crate::kinematics::ROLES
                            .iter()
                            .filter(|q| **q != role)
                            .all(|q| (f.pose.get(*q) - pose.get(*q)).abs() < 1e-6)
                };
                if !out.iter().any(same) {
                    out.push(Family {
                        pose,
                        s_ref,
                        sigma,
                        turned,
                    });
                }
            }
        }
        out
    }

    /// +1 or -1 when turning the swept axis by a small angle moves the geometry along the request's arc.
    fn slope(&self, r: &SweepRequest, pose: &Pose, s_ref: f64) -> Option<f64> {
        let role = swept_role(r.arm);
        [1.0, -1.0].into_iter().find(|sigma| {
            let mut p = *pose;
            p.set(role, pose.get(role) + sigma * 0.5);
            self.matches(r, &p, s_ref + 0.5)
        })
    }

    /// True when the pose measures the request's geometry at `s`.
    fn matches(&self, r: &SweepRequest, pose: &Pose, s: f64) -> bool {
        let (wi, wo) = self.kinematics.forward(pose);
        let (ei, eo) = r.geometry_at(s).directions();
        wi.angle_to(&ei).to_degrees() < 1e-6 && wo.angle_to(&eo).to_degrees() < 1e-6
    }

    fn pose_at(&self, r: &SweepRequest, f: &Family, s: f64) -> Pose {
        let role = swept_role(r.arm);
        let mut p = f.pose;
        p.set(role, f.pose.get(role) + f.sigma * (s - f.s_ref));
        p
    }

    /// Every rule at signed angle `s` under family `f`.
    fn check(&self, r: &SweepRequest, f: &Family, s: f64) -> Result<Pose, Reason> {
        let r = &r.turned_if(f.turned);
        let (wi, wo) = r.geometry_at(s).directions();
        self.constraints.check_directions(&wi, &wo)?;
        let pose = self.pose_at(r, f, s);
        let role = swept_role(r.arm);
        if let Some(axis) = self.instrument.axis(role) {
            let x = pose.get(role);
            if x < axis.min_deg - ANGLE_TOLERANCE_DEG || x > axis.max_deg + ANGLE_TOLERANCE_DEG {
                return Err(Reason::AxisLimits);
            }
        }
        let margin = self.time.arm_overshoot_margin_deg();
        if !self.constraints.separation_ok(pose.arm_separation_deg() - margin)
            || (pose.light_deg < pose.detector_deg) != self.light_below_detector
        {
            return Err(Reason::ArmSeparation);
        }
        if !self.matches(r, &pose, s) {
            return Err(Reason::OutOfPlane);
        }
        Ok(pose)
    }

    /// The first family under which `s` passes, or the first failing rule (in `Reason` order) of all families.
    fn classify(&self, r: &SweepRequest, families: &[Family], s: f64) -> Result<usize, Reason> {
        let mut worst: Option<Reason> = None;
        for (k, f) in families.iter().enumerate() {
            match self.check(r, f, s) {
                Ok(_) => return Ok(k),
                Err(reason) => worst = Some(worst.map_or(reason, |w| w.min(reason))),
            }
        }
        Err(worst.unwrap_or(Reason::AxisLimits))
    }

    /// The furthest angle from `ok` towards `bad` (exclusive) that family `f` still passes.
    fn edge(&self, r: &SweepRequest, f: &Family, mut ok: f64, mut bad: f64) -> f64 {
        while (bad - ok).abs() > EDGE_TOLERANCE_DEG {
            let mid = 0.5 * (ok + bad);
            if self.check(r, f, mid).is_ok() {
                ok = mid;
            } else {
                bad = mid;
            }
        }
        ok
    }

    /// Check one requested arc (module doc).
    pub fn verdict(&self, r: &SweepRequest) -> PathVerdict {
        let length = r.length_deg();
        let families = self.families(r);
        let n = ((length / SCAN_STEP_DEG).ceil() as usize).max(1);
        let h = length / n as f64;
        let samples: Vec<f64> = (0..=n).map(|k| r.from_deg + h * k as f64).collect();
        let verdicts: Vec<Result<usize, Reason>> =
            samples.iter().map(|s| self.classify(r, &families, *s)).collect();

        let mut pieces = Vec::new();
        let mut k = 0;
        while k <= n {
            let Ok(f) = verdicts[k] else {
                k += 1;
                continue;
            };
            let mut end = k;
            while end < n && verdicts[end + 1] == Ok(f) {
                end += 1;
            }
            let family = &families[f];
            let from = if k == 0 {
                samples[0]
            } else {
                self.edge(r, family, samples[k], samples[k - 1])
            };
            let to = if end == n {
                samples[n]
            } else {
                self.edge(r, family, samples[end], samples[end + 1])
            };
            if to - from >= MIN_PIECE_DEG {
                pieces.push(Piece {
                    from_deg: from,
                    to_deg: to,
                    from_pose: self.pose_at(r, family, from),
                    to_pose: self.pose_at(r, family, to),
                    turned: family.turned,
                });
            }
            k = end + 1;
        }

        // Degrees not swept, shared among the failing rules by their share of the failing samples.
        let covered: f64 = pieces.iter().map(|p| p.to_deg - p.from_deg).sum();
        let mut counts: BTreeMap<Reason, usize> = BTreeMap::new();
        for v in &verdicts {
            if let Err(reason) = v {
                *counts.entry(*reason).or_default() += 1;
            }
        }
        let failing: usize = counts.values().sum();
        let missing = (length - covered).max(0.0);
        let mut skipped_deg = BTreeMap::new();
        // (Pieces shorter than MIN_PIECE_DEG between two failing zones count with their neighbours' rules.)
        if missing > EDGE_TOLERANCE_DEG * 4.0 && failing > 0 {
            for (reason, c) in counts {
                skipped_deg.insert(reason, missing * c as f64 / failing as f64);
            }
        }
        PathVerdict { pieces, skipped_deg }
    }
}
