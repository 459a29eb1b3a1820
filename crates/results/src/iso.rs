//! The isotropic reduction of a run, and a piecewise-linear interpolant on its measurement grid.
//!
//! An isotropic BRDF depends on (theta_i, theta_o, delta_phi) only, with delta_phi = |phi_o - phi_i| folded into
//! [0, pi] ([`IsotropicAngles`]); Helmholtz reciprocity adds f(theta_i, theta_o, dphi) = f(theta_o, theta_i, dphi).
//!
//! [`IsoGrid`] is the interpolant used to resample a run (the MERL export):
//! - nodes: the distinct polar angles of the valid points (theta_i and theta_o together, since reciprocity
//!   makes the grid symmetric) and the distinct azimuth differences, each merged within
//!   [`NODE_TOLERANCE_RAD`] (read-backs and rounding scatter them by far less);
//! - node values: the mean of the points at that node and of their reciprocal images; at the pole
//!   (theta below [`NODE_TOLERANCE_RAD`]) the azimuth is undefined and a point fills the node for every
//!   delta_phi;
//! - evaluation: trilinear in (theta_i, theta_o, delta_phi) on log f (a weighted geometric mean of the
//!   surrounding node values; linear on f when one of them is not positive), no extrapolation: a query
//!   outside the nodes' range, or one whose surrounding nodes (those with a non-zero weight) are not all
//!   measured, has no value. It is exact at the nodes, never leaves the range of the surrounding measured
//!   values (a weighted mean of them), and makes the coverage of the table exactly the region the measurement
//!   brackets. Log rather than linear because a BRDF spans decades across a lobe: between a specular peak of
//!   2.7/sr and a diffuse 0.015/sr node 45 degrees away, linear interpolation puts 0.075/sr one degree from the
//!   diffuse node (five times its value), the geometric mean 0.017/sr; on smooth data the two agree to
//!   second order.

use gonio_brdf::geometry::{Direction, IsotropicAngles};

use crate::points::Point;

/// Nodes closer than this (radians, 0.01 degree) are the same node.
pub const NODE_TOLERANCE_RAD: f64 = 0.01 * std::f64::consts::PI / 180.0;

/// A valid point in the isotropic parameterisation.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct IsoPoint {
    pub band_nm: f64,
    pub angles: IsotropicAngles,
    pub f_sr: f64,
    pub u_sr: Option<f64>,
}

impl IsoPoint {
    /// The isotropic angles of a point; `None` for a point without a valid value or with a direction at or
    /// below the horizon.
    pub fn from_point(p: &Point) -> Option<IsoPoint> {
        let f_sr = p.value()?;
        let (wi, wo) = directions(p);
        if !(wi.is_above_horizon() && wo.is_above_horizon()) {
            return None;
        }
        Some(IsoPoint {
            band_nm: p.band_nm,
            angles: IsotropicAngles::from_directions(&wi, &wo),
            f_sr,
            u_sr: p.brdf_u_sr,
        })
    }
}

/// The (wi, wo) of a point from its nominal angles (degrees).
pub fn directions(p: &Point) -> (Direction, Direction) {
    (
        Direction::from_spherical_deg(p.theta_i_deg, p.phi_i_deg),
        Direction::from_spherical_deg(p.theta_o_deg, p.phi_o_deg),
    )
}

/// Sorted cluster centres of `values` (a cluster: consecutive values within the tolerance of its first).
pub fn cluster(mut values: Vec<f64>) -> Vec<f64> {
    values.retain(|v| v.is_finite());
    values.sort_by(f64::total_cmp);
    let mut nodes: Vec<(f64, f64, usize)> = Vec::new(); // (first, sum, count)
    for v in values {
        match nodes.last_mut() {
            Some((first, sum, count)) if v - *first <= NODE_TOLERANCE_RAD => {
                *sum += v;
                *count += 1;
            }
            _ => nodes.push((v, v, 1)),
        }
    }
    nodes
        .into_iter()
        .map(|(_, sum, count)| sum / count as f64)
        .collect()
}

