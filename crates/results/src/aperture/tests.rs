use super::*;

use gonio_brdf::integrate::integrate_infallible;

pub(crate) const HALF_ANGLE_RAD: f64 = 0.01;

/// The cos-weighted aperture average of `material`, integrated independently of [`factor`] and of the fit's
/// 7-point rule (a lobe-adapted rule centred on the aperture, fixed and fine).
pub(crate) fn aperture_average(material: &Material, wi: &Direction, wo: &Direction, nm: f64) -> f64 {
    let wl = Wavelength::from_nm(nm).expect("band");
    let rule = Rule::LobeAdapted {
        lobe_width_rad: HALF_ANGLE_RAD / 8.0,
        n_per_panel: 8,
        n_azimuth: 32,
    };
    let integral = integrate_infallible(
        |w| material.eval(wi, w, wl).unwrap_or(0.0) * w.cos_theta().max(0.0),
        &Region::cone(*wo, HALF_ANGLE_RAD),
        rule,
    );
    integral.value / (cone_solid_angle_sr(HALF_ANGLE_RAD) * wo.cos_theta())
}

/// Geometries in the plane of incidence and off it, a third within 3 degrees of the specular direction.
fn geometries() -> Vec<[f64; 4]> {
    let mut g = Vec::new();
    for ti in [10.0, 30.0, 50.0, 65.0] {
        for k in 0..24 {
            let k = f64::from(k);
            g.push([ti, 0.0, ti + (k - 12.0) * 0.25, 180.0]);
            g.push([ti, 0.0, 5.0 + 3.0 * k, 180.0 + 7.0 * k]);
            g.push([ti, 0.0, ti, 180.0 + (k - 12.0) * 0.3]);
        }
    }
    g
}

fn run_of(material: &Material) -> (Run, Vec<f64>) {
    let wl = Wavelength::from_nm(550.0).expect("band");
    let mut points = Vec::new();
    let mut truth = Vec::new();
    for g in geometries() {
        let mut p = Point::at(550.0, g, 0.0);
        let (wi, wo) = directions(&p);
        p.brdf_sr = Some(aperture_average(material, &wi, &wo, 550.0));
        p.brdf_u_sr = Some(1e-4 * p.brdf_sr.unwrap_or(0.0));
        truth.push(material.eval(&wi, &wo, wl).expect("eval"));
        points.push(p);
    }
    let run = Run {
        origin: "test".into(),
        name: "aperture".into(),
        points,
        axis_names: Vec::new(),
        dry_run: true,
        provenance: None,
    };
    (run, truth)
}

#[test]
fn a_glossy_lobe_is_corrected_to_its_point_value_within_the_stated_uncertainty() {
    let gold = Material::preset("gold").expect("preset");
    let (run, truth) = run_of(&gold);
    let c = corrections(&run, &Optics::aperture_only(HALF_ANGLE_RAD)).expect("a model fits");
    assert_eq!(c.model, FitModel::Conductor, "rms {}", c.residual_rms);
    let (mut before, mut after, mut corrected) = (0.0f64, 0.0f64, 0);
    for ((p, t), corr) in run.points.iter().zip(&truth).zip(&c.points) {
        let v = p.brdf_sr.expect("value");
        let Some(Correction::Applied { factor, u_rel }) = corr else {
            panic!(
                "point at {:?} not corrected: {corr:?}",
                (p.theta_i_deg, p.theta_o_deg, p.phi_o_deg)
            );
        };
        let fixed = v * factor;
        before = before.max((v / t - 1.0).abs());
        after = after.max((fixed / t - 1.0).abs());
        // The correction's own uncertainty covers what is left (k = 2), with the data's 1e-4.
        assert!(
            (fixed / t - 1.0).abs() <= 2.0 * u_rel.hypot(1e-4) + 1e-6,
            "{:?}: {fixed} vs {t}, u_rel {u_rel}",
            (p.theta_i_deg, p.theta_o_deg, p.phi_o_deg)
        );
        corrected += usize::from((factor - 1.0).abs() > 1e-3);
    }
    // Near the peak the average is well below the point value; the correction removes nearly all of it.
    assert!(before > 3e-3, "largest aperture bias {before}");
    assert!(after < before / 5.0, "after {after}, before {before}");
    assert!(corrected > 20, "{corrected} points moved by more than 0.1 %");
}

