//! Benchmark (a): time per simulated reading against its actual error versus a brute-force reference, over
//! tolerances, and the adaptive integrator against a fixed high-order tensor rule at equal error.

use std::f64::consts::PI;
use std::hint::black_box;
use std::time::Instant;

use gonio_brdf::integrate::gauss_legendre;
use gonio_brdf::{Brdf, Direction, Material, Wavelength};
use gonio_instrument::Instrument;
use gonio_simulator::optics::{Optics, SampleSpec};
use gonio_simulator::scene::{Band, Pose};

mod apriori;

pub use apriori::{APRIORI_MAX_N, APRIORI_TOLERANCE, APriori, SceneResult, run_apriori};

pub const MATERIALS: [&str; 5] = [
    "mirror",
    "white-styrofoam",
    "construction-paper",
    "coloured-plastic",
    "gold",
];
pub const TOLERANCES: [f64; 7] = [1e-2, 1e-3, 1e-4, 1e-5, 1e-6, 1e-7, 1e-8];
pub const BAND: Band = Band {
    band_nm: Some(550.0),
    transmission: 0.5,
};

/// The two geometries: light at 30 deg, detector on the specular direction (-30) or off it (-60), no tilt.
pub fn geometries() -> [(&'static str, Pose); 2] {
    let pose = |d: f64| Pose {
        light_deg: 30.0,
        detector_deg: d,
        tilt_deg: 0.0,
        rotation_deg: 0.0,
    };
    [("specular", pose(-30.0)), ("off-specular", pose(-60.0))]
}

/// One (material, geometry, tolerance) measurement.
#[derive(Debug, Clone)]
pub struct ReadingPoint {
    pub material: &'static str,
    pub geometry: &'static str,
    pub tolerance: f64,
    pub time_us: f64,
    /// |reading - reference| / reference (0 when both are 0).
    pub rel_error: f64,
    pub evaluations: u32,
}

/// The fixed rule at one order.
#[derive(Debug, Clone)]
pub struct FixedPoint {
    pub n: usize,
    pub time_us: f64,
    pub rel_error: f64,
}

/// The fixed-rule comparison at one (material, geometry).
#[derive(Debug, Clone)]
pub struct FixedComparison {
    pub material: &'static str,
    pub geometry: &'static str,
    pub curve: Vec<FixedPoint>,
    /// The adaptive reading at tolerance 1e-6: its time and actual error.
    pub adaptive_time_us: f64,
    pub adaptive_error: f64,
    /// The cheapest fixed order whose error is <= the adaptive one's (None if none reached it).
    pub equal_error: Option<FixedPoint>,
}

/// Mean wall time of `f` in microseconds: repeated until at least `min_s` seconds have passed.
pub fn time_us(min_s: f64, mut f: impl FnMut()) -> f64 {
    f();
    let mut reps = 1usize;
    loop {
        let start = Instant::now();
        for _ in 0..reps {
            f();
        }
        let elapsed = start.elapsed().as_secs_f64();
        if elapsed >= min_s {
            return elapsed / reps as f64 * 1e6;
        }
        reps = reps
            .saturating_mul(if elapsed > 0.0 {
                ((min_s / elapsed) * 1.2).ceil() as usize
            } else {
                10
            })
            .max(reps + 1);
    }
}

/// Two unit vectors perpendicular to `a`, built independently of the simulator's.
fn basis(a: &Direction) -> ([f64; 3], [f64; 3]) {
    let v = [a.x(), a.y(), a.z()];
    let helper = if v[2].abs() < 0.9 {
        [0.0, 0.0, 1.0]
    } else {
        [0.0, 1.0, 0.0]
    };
    let mut e1 = [
        v[1] * helper[2] - v[2] * helper[1],
        v[2] * helper[0] - v[0] * helper[2],
        v[0] * helper[1] - v[1] * helper[0],
    ];
    let n = (e1[0] * e1[0] + e1[1] * e1[1] + e1[2] * e1[2]).sqrt();
    e1 = [e1[0] / n, e1[1] / n, e1[2] / n];
    let e2 = [
        v[1] * e1[2] - v[2] * e1[1],
        v[2] * e1[0] - v[0] * e1[2],
        v[0] * e1[1] - v[1] * e1[0],
    ];
    (e1, e2)
}

/// The part of the ring at angle `rho` from the axis that lies above the horizon: the ring is
/// `w(phi) = cos(rho) a + sin(rho) (cos(phi) e1 + sin(phi) e2)`, whose height is
/// `cos(rho) a_z + sin(rho) R cos(phi - phi0)` with `R = |(e1_z, e2_z)|`.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Arc {
    /// The whole ring is above the horizon.
    Full,
    /// Above the horizon for `phi` in `(phi0 - half, phi0 + half)`.
    Part { phi0: f64, half: f64 },
    /// Nothing above the horizon.
    Empty,
}

