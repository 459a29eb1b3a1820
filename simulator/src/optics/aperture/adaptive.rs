//! The adaptive rule: globally adaptive Genz-Malik cubature (degree 7 with an embedded degree 5 rule) on
//! rectangles of the integration variables, started from a partition that a lobe's peak and a kink cannot hide
//! in. The fallback of every other rule, for narrow lobes, kinks and tabulated data.

use std::cmp::Ordering;
use std::collections::BinaryHeap;
use std::f64::consts::PI;

use super::integrand::{Coordinates, Integrand};
use super::{ApertureFunction, Cone, ConeIntegral, Features};

/// Upper bound on BRDF evaluations for the adaptive rule (about 5 ms of work); the error estimate says how far
/// from the tolerance the result is when it is reached.
const MAX_ADAPTIVE_EVALUATIONS: u32 = 200_000;

/// A rectangle of (rho, phi) with its Genz-Malik estimate.
#[derive(Debug, Clone, Copy)]
struct Region {
    centre: [f64; 2],
    half: [f64; 2],
    value: f64,
    error: f64,
    split_axis: usize,
}

impl PartialEq for Region {
    fn eq(&self, other: &Self) -> bool {
        self.error.total_cmp(&other.error) == Ordering::Equal
    }
}
impl Eq for Region {}
impl PartialOrd for Region {
    fn partial_cmp(&self, other: &Self) -> Option<Ordering> {
        Some(self.cmp(other))
    }
}
impl Ord for Region {
    fn cmp(&self, other: &Self) -> Ordering {
        self.error.total_cmp(&other.error)
    }
}

/// Safety factor on the Genz-Malik estimate |I7 - I5|: on a region cut by a kink (Oren-Nayar's) the degree-7
/// result can be off by more than its difference with the degree-5 one (seen: 1.5 times); on smooth regions the
/// difference already over-estimates the degree-7 error by orders of magnitude, so the factor costs little.
const GM_SAFETY: f64 = 4.0;

// Genz-Malik degree-7 rule with embedded degree-5 rule, in two dimensions (weights sum to 1 on [-1, 1]^2).
const GM_L2: f64 = 0.358_568_582_800_318_1; // sqrt(9/70)
const GM_L3: f64 = 0.948_683_298_050_513_8; // sqrt(9/10)
const GM_L4: f64 = 0.948_683_298_050_513_8; // sqrt(9/10)
const GM_L5: f64 = 0.688_247_201_611_685_3; // sqrt(9/19)
const GM_W7: [f64; 5] = [
    (12824.0 - 9120.0 * 2.0 + 400.0 * 4.0) / 19683.0,
    980.0 / 6561.0,
    (1820.0 - 400.0 * 2.0) / 19683.0,
    200.0 / 19683.0,
    6859.0 / 19683.0 / 4.0,
];
const GM_W5: [f64; 4] = [
    (729.0 - 950.0 * 2.0 + 50.0 * 4.0) / 729.0,
    245.0 / 486.0,
    (265.0 - 100.0 * 2.0) / 1458.0,
    25.0 / 729.0,
];

fn genz_malik<F: ApertureFunction>(it: &mut Integrand<'_, F>, centre: [f64; 2], half: [f64; 2]) -> Region {
    let mut g = |u: f64, v: f64| it.at(centre[0] + u * half[0], centre[1] + v * half[1]);
    let f0 = g(0.0, 0.0);
    let mut s2 = 0.0;
    let mut s3 = 0.0;
    let mut fourth = [0.0; 2];
    for (axis, fourth_axis) in fourth.iter_mut().enumerate() {
        let (a2p, a2m, a3p, a3m) = if axis == 0 {
            (g(GM_L2, 0.0), g(-GM_L2, 0.0), g(GM_L3, 0.0), g(-GM_L3, 0.0))
        } else {
            (g(0.0, GM_L2), g(0.0, -GM_L2), g(0.0, GM_L3), g(0.0, -GM_L3))
        };
        s2 += a2p + a2m;
        s3 += a3p + a3m;
        // Fourth difference along the axis: decides where to split (as in HCubature / Genz-Malik).
        *fourth_axis =
            ((a2p + a2m - 2.0 * f0) - (GM_L2 * GM_L2 / (GM_L3 * GM_L3)) * (a3p + a3m - 2.0 * f0)).abs();
    }
    let s4 = g(GM_L4, GM_L4) + g(GM_L4, -GM_L4) + g(-GM_L4, GM_L4) + g(-GM_L4, -GM_L4);
    let s5 = g(GM_L5, GM_L5) + g(GM_L5, -GM_L5) + g(-GM_L5, GM_L5) + g(-GM_L5, -GM_L5);
    let area = 4.0 * half[0] * half[1];
    let i7 = area * (GM_W7[0] * f0 + GM_W7[1] * s2 + GM_W7[2] * s3 + GM_W7[3] * s4 + GM_W7[4] * s5);
    let i5 = area * (GM_W5[0] * f0 + GM_W5[1] * s2 + GM_W5[2] * s3 + GM_W5[3] * s4);
    let split_axis = if fourth[1] > fourth[0] { 1 } else { 0 };
    Region {
        centre,
        half,
        value: i7,
        error: GM_SAFETY * (i7 - i5).abs(),
        split_axis,
    }
}