#[test]
fn a_diffuse_sample_is_barely_moved() {
    let paper = Material::preset("construction-paper").expect("preset");
    let (run, truth) = run_of(&paper);
    let c = corrections(&run, &Optics::aperture_only(HALF_ANGLE_RAD)).expect("a model fits");
    assert_eq!(c.model, FitModel::OrenNayar, "rms {}", c.residual_rms);
    for ((p, t), corr) in run.points.iter().zip(&truth).zip(&c.points) {
        let Some(Correction::Applied { factor, u_rel }) = corr else {
            panic!("{corr:?}");
        };
        let fixed = p.brdf_sr.expect("value") * factor;
        // Oren-Nayar curves by up to 0.2 % over the aperture at grazing geometries: corrected as well.
        assert!((fixed / t - 1.0).abs() < 2e-5, "{fixed} vs {t} (c {factor})");
        assert!(
            (fixed / t - 1.0).abs() <= 2.0 * u_rel.hypot(1e-4),
            "{fixed} vs {t}"
        );
    }
}

#[test]
fn a_lobe_narrower_than_the_aperture_is_flagged_with_at_least_its_whole_value_as_uncertainty() {
    let sharp = Material::from_document(
        "[material]\nmodel = \"conductor\"\ndistribution = \"ggx\"\nmasking = \"height-correlated\"\nalpha = 0.004\neta = 0.2\nk = 3.0\n",
        "sharp",
        std::path::Path::new("."),
    )
    .expect("material");
    let (run, truth) = run_of(&sharp);
    let c = corrections(&run, &Optics::aperture_only(HALF_ANGLE_RAD)).expect("a model fits");
    let mut flagged = 0;
    for ((p, t), corr) in run.points.iter().zip(&truth).zip(&c.points) {
        if let Some(Correction::NarrowLobe { u_rel }) = corr {
            flagged += 1;
            // The whole value at least: a point at the mirror direction of a delta (truth 0) is covered; the
            // peak of a finite lobe narrower than the aperture is not determined by averages (module doc).
            assert!(*u_rel >= 1.0, "{u_rel}");
            let v = p.brdf_sr.expect("value");
            if *t <= v {
                assert!((v - t).abs() <= 2.0 * u_rel * v, "{v} vs {t}");
            }
        }
    }
    assert!(flagged >= 20, "{flagged} flagged");
    // Far from the lobe nothing is flagged: corrected (by next to nothing) where a model describes the data, else
    // left as measured (no model fits aperture averages of a lobe this narrow: the best leaves about 40 %).
    for (p, corr) in run.points.iter().zip(&c.points) {
        let (wi, wo) = directions(p);
        let off_deg = (-wi.x() * wo.x() - wi.y() * wo.y() + wi.z() * wo.z())
            .clamp(-1.0, 1.0)
            .acos()
            .to_degrees();
        if off_deg > 5.0 {
            assert!(
                matches!(corr, Some(Correction::Applied { .. }) | None),
                "{off_deg} deg off: {corr:?}"
            );
        }
    }
}

#[test]
fn no_aperture_no_correction() {
    let (run, _) = run_of(&Material::preset("gold").expect("preset"));
    assert!(corrections(&run, &Optics::aperture_only(0.0)).is_none());
    assert!(corrections(&run, &Optics::aperture_only(f64::NAN)).is_none());
}

