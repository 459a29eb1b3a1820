use super::*;

use crate::aperture::tests::{HALF_ANGLE_RAD, aperture_average};
use crate::budget::{Budget, components};
use crate::points::Point;

/// Gold's aperture averages (noise-free), each stored as a completed campaign stores it: the average in
/// `brdf_aperture_sr` and beside it a value "corrected" to the nominal geometry by a correction that is 2 %
/// wrong near the specular direction (the correction's error: the `aperture` component says 2 %), with an
/// independent noise of 1e-4 of the value.
fn gold_run() -> Run {
    let gold = Material::preset("gold").expect("preset");
    let mut points = Vec::new();
    for ti in [10.0, 30.0, 50.0] {
        for k in 0..20 {
            let k = f64::from(k);
            for g in [
                [ti, 0.0, ti + (k - 10.0) * 0.8, 180.0],
                [ti, 0.0, 5.0 + 3.5 * k, 180.0 + 8.0 * k],
            ] {
                let mut p = Point::at(550.0, g, 0.0);
                let (wi, wo) = directions(&p);
                let average = aperture_average(&gold, &wi, &wo, 550.0);
                let near_specular = (g[2] - ti).abs() < 4.0 && g[3] == 180.0;
                let wrong = if near_specular { 1.02 } else { 1.0 };
                let value = average * wrong;
                p.brdf_sr = Some(value);
                p.brdf_aperture_sr = Some(average);
                let mut budget = Budget::default();
                budget.add(components::SIGNAL_NOISE, 1e-4 * value, None);
                budget.add(components::APERTURE, 0.02 * value, None);
                p.brdf_u_sr = Some(budget.total_sr());
                p.budget = budget;
                points.push(p);
            }
        }
    }
    dry_run_of("gold", points)
}

/// A dry-run of these points, without provenance.
fn dry_run_of(name: &str, points: Vec<Point>) -> Run {
    Run {
        origin: "test".into(),
        name: name.into(),
        points,
        axis_names: Vec::new(),
        dry_run: true,
        provenance: None,
    }
}

fn alpha(report: &FitReport) -> f64 {
    report
        .params
        .iter()
        .find(|p| p.key == "alpha")
        .map(|p| p.value)
        .expect("alpha")
}

#[test]
fn corrected_values_are_fitted_as_the_aperture_averages_they_were() {
    let run = gold_run();
    let mut opts = FitOptions::new(FitModel::Conductor);
    opts.aperture_half_angle_rad = Some(HALF_ANGLE_RAD);
    let report = fit(&run, &opts).expect("fit");
    // The averages against the averaged model, weighted by the noise alone: gold's roughness comes back, and
    // the residuals are what the 7-point rule leaves (far under the 1e-4 noise the points state).
    assert!(
        (alpha(&report) / 0.08 - 1.0).abs() < 1e-4,
        "alpha {}",
        alpha(&report)
    );
    assert!(
        report.residuals.chi2_per_dof < 0.1,
        "chi2/dof {}",
        report.residuals.chi2_per_dof
    );
    // Without the aperture's size the corrected values are all there is: their 2 % error near the specular
    // direction, down-weighted by the correction's uncertainty, still pulls the roughness further away.
    let point_values = fit(&run, &FitOptions::new(FitModel::Conductor)).expect("fit");
    assert!(
        (alpha(&point_values) / 0.08 - 1.0).abs() > 10.0 * (alpha(&report) / 0.08 - 1.0).abs(),
        "alpha {} from the corrected values, {} from the averages",
        alpha(&point_values),
        alpha(&report)
    );
}

/// White styrofoam's point values (noise-free), each with an independent noise of 1e-3 of the value, the
/// campaign's solid angle (1e-3, the same way for all) and one angle error that raises the values beyond
/// theta_o = 40 degrees and lowers those before it (signed: crate::budget).
fn styrofoam_run() -> Run {
    let foam = Material::preset("white-styrofoam").expect("preset");
    let wl = Wavelength::from_nm(450.0).expect("band");
    let mut points = Vec::new();
    for ti in [0.0, 20.0, 40.0, 60.0] {
        for k in 0..16 {
            let k = f64::from(k);
            let mut p = Point::at(450.0, [ti, 0.0, 2.0 + 5.0 * k, 20.0 * k], 0.0);
            let (wi, wo) = directions(&p);
            let value = foam.eval(&wi, &wo, wl).expect("eval");
            p.brdf_sr = Some(value);
            let mut budget = Budget::default();
            budget.add(components::SIGNAL_NOISE, 1e-3 * value, None);
            budget.add(components::SOLID_ANGLE, 1e-3 * value, Some("campaign".into()));
            let side = if p.theta_o_deg > 40.0 { 1.0 } else { -1.0 };
            budget.add(components::POINTING, side * 2e-3 * value, Some("theta_o".into()));
            p.brdf_u_sr = Some(budget.total_sr());
            p.budget = budget;
            points.push(p);
        }
    }
    dry_run_of("styrofoam", points)
}

