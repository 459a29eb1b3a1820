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

// ---------------------------------------------------------------- the fixed rule sized a priori

/// The tolerance a fixed rule is sized for, a priori.
pub const APRIORI_TOLERANCE: f64 = 1e-6;
/// Largest order of the fixed rule tried.
pub const APRIORI_MAX_N: usize = 256;

/// One scene of the representative set: a material, a detector aperture and a pose.
#[derive(Debug, Clone)]
pub struct Scene {
    pub material: &'static str,
    pub label: String,
    /// Aperture half-angle (rad); None: the simulated instrument's own.
    pub aperture_rad: Option<f64>,
    pub pose: Pose,
}

/// The representative set: the seed materials on and off specular at the instrument's aperture (the mirror has no
/// regular part to integrate), then apertures of 0.05 and 0.1 rad half-angle with gold's and plastic's lobes at the
/// aperture's centre, half-way to its edge and at its edge, and near-grazing cones that cross the horizon.
pub fn apriori_scenes() -> Vec<Scene> {
    let pose = |light_deg: f64, detector_deg: f64| Pose {
        light_deg,
        detector_deg,
        tilt_deg: 0.0,
        rotation_deg: 0.0,
    };
    let mut v = Vec::new();
    for material in MATERIALS.iter().copied().filter(|m| *m != "mirror") {
        for (label, p) in geometries() {
            v.push(Scene {
                material,
                label: label.to_string(),
                aperture_rad: None,
                pose: p,
            });
        }
    }
    for beta in [0.05f64, 0.1] {
        let bd = beta.to_degrees();
        for material in ["gold", "coloured-plastic"] {
            for (label, off) in [
                ("lobe at the centre", 0.0),
                ("lobe half-way to the edge", 0.5),
                ("lobe at the edge", 1.0),
            ] {
                // Light at 30 deg: the mirror direction is at -30; the detector `off` apertures beyond it.
                v.push(Scene {
                    material,
                    label: label.to_string(),
                    aperture_rad: Some(beta),
                    pose: pose(30.0, -(30.0 + off * bd)),
                });
            }
        }
        for material in [
            "gold",
            "coloured-plastic",
            "white-styrofoam",
            "construction-paper",
        ] {
            // Light at 85 deg, cone axis at 90 - beta/2: half the cone's radius lies below the horizon.
            v.push(Scene {
                material,
                label: "near grazing, cone across the horizon".to_string(),
                aperture_rad: Some(beta),
                pose: pose(85.0, -(90.0 - 0.5 * bd)),
            });
        }
    }
    v
}

/// One scene measured.
#[derive(Debug, Clone)]
pub struct SceneResult {
    pub scene: Scene,
    pub aperture_rad: f64,
    pub crosses_horizon: bool,
    /// |reference(1000 x 1000) - reference(2000 x 2000)| / reference: the reference's own accuracy.
    pub reference_accuracy: f64,
    /// The adaptive reading at tolerance 1e-6: time (whole reading), actual error, evaluations.
    pub adaptive_time_us: f64,
    pub adaptive_error: f64,
    pub adaptive_evaluations: u32,
    /// The smallest n at which the fixed rule meets the tolerance on this scene alone (hindsight).
    pub own_n: Option<usize>,
    /// The fixed rule at the a-priori n (all scenes): time alone and actual error.
    pub fixed_all: Option<FixedPoint>,
    /// The fixed rule at the a-priori n sized on the cones above the horizon only (for those scenes).
    pub fixed_above: Option<FixedPoint>,
}

/// The a-priori comparison.
#[derive(Debug, Clone)]
pub struct APriori {
    pub scenes: Vec<SceneResult>,
    /// Smallest n meeting the tolerance on every scene at once (None: not within APRIORI_MAX_N).
    pub n_all: Option<usize>,
    /// The same over the scenes whose cone stays above the horizon.
    pub n_above: Option<usize>,
}

/// Fixed-rule errors, computed once per (scene, n).
struct Errors<'a> {
    cases: Vec<(&'a Material, Direction, Direction, f64, f64)>,
    cache: Vec<Vec<Option<f64>>>,
}

impl Errors<'_> {
    fn at(&mut self, c: usize, n: usize) -> f64 {
        if let Some(e) = self.cache[c][n] {
            return e;
        }
        let (m, wi, wo, beta, reference) = self.cases[c];
        let v = fixed_rule(m, &wi, &wo, beta, n);
        let e = (v - reference).abs() / reference;
        self.cache[c][n] = Some(e);
        e
    }

    /// Smallest n at which every case of `which` meets `tol`.
    fn n_for(&mut self, which: &[usize], tol: f64) -> Option<usize> {
        // Each case alone first (cheap scans), then upwards from the largest of those until all meet at once.
        let mut start = 1;
        for &c in which {
            let own = (1..=APRIORI_MAX_N).find(|&n| self.at(c, n) <= tol)?;
            start = start.max(own);
        }
        (start..=APRIORI_MAX_N).find(|&n| which.iter().all(|&c| self.at(c, n) <= tol))
    }
}

