//! What "silently wrong" means for a dry-run point: its value against the simulator's ground truth stored with it
//! ([`check_points`], the verdict on every point of every soak that runs a campaign).
//!
//! On the ideal instrument (`config/instruments/simulated.toml`) a measured BRDF differs from the aperture-averaged
//! truth only by the reading's noise, so a value more than 5 standard uncertainties (plus the optics' 1e-6
//! integration floor) away is wrong: data the host corrupted (a stale or mismatched reply, a value stored for the
//! wrong point).
//!
//! On an imperfect instrument (`config/instruments/realistic.toml`) the instrument's own errors, 1-2 % and more
//! near specular, are real and expected: the host cannot know them, so they are not data loss. A value is then
//! silently wrong only when it is further from its truth than its noise PLUS everything the imperfections can
//! explain, taken from the point's own attribution (`truth_effects_json`, what each effect did to this reading):
//! - the point's attributed effects, each as a magnitude and compounded (`Π(1 + |e|) - 1`): geometry (the BRDF at
//!   the true geometry against the nominal one), the sample's non-uniformity, the source's flicker, the
//!   photodiode's saturation, the range's gain, nonlinearity and offset, the stray light (`s / (1 - s)` of a
//!   reading whose fraction `s` is stray), the finite band's mean of the sample's spectrum against its centre
//!   value (`filter`), the beam's profile and true divergence (`beam`), and the beam missing the field of view
//!   (`1 - intercepted_fraction`);
//! - the ambient light against the light, scaled by how much it can change between the dark reading (which
//!   subtracts the ambient light of its moment) and the point: `2v / (1 - v)` of it for a variation `v`;
//! - the source's slow factor (warm-up and walk) against the direct-beam reading's, which no point records: the
//!   BRDF sees their ratio, and the reference's factor lies between `1 - warm-up - 5 sigma of walk` and
//!   `1 + 5 sigma of walk` over the campaign, so the term is the larger of the ratio's two extremes;
//! - the direct-beam reading's other imperfections (flicker, range gain, nonlinearity, offset, saturation, stray
//!   light): a bound from the file's magnitudes ([`Tolerance::reference_rel`]);
//! - and the pose: the true incident and outgoing directions (after zero offsets, sample tilt and re-seating,
//!   eccentricity, encoder error) must lie within [`Tolerance::pose_deg`] of the nominal ones, a bound from the
//!   file's geometry magnitudes: a reading taken at another pose than the point's is wrong however close its
//!   value happens to be.
//!
//! What this cannot see: a corruption smaller than the point's allowance (reported as its median and largest over
//! the campaign, so the reader knows the check's resolution). The soaks' other guarantees (every planned row once,
//! committed rows unchanged byte for byte, safety) do not depend on the instrument's errors and are checked as on
//! the ideal instrument.

use std::collections::BTreeMap;

use gonio_engine::store::PointRecord;
use gonio_instrument::InstrumentFile;
use gonio_results::budget::components;
use serde_json::Value;

/// Standard deviations the bounds from the file's magnitudes span (the hidden values are drawn as Gaussians with
/// those standard deviations; 5 sigma is also the noise bound of the ideal check).
pub const K_SIGMA: f64 = 5.0;

/// How far an imperfect instrument's point may be from its truth, from the instrument file's magnitudes.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Tolerance {
    /// The file has imperfections: points carry an attribution and the allowances apply.
    pub imperfect: bool,
    /// Relative bound on the direct-beam reading's own imperfections but the source's slow drift.
    pub reference_rel: f64,
    /// The source's warm-up (relative deficit at switch-on) and random walk per square root of an hour.
    pub warmup_fraction: f64,
    pub walk_per_rthour: f64,
    /// The fraction of the ambient light a dark reading may leave behind: `2v / (1 - v)` for its variation `v`.
    pub ambient_residual: f64,
    /// Largest angle between a point's nominal and true directions the geometry errors explain (deg).
    pub pose_deg: f64,
}

impl Tolerance {
    /// The ideal instrument: only the noise.
    pub fn ideal() -> Tolerance {
        Tolerance::default()
    }