#[test]
fn what_the_points_share_moves_the_parameters_as_refitting_the_moved_points_does() {
    let run = styrofoam_run();
    // Plain least squares: a robust loss reweights noise-free points by residuals of nothing, and the refit's
    // weights would then differ from the solution's by more than the move itself.
    let opts = FitOptions {
        loss: Loss::None,
        ..FitOptions::new(FitModel::OrenNayar)
    };
    let report = fit(&run, &opts).expect("fit");
    // Each group moved in turn and the whole robust fit repeated: the reference the linearisation must meet.
    let refit_shift = |group: &str| -> Vec<f64> {
        let mut moved = run.clone();
        for p in &mut moved.points {
            let u: f64 = p
                .budget
                .entries
                .iter()
                .filter(|e| e.shared.as_deref() == Some(group))
                .map(|e| e.u_sr)
                .sum();
            p.brdf_sr = p.brdf_sr.map(|f| f + u);
        }
        let refit = fit_unshared(&moved, &opts, Chi2Whole::Skip).expect("refit");
        refit
            .params
            .iter()
            .zip(&report.params)
            .map(|(a, b)| a.value - b.value)
            .collect()
    };
    let (omega, angle) = (refit_shift("campaign"), refit_shift("theta_o"));
    for (k, p) in report.params.iter().enumerate() {
        let expected = omega[k].hypot(angle[k]);
        let got = p.shared_uncertainty.expect("moved by what is shared");
        assert!(
            (got / expected - 1.0).abs() < 0.02,
            "{}: {got} against {expected} by refitting",
            p.key
        );
    }
    // The signed angle error tilts the values against theta_o: it moves the roughness, which a common scale
    // (the solid angle) cannot; the solid angle moves the albedo by its 1e-3.
    let sigma = report
        .params
        .iter()
        .position(|p| p.key == "sigma_deg")
        .expect("sigma");
    let albedo = report
        .params
        .iter()
        .position(|p| p.key == "albedo")
        .expect("albedo");
    assert!(
        angle[sigma].abs() > 100.0 * omega[sigma].abs(),
        "{angle:?} {omega:?}"
    );
    assert!(
        (omega[albedo] / report.params[albedo].value - 1e-3).abs() < 1e-5,
        "{omega:?}"
    );
}

#[test]
fn chi2_counts_what_the_points_share_as_shared() {
    // The angle error happened, three of its standard uncertainties: every value moved by three times its
    // signed entry, the values beyond theta_o = 40 degrees up and the others down.
    let mut run = styrofoam_run();
    for p in &mut run.points {
        let e: f64 = p
            .budget
            .entries
            .iter()
            .filter(|e| e.shared.as_deref() == Some("theta_o"))
            .map(|e| e.u_sr)
            .sum();
        p.brdf_sr = p.brdf_sr.map(|f| f + 3.0 * e);
    }
    let opts = FitOptions {
        loss: Loss::None,
        ..FitOptions::new(FitModel::OrenNayar)
    };
    let r = fit(&run, &opts).expect("fit").residuals;
    // Against the independent 1e-3 alone the step is misfit, tens of its uncertainties; against the whole
    // budget it is the one error of three standard uncertainties it is: at the true roughness and albedo
    // the noise-free points leave nothing but that error's 3^2 (the fit, weighted by the independent parts,
    // bent its roughness towards the step; the whole budget's sum is taken where the parameters fit best
    // under it, which is no worse than the truth).
    assert!(r.chi2_per_dof_independent > 20.0, "{r:?}");
    let dof = (r.points - 2) as f64;
    assert!(r.chi2_per_dof * dof <= 9.0 * 1.05, "{r:?}");
    assert!(
        r.chi2_per_dof * dof > 1.0,
        "the step is an error of several uncertainties: {r:?}"
    );
    // Without anything shared, the whole budget is the independent part, and its minimum over the parameters
    // is no larger than its value at the fit's.
    let plain = fit(&styrofoam_run_without_shared(), &opts)
        .expect("fit")
        .residuals;
    assert!(
        plain.chi2_per_dof <= plain.chi2_per_dof_independent * (1.0 + 1e-9) + 1e-12,
        "{plain:?}"
    );
}