pub(super) fn adaptive<F: ApertureFunction>(
    it: &mut Integrand<'_, F>,
    tol: f64,
    features: &Features,
) -> ConeIntegral {
    let (u_cuts, v_cuts) = match &it.coordinates {
        Coordinates::Polar => initial_partition(it.cone, features),
        Coordinates::Latitude(lat) => lat.initial_partition(),
    };
    let mut heap = BinaryHeap::with_capacity(4 * u_cuts.len() * v_cuts.len());
    for r in u_cuts.windows(2) {
        for p in v_cuts.windows(2) {
            let centre = [0.5 * (r[0] + r[1]), 0.5 * (p[0] + p[1])];
            let half = [0.5 * (r[1] - r[0]), 0.5 * (p[1] - p[0])];
            heap.push(genz_malik(it, centre, half));
        }
    }
    let mut value: f64 = heap.iter().map(|r| r.value).sum();
    let mut error: f64 = heap.iter().map(|r| r.error).sum();
    loop {
        let rounding = 64.0 * f64::EPSILON * value.abs();
        if error <= (tol * value.abs()).max(rounding) || it.evaluations >= MAX_ADAPTIVE_EVALUATIONS {
            // Re-add from scratch: the running sums drift by rounding over thousands of updates.
            let value: f64 = heap.iter().map(|r| r.value).sum();
            let error: f64 = heap.iter().map(|r| r.error).sum();
            return ConeIntegral {
                value,
                error: error.max(rounding),
                evaluations: it.evaluations,
            };
        }
        let Some(worst) = heap.pop() else {
            return ConeIntegral {
                value: 0.0,
                error: 0.0,
                evaluations: it.evaluations,
            };
        };
        let a = worst.split_axis;
        let mut half = worst.half;
        half[a] *= 0.5;
        let mut c1 = worst.centre;
        let mut c2 = worst.centre;
        c1[a] -= half[a];
        c2[a] += half[a];
        let (r1, r2) = (genz_malik(it, c1, half), genz_malik(it, c2, half));
        value += r1.value + r2.value - worst.value;
        error += r1.error + r2.error - worst.error;
        heap.push(r1);
        heap.push(r2);
    }
}