    /// The tolerance of the instrument `file`.
    pub fn of(file: &InstrumentFile) -> Tolerance {
        let imp = &file.simulator.imperfections;
        if imp.is_ideal() {
            return Tolerance::ideal();
        }
        let (g, d, s) = (&imp.geometry, &imp.detector, &imp.source);
        let det = &file.instrument.detector;
        // The direct beam's photocurrent, at most the source's power at 1 A/W (silicon stays below 0.7 A/W).
        let beam_a = file.instrument.source.power_w.max(0.0);
        let saturation = if d.saturation_current_a > 0.0 {
            beam_a / (beam_a + d.saturation_current_a)
        } else {
            0.0
        };
        // The detector aperture's solid angle: the stray light the direct-beam reading collects at its peak.
        let aperture_sr = if det.distance_mm > 0.0 {
            std::f64::consts::PI * (det.aperture_radius_mm / det.distance_mm).powi(2)
        } else {
            0.0
        };
        let reference_rel = K_SIGMA * s.flicker_rms
            + K_SIGMA * (d.range_gain_sd + d.nonlinearity_sd)
            // Auto-ranging keeps a reading above a tenth of its range's full scale (the ranges are decades apart).
            + K_SIGMA * d.offset_sd_fs * 10.0
            + saturation
            + d.stray_peak_sr * aperture_sr;
        // Each direction goes through the zero offsets of two axes, the sample's tilt and its re-seating (two
        // components each), the eccentricity seen from the arm's distance, and the encoder's cyclic error on two
        // axes.
        let eccentricity_deg = if det.distance_mm > 0.0 {
            (2.0 * g.eccentricity_sd_mm / det.distance_mm).atan().to_degrees()
        } else {
            0.0
        };
        let pose_deg = K_SIGMA
            * (2.0 * g.zero_offset_sd_deg
                + 2.0 * g.sample_tilt_sd_deg
                + 2.0 * g.reseat_tilt_sd_deg
                + eccentricity_deg)
            + 2.0 * g.encoder_error_amplitude_deg
            // The plan's angles are rounded to 0.1 deg in the soak's campaign text.
            + 0.01;
        let v = d.ambient_variation.max(0.0);
        Tolerance {
            imperfect: true,
            reference_rel,
            warmup_fraction: s.warmup_fraction,
            walk_per_rthour: s.random_walk_per_rthour,
            ambient_residual: if v < 1.0 {
                (2.0 * v / (1.0 - v)).min(1.0)
            } else {
                1.0
            },
            pose_deg,
        }
    }

    /// The range of the direct-beam reading's slow source factor over a campaign of `campaign_s` instrument
    /// seconds: (lowest, highest).
    pub fn reference_slow_range(&self, campaign_s: f64) -> (f64, f64) {
        let walk = K_SIGMA * self.walk_per_rthour * (campaign_s.max(0.0) / 3600.0).sqrt();
        ((1.0 - self.warmup_fraction - walk).max(1e-3), 1.0 + walk)
    }
}

/// The verdict on every point.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct PointCheck {
    /// Values within tolerance of the ground truth.
    pub valid: u64,
    /// Points recorded as failed (`failed: ...`), by reason (the device and error, numbers stripped).
    pub failed: BTreeMap<String, u64>,
    /// Points without a value for a measurement reason (overfilled, grazing, saturated, ...), by flag.
    pub flagged: BTreeMap<String, u64>,
    /// Values outside tolerance: silently wrong (index and details).
    pub wrong: Vec<String>,
    /// Points with neither a valid value nor a reason (index and details).
    pub unexplained: Vec<String>,
    /// Largest |f - truth| / u over the valid points.
    pub max_error_in_u: f64,
    /// Largest |f - truth| over the reading's own noise (the budget's `signal-noise` and `dark`): how far the
    /// imperfections move a value beyond what noise alone would.
    pub max_error_in_noise: f64,
    /// Largest |f - truth| / |truth| over the valid points.
    pub max_error_rel: f64,
    /// Largest |f - truth| over its bound (noise plus allowance) over the valid points: below 1 by definition.
    pub max_bound_used: f64,
    /// The imperfections' relative allowance over the valued points (0 on the ideal instrument): median, largest.
    pub allowance_median_rel: f64,
    pub allowance_max_rel: f64,
    /// Largest angle between a valued point's nominal and true directions (deg; 0 on the ideal instrument).
    pub max_pose_deg: f64,
    /// The bounds applied: the direct-beam reading's relative allowance but the source's drift, the pose's (deg);
    /// 0 on the ideal one.
    pub reference_rel: f64,
    pub pose_bound_deg: f64,
}

impl PointCheck {
    pub fn failed_total(&self) -> u64 {
        self.failed.values().sum()
    }
    pub fn flagged_total(&self) -> u64 {
        self.flagged.values().sum()
    }
}

