//! Adaptive plans: a short first pass, then the rest of the budget where the BRDF is non-negligible and varies
//! fast, batch by batch, until an error estimate falls below a target or a budget runs out.
//!
//! Domain: isotropic samples, in (theta_i, theta_o, delta_phi) with theta_i <= theta_o (reciprocity covers the
//! rest). Anisotropic samples are refused for now (`[plan.adaptive]`).
//!
//! - Candidates: a grid at `resolution_deg` in theta and 2 x that in delta_phi, filtered by the constraints
//!   (static rules, the instrument's kinematics, and the arm separation with the backlash overshoot margin, as
//!   the plan builder applies them to a batch), plus, at each batch, the midpoints (in theta_i, theta_o,
//!   delta_phi) between every measured point and its K nearest measured neighbours: they refine below the grid
//!   where the BRDF changes fast (a specular lobe near grazing is narrower than any practical grid), down to an
//!   eighth of the grid step. Midpoints are checked for reachability only when picked.
//! - First pass: in-plane sweeps (both sides of the normal) at `first_pass_theta_i_deg` incidences, theta_o in
//!   steps of `first_pass_step_deg`: the specular lobe and the grazing behaviour show up there. With
//!   `first_pass_sweeps`, the same arcs are swept instead (the detector through the plane of incidence, from
//!   grazing to grazing: [`Adaptive::first_pass_sweeps`]) and every sweep reading counts, binned at half the
//!   candidate grid's step ([`Adaptive::sweep_bin`]); the budget then counts the later passes' points only
//!   ([`Adaptive::next_batch_counting`]), and the first of them is placed from the sweeps alone. Bins an eighth
//!   of the step wide (the finest refinement) were tried first (BENCHMARKS.md section 2's swept rows, gold at
//!   3,200 points: relative RMS 0.19 against 0.12 for a first pass of points): so dense a line of values fills
//!   every candidate's K nearest near the plane, and the interpolation and the estimate there see only the arc.
//! - Refinement: values are compared as `u = ln(1 + f)` (f in 1/sr), so that a lobe of 100/sr and a diffuse base of
//!   0.1/sr both count. For each unmeasured candidate, take its `K` nearest measured points (distance: the
//!   Euclidean distance between the stacked unit vectors (wi, wo) in the canonical phi_i = 0 frame, about the
//!   angle in radians); its local error estimate is `(max u - min u) x min(1, d / d0)^2`, d the distance to the
//!   nearest measured point and d0 the first-pass step. The square weighs the size of the unmeasured
//!   neighbourhood, not only its variation: small errors over the wide tails of a lobe add up to as much as
//!   large ones in its narrow core (with a linear factor, the campaign benchmark's log error on gold was 1.6
//!   times higher at 800 points; cubes did no better than squares). The batch takes the highest estimates, each
//!   pick lowering the estimates of candidates near it so that a batch spreads along a lobe instead of piling up;
//!   ties (a flat region, or a BRDF that is 0 everywhere off a delta) go to the candidate farthest from every
//!   measured and picked point, so a batch is always full.
//! - Stop: when the largest estimate is below `target_error` (a heuristic error in `u` units, roughly a relative
//!   error where f is large), when `budget_points` are measured, or when `budget_s` of instrument time has passed.
//! - [`Adaptive::reconstruct`] is the interpolation the estimate assumes (inverse-distance weighting of `u` over
//!   the K nearest points); the tests compare it against a uniform grid of the same size.

//!
//! The specs, the candidate grid and the batch picking are here; the first pass's incidences and sweeps in
//! `first_pass`; the k-d tree and the interpolation over the nearest measured points in `neighbours`; each
//! candidate's nearest points kept from one batch to the next in `memo`.

mod first_pass;
mod memo;
mod neighbours;

pub use first_pass::MAX_FIRST_PASS_INCIDENCES;
use first_pass::{dedup_geometries, first_pass_incidences};
pub use memo::BatchMemo;
use neighbours::{KdTree, reconstruct_embedded};

use gonio_brdf::geometry::Direction;

use crate::constraints::Constraints;
use crate::kinematics::{Geometry, Kinematics, Pose};
use crate::plan::{AdaptiveSpec, BuildContext, PlanError};
use crate::timing::TimeModel;

