//! The points CSV: `index,band_nm,theta_i_deg,phi_i_deg,theta_o_deg,phi_o_deg,signal_w,dark_w,incident_w,
//! brdf_sr,brdf_u_sr,flags,t_s`, one `<axis>_deg` read-back column per axis (instrument file order), then in
//! dry-runs `brdf_true_sr,brdf_true_aperture_sr`. Numbers are written in shortest round-trip form (ryu via
//! `Display`), so the CSV holds exactly what the store holds; a missing value is an empty field.

use std::fmt::Write as _;

use crate::store::PointRecord;

/// The fixed leading columns.
pub const HEADER: &str = "index,band_nm,theta_i_deg,phi_i_deg,theta_o_deg,phi_o_deg,signal_w,dark_w,incident_w,brdf_sr,brdf_u_sr,flags,t_s";

/// The header line (without newline) for these axes.
pub fn header(axis_names: &[String], dry_run: bool) -> String {
    let mut s = String::from(HEADER);
    for a in axis_names {
        let _ = write!(s, ",{a}_deg");
    }
    if dry_run {
        s.push_str(",brdf_true_sr,brdf_true_aperture_sr");
    }
    s
}

fn num(s: &mut String, v: f64) {
    // `+ 0.0` turns -0 into 0.
    let _ = write!(s, ",{}", v + 0.0);
}

fn opt(s: &mut String, v: Option<f64>) {
    match v {
        Some(v) => num(s, v),
        None => s.push(','),
    }
}

/// The whole CSV text, header included.
pub fn points_csv(points: &[PointRecord], axis_names: &[String], dry_run: bool) -> String {
    let mut s = header(axis_names, dry_run);
    s.push('\n');
    for p in points {
        let _ = write!(s, "{}", p.index);
        for v in [
            p.band_nm,
            p.theta_i_deg,
            p.phi_i_deg,
            p.theta_o_deg,
            p.phi_o_deg,
            p.signal_w,
            p.dark_w,
            p.incident_w,
        ] {
            num(&mut s, v);
        }
        opt(&mut s, p.brdf_sr);
        opt(&mut s, p.brdf_u_sr);
        // Flags never contain commas or quotes (they are our own words), but make sure.
        let flags = p.flags.join(";").replace([',', '"', '\n'], " ");
        let _ = write!(s, ",{flags}");
        num(&mut s, p.t_s);
        for name in axis_names {
            let v = p.readback_deg.iter().find(|(n, _)| n == name).map(|(_, v)| *v);
            opt(&mut s, v);
        }
        if dry_run {
            opt(&mut s, p.truth_point_sr);
            opt(&mut s, p.truth_aperture_sr);
        }
        s.push('\n');
    }
    s
}

/// Error of a dry-run against the simulator's ground truth, over valid points (a BRDF value and a truth).
/// Metrics of radiometry-and-materials.md "Error metrics": cosine-weighted relative RMS
/// `sqrt(sum(((f - t) cos theta_i)^2) / sum((t cos theta_i)^2))`, RMS log error
/// `sqrt(mean((ln(1 + f cos theta_i) - ln(1 + t cos theta_i))^2))`, and the largest relative error `|f - t| / t`.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct TruthErrors {
    pub points: usize,
    pub cos_weighted_relative_rms: f64,
    pub log_rms: f64,
    pub max_relative_error: f64,
    /// Largest |f - t| / u (u: the point's standard uncertainty).
    pub max_normalised_error: f64,
}

/// Errors against `truth` (a function picking the aperture-averaged or the point truth); None without points.
pub fn truth_errors(
    points: &[PointRecord],
    truth: impl Fn(&PointRecord) -> Option<f64>,
) -> Option<TruthErrors> {
    let (mut n, mut num, mut den, mut log2, mut max_rel, mut max_norm) =
        (0usize, 0.0, 0.0, 0.0, 0.0f64, 0.0f64);
    for p in points {
        let (Some(f), Some(t)) = (p.brdf_sr, truth(p)) else {
            continue;
        };
        if !p.flags.is_empty() || !f.is_finite() || !t.is_finite() {
            continue;
        }
        let c = p.theta_i_deg.to_radians().cos();
        n += 1;
        num += ((f - t) * c).powi(2);
        den += (t * c).powi(2);
        log2 += ((1.0 + f * c).max(1e-300).ln() - (1.0 + t * c).max(1e-300).ln()).powi(2);
        if t > 0.0 {
            max_rel = max_rel.max((f - t).abs() / t);
        }
        if let Some(u) = p.brdf_u_sr.filter(|u| *u > 0.0) {
            max_norm = max_norm.max((f - t).abs() / u);
        }
    }
    (n > 0).then(|| TruthErrors {
        points: n,
        cos_weighted_relative_rms: if den > 0.0 { (num / den).sqrt() } else { f64::NAN },
        log_rms: (log2 / n as f64).sqrt(),
        max_relative_error: max_rel,
        max_normalised_error: max_norm,
    })
}