/// Runs the a-priori comparison. `min_s` is the minimum timing window per point.
pub fn run_apriori(inst: &Instrument, min_s: f64) -> APriori {
    let wl = Wavelength::DEFAULT;
    let scenes = apriori_scenes();
    let materials: Vec<Material> = scenes
        .iter()
        .map(|s| {
            Material::preset(s.material)
                .and_then(|m| m.resolved(wl))
                .unwrap_or_else(|e| panic!("preset {}: {e}", s.material))
        })
        .collect();
    let mut results = Vec::new();
    let mut cases = Vec::new();
    for (scene, material) in scenes.iter().zip(&materials) {
        let mut inst = inst.clone();
        if let Some(beta) = scene.aperture_rad {
            inst.detector.aperture_radius_mm = inst.detector.distance_mm * beta.tan();
        }
        let o = optics(&inst, material, APRIORI_TOLERANCE);
        let beta = o.aperture_half_angle_rad();
        let r = o.reading(&scene.pose, &BAND, 0.0).expect("reading");
        let truth = o.truth_aperture(&r.wi, &r.wo, wl).expect("truth");
        let on_sample = r.incident_power_w * r.intercepted_fraction;
        let coarse = brute_cone(material, &r.wi, &r.wo, beta, 1000, 1000);
        let fine = brute_cone(material, &r.wi, &r.wo, beta, 2000, 2000);
        let reference_w = on_sample * (fine + truth.delta);
        let t = time_us(min_s, || {
            black_box(
                o.reading(black_box(&scene.pose), &BAND, 0.0)
                    .map(|r| r.power_w)
                    .ok(),
            );
        });
        results.push(SceneResult {
            scene: scene.clone(),
            aperture_rad: beta,
            crosses_horizon: r.wo.theta() + beta > PI / 2.0,
            reference_accuracy: (coarse - fine).abs() / fine,
            adaptive_time_us: t,
            adaptive_error: (r.noiseless_power_w - reference_w).abs() / reference_w,
            adaptive_evaluations: r.evaluations,
            own_n: None,
            fixed_all: None,
            fixed_above: None,
        });
        cases.push((material, r.wi, r.wo, beta, fine));
    }
    let mut errors = Errors {
        cache: vec![vec![None; APRIORI_MAX_N + 1]; cases.len()],
        cases,
    };
    let all: Vec<usize> = (0..results.len()).collect();
    let above: Vec<usize> = all
        .iter()
        .copied()
        .filter(|&c| !results[c].crosses_horizon)
        .collect();
    for (c, r) in results.iter_mut().enumerate() {
        r.own_n = (1..=APRIORI_MAX_N).find(|&n| errors.at(c, n) <= APRIORI_TOLERANCE);
    }
    let n_all = errors.n_for(&all, APRIORI_TOLERANCE);
    let n_above = errors.n_for(&above, APRIORI_TOLERANCE);
    for (c, r) in results.iter_mut().enumerate() {
        let (m, wi, wo, beta, _) = errors.cases[c];
        let mut point = |n: usize| FixedPoint {
            n,
            time_us: time_us(min_s / 4.0, || {
                black_box(fixed_rule(m, black_box(&wi), &wo, beta, n));
            }),
            rel_error: errors.at(c, n),
        };
        r.fixed_all = Some(point(n_all.unwrap_or(APRIORI_MAX_N)));
        if !r.crosses_horizon {
            r.fixed_above = n_above.map(&mut point);
        }
    }
    APriori {
        scenes: results,
        n_all,
        n_above,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use gonio_brdf::radiometry::projected_solid_angle_sr;

    fn white() -> Material {
        Material::from_document(
            "[material]\nmodel = \"lambertian\"\nalbedo = 1.0\n",
            "test",
            std::path::Path::new("."),
        )
        .expect("lambertian")
    }

    #[test]
    fn the_reference_and_the_fixed_rule_clip_a_cone_at_the_horizon_exactly() {
        // f = 1/pi: the integral is the cone's projected solid angle above the horizon over pi, which the
        // clipped-cap formula gives in closed form.
        let m = white();
        let wi = Direction::NORMAL;
        for (theta_deg, beta) in [(30.0, 0.1), (87.0, 0.1), (89.9, 0.05), (88.0, 0.0523)] {
            let axis = Direction::from_spherical_deg(theta_deg, 20.0);
            let exact = projected_solid_angle_sr(&axis, beta) / PI;
            let brute = brute_cone(&m, &wi, &axis, beta, 400, 400);
            assert!(
                (brute - exact).abs() <= 1e-9 * exact,
                "{theta_deg}: {brute} vs {exact}"
            );
            // The fixed rule converges to it (slowly across the horizon: the ring integral has a kink there).
            let fixed = fixed_rule(&m, &wi, &axis, beta, 64);
            assert!(
                (fixed - exact).abs() <= 1e-5 * exact,
                "{theta_deg}: {fixed} vs {exact}"
            );
        }
    }

    #[test]
    fn the_visible_arc_is_where_the_ring_is_above_the_horizon() {
        let axis = Direction::from_spherical_deg(88.0, 0.0);
        let a = [axis.x(), axis.y(), axis.z()];
        let (e1, e2) = basis(&axis);
        let rho = 0.06f64;
        let (sr, cr) = rho.sin_cos();
        let Arc::Part { phi0, half } = visible_arc(&a, &e1, &e2, sr, cr) else {
            panic!("the ring crosses the horizon");
        };
        let height = |phi: f64| cr * a[2] + sr * (phi.cos() * e1[2] + phi.sin() * e2[2]);
        assert!(height(phi0) > 0.0 && height(phi0 + half * 0.999) > 0.0);
        assert!(height(phi0 + half * 1.001) < 0.0 && height(phi0 + PI) < 0.0);
        assert!(height(phi0 + half).abs() < 1e-15);
        // A small ring near the axis is whole; a cone below the horizon has nothing.
        let (s, c) = 0.01f64.sin_cos();
        assert_eq!(visible_arc(&a, &e1, &e2, s, c), Arc::Full);
        let down = [a[0], a[1], -a[2]];
        assert_eq!(visible_arc(&down, &e1, &e2, s, c), Arc::Empty);
    }
}