/// The index of the node within tolerance of `x`, if any.
pub fn node_of(nodes: &[f64], x: f64) -> Option<usize> {
    let i = nodes.partition_point(|n| *n < x);
    let mut best = None;
    let mut best_distance = NODE_TOLERANCE_RAD;
    if let Some(n) = nodes.get(i)
        && (n - x).abs() <= best_distance
    {
        best = Some(i);
        best_distance = (n - x).abs();
    }
    if let Some(j) = i.checked_sub(1)
        && let Some(n) = nodes.get(j)
        && (x - n).abs() <= best_distance
    {
        best = Some(j);
    }
    best
}

/// Lower node, upper node and the weight of the upper one, for `x` within the nodes' range (a tolerance
/// beyond the ends is accepted). A weight within 1e-9 of 0 or 1 snaps, so that a query on a node needs no
/// neighbour.
fn bracket(nodes: &[f64], x: f64) -> Option<(usize, usize, f64)> {
    let (&first, &last) = (nodes.first()?, nodes.last()?);
    if !(x >= first - NODE_TOLERANCE_RAD && x <= last + NODE_TOLERANCE_RAD) {
        return None;
    }
    if let Some(j) = node_of(nodes, x) {
        return Some((j, j, 0.0));
    }
    let x = x.clamp(first, last);
    let upper = nodes.partition_point(|n| *n < x).clamp(1, nodes.len() - 1);
    let lower = upper - 1;
    let span = nodes[upper] - nodes[lower];
    let t = if span > 0.0 {
        (x - nodes[lower]) / span
    } else {
        0.0
    };
    Some(if t < 1e-9 {
        (lower, lower, 0.0)
    } else if t > 1.0 - 1e-9 {
        (upper, upper, 0.0)
    } else {
        (lower, upper, t)
    })
}

/// The piecewise-linear interpolant of one band's points on their grid (module doc).
#[derive(Debug, Clone)]
pub struct IsoGrid {
    theta: Vec<f64>,
    dphi: Vec<f64>,
    /// Mean value per (theta_i, theta_o, dphi) node, `theta.len()^2 * dphi.len()`, NaN where not measured.
    values: Vec<f64>,
    /// Mean value per (theta_i, theta_o) node pair with either angle at the pole, NaN where not measured.
    pole: Vec<f64>,
}

impl IsoGrid {
    /// The grid of these points (all of one band; the caller selects).
    pub fn build(points: &[IsoPoint]) -> IsoGrid {
        let theta = cluster(
            points
                .iter()
                .flat_map(|p| [p.angles.theta_i, p.angles.theta_o])
                .collect(),
        );
        let at_pole = |t: f64| t <= NODE_TOLERANCE_RAD;
        let dphi = cluster(
            points
                .iter()
                .filter(|p| !at_pole(p.angles.theta_i) && !at_pole(p.angles.theta_o))
                .map(|p| p.angles.delta_phi)
                .collect(),
        );
        let (nt, np) = (theta.len(), dphi.len());
        let mut sums = vec![(0.0, 0usize); nt * nt * np];
        let mut pole_sums = vec![(0.0, 0usize); nt * nt];
        for p in points {
            let (Some(i), Some(o)) = (
                node_of(&theta, p.angles.theta_i),
                node_of(&theta, p.angles.theta_o),
            ) else {
                continue;
            };
            if at_pole(theta[i]) || at_pole(theta[o]) {
                for (a, b) in [(i, o), (o, i)] {
                    let s = &mut pole_sums[a * nt + b];
                    s.0 += p.f_sr;
                    s.1 += 1;
                }
                continue;
            }
            let Some(k) = node_of(&dphi, p.angles.delta_phi) else {
                continue;
            };
            for (a, b) in [(i, o), (o, i)] {
                let s = &mut sums[(a * nt + b) * np + k];
                s.0 += p.f_sr;
                s.1 += 1;
            }
        }
        // A point on the diagonal (theta_i = theta_o) was added twice to the same node: the mean is unchanged.
        let mean = |(sum, n): (f64, usize)| if n > 0 { sum / n as f64 } else { f64::NAN };
        IsoGrid {
            values: sums.into_iter().map(mean).collect(),
            pole: pole_sums.into_iter().map(mean).collect(),
            theta,
            dphi,
        }
    }