/// Check committed points against the ground truth stored with them, on an instrument of tolerance `tol`
/// ([`crate::truth_check`]).
pub fn check_points(points: &[PointRecord], tol: &Tolerance) -> PointCheck {
    let campaign_s = points.iter().map(|p| p.t_s).fold(0.0f64, f64::max);
    let mut c = PointCheck {
        reference_rel: tol.reference_rel,
        pose_bound_deg: tol.pose_deg,
        ..PointCheck::default()
    };
    let mut allowances = Vec::new();
    for p in points {
        let failed = p.flags.iter().find(|f| f.starts_with("failed"));
        let at = || {
            format!(
                "point {} ({} nm, theta_i {} theta_o {} phi_o {})",
                p.index, p.band_nm, p.theta_i_deg, p.theta_o_deg, p.phi_o_deg
            )
        };
        // The aperture average the detector saw (before a completed campaign's correction to the nominal
        // geometry, gonio_engine::budget), against the simulator's aperture truth.
        let seen = p.brdf_aperture_sr.or(p.brdf_sr);
        match (failed, seen, p.brdf_u_sr, p.truth_aperture_sr) {
            (Some(reason), None, _, _) => {
                *c.failed.entry(reason_class(reason)).or_default() += 1;
            }
            (None, None, _, _) if !p.flags.is_empty() => {
                for f in &p.flags {
                    *c.flagged.entry(f.clone()).or_default() += 1;
                }
            }
            (None, Some(f), Some(u), Some(t)) if p.flags.is_empty() => {
                let nominal = [p.theta_i_deg, p.phi_i_deg, p.theta_o_deg, p.phi_o_deg];
                // The imperfections' share: none on the ideal instrument; from the point's attribution otherwise.
                let (allowance, pose_deg) = if tol.imperfect {
                    match p
                        .truth_effects_json
                        .as_deref()
                        .map(|j| point_allowance(j, nominal, tol, campaign_s))
                    {
                        Some(Ok(allowance)) => allowance,
                        Some(Err(why)) => {
                            c.wrong.push(format!("{}: {f} 1/sr, truth {t}: {why}", at()));
                            continue;
                        }
                        None => {
                            c.wrong.push(format!(
                                "{}: {f} 1/sr, truth {t}: no attribution on an imperfect instrument",
                                at()
                            ));
                            continue;
                        }
                    }
                } else {
                    (0.0, 0.0)
                };
                allowances.push(allowance);
                c.max_pose_deg = c.max_pose_deg.max(pose_deg);
                let err = (f - t).abs();
                let bound = 5.0 * u + 1e-6 * t.abs() + allowance * t.abs();
                let pose_ok = !tol.imperfect || pose_deg <= tol.pose_deg;
                if f.is_finite() && u.is_finite() && u > 0.0 && err <= bound && pose_ok {
                    c.valid += 1;
                    c.max_error_in_u = c.max_error_in_u.max(err / u);
                    let noise = p
                        .budget
                        .entries
                        .iter()
                        .filter(|e| {
                            e.component == components::SIGNAL_NOISE || e.component == components::DARK
                        })
                        .map(|e| e.u_sr * e.u_sr)
                        .sum::<f64>()
                        .sqrt();
                    if noise > 0.0 {
                        c.max_error_in_noise = c.max_error_in_noise.max(err / noise);
                    }
                    if t != 0.0 {
                        c.max_error_rel = c.max_error_rel.max(err / t.abs());
                    }
                    c.max_bound_used = c.max_bound_used.max(err / bound);
                } else if !pose_ok {
                    c.wrong.push(format!(
                        "{}: measured {pose_deg:.3} deg from its nominal directions, beyond the {:.3} deg the \
                         geometry errors explain",
                        at(),
                        tol.pose_deg
                    ));
                } else {
                    c.wrong.push(format!(
                        "{}: {f} 1/sr, truth {t}, u {u} ({:.1} u off; imperfections allow {:.2} %)",
                        at(),
                        err / u,
                        allowance * 100.0
                    ));
                }
            }
            _ => c.unexplained.push(format!(
                "point {}: value {:?}, u {:?}, truth {:?}, flags {:?}",
                p.index, p.brdf_sr, p.brdf_u_sr, p.truth_aperture_sr, p.flags
            )),
        }
    }
    allowances.sort_by(f64::total_cmp);
    c.allowance_median_rel = allowances.get(allowances.len() / 2).copied().unwrap_or(0.0);
    c.allowance_max_rel = allowances.last().copied().unwrap_or(0.0);
    c
}