/// A standard normal deviate per index (splitmix64, Box-Muller): noise for a test, the same on every run.
fn normal(seed: u64, i: u64) -> f64 {
    let mix = |mut z: u64| {
        z = z.wrapping_add(0x9E37_79B9_7F4A_7C15);
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    };
    let uniform = |z: u64| ((z >> 11) as f64 + 0.5) / (1u64 << 53) as f64;
    let (a, b) = (
        uniform(mix(seed ^ (2 * i))),
        uniform(mix(seed.rotate_left(17) ^ (2 * i + 1))),
    );
    (-2.0 * a.ln()).sqrt() * (std::f64::consts::TAU * b).cos()
}

#[test]
fn chi2_of_the_true_model_is_about_one_when_the_points_share_a_large_error() {
    // White styrofoam at 240 geometries, each value off by independent noise of its stated 1e-3 and by one
    // error of the detector's angle 2.5 of its standard uncertainties (2e-3 of the value, signed by the side of
    // theta_o = 40 deg) and one of the solid angle: the fit, weighted by the independent part, bends towards
    // the angle's step; against the whole budget the data are what the budget says they are.
    let foam = Material::preset("white-styrofoam").expect("preset");
    let wl = Wavelength::from_nm(450.0).expect("band");
    for seed in [1u64, 2, 3] {
        let mut points = Vec::new();
        for (j, ti) in [0.0, 10.0, 20.0, 30.0, 40.0, 50.0, 60.0, 70.0]
            .into_iter()
            .enumerate()
        {
            for k in 0..30 {
                let kf = f64::from(k);
                let mut p = Point::at(450.0, [ti, 0.0, 2.0 + 2.6 * kf, 12.0 * kf], 0.0);
                let (wi, wo) = directions(&p);
                let truth = foam.eval(&wi, &wo, wl).expect("eval");
                let side = if p.theta_o_deg > 40.0 { 1.0 } else { -1.0 };
                let i = (j * 30 + k as usize) as u64;
                let noise = 1e-3 * truth * normal(seed, i);
                p.brdf_sr = Some(truth + noise + 2.5 * side * 2e-3 * truth - 1.0 * 1e-3 * truth);
                let mut budget = Budget::default();
                budget.add(components::SIGNAL_NOISE, 1e-3 * truth, None);
                budget.add(components::SOLID_ANGLE, 1e-3 * truth, Some("campaign".into()));
                budget.add(components::POINTING, side * 2e-3 * truth, Some("theta_o".into()));
                p.brdf_u_sr = Some(budget.total_sr());
                p.budget = budget;
                points.push(p);
            }
        }
        let opts = FitOptions {
            loss: Loss::None,
            ..FitOptions::new(FitModel::OrenNayar)
        };
        let r = fit(&dry_run_of("styrofoam", points), &opts)
            .expect("fit")
            .residuals;
        // 238 degrees of freedom: chi2/dof has a standard deviation of about 0.09.
        assert!(
            (0.7..1.35).contains(&r.chi2_per_dof),
            "seed {seed}: chi2/dof {} (against the independent part alone {})",
            r.chi2_per_dof,
            r.chi2_per_dof_independent
        );
        assert!(r.chi2_per_dof_independent > 3.0, "seed {seed}: {r:?}");
    }
}

fn styrofoam_run_without_shared() -> Run {
    let mut run = styrofoam_run();
    for p in &mut run.points {
        p.budget.entries.retain(|e| e.shared.is_none());
        p.brdf_u_sr = Some(p.budget.total_sr());
    }
    run
}

/// Standard normal draws from a fixed seed (xorshift64 and Box-Muller): the tests' noise, the same every run.
fn normal_draws(seed: u64, n: usize) -> Vec<f64> {
    let mut state = seed.max(1);
    let mut uniform = move || {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        ((state >> 11) as f64 + 0.5) / (1u64 << 53) as f64
    };
    (0..n)
        .map(|_| {
            let (a, b) = (uniform(), uniform());
            (-2.0 * a.ln()).sqrt() * (std::f64::consts::TAU * b).cos()
        })
        .collect()
}

