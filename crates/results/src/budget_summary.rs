//! run.json's `uncertainty`: what the points' budgets ([`crate::budget`]) add up to over a run. Relative
//! figures are each point's standard uncertainty over its value, summarised by the median over the valid
//! points with a budget; a component's figure is taken over the points that have it. Dry-runs add how often
//! the k = 2 interval covers the simulator's point truth, and the rms of (value - truth) / u: the check that
//! the budget is honest.

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};

use crate::fit::observations::median;
use crate::points::Point;

/// One component over a run.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ComponentSummary {
    /// How many valid points carry the component.
    pub points: u64,
    /// Median of u / value over those points (k = 1).
    pub median_relative_u: f64,
    /// How many points have it as their largest component.
    pub largest_in: u64,
    /// The groups that share it (`campaign`, `band-550`, ...); empty: independent per point.
    pub shared_by: Vec<String>,
}

/// Against the simulator's point truth (dry-runs).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct BudgetCheck {
    pub points: u64,
    /// Fraction of points whose k = 2 interval holds the truth.
    pub coverage_k2: f64,
    /// rms of (value - truth) / brdf_u_sr (1 for an honest budget).
    pub rms_z: f64,
}

/// The run's uncertainty summary.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct BudgetSummary {
    /// Valid points with a budget.
    pub points: u64,
    /// Median of brdf_u_sr / brdf_sr (k = 1).
    pub median_relative_u: f64,
    /// Median of the independent part over the value (k = 1).
    pub median_relative_u_independent: f64,
    pub components: BTreeMap<String, ComponentSummary>,
    /// Dry-runs only.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub against_point_truth: Option<BudgetCheck>,
}

/// The summary of a run's points; `None` when no valid point has a budget (older runs).
pub fn summarise(points: &[Point]) -> Option<BudgetSummary> {
    let with: Vec<(&Point, f64)> = points
        .iter()
        .filter(|p| !p.budget.entries.is_empty())
        .filter_map(|p| {
            p.value()
                .filter(|f| *f != 0.0 && f.is_finite())
                .map(|f| (p, f.abs()))
        })
        .collect();
    if with.is_empty() {
        return None;
    }
    let mut relative = BTreeMap::<String, Vec<f64>>::new();
    let mut largest = BTreeMap::<String, u64>::new();
    let mut shared_by = BTreeMap::<String, Vec<String>>::new();
    for (p, f) in &with {
        for (name, u) in p.budget.by_component() {
            relative.entry(name.to_string()).or_default().push(u / f);
        }
        for e in &p.budget.entries {
            let groups = shared_by.entry(e.component.clone()).or_default();
            if let Some(g) = &e.shared
                && !groups.contains(g)
            {
                groups.push(g.clone());
            }
        }
        if let Some(top) = p.budget.largest(1).first() {
            *largest.entry(top.0.to_string()).or_default() += 1;
        }
    }
    let components = relative
        .into_iter()
        .map(|(name, v)| {
            let summary = ComponentSummary {
                points: v.len() as u64,
                median_relative_u: median(v),
                largest_in: largest.get(&name).copied().unwrap_or(0),
                shared_by: shared_by.remove(&name).unwrap_or_default(),
            };
            (name, summary)
        })
        .collect();
    let (mut n, mut covered, mut z2) = (0u64, 0u64, 0.0);
    for (p, _) in &with {
        let (Some(f), Some(t), Some(u)) = (p.value(), p.truth_point_sr, p.brdf_u_sr) else {
            continue;
        };
        if !t.is_finite() || u <= 0.0 {
            continue;
        }
        n += 1;
        let z = (f - t) / u;
        if z.abs() <= 2.0 {
            covered += 1;
        }
        z2 += z * z;
    }
    Some(BudgetSummary {
        points: with.len() as u64,
        median_relative_u: median(with.iter().map(|(p, f)| p.budget.total_sr() / f).collect()),
        median_relative_u_independent: median(
            with.iter().map(|(p, f)| p.budget.independent_sr() / f).collect(),
        ),
        components,
        against_point_truth: (n > 0).then(|| BudgetCheck {
            points: n,
            coverage_k2: covered as f64 / n as f64,
            rms_z: (z2 / n as f64).sqrt(),
        }),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::budget::{Budget, components, groups};

    fn point(f: f64, truth: Option<f64>, budget: Budget) -> Point {
        Point {
            brdf_u_sr: Some(budget.total_sr()),
            t_s: Some(1.0),
            budget,
            truth_point_sr: truth,
            truth_aperture_sr: truth,
            ..Point::at(550.0, [0.0, 0.0, 30.0, 180.0], f)
        }
    }

    #[test]
    fn medians_largest_components_and_the_check_against_truth() {
        let mut a = Budget::default();
        a.add(components::SIGNAL_NOISE, 0.003, None);
        a.add(components::SOLID_ANGLE, 0.004, Some(groups::CAMPAIGN.into()));
        let mut b = Budget::default();
        b.add(components::SIGNAL_NOISE, 0.01, None);
        // u = 0.005 and 0.01 on values of 1: truths 0.991 (z = 1.8, covered) and 1.03 (z = -3, not).
        let points = vec![
            point(1.0, Some(0.991), a),
            point(1.0, Some(1.03), b),
            point(1.0, None, Budget::default()),
        ];
        let s = summarise(&points).unwrap();
        assert_eq!(s.points, 2);
        assert!((s.median_relative_u - 0.0075).abs() < 1e-12);
        assert!((s.median_relative_u_independent - 0.0065).abs() < 1e-12);
        let noise = &s.components[components::SIGNAL_NOISE];
        assert_eq!((noise.points, noise.largest_in), (2, 1));
        assert!(noise.shared_by.is_empty());
        let omega = &s.components[components::SOLID_ANGLE];
        assert_eq!(omega.shared_by, vec!["campaign".to_string()]);
        assert_eq!(omega.largest_in, 1);
        let check = s.against_point_truth.unwrap();
        assert_eq!(check.points, 2);
        assert!((check.coverage_k2 - 0.5).abs() < 1e-12);
        assert!((check.rms_z - 6.12f64.sqrt()).abs() < 1e-9);
        assert!(summarise(&points[2..]).is_none());
    }
}
