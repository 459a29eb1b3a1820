//! A run as a standard BRDF table after the reporting conventions of ASTM E1392 (angle resolved optical scatter
//! of opaque surfaces) and E2387 (goniometric optical scatter): one row per valid measurement with its whole
//! geometry, wavelength and bandwidth, polarisation, the BRDF and its uncertainty, and a header that says how
//! the numbers were obtained.
//!
//! Layout: `#` comment lines (the header: format, sample coordinate system, BRDF definition, receiver solid angle,
//! calibration, instrument signature, polarisation, uncertainty, excluded points, provenance), then one CSV
//! header line ([`COLUMNS`]) and one row per valid point in the run's order. Readers that skip `#` lines read it
//! as a table (`pandas.read_csv(comment="#")`, spreadsheets after removing them).
//!
//! What the conventions ask for and where it is:
//! - geometry: theta_i, phi_i (towards the source) and theta_r, phi_r (towards the receiver), degrees, in the
//!   sample coordinate system the header defines;
//! - the BSDF as defined there: scattered power per unit receiver solid angle over incident power and the cosine
//!   of the scatter angle, (P_s / Omega) / (P_i cos theta_r), 1/sr, not cosine-corrected;
//! - the receiver solid angle Omega (sr) from the detector's limiting aperture and its distance to the sample,
//!   `2 pi (1 - d / sqrt(d^2 + r^2))` ([`gonio_brdf::radiometry::aperture_solid_angle_sr`]);
//! - wavelength and bandwidth (nm) of the filter, the polarisation of source and receiver;
//! - the calibration (absolute or relative, and the reference) and the instrument signature (the BRDF read with
//!   no sample), "not measured" when the instrument has no such measurement;
//! - the combined standard uncertainty u (k = 1) of each value and an expanded uncertainty U = k u with
//!   [`COVERAGE_FACTOR`].

use std::fmt::Write as _;

use gonio_brdf::radiometry::{aperture_half_angle_rad, aperture_solid_angle_sr};

use crate::export::CONVENTIONS;
use crate::provenance_summary::{ExportSetup, provenance_lines};
use crate::run::Run;

/// The columns of the table, in order.
pub const COLUMNS: [&str; 11] = [
    "index",
    "theta_i_deg",
    "phi_i_deg",
    "theta_r_deg",
    "phi_r_deg",
    "wavelength_nm",
    "bandwidth_nm",
    "polarisation",
    "brdf_sr",
    "u_brdf_sr",
    "U_brdf_sr",
];

/// The coverage factor of the expanded uncertainty column (about 95 % for a normal distribution).
pub const COVERAGE_FACTOR: f64 = 2.0;

fn num(v: f64) -> String {
    format!("{}", v + 0.0)
}

/// The table's text (module doc).
pub fn write(run: &Run, exported_by: &str, setup: Option<&ExportSetup>) -> String {
    let mut s = String::new();
    let mut line = |text: String| {
        s.push_str("# ");
        s.push_str(&text);
        s.push('\n');
    };
    line("BRDF table after ASTM E1392-96 / E2387 reporting conventions, written by gonio".into());
    line(format!(
        "sample_coordinate_system: {}",
        CONVENTIONS
            .iter()
            .find(|(k, _)| *k == "frame")
            .map_or("", |(_, v)| v)
            .replace(
                "i is the direction towards the source, o towards the detector",
                "theta_i, phi_i: towards the source; theta_r, phi_r: towards the receiver (detector)"
            )
    ));
    line("brdf_definition: BRDF = (P_s / Omega) / (P_i cos theta_r), 1/sr, not cosine-corrected".into());
    match setup {
        Some(st) if st.detector_distance_mm > 0.0 && st.detector_aperture_radius_mm > 0.0 => {
            let (r, d) = (st.detector_aperture_radius_mm, st.detector_distance_mm);
            line(format!(
                "receiver_solid_angle_sr: {:.6e} (circular aperture of radius {r} mm at {d} mm from the sample; \
                 half-angle {:.4} deg)",
                aperture_solid_angle_sr(r, d),
                aperture_half_angle_rad(r, d).to_degrees()
            ));
        }
        _ => line("receiver_solid_angle_sr: unknown (the run's instrument file is not available)".into()),
    }
    line(format!(
        "calibration_method: {}",
        setup.map_or_else(|| "unknown".into(), ExportSetup::calibration_words)
    ));
    line(format!(
        "instrument_signature: {}",
        setup.and_then(|st| st.signature.clone()).unwrap_or_else(|| {
            "not measured (the instrument's signature, its reading without a sample, was not \
                                measured for this run)"
                .into()
        })
    ));
    line(format!(
        "polarisation: {}",
        setup.map_or_else(|| "unknown".into(), |st| st.polarisation.clone())
    ));
    line(format!(
        "uncertainty: u_brdf_sr is the combined standard uncertainty (k = 1) of the measurement equation \
         (detector noise, dark, calibration readings, drift); U_brdf_sr = k u with coverage factor k = {}",
        COVERAGE_FACTOR
    ));
    line("wavelength_nm, bandwidth_nm: the filter's centre and full width at half maximum".into());
    let valid = run.valid_points().count();
    let excluded = run.points.len() - valid;
    let mut reasons: Vec<String> = Vec::new();
    for p in run.points.iter().filter(|p| !p.is_valid()) {
        let reason = p
            .flags
            .first()
            .map_or("no value", |f| f.split(':').next().unwrap_or(f));
        if !reasons.iter().any(|r| r == reason) {
            reasons.push(reason.to_string());
        }
    }
    line(format!(
        "rows: {valid} valid measurements; {excluded} excluded{}",
        if reasons.is_empty() {
            String::new()
        } else {
            format!(" ({})", reasons.join(", "))
        }
    ));
    for (k, v) in provenance_lines(run, exported_by, setup) {
        line(format!("provenance.{k}: {v}"));
    }
    s.push_str(&COLUMNS.join(","));
    s.push('\n');
    let polarisation = setup.map_or_else(|| "unknown".into(), |st| st.polarisation.replace(',', ";"));
    for p in run.valid_points() {
        let (Some(f), u) = (p.value(), p.brdf_u_sr) else {
            continue;
        };
        let bandwidth = setup
            .and_then(|st| st.bandwidth_nm(p.band_nm))
            .map(num)
            .unwrap_or_default();
        let (u, big_u) = match u.filter(|u| u.is_finite()) {
            Some(u) => (num(u), num(COVERAGE_FACTOR * u)),
            None => (String::new(), String::new()),
        };
        let _ = writeln!(
            s,
            "{},{},{},{},{},{},{bandwidth},{polarisation},{},{u},{big_u}",
            p.index,
            num(p.theta_i_deg),
            num(p.phi_i_deg),
            num(p.theta_o_deg),
            num(p.phi_o_deg),
            num(p.band_nm),
            num(f),
        );
    }
    s
}