/// 64 points of a Lambertian sample of `albedo`, half near the normal (theta_o 10-16 deg, a cosine weight near 1)
/// known to `near_rel` of the value, half near grazing (theta_o 84 deg, a cosine weight of 0.1) known to
/// `grazing_rel`, each value with its stated noise drawn (seed `seed`).
fn lambertian_near_and_grazing(albedo: f64, seed: u64, near_rel: f64, grazing_rel: f64) -> Vec<Point> {
    let draws = normal_draws(seed, 64);
    (0..64)
        .map(|k| {
            let near = k % 2 == 0;
            let g = if near {
                [5.0, 0.0, 10.0 + 0.1 * f64::from(k), 180.0]
            } else {
                [5.0, 0.0, 84.0, 3.0 * f64::from(k)]
            };
            let rel = if near { near_rel } else { grazing_rel };
            let value = albedo / std::f64::consts::PI;
            let mut p = Point::at(550.0, g, 0.0);
            p.brdf_sr = Some(value * (1.0 + rel * draws[k as usize]));
            let mut budget = Budget::default();
            budget.add(components::SIGNAL_NOISE, rel * value, None);
            p.brdf_u_sr = Some(budget.total_sr());
            p.budget = budget;
            p
        })
        .collect()
}

#[test]
fn the_stated_parameter_uncertainty_covers_the_truth_over_noise_draws() {
    // A Lambertian sample (albedo 0.9), half its points near the normal and known to 1e-4, half near grazing
    // (theta_o 84 deg, a cosine weight of 0.1) and known to 1e-3, each value with its stated noise drawn, fitted
    // as a lab fits them (the default robust loss). The cosine weights make the residuals other than
    // standardised: (J^T J)^-1 scaled by the mean residual alone understates the albedo's uncertainty here by
    // about 1.4 (as it made the coloured plastic's alpha 2 of its uncertainties off in rms on the ideal
    // instrument); the sandwich does not.
    let albedo = 0.9;
    let mut z = Vec::new();
    for seed in 1..=40u64 {
        let points = lambertian_near_and_grazing(albedo, seed, 1e-4, 1e-3);
        let report = fit(
            &dry_run_of("lambertian", points),
            &FitOptions::new(FitModel::Lambertian),
        )
        .expect("fit");
        let fitted = report.params.iter().find(|p| p.key == "albedo").expect("albedo");
        z.push((fitted.value - albedo) / fitted.std_uncertainty.expect("u"));
    }
    let rms = (z.iter().map(|z| z * z).sum::<f64>() / z.len() as f64).sqrt();
    assert!((0.75..1.3).contains(&rms), "rms z {rms} over {z:?}");
}

#[test]
fn an_outlier_is_judged_by_its_own_noise_not_by_its_cosine_weight() {
    // Clean data (every value within its stated Gaussian noise, 1e-4 of the value), half the points near the
    // normal (cosine weight near 1), half near grazing (theta_o 84 deg, a cosine weight of 0.1). Judged
    // cos-weighted, the residuals' robust scale came from the grazing half and a fifth of the sound points near
    // the normal read as outliers (a Gaussian sample's share beyond the Cauchy weight's half is under 2 %); the
    // robust loss is then a loss of information the stated uncertainty does not know about.
    let albedo = 0.9;
    let (mut z, mut downweighted, mut points_fitted) = (Vec::new(), 0, 0);
    for seed in 101..=140u64 {
        let points = lambertian_near_and_grazing(albedo, seed, 1e-4, 1e-4);
        let report = fit(
            &dry_run_of("lambertian", points),
            &FitOptions::new(FitModel::Lambertian),
        )
        .expect("fit");
        downweighted += report.downweighted;
        points_fitted += report.residuals.points;
        let fitted = report.params.iter().find(|p| p.key == "albedo").expect("albedo");
        z.push((fitted.value - albedo) / fitted.std_uncertainty.expect("u"));
    }
    let share = downweighted as f64 / points_fitted as f64;
    assert!(
        share < 0.05,
        "{downweighted} of {points_fitted} sound points down-weighted"
    );
    let rms = (z.iter().map(|z| z * z).sum::<f64>() / z.len() as f64).sqrt();
    assert!((0.75..1.25).contains(&rms), "rms z {rms} over {z:?}");
}

