//! Adaptive plans against a uniform grid of the same size, reconstructed with the same interpolation and
//! compared with a dense reference.

use crate::common;

use common::simulated;
use gonio_brdf::Brdf;
use gonio_brdf::geometry::{Direction, half_vector};
use gonio_brdf::material::Material;
use gonio_brdf::spectrum::Wavelength;
use gonio_scheduler::adaptive::{Adaptive, BatchMemo, Measured};
use gonio_scheduler::constraints::Constraints;
use gonio_scheduler::kinematics::Geometry;
use gonio_scheduler::plan::AdaptiveSpec;
use gonio_scheduler::plan::{BuildContext, SampleTraits};

/// A narrow GGX-like lobe over a weak diffuse base, defined here (not from the models).
fn narrow_lobe(g: &Geometry) -> f64 {
    let (wi, wo) = g.directions();
    if wi.z() <= 0.0 || wo.z() <= 0.0 {
        return 0.0;
    }
    let h = half_vector(&wi, &wo).expect("upper hemisphere");
    let a2: f64 = 0.1 * 0.1;
    let c2 = h.z() * h.z();
    let d = a2 / (std::f64::consts::PI * (c2 * (a2 - 1.0) + 1.0).powi(2));
    0.05 + 0.8 * d / (4.0 * wi.z() * wo.z()).max(0.05)
}

fn spec(budget: u32) -> AdaptiveSpec {
    AdaptiveSpec {
        budget_points: budget,
        budget_s: None,
        batch_points: 20,
        target_error: 0.0,
        first_pass_step_deg: 10.0,
        first_pass_theta_i_deg: None,
        resolution_deg: 5.0,
        first_pass_sweeps: None,
    }
}

/// Uniform isotropic grid with about `n` reachable points (theta_i <= theta_o, as the adaptive domain).
fn uniform(n: usize, reachable: &dyn Fn(&Geometry) -> bool) -> Vec<Geometry> {
    let mut best: Vec<Geometry> = Vec::new();
    let mut step = 30.0;
    while step > 2.0 {
        let mut pts = Vec::new();
        let nt = (85.0 / step) as usize;
        let np = (180.0 / (2.0 * step)) as usize;
        for a in 0..=nt {
            for b in a..=nt {
                for c in 0..=np {
                    let (ti, to, dp) = (a as f64 * step, b as f64 * step, c as f64 * 2.0 * step);
                    if (ti == 0.0 || to == 0.0) && c > 0 {
                        continue;
                    }
                    let g = Geometry::new(ti, 0.0, to, dp);
                    if reachable(&g) {
                        pts.push(g);
                    }
                }
            }
        }
        if pts.len() > n {
            break;
        }
        best = pts;
        step *= 0.97;
    }
    best
}

/// Log RMS error of the reconstruction over a dense reference set.
fn error(adaptive: &Adaptive, measured: &[Measured], reference: &[(Geometry, f64)]) -> f64 {
    let at: Vec<Geometry> = reference.iter().map(|r| r.0).collect();
    let rec = adaptive.reconstruct_all(measured, &at);
    let s: f64 = reference
        .iter()
        .zip(rec)
        .map(|((_, f), r)| (r.max(0.0).ln_1p() - f.ln_1p()).powi(2))
        .sum();
    (s / reference.len() as f64).sqrt()
}

/// How the adaptive planner is built in these tests: an isotropic sample, no start pose.
fn isotropic_context(inst: &gonio_instrument::Instrument) -> BuildContext<'_> {
    BuildContext {
        instrument: inst,
        traits: SampleTraits {
            isotropic: true,
            spectrally_flat: false,
        },
        sample_radius_mm: None,
        start: None,
    }
}