#[test]
fn the_slopes_follow_the_lobe() {
    let gold = Material::preset("gold").expect("preset");
    let (run, _) = run_of(&gold);
    let c = corrections(&run, &Optics::aperture_only(HALF_ANGLE_RAD)).expect("a model fits");
    let mut checked = 0;
    for (p, s) in run.points.iter().zip(&c.slopes) {
        let [gi, go, _] = s.expect("a slope at every valid point");
        // In the plane of incidence, on either side of the mirror direction, the lobe falls away from it.
        if p.phi_o_deg == 180.0 && (p.theta_o_deg - p.theta_i_deg).abs() > 1.0 && p.theta_o_deg < 60.0 {
            let away = (p.theta_o_deg - p.theta_i_deg).signum();
            assert!(
                go * away < -1.0,
                "{:?}: d ln f / d theta_o = {go}",
                (p.theta_i_deg, p.theta_o_deg)
            );
            assert!(
                gi * away > 0.0,
                "{:?}: d ln f / d theta_i = {gi}",
                (p.theta_i_deg, p.theta_o_deg)
            );
            checked += 1;
        }
    }
    assert!(checked >= 20, "{checked} points on the lobe's flanks");
}

/// A smooth matte model (albedo 0.5) that fitted well: what a fit that missed a lobe looks like.
fn matte_fit() -> Fitted {
    let matte = Material::from_document(
        "[material]\nmodel = \"lambertian\"\nalbedo = 0.5\n",
        "matte",
        std::path::Path::new("."),
    )
    .expect("material");
    Fitted {
        model: FitModel::OrenNayar,
        material: matte,
        rms: 0.01,
        alpha: None,
    }
}

#[test]
fn a_specular_value_the_model_does_not_resolve_is_not_corrected_by_it() {
    // A fit that missed the lobe: a smooth matte model, and points near the specular direction reading what a
    // mirror's delta puts through the aperture.
    let best = matte_fit();
    let models = [&best];
    let at = |g: [f64; 4], value: f64| {
        let mut p = Point::at(550.0, g, 0.0);
        p.brdf_sr = Some(value);
        p.brdf_u_sr = Some(1e-4 * value);
        p
    };
    let matte_value = 0.5 / std::f64::consts::PI;
    // 0.1 degree from the specular direction, a thousand times the model: flagged, the value its uncertainty.
    let spike = at([30.0, 0.0, 30.1, 180.0], 1000.0 * matte_value);
    assert!(matches!(
        correction(&spike, &Optics::aperture_only(HALF_ANGLE_RAD), &models),
        Some(Correction::NarrowLobe { u_rel }) if u_rel >= 1.0
    ));
    // The same geometry reading what the model says: corrected as usual.
    let matching = at([30.0, 0.0, 30.1, 180.0], 1.05 * matte_value);
    assert!(matches!(
        correction(&matching, &Optics::aperture_only(HALF_ANGLE_RAD), &models),
        Some(Correction::Applied { .. })
    ));
    // Far from the specular direction a misfit is the fit's business (its residual), not a lobe's.
    let far = at([30.0, 0.0, 60.0, 90.0], 1000.0 * matte_value);
    assert!(matches!(
        correction(&far, &Optics::aperture_only(HALF_ANGLE_RAD), &models),
        Some(Correction::Applied { .. })
    ));
}