/// Neighbours used by the estimate and the interpolation.
const K: usize = 8;

/// A measured point: geometry and BRDF value (1/sr).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Measured {
    pub geometry: Geometry,
    pub value: f64,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum StopReason {
    TargetReached,
    PointBudget,
    TimeBudget,
    NoCandidates,
}

/// The next batch, or why there is none.
#[derive(Debug, Clone, PartialEq)]
pub struct Batch {
    pub geometries: Vec<Geometry>,
    /// Set when the campaign should stop (then `geometries` is empty).
    pub done: Option<StopReason>,
    /// Largest local error estimate before this batch.
    pub error_estimate: f64,
}

/// The canonical embedding of an isotropic geometry: (wi, wo) stacked, phi_i = 0, theta_i <= theta_o.
fn embed(g: &Geometry) -> [f64; 6] {
    let (mut ti, mut to) = (g.theta_i_deg, g.theta_o_deg);
    if ti > to {
        std::mem::swap(&mut ti, &mut to);
    }
    let wi = Direction::from_spherical_deg(ti, 0.0);
    let wo = Direction::from_spherical_deg(to, g.delta_phi_deg());
    [wi.x(), wi.y(), wi.z(), wo.x(), wo.y(), wo.z()]
}

fn dist2(a: &[f64; 6], b: &[f64; 6]) -> f64 {
    a.iter().zip(b).map(|(x, y)| (x - y) * (x - y)).sum()
}

/// Geometries closer than this (Euclidean distance of the embeddings, about radians) are one geometry.
const SAME_GEOMETRY: f64 = 1e-6;

fn transform(f: f64) -> f64 {
    f.max(0.0).ln_1p()
}

/// An adaptive planner for one campaign.
#[derive(Debug, Clone)]
pub struct Adaptive {
    spec: AdaptiveSpec,
    candidates: Vec<(Geometry, [f64; 6])>,
    first: Vec<Geometry>,
    /// The first pass's incidences (degrees).
    incidences: Vec<f64>,
    /// The grazing limit: the candidates' and the first pass's largest theta (degrees).
    theta_max_deg: f64,
    d0: f64,
    reach: Reach,
}

/// Whether the instrument can measure an isotropic geometry, with the same rules the plan builder applies to a
/// batch (static constraints, an axis solution, and arms apart by the separation plus the backlash overshoot
/// margin); a candidate the builder would drop would otherwise keep the top estimate and be proposed forever.
#[derive(Debug, Clone)]
struct Reach {
    constraints: Constraints,
    kin: Kinematics,
    hint: Pose,
    margin_deg: f64,
}

impl Reach {
    fn ok(&self, g: &Geometry) -> bool {
        let (wi, wo) = g.directions();
        if self.constraints.check_directions(&wi, &wo).is_err() {
            return false;
        }
        let rotation = self.hint.rotation_deg;
        // Either way round (reciprocity lets the builder measure the reciprocal instead).
        [(wi, wo), (wo, wi)].iter().any(|(a, b)| {
            self.kin
                .isotropic_solutions(a, b, rotation, &self.hint)
                .is_ok_and(|poses| {
                    poses.iter().any(|(p, _)| {
                        self.constraints
                            .separation_ok(p.arm_separation_deg() - self.margin_deg)
                    })
                })
        })
    }
}