    /// Polar-angle nodes, radians.
    pub fn theta_nodes(&self) -> &[f64] {
        &self.theta
    }

    /// Azimuth-difference nodes, radians.
    pub fn dphi_nodes(&self) -> &[f64] {
        &self.dphi
    }

    /// The measured (mean) value at node (theta_i index, theta_o index, delta_phi index); at the pole the
    /// azimuth index is ignored. `None` where nothing was measured.
    pub fn node(&self, i: usize, o: usize, k: usize) -> Option<f64> {
        if i >= self.theta.len() || o >= self.theta.len() {
            return None;
        }
        Some(self.node_value(i, o, k)).filter(|v| v.is_finite())
    }

    /// True when a polar-angle node is at the pole (its azimuth is undefined).
    pub fn is_pole(&self, i: usize) -> bool {
        self.theta.get(i).is_some_and(|t| *t <= NODE_TOLERANCE_RAD)
    }

    fn node_value(&self, i: usize, o: usize, k: usize) -> f64 {
        let nt = self.theta.len();
        if self.theta[i] <= NODE_TOLERANCE_RAD || self.theta[o] <= NODE_TOLERANCE_RAD {
            self.pole.get(i * nt + o).copied().unwrap_or(f64::NAN)
        } else {
            self.values
                .get((i * nt + o) * self.dphi.len() + k)
                .copied()
                .unwrap_or(f64::NAN)
        }
    }

    /// [`IsoGrid::eval`], and where that has no value, the value with every angle that lies within `margin`
    /// (radians) of a node moved onto that node: a measured node then also covers the queries just beside it
    /// on the side of a hole or of the edge of the measured region (constant there, as a nearest-node lookup
    /// would be). Where the strict interpolation has a value it is returned unchanged.
    pub fn eval_near(&self, a: &IsotropicAngles, margin: f64) -> Option<f64> {
        if let Some(v) = self.eval(a) {
            return Some(v);
        }
        let snap = |nodes: &[f64], x: f64| -> f64 {
            let i = nodes.partition_point(|n| *n < x);
            [i.checked_sub(1), Some(i)]
                .into_iter()
                .flatten()
                .filter_map(|j| nodes.get(j).copied())
                .filter(|n| (n - x).abs() <= margin)
                .min_by(|p, q| (p - x).abs().total_cmp(&(q - x).abs()))
                .unwrap_or(x)
        };
        let snapped = IsotropicAngles {
            theta_i: snap(&self.theta, a.theta_i),
            theta_o: snap(&self.theta, a.theta_o),
            delta_phi: snap(&self.dphi, a.delta_phi),
        };
        if snapped == *a {
            return None;
        }
        self.eval(&snapped)
    }

