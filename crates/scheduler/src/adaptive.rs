//! Adaptive plans: a short first pass, then the rest of the budget where the BRDF is non-negligible and varies
//! fast, batch by batch, until an error estimate falls below a target or a budget runs out.
//!
//! Domain: isotropic samples, in (theta_i, theta_o, delta_phi) with theta_i <= theta_o (reciprocity covers the
//! rest). Anisotropic samples are refused for now (`[plan.adaptive]`).
//!
//! - Candidates: a grid at `resolution_deg` in theta and 2 x that in delta_phi, filtered by the constraints
//!   (static rules and the instrument's kinematics).
//! - First pass: in-plane sweeps (both sides of the normal) at `first_pass_theta_i_deg` incidences, theta_o in
//!   steps of `first_pass_step_deg`: the specular lobe and the grazing behaviour show up there.
//! - Refinement: values are compared as `u = ln(1 + f)` (f in 1/sr), so that a lobe of 100/sr and a diffuse base of
//!   0.1/sr both count. For each unmeasured candidate, take its `K` nearest measured points (distance: the
//!   Euclidean distance between the stacked unit vectors (wi, wo) in the canonical phi_i = 0 frame, about the
//!   angle in radians); its local error estimate is `(max u - min u) x min(1, d / d0)`, d the distance to the
//!   nearest measured point and d0 the first-pass step. The batch takes the highest estimates, each pick lowering
//!   the estimates of candidates near it so that a batch spreads along a lobe instead of piling up.
//! - Stop: when the largest estimate is below `target_error` (a heuristic error in `u` units, roughly a relative
//!   error where f is large), when `budget_points` are measured, or when `budget_s` of instrument time has passed.
//! - [`Adaptive::reconstruct`] is the interpolation the estimate assumes (inverse-distance weighting of `u` over
//!   the K nearest points); the tests compare it against a uniform grid of the same size.

use gonio_brdf::geometry::Direction;
use serde::Deserialize;

use crate::constraints::Constraints;
use crate::kinematics::{Geometry, Kinematics, Pose};
use crate::plan::{BuildContext, PlanError, angle_list};

/// Neighbours used by the estimate and the interpolation.
const K: usize = 8;

/// `[plan.adaptive]`.
#[derive(Debug, Clone, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct AdaptiveSpec {
    /// Points to measure in all (first pass included).
    pub budget_points: u32,
    /// Instrument time after which to stop (s); none by default.
    #[serde(default)]
    pub budget_s: Option<f64>,
    /// Points per batch after the first pass.
    #[serde(default = "default_batch")]
    pub batch_points: u32,
    /// Stop when the largest local error estimate is below this (ln(1 + f) units).
    #[serde(default = "default_target")]
    pub target_error: f64,
    #[serde(default = "default_first_step")]
    pub first_pass_step_deg: f64,
    /// Incidence angles of the first pass; default [0, 30, 60].
    #[serde(default)]
    pub first_pass_theta_i_deg: Option<toml::Value>,
    /// Candidate grid step in theta (delta_phi uses twice this).
    #[serde(default = "default_resolution")]
    pub resolution_deg: f64,
}

fn default_batch() -> u32 {
    40
}
fn default_target() -> f64 {
    0.02
}
fn default_first_step() -> f64 {
    10.0
}
fn default_resolution() -> f64 {
    2.5
}

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

fn transform(f: f64) -> f64 {
    f.max(0.0).ln_1p()
}