/// The starting rectangles of the adaptive rule, as cuts in rho (from 0 to beta) and phi (a full turn).
///
/// Without a peak: 2 x 4 rectangles. With a peak at (rho_p, phi_p) of width w: cuts at rho_p +- w 2^k and
/// phi_p +- (w / rho_p) 2^k (k = 0, 1, ...), the partition a lobe-adapted rule would use, so that the rectangles
/// next to the peak are about one width across and the peak sits on their corners: it cannot hide between the
/// sample points of a large rectangle (the classic failure of adaptive cubature on a narrow peak).
fn initial_partition(cone: &Cone, features: &Features) -> (Vec<f64>, Vec<f64>) {
    let beta = cone.half_angle;
    // A kink along a vertical plane (normal p, horizontal) crosses the cone along the azimuths about the axis
    // where `w . p = cos(rho) (a . p) + sin(rho) (cos(phi) e1 . p + sin(phi) e2 . p)` vanishes; when the plane
    // contains the axis (a detector at the zenith, Oren-Nayar's plane always does) these are the two azimuths
    // `atan2(-e1 . p, e2 . p)` and that + pi, exactly, and near them otherwise: cut there.
    let kink_cuts: Vec<f64> = features
        .kink_azimuth
        .filter(|k| k.is_finite())
        .map(|k| {
            let p = [-k.sin(), k.cos(), 0.0];
            let phi = (-dot3(&cone.e1, &p)).atan2(dot3(&cone.e2, &p));
            vec![phi.rem_euclid(2.0 * PI), (phi + PI).rem_euclid(2.0 * PI)]
        })
        .unwrap_or_default();
    let with_kink = |mut cuts: Vec<f64>| {
        cuts.extend(&kink_cuts);
        cuts.sort_by(f64::total_cmp);
        cuts.dedup_by(|x, y| (*x - *y).abs() <= 1e-12);
        cuts
    };
    let Some(peak) = features.peak.filter(|p| p.width > 0.0 && p.width.is_finite()) else {
        return (
            vec![0.0, 0.5 * beta, beta],
            with_kink((0..=4).map(|j| j as f64 * PI / 2.0).collect()),
        );
    };
    let p = [peak.direction.x(), peak.direction.y(), peak.direction.z()];
    let rho_p = peak.direction.angle_to(&cone.axis);
    let phi_p = (dot3(&p, &cone.e2))
        .atan2(dot3(&p, &cone.e1))
        .rem_euclid(2.0 * PI);
    let w = peak.width;
    let mut rho_cuts = vec![0.0, beta];
    let mut step = w;
    while step < 2.0 * beta {
        for c in [rho_p - step, rho_p + step] {
            if c > 0.0 && c < beta {
                rho_cuts.push(c);
            }
        }
        step *= 2.0;
    }
    if rho_p > 0.0 && rho_p < beta {
        rho_cuts.push(rho_p);
    }
    rho_cuts.sort_by(f64::total_cmp);
    rho_cuts.dedup_by(|x, y| (*x - *y).abs() <= 1e-12 * beta);
    // Azimuth: geometric cuts about phi_p while they are narrower than a half turn, then a quarter grid.
    let mut phi_offsets = vec![0.0, PI];
    let mut step = w / rho_p.max(w);
    while step < PI {
        phi_offsets.push(step);
        phi_offsets.push(2.0 * PI - step);
        step *= 2.0;
    }
    phi_offsets.push(PI / 2.0);
    phi_offsets.push(3.0 * PI / 2.0);
    let mut phi_cuts: Vec<f64> = phi_offsets
        .iter()
        .map(|o| (phi_p + o).rem_euclid(2.0 * PI))
        .collect();
    phi_cuts.push(0.0);
    phi_cuts.push(2.0 * PI);
    (rho_cuts, with_kink(phi_cuts))
}

fn dot3(a: &[f64; 3], b: &[f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn genz_malik_weights_integrate_monomials() {
        // Degree 7 rule exact for x^a y^b, a + b <= 7, on [-1, 1]^2 (mean value = weights sum to 1).
        let f = |a: i32, b: i32| move |u: f64, v: f64| u.powi(a) * v.powi(b);
        for a in 0..=7 {
            for b in 0..=(7 - a) {
                let g = f(a, b);
                let pts: Vec<(f64, f64, f64)> = gm_points();
                let num: f64 = pts.iter().map(|&(u, v, w)| w * g(u, v)).sum::<f64>() * 4.0;
                let m = |k: i32| if k % 2 == 1 { 0.0 } else { 2.0 / (k as f64 + 1.0) };
                let exact = m(a) * m(b);
                assert!((num - exact).abs() < 1e-14, "x^{a} y^{b}: {num} vs {exact}");
            }
        }
    }

    fn gm_points() -> Vec<(f64, f64, f64)> {
        let mut p = vec![(0.0, 0.0, GM_W7[0])];
        for s in [1.0, -1.0] {
            p.push((s * GM_L2, 0.0, GM_W7[1]));
            p.push((0.0, s * GM_L2, GM_W7[1]));
            p.push((s * GM_L3, 0.0, GM_W7[2]));
            p.push((0.0, s * GM_L3, GM_W7[2]));
            for t in [1.0, -1.0] {
                p.push((s * GM_L4, t * GM_L4, GM_W7[3]));
                p.push((s * GM_L5, t * GM_L5, GM_W7[4]));
            }
        }
        p
    }
}