    /// The value at the point of the measured region nearest to `a` that differs from it only by moving some
    /// of its angles onto a node (lower or upper) within `margin` (radians): the value a table node just beyond
    /// the edge of the measured region holds so that a renderer's interpolation between it and its measured
    /// neighbours reproduces the measured values up to the edge (crates/results/src/rgl.rs). Nearest: the
    /// smallest summed squared chord between the directions of `a` and of the moved angles, so that a large
    /// azimuth step near the pole, where it moves the directions little, is preferred to a polar step. `None`
    /// when [`IsoGrid::eval`] has a value at `a` (the caller wants that) or no such point has one.
    pub fn eval_held(&self, a: &IsotropicAngles, margin: f64) -> Option<f64> {
        if self.eval(a).is_some() {
            return None;
        }
        // Per angle: itself, and the nodes on either side of it within the margin.
        let candidates = |nodes: &[f64], x: f64| -> Vec<f64> {
            let i = nodes.partition_point(|n| *n < x);
            let mut c = vec![x];
            c.extend(
                [i.checked_sub(1), Some(i)]
                    .into_iter()
                    .flatten()
                    .filter_map(|j| nodes.get(j).copied())
                    .filter(|n| (n - x).abs() <= margin && *n != x),
            );
            c
        };
        let (wi, wo) = a.to_directions();
        let chord2 = |p: &Direction, q: &Direction| {
            (p.x() - q.x()).powi(2) + (p.y() - q.y()).powi(2) + (p.z() - q.z()).powi(2)
        };
        let mut best: Option<(f64, f64)> = None;
        for theta_i in candidates(&self.theta, a.theta_i) {
            for theta_o in candidates(&self.theta, a.theta_o) {
                for delta_phi in candidates(&self.dphi, a.delta_phi) {
                    let b = IsotropicAngles {
                        theta_i,
                        theta_o,
                        delta_phi,
                    };
                    let (bi, bo) = b.to_directions();
                    let d = chord2(&wi, &bi) + chord2(&wo, &bo);
                    if best.is_some_and(|(bd, _)| bd <= d) {
                        continue;
                    }
                    if let Some(v) = self.eval(&b) {
                        best = Some((d, v));
                    }
                }
            }
        }
        best.map(|(_, v)| v)
    }