/// An adaptive planner for one campaign.
#[derive(Debug, Clone)]
pub struct Adaptive {
    spec: AdaptiveSpec,
    candidates: Vec<(Geometry, [f64; 6])>,
    first: Vec<Geometry>,
    d0: f64,
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
        let incidences = match &spec.first_pass_theta_i_deg {
            Some(v) => angle_list("adaptive", "first_pass_theta_i_deg", v)?,
            None => vec![0.0, 30.0, 60.0],
        };
        let constraints = Constraints::new(ctx.instrument, ctx.sample_radius_mm);
        let kin = Kinematics::new(ctx.instrument);
        let hint = ctx.start.unwrap_or(Pose::new(0.0, 0.0, 0.0, 0.0));
        let reachable = |g: &Geometry| {
            let (wi, wo) = g.directions();
            constraints.check_directions(&wi, &wo).is_ok()
                && kin
                    .isotropic_solutions(&wi, &wo, hint.rotation_deg, &hint)
                    .is_ok()
        };
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
        let mut first = Vec::new();
        for ti in &incidences {
            for to in steps(spec.first_pass_step_deg, theta_max) {
                for dp in [180.0, 0.0] {
                    if to == 0.0 && dp == 0.0 {
                        continue;
                    }
                    let g = Geometry::new(*ti, 0.0, to, dp);
                    if reachable(&g)
                        && !first
                            .iter()
                            .any(|f: &Geometry| dist2(&embed(f), &embed(&g)) < 1e-12)
                    {
                        first.push(g);
                    }
                }
            }
        }
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
            d0,
        })
    }

    /// The first pass (isotropic geometries, phi_i = 0).
    pub fn first_pass(&self) -> Vec<Geometry> {
        self.first.clone()
    }

    /// Number of reachable candidates.
    pub fn candidate_count(&self) -> usize {
        self.candidates.len()
    }

    /// The K nearest measured points to `e`: (squared distance, u).
    fn nearest(&self, e: &[f64; 6], measured: &[([f64; 6], f64)]) -> Vec<(f64, f64)> {
        let mut best: Vec<(f64, f64)> = Vec::with_capacity(K + 1);
        for (m, u) in measured {
            let d = dist2(e, m);
            if best.len() < K || d < best[best.len() - 1].0 {
                let at = best.partition_point(|(x, _)| *x <= d);
                best.insert(at, (d, *u));
                best.truncate(K);
            }
        }
        best
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
        let pts: Vec<([f64; 6], f64)> = measured
            .iter()
            .map(|m| (embed(&m.geometry), transform(m.value)))
            .collect();
        at.iter()
            .map(|g| reconstruct_embedded(&self.nearest(&embed(g), &pts)).exp_m1())
            .collect()
    }

    /// The next batch given everything measured so far (`elapsed_s` of instrument time).
    pub fn next_batch(&self, measured: &[Measured], elapsed_s: f64) -> Batch {
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
        let pts: Vec<([f64; 6], f64)> = measured
            .iter()
            .map(|m| (embed(&m.geometry), transform(m.value)))
            .collect();
        let mut scored: Vec<(f64, usize, f64)> = Vec::new(); // (estimate, candidate, nearest distance)
        for (c, (_, e)) in self.candidates.iter().enumerate() {
            let near = self.nearest(e, &pts);
            let Some(&(d2, _)) = near.first() else { continue };
            if d2 < 1e-14 {
                continue; // already measured
            }
            let (lo, hi) = near
                .iter()
                .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), (_, u)| {
                    (lo.min(*u), hi.max(*u))
                });
            let d = d2.sqrt();
            scored.push(((hi - lo) * (d / self.d0).min(1.0), c, d));
        }
        let error_estimate = scored.iter().map(|s| s.0).fold(0.0, f64::max);
        if measured.len() >= budget {
            return stop(StopReason::PointBudget, error_estimate);
        }
        if self.spec.budget_s.is_some_and(|b| elapsed_s >= b) {
            return stop(StopReason::TimeBudget, error_estimate);
        }
        if scored.is_empty() {
            return stop(StopReason::NoCandidates, error_estimate);
        }
        if error_estimate < self.spec.target_error {
            return stop(StopReason::TargetReached, error_estimate);
        }
        let want = (self.spec.batch_points as usize).min(budget - measured.len());
        let mut picked: Vec<usize> = Vec::with_capacity(want);
        for _ in 0..want {
            // Highest estimate, discounted near the points already picked in this batch.
            let mut best: Option<(f64, usize)> = None;
            for (k, (s, c, d)) in scored.iter().enumerate() {
                let e = &self.candidates[*c].1;
                let mut s = *s;
                for p in &picked {
                    let dp = dist2(e, &self.candidates[scored[*p].1].1).sqrt();
                    if dp < *d {
                        s *= dp / d;
                    }
                }
                if best.is_none_or(|(b, _)| s > b) && !picked.contains(&k) {
                    best = Some((s, k));
                }
            }
            match best {
                Some((s, k)) if s > 0.0 || picked.is_empty() => picked.push(k),
                _ => break,
            }
        }
        let geometries = picked.iter().map(|k| self.candidates[scored[*k].1].0).collect();
        Batch {
            geometries,
            done: None,
            error_estimate,
        }
    }
}

fn reconstruct_embedded(near: &[(f64, f64)]) -> f64 {
    let mut wsum = 0.0;
    let mut vsum = 0.0;
    for (d2, u) in near {
        if *d2 < 1e-18 {
            return *u;
        }
        let w = 1.0 / d2;
        wsum += w;
        vsum += w * u;
    }
    if wsum > 0.0 { vsum / wsum } else { 0.0 }
}