#[test]
fn each_band_of_a_conductor_starts_from_its_own_pair() {
    // Gold's bands want different pairs (eta 1.5 at 450 nm, 0.35 at 550, 0.17 at 650): a cost that is each
    // band's distance to its own metal's (eta, k), and a start that gives every band the same pair.
    let defs = params::param_defs(FitModel::Conductor, 3);
    let want = [(1.51, 1.88), (0.35, 2.71), (0.168, 3.138)];
    let index = |key: &str, b: usize| {
        defs.iter()
            .position(|d| d.key == key && d.band == Some(b))
            .expect("a parameter per band")
    };
    let cost = |x: &[f64]| -> f64 {
        (0..3)
            .map(|b| (x[index("eta", b)] - want[b].0).powi(2) + (x[index("k", b)] - want[b].1).powi(2))
            .sum()
    };
    let mut start = vec![0.08; defs.len()];
    for b in 0..3 {
        (start[index("eta", b)], start[index("k", b)]) = (1.2, 6.0);
    }
    observations::pairs_per_band(&mut start, &defs, 3, cost);
    let pair = |b: usize| (start[index("eta", b)], start[index("k", b)]);
    assert_eq!(pair(0), (1.5, 2.0));
    assert_eq!(pair(1), (0.3, 3.0));
    assert_eq!(pair(2), (0.3, 3.0));
    // Nothing to choose for a model without them: the start is left alone.
    let lambertian = params::param_defs(FitModel::Lambertian, 3);
    let mut albedo = vec![0.5; lambertian.len()];
    observations::pairs_per_band(&mut albedo, &lambertian, 3, |_| 0.0);
    assert!(albedo.iter().all(|a| *a == 0.5));
}

#[test]
fn the_whole_budgets_minimum_is_found_from_far_off_not_read_from_one_linear_step() {
    // Residuals nonlinear in the one parameter (a rate x in e^(x t_k), as alpha moves a lobe's shape), started
    // far from their minimum: one linearised step from there (what the fit once reported) reads a sum well off
    // the minimum; the search lands on it. No shared groups: the minimum is the least squares' own, found here
    // by a ternary search on the one parameter.
    let draws = normal_draws(7, 20);
    let t: Vec<f64> = (0..20).map(|k| 0.1 * f64::from(k)).collect();
    let y: Vec<f64> = t
        .iter()
        .zip(&draws)
        .map(|(t, d)| (0.5 * t).exp() + 0.05 * d)
        .collect();
    let points: Vec<Point> = (0..20)
        .map(|_| Point::at(550.0, [10.0, 0.0, 20.0, 180.0], 0.0))
        .collect();
    let run = dry_run_of("rate", points);
    let obs: Vec<Obs> = (0..20)
        .map(|k| Obs {
            point: k,
            per_value: 1.0,
            wi: Direction::NORMAL,
            wo: Direction::NORMAL,
            band: 0,
            f: y[k],
            u: 1.0,
            cos_weight: 1.0,
            cos_i: 1.0,
            aperture: Vec::new(),
        })
        .collect();
    let standardised = |x: &[f64]| -> Option<Vec<f64>> {
        Some(t.iter().zip(&y).map(|(t, y)| (x[0] * t).exp() - y).collect())
    };
    let sum = |x: f64| standardised(&[x]).expect("z").iter().map(|z| z * z).sum::<f64>();
    let (mut lo, mut hi) = (-1.0, 2.0);
    for _ in 0..200 {
        let (a, b) = (lo + (hi - lo) / 3.0, hi - (hi - lo) / 3.0);
        if sum(a) < sum(b) {
            hi = b;
        } else {
            lo = a;
        }
    }
    let minimum = sum(0.5 * (lo + hi));
    let start = [1.5];
    let bounds = ([-10.0].as_slice(), [10.0].as_slice());
    let found =
        shared::whole_budget_minimum(&run, &obs, &start, &[false], bounds, standardised).expect("a minimum");
    assert!(
        (found - minimum).abs() <= 1e-6 * minimum,
        "found {found}, the minimum is {minimum}"
    );
    let z = standardised(&start).expect("z");
    let a = lm::jacobian(&standardised, &start, &z, bounds.0, bounds.1).expect("derivative");
    let one_step = shared::chi2_whole_budget(&run, &obs, &z, &a, 0.0)
        .expect("one step")
        .chi2;
    assert!(
        (one_step - minimum).abs() > 0.5 * minimum,
        "one step {one_step} against {minimum}: the case does not tell the search from one step"
    );
}