    /// The interpolated value at these angles; `None` outside the measured region (module doc).
    pub fn eval(&self, a: &IsotropicAngles) -> Option<f64> {
        let (i0, i1, ti) = bracket(&self.theta, a.theta_i)?;
        let (o0, o1, to) = bracket(&self.theta, a.theta_o)?;
        // The azimuth bracket, found once and only when a corner off the pole needs it.
        let mut azimuth: Option<Option<(usize, usize, f64)>> = None;
        // The corners with a non-zero weight: at most 8.
        let mut corners = [(0.0f64, 0.0f64); 8];
        let mut n = 0;
        for (i, wi) in [(i0, 1.0 - ti), (i1, ti)] {
            for (o, wo) in [(o0, 1.0 - to), (o1, to)] {
                let w = wi * wo;
                if w == 0.0 {
                    continue;
                }
                let pole = self.theta[i] <= NODE_TOLERANCE_RAD || self.theta[o] <= NODE_TOLERANCE_RAD;
                if pole {
                    corners[n] = (w, self.node_value(i, o, 0));
                    n += 1;
                    continue;
                }
                let (k0, k1, tp) = (*azimuth.get_or_insert_with(|| bracket(&self.dphi, a.delta_phi)))?;
                for (k, wk) in [(k0, 1.0 - tp), (k1, tp)] {
                    if wk != 0.0 {
                        corners[n] = (w * wk, self.node_value(i, o, k));
                        n += 1;
                    }
                }
            }
        }
        let corners = &corners[..n];
        if corners.iter().any(|(_, v)| !v.is_finite()) {
            return None;
        }
        // Linear in log f (a weighted geometric mean) when every corner is positive, else linear in f.
        if corners.iter().all(|(_, v)| *v > 0.0) {
            Some(corners.iter().map(|(w, v)| w * v.ln()).sum::<f64>().exp())
        } else {
            Some(corners.iter().map(|(w, v)| w * v).sum())
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::f64::consts::PI;

    fn iso(ti_deg: f64, to_deg: f64, dp_deg: f64, f: f64) -> IsoPoint {
        IsoPoint {
            band_nm: 550.0,
            angles: IsotropicAngles {
                theta_i: ti_deg.to_radians(),
                theta_o: to_deg.to_radians(),
                delta_phi: dp_deg.to_radians(),
            },
            f_sr: f,
            u_sr: None,
        }
    }

    fn at(ti_deg: f64, to_deg: f64, dp_deg: f64) -> IsotropicAngles {
        IsotropicAngles {
            theta_i: ti_deg.to_radians(),
            theta_o: to_deg.to_radians(),
            delta_phi: dp_deg.to_radians(),
        }
    }

    /// A function whose logarithm is linear in each angle separately: log-trilinear interpolation reproduces it
    /// exactly.
    fn multilinear(ti: f64, to: f64, dp: f64) -> f64 {
        (-2.0 + 0.01 * (ti + to) + 0.001 * ti * to + 0.002 * dp + 1e-5 * (ti + to) * dp).exp()
    }

    #[test]
    fn reproduces_a_multilinear_function_with_reciprocity() {
        // Only theta_i <= theta_o measured (as a plan with reciprocity does); the rest comes by reciprocity.
        let mut pts = Vec::new();
        for ti in [15.0, 30.0, 45.0] {
            for to in [15.0, 30.0, 45.0] {
                if ti <= to {
                    for dp in [0.0, 90.0, 180.0] {
                        pts.push(iso(ti, to, dp, multilinear(ti, to, dp)));
                    }
                }
            }
        }
        let g = IsoGrid::build(&pts);
        for (ti, to, dp) in [
            (20.0, 40.0, 33.0),
            (40.0, 20.0, 33.0),
            (15.0, 45.0, 180.0),
            (44.0, 16.0, 1.0),
        ] {
            let v = g.eval(&at(ti, to, dp)).expect("inside the grid");
            let want = multilinear(ti, to, dp);
            assert!(
                (v - want).abs() < 1e-12 * want,
                "({ti}, {to}, {dp}): {v} vs {want}"
            );
        }
        // Outside the measured range: no value, no extrapolation.
        assert_eq!(g.eval(&at(10.0, 30.0, 0.0)), None);
        assert_eq!(g.eval(&at(30.0, 50.0, 0.0)), None);
    }

    #[test]
    fn a_missing_node_leaves_a_hole_and_the_pole_fills_every_azimuth() {
        let mut pts = vec![iso(0.0, 30.0, 0.0, 2.0), iso(0.0, 60.0, 0.0, 4.0)];
        for dp in [0.0, 180.0] {
            pts.push(iso(30.0, 30.0, dp, 1.0));
            pts.push(iso(30.0, 60.0, dp, 1.0));
        }
        pts.push(iso(60.0, 60.0, 0.0, 1.0)); // (60, 60, 180) not measured
        let g = IsoGrid::build(&pts);
        // A zero among the corners: linear in f there.
        let z = IsoGrid::build(&[iso(30.0, 30.0, 0.0, 0.0), iso(30.0, 30.0, 180.0, 1.0)]);
        assert_eq!(z.eval(&at(30.0, 30.0, 45.0)), Some(0.25));
        // At normal incidence the azimuth does not matter: the pole node serves every delta_phi (halfway
        // between 2 and 4 in log: sqrt(8)).
        let v = g.eval(&at(0.0, 45.0, 123.0)).expect("covered");
        assert!((v - 8f64.sqrt()).abs() < 1e-12, "{v}");
        assert_eq!(g.eval(&at(45.0, 0.0, 77.0)), Some(v));
        // Between the pole and 30 degrees: linear in theta_i, in log.
        let v = g.eval(&at(15.0, 30.0, 90.0)).expect("covered");
        assert!((v - 2f64.sqrt()).abs() < 1e-12, "{v}");
        // Around the unmeasured (60, 60, 180) node: no value; at (60, 60, 0) itself: the node.
        assert_eq!(g.eval(&at(50.0, 55.0, 170.0)), None);
        assert_eq!(g.eval(&at(60.0, 60.0, 0.0)), Some(1.0));
        assert!(g.eval(&at(60.0, 60.0, PI.to_degrees() / 2.0)).is_none());
    }

    /// theta_i, theta_o in {20, 40}, delta_phi in {0, 90, 180} of [`multilinear`], without (20, 20, 0): the
    /// retro-reflection, not measurable, a hole.
    fn grid_with_retro_hole() -> IsoGrid {
        let mut pts = Vec::new();
        for ti in [20.0, 40.0] {
            for to in [20.0, 40.0] {
                for dp in [0.0, 90.0, 180.0] {
                    if !(ti == 20.0 && to == 20.0 && dp == 0.0) {
                        pts.push(iso(ti, to, dp, multilinear(ti, to, dp)));
                    }
                }
            }
        }
        IsoGrid::build(&pts)
    }

    #[test]
    fn a_margin_extends_nodes_to_their_neighbourhood_only() {
        let g = grid_with_retro_hole();
        let margin = 1f64.to_radians();
        // Beside the hole, next to the measured node (20, 20, 90): strict interpolation needs the hole, the
        // margin gives the node's value; next to the hole itself there is still nothing.
        assert_eq!(g.eval(&at(20.0, 20.5, 89.5)), None);
        let near = g
            .eval_near(&at(20.0, 20.5, 89.5), margin)
            .expect("within the margin of (20, 20, 90)");
        assert!((near - multilinear(20.0, 20.0, 90.0)).abs() < 1e-12, "{near}");
        assert_eq!(g.eval_near(&at(20.0, 20.5, 1.0), margin), None);
        // Just beyond the edge: the edge node's value; further out, nothing.
        let edge = g
            .eval_near(&at(40.8, 30.0, 90.0), margin)
            .expect("within the margin of the edge");
        let want = g.eval(&at(40.0, 30.0, 90.0)).expect("inside");
        assert!((edge - want).abs() < 1e-12, "{edge} vs {want}");
        assert_eq!(g.eval_near(&at(42.0, 30.0, 90.0), margin), None);
        // Inside, the strict value is kept.
        assert_eq!(
            g.eval_near(&at(30.0, 30.0, 45.0), margin),
            g.eval(&at(30.0, 30.0, 45.0))
        );
    }

    #[test]
    fn a_guard_value_is_the_nearest_measured_point_within_the_margin() {
        let g = grid_with_retro_hole();
        let margin = 15f64.to_radians();
        // In the hole at (20, 30, 80): moving theta_o to 40 (a 10 degree step of theta_o) or delta_phi to 90
        // (at theta_o = 30 a chord of 2 sin 30 sin 5 = 0.087, against 2 sin 5 = 0.174) both reach the measured
        // region; the azimuth move is the nearer, and there the interpolant is the multilinear function.
        assert_eq!(g.eval(&at(20.0, 30.0, 80.0)), None);
        let held = g
            .eval_held(&at(20.0, 30.0, 80.0), margin)
            .expect("the measured region is within the margin");
        let want = multilinear(20.0, 30.0, 90.0);
        assert!((held - want).abs() < 1e-12 * want, "{held} vs {want}");
        // Beyond the edge theta_o = 40: the edge's value; beyond the margin, nothing.
        let edge = g
            .eval_held(&at(20.0, 45.0, 90.0), margin)
            .expect("within the margin of the edge");
        let want = multilinear(20.0, 40.0, 90.0);
        assert!((edge - want).abs() < 1e-12 * want, "{edge} vs {want}");
        assert_eq!(g.eval_held(&at(20.0, 60.0, 90.0), margin), None);
        // Inside the measured region it has nothing to hold: the caller uses the interpolant.
        assert!(g.eval(&at(30.0, 30.0, 135.0)).is_some());
        assert_eq!(g.eval_held(&at(30.0, 30.0, 135.0), margin), None);
    }

    #[test]
    fn nodes_merge_within_tolerance() {
        let n = cluster(vec![0.5, 0.5 + 1e-9, 1.0, 1.0 - 1e-12, 0.25]);
        assert_eq!(n.len(), 3);
        assert_eq!(node_of(&n, 1.0 + 1e-7), Some(2));
        assert_eq!(node_of(&n, 0.75), None);
    }
}