#[test]
fn the_beam_s_width_widens_where_a_delta_reaches() {
    // A matte model and a point 0.9 degree from the specular direction reading a thousand times it: outside a
    // 0.57 degree aperture alone, inside it with a 1.5 mm beam at 250 mm (0.34 degree more).
    let best = matte_fit();
    let models = [&best];
    let mut p = Point::at(550.0, [30.0, 0.0, 30.9, 180.0], 0.0);
    p.brdf_sr = Some(1000.0 * 0.5 / std::f64::consts::PI);
    p.brdf_u_sr = Some(1e-4);
    let aperture = Optics::aperture_only(HALF_ANGLE_RAD);
    assert!(matches!(
        correction(&p, &aperture, &models),
        Some(Correction::Applied { .. })
    ));
    let with_beam = Optics {
        beam_half_angle_rad: 1.5 / 250.0,
        ..aperture
    };
    assert!(matches!(
        correction(&p, &with_beam, &models),
        Some(Correction::NarrowLobe { u_rel }) if u_rel >= 1.0
    ));
    // A misalignment allowance reaches further still: 1.3 degrees off with 0.4 degree of it.
    let mut far = p.clone();
    far.theta_o_deg = 31.3;
    assert!(matches!(
        correction(&far, &with_beam, &models),
        Some(Correction::Applied { .. })
    ));
    let misaligned = Optics {
        misalignment_rad: 0.4f64.to_radians(),
        ..with_beam
    };
    assert!(matches!(
        correction(&far, &misaligned, &models),
        Some(Correction::NarrowLobe { .. })
    ));
    // A fitted lobe no wider than the aperture and the beam together is the instrument's response, not the
    // sample's: flagged near the specular direction whatever its ratio.
    let sharpish = Fitted {
        alpha: Some(0.013),
        ..best
    };
    let mut near = p.clone();
    near.theta_o_deg = 30.2;
    let value_of = |f: &Fitted| {
        let (wi, wo) = directions(&near);
        point_and_average(
            &f.material,
            &wi,
            &wo,
            Wavelength::from_nm(550.0).expect("band"),
            HALF_ANGLE_RAD,
        )
        .expect("average")
        .1
    };
    near.brdf_sr = Some(value_of(&sharpish));
    assert!(matches!(
        correction(&near, &aperture, &[&sharpish]),
        Some(Correction::Applied { .. })
    ));
    assert!(matches!(
        correction(&near, &with_beam, &[&sharpish]),
        Some(Correction::NarrowLobe { .. })
    ));
}

#[test]
fn a_mirror_no_model_describes_is_flagged_where_the_beam_can_reach_and_left_alone_elsewhere() {
    // What a mirror reads: its reflection through the aperture near the specular direction (a tenth of the
    // beam's power over the aperture's solid angle), nothing elsewhere but the detector's noise.
    let optics = Optics {
        beam_half_angle_rad: 1.5 / 250.0,
        ..Optics::aperture_only(HALF_ANGLE_RAD)
    };
    let mut points = Vec::new();
    let mut k = 0u32;
    for g in geometries() {
        let mut p = Point::at(550.0, g, 0.0);
        let (wi, wo) = directions(&p);
        let off = wi.reflect_about_normal().angle_to(&wo);
        k += 1;
        let noise = 1e-6 * f64::from(k % 7) - 3e-6;
        let value = if off < optics.resolution_rad() {
            0.9 * (1.0 - off / optics.resolution_rad())
                / (cone_solid_angle_sr(HALF_ANGLE_RAD) * wo.cos_theta())
        } else {
            noise
        };
        p.brdf_sr = Some(value);
        p.brdf_u_sr = Some(1e-5 + 1e-4 * value.abs());
        points.push(p);
    }
    let run = Run {
        origin: "test".into(),
        name: "mirror".into(),
        points,
        axis_names: Vec::new(),
        dry_run: true,
        provenance: None,
    };
    let c = corrections(&run, &optics).expect("models fitted");
    assert!(
        c.residual_rms > MODEL_RMS_LIMIT,
        "{:?} {}",
        c.model,
        c.residual_rms
    );
    let mut flagged = 0;
    for (p, corr) in run.points.iter().zip(&c.points) {
        let (wi, wo) = directions(p);
        let off = wi.reflect_about_normal().angle_to(&wo);
        // Flagged wherever the beam can reach, and as far as the poor fit's lobe says; far beyond both, left as
        // measured.
        if off <= optics.delta_reach_rad() {
            flagged += 1;
            assert_eq!(
                corr,
                &Some(Correction::NarrowLobe { u_rel: 1.0 }),
                "{off} rad off"
            );
        } else if off > 10f64.to_radians() {
            assert_eq!(corr, &None, "{off} rad off");
        } else {
            assert!(!matches!(corr, Some(Correction::Applied { .. })), "{off} rad off");
        }
    }
    assert!(flagged >= 20, "{flagged}");
}