impl Adaptive {
    pub fn new(spec: &AdaptiveSpec, ctx: &BuildContext) -> Result<Adaptive, PlanError> {
        let bad = |key: &str, msg: String| PlanError::Invalid {
            table: ".adaptive".into(),
            key: key.into(),
            message: msg,
        };
        if !ctx.traits.isotropic {
            return Err(bad(
                "budget_points",
                "adaptive plans need an isotropic sample for now; use [plan.grid]".into(),
            ));
        }
        if spec.budget_points == 0 {
            return Err(bad("budget_points", "expected at least 1".into()));
        }
        if spec.batch_points == 0 {
            return Err(bad("batch_points", "expected at least 1".into()));
        }
        for (key, v) in [
            ("first_pass_step_deg", spec.first_pass_step_deg),
            ("resolution_deg", spec.resolution_deg),
        ] {
            if !(v.is_finite() && (0.5..=45.0).contains(&v)) {
                return Err(bad(key, format!("expected degrees in [0.5, 45], got {v}")));
            }
        }
        if !(spec.target_error.is_finite() && spec.target_error >= 0.0) {
            return Err(bad(
                "target_error",
                format!("expected >= 0, got {}", spec.target_error),
            ));
        }
        if let Some(s) = spec.budget_s
            && !(s.is_finite() && s > 0.0)
        {
            return Err(bad("budget_s", format!("expected seconds > 0, got {s}")));
        }
        if let Some(f) = &spec.first_pass_sweeps {
            // The sweep's own checks (the axis's top speed among them) follow when the campaign builds them.
            if !(f.speed_deg_s.is_finite() && f.speed_deg_s > 0.0) {
                return Err(bad(
                    "first_pass_sweeps",
                    format!("speed_deg_s: expected deg/s > 0, got {}", f.speed_deg_s),
                ));
            }
            if f.averaging == 0 {
                return Err(bad("first_pass_sweeps", "averaging: expected at least 1".into()));
            }
        }
        let incidences = match &spec.first_pass_theta_i_deg {
            Some(v) => first_pass_incidences(v)?,
            None => vec![0.0, 30.0, 60.0],
        };
        let reach = Reach {
            constraints: Constraints::new(ctx.instrument, ctx.sample_radius_mm),
            kin: Kinematics::new(ctx.instrument),
            hint: ctx.start.unwrap_or(Pose::new(0.0, 0.0, 0.0, 0.0)),
            margin_deg: TimeModel::new(ctx.instrument).arm_overshoot_margin_deg(),
        };
        let reachable = |g: &Geometry| reach.ok(g);
        let theta_max = ctx.instrument.safety.grazing_limit_deg;
        let steps = |step: f64, max: f64| -> Vec<f64> {
            let n = (max / step + 1e-9).floor() as usize;
            (0..=n).map(|k| k as f64 * step).collect()
        };
        let thetas = steps(spec.resolution_deg, theta_max);
        let phis = steps(2.0 * spec.resolution_deg, 180.0);
        let mut candidates = Vec::new();
        for (a, ti) in thetas.iter().enumerate() {
            for to in &thetas[a..] {
                for dp in &phis {
                    if (*ti == 0.0 || *to == 0.0) && *dp != 0.0 {
                        continue;
                    }
                    let g = Geometry::new(*ti, 0.0, *to, *dp);
                    if reachable(&g) {
                        candidates.push((g, embed(&g)));
                    }
                }
            }
        }
        let mut sweeps = Vec::new();
        for ti in &incidences {
            for to in steps(spec.first_pass_step_deg, theta_max) {
                for dp in [180.0, 0.0] {
                    if to == 0.0 && dp == 0.0 {
                        continue;
                    }
                    sweeps.push(Geometry::new(*ti, 0.0, to, dp));
                }
            }
        }
        // Reciprocal pairs of the sweeps (theta_i and theta_o swapped) are one geometry: keep the first.
        let mut first = dedup_geometries(sweeps);
        first.retain(|g| reachable(g));
        // The first pass takes at most a quarter of the budget.
        let cap = (spec.budget_points as usize / 4).max(1);
        if first.len() > cap {
            let stride = first.len() as f64 / cap as f64;
            first = (0..cap).map(|k| first[(k as f64 * stride) as usize]).collect();
        }
        let d0 = 2.0 * (spec.first_pass_step_deg.to_radians() / 2.0).sin();
        Ok(Adaptive {
            spec: spec.clone(),
            candidates,
            first,
            incidences,
            theta_max_deg: theta_max,
            d0,
            reach,
        })
    }

    /// The first pass of points (isotropic geometries, phi_i = 0); with `first_pass_sweeps`, what the planner
    /// falls back to when the sweeps gave no valid value.
    pub fn first_pass(&self) -> Vec<Geometry> {
        self.first.clone()
    }

    /// Number of reachable candidates.
    pub fn candidate_count(&self) -> usize {
        self.candidates.len()
    }