fn visible_arc(a: &[f64; 3], e1: &[f64; 3], e2: &[f64; 3], sr: f64, cr: f64) -> Arc {
    let r = e1[2].hypot(e2[2]);
    let (centre, swing) = (cr * a[2], sr * r);
    if centre - swing > 0.0 {
        Arc::Full
    } else if centre + swing <= 0.0 {
        Arc::Empty
    } else {
        // Above the horizon where cos(phi - phi0) > -centre / swing (swing > 0 here).
        Arc::Part {
            phi0: e2[2].atan2(e1[2]),
            half: (-centre / swing).clamp(-1.0, 1.0).acos(),
        }
    }
}

/// `∫ f(wi, w) cos(theta_w) dphi` over the visible part of one ring: the trapezoid rule with `n_full` nodes
/// on a whole ring (spectrally accurate for a smooth periodic integrand), Gauss-Legendre `arc_rule` on a part.
#[allow(clippy::too_many_arguments)]
fn ring(
    m: &dyn Brdf,
    wi: &Direction,
    a: &[f64; 3],
    e1: &[f64; 3],
    e2: &[f64; 3],
    (sr, cr): (f64, f64),
    n_full: usize,
    arc_rule: &[(f64, f64)],
) -> f64 {
    let wl = Wavelength::DEFAULT;
    let g = |phi: f64| {
        let (sp, cp) = phi.sin_cos();
        let w = [0, 1, 2].map(|k| cr * a[k] + sr * (cp * e1[k] + sp * e2[k]));
        if w[2] <= 0.0 {
            return 0.0;
        }
        match Direction::new(w[0], w[1], w[2]) {
            Some(d) => m.eval(wi, &d, wl).unwrap_or(0.0) * d.z(),
            None => 0.0,
        }
    };
    match visible_arc(a, e1, e2, sr, cr) {
        Arc::Empty => 0.0,
        Arc::Full => {
            let mut sum = 0.0;
            for j in 0..n_full {
                sum += g((j as f64 + 0.5) * 2.0 * PI / n_full as f64);
            }
            sum * 2.0 * PI / n_full as f64
        }
        Arc::Part { phi0, half } => arc_rule.iter().map(|(x, w)| half * w * g(phi0 + half * x)).sum(),
    }
}

/// A composite Gauss-Legendre rule on [-1, 1]: `panels` panels of `order` nodes, as (node, weight).
fn composite_gl(panels: usize, order: usize) -> Vec<(f64, f64)> {
    let nodes = gauss_legendre(order);
    let h = 2.0 / panels as f64;
    let mut out = Vec::with_capacity(panels * order);
    for p in 0..panels {
        let centre = -1.0 + (p as f64 + 0.5) * h;
        for n in nodes.iter() {
            out.push((centre + 0.5 * h * n.x, 0.5 * h * n.weight));
        }
    }
    out
}

/// Brute-force `∫_cone f(wi, w) cos(theta_w) d omega` over the part of the cone above the horizon: composite
/// Simpson in u = 1 - cos(rho) (d omega = du dphi) with `nu` intervals, times the trapezoid rule with `nphi`
/// nodes on whole rings and composite Gauss-Legendre with about `nphi` nodes on the visible arc of a ring that
/// crosses the horizon. When the cone crosses the horizon, u is split where the rings start to cross it (u*) and
/// the outer part is integrated in s with u = u* + (u_max - u*) s^2, which absorbs the (u - u*)^(3/2) behaviour
/// of the ring integral there.
pub fn brute_cone(m: &dyn Brdf, wi: &Direction, axis: &Direction, beta: f64, nu: usize, nphi: usize) -> f64 {
    let a = [axis.x(), axis.y(), axis.z()];
    let (e1, e2) = basis(axis);
    let arc_rule = composite_gl(nphi.div_ceil(20).max(1), 20);
    let ring_at_u = |u: f64| {
        let (cr, sr) = (1.0 - u, (u * (2.0 - u)).max(0.0).sqrt());
        ring(m, wi, &a, &e1, &e2, (sr, cr), nphi, &arc_rule)
    };
    let simpson = |lo: f64, hi: f64, f: &dyn Fn(f64) -> f64| {
        let n = nu + nu % 2;
        let h = (hi - lo) / n as f64;
        let mut total = 0.0;
        for i in 0..=n {
            let weight = if i == 0 || i == n {
                1.0
            } else if i % 2 == 1 {
                4.0
            } else {
                2.0
            };
            total += weight * f(lo + i as f64 * h);
        }
        total * h / 3.0
    };
    let umax = 2.0 * (beta / 2.0).sin().powi(2);
    // The rings touch the horizon from rho* = pi/2 - theta_axis on.
    let rho_star = PI / 2.0 - axis.theta();
    if rho_star >= beta {
        return simpson(0.0, umax, &ring_at_u);
    }
    let ustar = if rho_star > 0.0 {
        2.0 * (rho_star / 2.0).sin().powi(2)
    } else {
        0.0
    };
    let inner = if ustar > 0.0 {
        simpson(0.0, ustar, &ring_at_u)
    } else {
        0.0
    };
    let span = umax - ustar;
    let outer = simpson(0.0, 1.0, &|s: f64| {
        ring_at_u(ustar + span * s * s) * 2.0 * span * s
    });
    inner + outer
}

