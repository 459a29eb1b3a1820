//! The fixed rule sized a priori: for each scene, the smallest order that meets the tolerance, chosen before
//! the reading from the scene alone, against the adaptive integrator.

use super::*;

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
    pub(super) fn at(&mut self, c: usize, n: usize) -> f64 {
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
    pub(super) fn n_for(&mut self, which: &[usize], tol: f64) -> Option<usize> {
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