    /// The interpolated BRDF at `g` from the measured points (inverse-distance weighting of ln(1 + f)).
    pub fn reconstruct(&self, measured: &[Measured], g: &Geometry) -> f64 {
        self.reconstruct_all(measured, std::slice::from_ref(g))
            .first()
            .copied()
            .unwrap_or(0.0)
    }

    /// [`Adaptive::reconstruct`] at many geometries.
    pub fn reconstruct_all(&self, measured: &[Measured], at: &[Geometry]) -> Vec<f64> {
        let tree = KdTree::new(
            measured
                .iter()
                .map(|m| (embed(&m.geometry), transform(m.value)))
                .collect(),
        );
        let mut near = Vec::with_capacity(K + 1);
        at.iter()
            .map(|g| {
                tree.nearest(&embed(g), K, &mut near);
                reconstruct_embedded(&near).exp_m1()
            })
            .collect()
    }

    /// The next batch given everything measured so far (`elapsed_s` of instrument time), every entry of
    /// `measured` a point of the budget.
    pub fn next_batch(&self, measured: &[Measured], elapsed_s: f64) -> Batch {
        self.next_batch_counting(measured, measured.len(), elapsed_s)
    }

    /// [`Adaptive::next_batch`] when only `points` of `measured` count against the budget (the others: a
    /// first pass of sweeps, binned by [`Adaptive::sweep_bin`]).
    pub fn next_batch_counting(&self, measured: &[Measured], points: usize, elapsed_s: f64) -> Batch {
        self.next_batch_remembering(measured, points, elapsed_s, &mut BatchMemo::new())
    }