/// A point's nominal directions: `[theta_i, phi_i, theta_o, phi_o]` (deg).
pub type Nominal = [f64; 4];

/// The relative allowance of one point from its attribution on an instrument of tolerance `tol`, in a campaign of
/// `campaign_s` instrument seconds, or why the attribution cannot be used; also the pose error (deg) it records.
pub fn point_allowance(
    effects_json: &str,
    nominal: Nominal,
    tol: &Tolerance,
    campaign_s: f64,
) -> Result<(f64, f64), String> {
    let v: Value = serde_json::from_str(effects_json).map_err(|e| format!("attribution unreadable: {e}"))?;
    let num = |path: [&str; 2]| {
        v.get(path[0])
            .and_then(|o| o.get(path[1]))
            .and_then(Value::as_f64)
    };
    let mut factor = 1.0;
    for key in [
        "geometry",
        "sample",
        "source_flicker",
        "saturation",
        "meter",
        "filter",
        "beam",
    ] {
        if let Some(e) = num(["relative", key]) {
            factor *= 1.0 + e.abs();
        }
    }
    if let Some(e) = num(["relative", "ambient"]) {
        factor *= 1.0 + e.abs() * tol.ambient_residual;
    }
    if let Some(e) = num(["relative", "source_slow"]) {
        // The BRDF sees the point's slow factor over the direct-beam reading's.
        let point = 1.0 + e;
        let (lo, hi) = tol.reference_slow_range(campaign_s);
        factor *= 1.0 + (point / lo - 1.0).abs().max((point / hi - 1.0).abs());
    }
    factor *= 1.0 + tol.reference_rel;
    if let Some(s) = num(["relative", "stray"]) {
        let s = s.clamp(0.0, 0.999);
        factor *= 1.0 + s / (1.0 - s);
    }
    if let Some(f) = num(["optics", "intercepted_fraction"]) {
        factor *= 1.0 + (1.0 - f.clamp(0.0, 1.0));
    }
    let true_dir = [
        num(["optics", "true_theta_i_deg"]),
        num(["optics", "true_phi_i_deg"]),
        num(["optics", "true_theta_o_deg"]),
        num(["optics", "true_phi_o_deg"]),
    ];
    let [Some(ti), Some(pi), Some(to), Some(po)] = true_dir else {
        return Err("attribution without the true directions".into());
    };
    let pose_deg = angle_deg(nominal[0], nominal[1], ti, pi).max(angle_deg(nominal[2], nominal[3], to, po));
    if !(factor.is_finite() && pose_deg.is_finite()) {
        return Err("attribution not finite".into());
    }
    Ok((factor - 1.0, pose_deg))
}

/// The angle between two directions given as polar and azimuth angles (deg).
pub fn angle_deg(theta_a_deg: f64, phi_a_deg: f64, theta_b_deg: f64, phi_b_deg: f64) -> f64 {
    let unit = |t: f64, p: f64| {
        let (t, p) = (t.to_radians(), p.to_radians());
        [t.sin() * p.cos(), t.sin() * p.sin(), t.cos()]
    };
    let (a, b) = (unit(theta_a_deg, phi_a_deg), unit(theta_b_deg, phi_b_deg));
    let dot = (a[0] * b[0] + a[1] * b[1] + a[2] * b[2]).clamp(-1.0, 1.0);
    // atan2 of the cross and dot products: accurate for the small angles that matter here.
    let cross = [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ];
    let sin = (cross[0].powi(2) + cross[1].powi(2) + cross[2].powi(2)).sqrt();
    sin.atan2(dot).to_degrees()
}

/// A failure reason without its numbers, so that reasons of one kind count together.
pub(crate) fn reason_class(reason: &str) -> String {
    let mut out = String::new();
    let mut in_number = false;
    let mut chars = reason.chars().peekable();
    while let Some(ch) = chars.next() {
        let signed = matches!(ch, '-' | '+') && chars.peek().is_some_and(char::is_ascii_digit);
        if ch.is_ascii_digit() || signed || (in_number && matches!(ch, '.' | 'e' | '-' | '+')) {
            if !in_number {
                out.push('#');
            }
            in_number = true;
        } else {
            in_number = false;
            out.push(ch);
        }
    }
    if out.len() > 160 {
        let mut cut = 160;
        while !out.is_char_boundary(cut) {
            cut -= 1;
        }
        out.truncate(cut);
        out.push('…');
    }
    out
}

#[cfg(test)]
mod tests;