fn compare(name: &str, f: &dyn Fn(&Geometry) -> f64) -> f64 {
    let inst = simulated();
    let ctx = isotropic_context(&inst);
    let constraints = Constraints::new(&inst, None);
    let reachable = |g: &Geometry| {
        let (wi, wo) = g.directions();
        constraints.check_directions(&wi, &wo).is_ok()
    };
    let grid = uniform(300, &reachable);
    let n = grid.len();
    let adaptive = Adaptive::new(&spec(n as u32), &ctx).expect("adaptive");
    let mut measured: Vec<Measured> = Vec::new();
    loop {
        let batch = adaptive.next_batch(&measured, 0.0);
        if batch.done.is_some() || batch.geometries.is_empty() {
            break;
        }
        for g in batch.geometries {
            measured.push(Measured {
                geometry: g,
                value: f(&g),
            });
        }
    }
    assert_eq!(measured.len(), n, "the adaptive plan spends its point budget");
    // Dense reference: 20,000 points of the R3 low-discrepancy sequence, uniform in (theta_i, theta_o, delta_phi).
    let mut reference = Vec::new();
    for k in 1..=20_000u32 {
        let k = f64::from(k);
        let (u1, u2, u3) = (
            (0.5 + k * 0.819_172_513_4).fract(),
            (0.5 + k * 0.671_043_606_7).fract(),
            (0.5 + k * 0.549_700_477_5).fract(),
        );
        let (a, b) = (85.0 * u1, 85.0 * u2);
        let g = Geometry::new(a.min(b), 0.0, a.max(b), 180.0 * u3);
        if reachable(&g) {
            reference.push((g, f(&g)));
        }
    }
    let uniform_measured: Vec<Measured> = grid
        .iter()
        .map(|g| Measured {
            geometry: *g,
            value: f(g),
        })
        .collect();
    let e_adaptive = error(&adaptive, &measured, &reference);
    let e_uniform = error(&adaptive, &uniform_measured, &reference);
    println!(
        "{name}: {n} points, log-RMS error adaptive {e_adaptive:.4}, uniform {e_uniform:.4}, ratio {:.3}",
        e_adaptive / e_uniform
    );
    e_adaptive / e_uniform
}

#[test]
fn adaptive_beats_uniform_on_a_narrow_lobe() {
    let ratio = compare("narrow GGX-like lobe", &narrow_lobe);
    assert!(ratio < 1.0, "adaptive/uniform error {ratio}");
}

#[test]
fn adaptive_beats_uniform_on_the_gold_and_plastic_presets() {
    for name in ["gold", "coloured-plastic"] {
        let m = Material::preset(name).expect("preset");
        let wl = Wavelength::from_nm(550.0).expect("wavelength");
        let f = |g: &Geometry| {
            let (wi, wo): (Direction, Direction) = g.directions();
            m.eval(&wi, &wo, wl).expect("eval")
        };
        let ratio = compare(name, &f);
        assert!(ratio < 1.0, "{name}: adaptive/uniform error {ratio}");
    }
}

/// The planner's memory between batches (each candidate's nearest measured points) changes how fast a batch is
/// found, never which: over a whole budget, every batch placed with one memo kept from pass to pass is the batch
/// a fresh planner places from the same points, estimate included.
#[test]
fn batches_placed_with_a_memo_are_the_batches_placed_without() {
    let inst = simulated();
    let ctx = isotropic_context(&inst);
    let adaptive = Adaptive::new(&spec(260), &ctx).expect("adaptive");
    let mut memo = BatchMemo::new();
    let mut measured: Vec<Measured> = Vec::new();
    let mut batches = 0;
    loop {
        let fresh = adaptive.next_batch(&measured, 0.0);
        let remembered = adaptive.next_batch_remembering(&measured, measured.len(), 0.0, &mut memo);
        assert_eq!(
            remembered,
            fresh,
            "batch {batches} from {} points",
            measured.len()
        );
        if fresh.done.is_some() || fresh.geometries.is_empty() {
            break;
        }
        batches += 1;
        measured.extend(fresh.geometries.iter().map(|g| Measured {
            geometry: *g,
            value: narrow_lobe(g),
        }));
    }
    assert!(batches >= 5, "only {batches} batches: the memo was not exercised");
    assert_eq!(measured.len(), 260);
}