    /// [`Adaptive::next_batch_counting`] with the candidates' neighbours kept in `memo` from the batch before
    /// (the same batch as without it, found faster: `memo`'s module doc). Hold one memo per run.
    pub fn next_batch_remembering(
        &self,
        measured: &[Measured],
        points: usize,
        elapsed_s: f64,
        memo: &mut BatchMemo,
    ) -> Batch {
        if measured.is_empty() {
            return Batch {
                geometries: self.first_pass(),
                done: None,
                error_estimate: f64::INFINITY,
            };
        }
        let budget = self.spec.budget_points as usize;
        let stop = |done, error_estimate| Batch {
            geometries: Vec::new(),
            done: Some(done),
            error_estimate,
        };
        let embedded: Vec<([f64; 6], f64)> = measured
            .iter()
            .map(|m| (embed(&m.geometry), transform(m.value)))
            .collect();
        let fixed: Vec<[f64; 6]> = self.candidates.iter().map(|c| c.1).collect();
        memo.update(&fixed, &embedded);
        let tree = KdTree::new(embedded);
        let min_d = self.min_spacing();
        // The estimate of a candidate from its nearest measured points (squared distance, u), nearest first;
        // None when it is already measured, or closer to a measured point than the finest spacing.
        let estimate = |near: &mut dyn Iterator<Item = (f64, f64)>| -> Option<(f64, f64)> {
            let (d2, u) = near.next()?;
            let d = d2.sqrt();
            if d < min_d.max(1e-7) {
                return None;
            }
            let (lo, hi) = near.fold((u, u), |(lo, hi), (_, u)| (lo.min(u), hi.max(u)));
            let r = (d / self.d0).min(1.0);
            Some(((hi - lo) * r * r, d))
        };
        // Candidates: the fixed grid, plus the midpoints between each measured point and its neighbours, which
        // refine below the grid where the values change fast (module doc).
        let mut pool: Vec<Candidate> = self
            .candidates
            .iter()
            .enumerate()
            .filter_map(|(j, (g, e))| {
                let (estimate, nearest) = estimate(&mut memo.nearest(j))?;
                Some(Candidate {
                    geometry: *g,
                    embedded: *e,
                    checked: true,
                    estimate,
                    nearest,
                })
            })
            .collect();
        let mut near = Vec::with_capacity(K + 2);
        let mut near_u = Vec::with_capacity(K + 1);
        let canon: Vec<[f64; 3]> = measured.iter().map(|m| canonical(&m.geometry)).collect();
        for (a, ca) in canon.iter().enumerate() {
            tree.nearest_ids(&embed(&measured[a].geometry), K + 1, &mut near);
            for &(d2, slot) in near.iter() {
                let b = tree.ids[slot];
                // Each pair once, and only pairs far enough apart for their midpoint to be new.
                if b <= a || d2 < 4.0 * min_d * min_d {
                    continue;
                }
                let cb = canon[b];
                let g = Geometry::new(
                    0.5 * (ca[0] + cb[0]),
                    0.0,
                    0.5 * (ca[1] + cb[1]),
                    0.5 * (ca[2] + cb[2]),
                );
                let embedded = embed(&g);
                tree.nearest(&embedded, K, &mut near_u);
                if let Some((estimate, nearest)) = estimate(&mut near_u.iter().copied()) {
                    pool.push(Candidate {
                        geometry: g,
                        embedded,
                        checked: false,
                        estimate,
                        nearest,
                    });
                }
            }
        }
        let error_estimate = pool.iter().map(|c| c.estimate).fold(0.0, f64::max);
        if points >= budget {
            return stop(StopReason::PointBudget, error_estimate);
        }
        if self.spec.budget_s.is_some_and(|b| elapsed_s >= b) {
            return stop(StopReason::TimeBudget, error_estimate);
        }
        if pool.is_empty() {
            return stop(StopReason::NoCandidates, error_estimate);
        }
        if error_estimate < self.spec.target_error {
            return stop(StopReason::TargetReached, error_estimate);
        }
        let want = (self.spec.batch_points as usize).min(budget - points);
        // Highest estimate first; an estimate is discounted near the points already picked in this batch, and a
        // discount only lowers it, so the scan for the best stops at the first raw estimate below the best found.
        pool.sort_by(|x, y| y.estimate.total_cmp(&x.estimate));
        let mut picked: Vec<usize> = Vec::with_capacity(want);
        let mut taken = vec![false; pool.len()];
        while picked.len() < want {
            // (discounted estimate, spread, index); the spread (distance to the nearest measured or picked point)
            // breaks ties, so that where nothing varies (a flat region, or a BRDF that is 0 everywhere off a
            // delta) the batch still fills the largest gaps instead of stopping after one point.
            let mut best: Option<(f64, f64, usize)> = None;
            for (k, c) in pool.iter().enumerate() {
                if best.is_some_and(|(b, _, _)| c.estimate < b) {
                    break;
                }
                if taken[k] {
                    continue;
                }
                let mut s = c.estimate;
                let mut spread = c.nearest;
                for &p in &picked {
                    let dp = dist2(&c.embedded, &pool[p].embedded).sqrt();
                    if dp < c.nearest {
                        s *= dp / c.nearest;
                    }
                    spread = spread.min(dp);
                }
                if best.is_none_or(|(b, sp, _)| s > b || (s == b && spread > sp)) {
                    best = Some((s, spread, k));
                }
            }
            match best {
                Some((s, spread, k)) if s > 0.0 || spread > 0.0 => {
                    taken[k] = true;
                    if !pool[k].checked && !self.reach.ok(&pool[k].geometry) {
                        continue;
                    }
                    picked.push(k);
                }
                _ => break,
            }
        }
        let geometries = picked.iter().map(|k| pool[*k].geometry).collect();
        Batch {
            geometries,
            done: None,
            error_estimate,
        }
    }

    /// The finest spacing refinement goes to (chord length in the embedding, about radians): an eighth of the
    /// candidate grid's step.
    fn min_spacing(&self) -> f64 {
        2.0 * (self.spec.resolution_deg.to_radians() / 16.0).sin()
    }
}

/// A candidate of one batch.
#[derive(Debug, Clone, Copy)]
struct Candidate {
    geometry: Geometry,
    embedded: [f64; 6],
    /// False for refinement midpoints until their reachability is checked (lazily: only the picked ones).
    checked: bool,
    estimate: f64,
    /// Distance to the nearest measured point.
    nearest: f64,
}

/// (theta_i, theta_o, delta_phi) in degrees with theta_i <= theta_o.
fn canonical(g: &Geometry) -> [f64; 3] {
    let (ti, to) = if g.theta_i_deg <= g.theta_o_deg {
        (g.theta_i_deg, g.theta_o_deg)
    } else {
        (g.theta_o_deg, g.theta_i_deg)
    };
    [ti, to, g.delta_phi_deg()]
}