/// A fixed tensor rule: Gauss-Legendre with `n` nodes in rho on [0, beta] times, on each ring, the trapezoid rule
/// with `2n` nodes in phi, or, on a ring that crosses the horizon, Gauss-Legendre with `2n` nodes on its visible
/// arc (the rule is told where the horizon is; no adaptivity, no error estimate). Above the horizon this is the
/// plain tensor rule.
pub fn fixed_rule(m: &dyn Brdf, wi: &Direction, axis: &Direction, beta: f64, n: usize) -> f64 {
    let a = [axis.x(), axis.y(), axis.z()];
    let (e1, e2) = basis(axis);
    let nodes = gauss_legendre(n);
    let arc: Vec<(f64, f64)> = gauss_legendre(2 * n).iter().map(|g| (g.x, g.weight)).collect();
    let mut total = 0.0;
    for node in nodes.iter() {
        let rho = 0.5 * beta * (node.x + 1.0);
        let (sr, cr) = rho.sin_cos();
        let r = ring(m, wi, &a, &e1, &e2, (sr, cr), 2 * n, &arc);
        total += 0.5 * beta * node.weight * sr * r;
    }
    total
}

fn optics(inst: &Instrument, material: &Material, tolerance: f64) -> Optics {
    let sample = SampleSpec {
        material: material.clone(),
        radius_mm: 25.0,
        orientation_deg: 0.0,
    };
    Optics::new(inst, sample, 1)
        .and_then(|o| o.with_tolerance(tolerance))
        .map(|o| o.with_source_noise(false).with_source_drift(false))
        .unwrap_or_else(|e| panic!("optics for the benchmark: {e}"))
}

/// Runs benchmark (a). `min_s` is the minimum timing window per point.
pub fn run(inst: &Instrument, min_s: f64) -> (Vec<ReadingPoint>, Vec<FixedComparison>) {
    let wl = Wavelength::DEFAULT;
    let mut points = Vec::new();
    let mut fixed = Vec::new();
    for name in MATERIALS {
        let material = Material::preset(name)
            .and_then(|m| m.resolved(wl))
            .unwrap_or_else(|e| panic!("preset {name}: {e}"));
        let base = optics(inst, &material, 1e-6);
        let beta = base.aperture_half_angle_rad();
        for (label, pose) in geometries() {
            let r = base.reading(&pose, &BAND, 0.0).expect("reading");
            let truth = base.truth_aperture(&r.wi, &r.wo, wl).expect("truth");
            let on_sample = r.incident_power_w * r.intercepted_fraction;
            // The materials are isotropic and mounted at orientation 0: sample frame = material frame.
            let brute = brute_cone(&material, &r.wi, &r.wo, beta, 1000, 1000);
            let reference_w = on_sample * (brute + truth.delta);
            let rel = |p: f64| {
                if reference_w == 0.0 {
                    if p == 0.0 { 0.0 } else { 1.0 }
                } else {
                    (p - reference_w).abs() / reference_w
                }
            };
            let mut adaptive_at_1e6 = (0.0, 0.0);
            for tol in TOLERANCES {
                let o = optics(inst, &material, tol);
                let reading = o.reading(&pose, &BAND, 0.0).expect("reading");
                let t = time_us(min_s, || {
                    black_box(o.reading(black_box(&pose), &BAND, 0.0).map(|r| r.power_w).ok());
                });
                let e = rel(reading.noiseless_power_w);
                if tol == 1e-6 {
                    adaptive_at_1e6 = (t, e);
                }
                points.push(ReadingPoint {
                    material: name,
                    geometry: label,
                    tolerance: tol,
                    time_us: t,
                    rel_error: e,
                    evaluations: reading.evaluations,
                });
            }
            // The fixed rule only makes sense where there is a regular part to integrate.
            if brute == 0.0 {
                continue;
            }
            let mut curve = Vec::new();
            for n in [1usize, 2, 3, 4, 6, 8, 12, 16, 24, 32, 48, 64] {
                let v = fixed_rule(&material, &r.wi, &r.wo, beta, n);
                let t = time_us(min_s / 4.0, || {
                    black_box(fixed_rule(&material, black_box(&r.wi), &r.wo, beta, n));
                });
                curve.push(FixedPoint {
                    n,
                    time_us: t,
                    rel_error: (v - brute).abs() / brute,
                });
            }
            let equal_error = curve
                .iter()
                .find(|p| p.rel_error <= adaptive_at_1e6.1.max(1e-15))
                .cloned();
            fixed.push(FixedComparison {
                material: name,
                geometry: label,
                curve,
                adaptive_time_us: adaptive_at_1e6.0,
                adaptive_error: adaptive_at_1e6.1,
                equal_error,
            });
        }
    }
    (points, fixed)
}

#[cfg(test)]
mod tests;
