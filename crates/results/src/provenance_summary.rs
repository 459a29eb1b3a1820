//! The provenance every export carries, in one short form: which campaign and run, on which instrument (its name
//! and the SHA-256 of its file), calibrated how, measured and exported by which software. CSV and JSON also
//! carry the whole run record; the formats with only a comment block or a description string (MERL's material
//! file, Zemax, ASTM, RGL) carry these lines.
//!
//! This crate reads no instrument or campaign file (it depends on gonio-brdf only), so what comes from them
//! (the instrument's name, detector aperture, filter bandwidths, the calibration method) is handed over by the
//! caller as an [`ExportSetup`].

use crate::run::Run;

/// Facts from the run's instrument and campaign files, read by the caller.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct ExportSetup {
    /// `[instrument] name`.
    pub instrument_name: String,
    /// Radius of the detector's limiting aperture, mm.
    pub detector_aperture_radius_mm: f64,
    /// Distance from the sample centre to that aperture, mm.
    pub detector_distance_mm: f64,
    /// (band, filter bandwidth FWHM) in nm for each band the instrument has; `None` where the file gives none.
    pub bandwidths_nm: Vec<(f64, Option<f64>)>,
    /// "absolute" (direct beam) or "relative" (reference sample).
    pub calibration_method: String,
    /// The reference sample of a relative calibration (a preset name or a material description).
    pub calibration_reference: Option<String>,
    /// The polarisation of the incident beam and the receiver's sensitivity to it.
    pub polarisation: String,
    /// A summary of the instrument signature (the BRDF the instrument reads without a sample), when measured.
    pub signature: Option<String>,
    /// What the alignment and characterisation the run applied corrected (`gonio align`'s calibration file:
    /// its date, and what it corrected); `None` when none was applied.
    pub alignment: Option<String>,
}

impl ExportSetup {
    /// The filter bandwidth (nm) of the band nearest `band_nm` within 0.5 nm, when known.
    pub fn bandwidth_nm(&self, band_nm: f64) -> Option<f64> {
        self.bandwidths_nm
            .iter()
            .find(|(b, _)| (b - band_nm).abs() <= crate::run::BAND_TOLERANCE_NM)
            .and_then(|(_, w)| *w)
    }

    /// The calibration in words: "absolute (direct beam)" or "relative to reference <name>".
    pub fn calibration_words(&self) -> String {
        match (self.calibration_method.as_str(), &self.calibration_reference) {
            ("relative", Some(r)) => format!("relative, against the reference sample {r}"),
            ("relative", None) => "relative, against a reference sample".into(),
            ("absolute", _) => "absolute, against direct-beam readings (sample removed)".into(),
            (other, _) => other.to_string(),
        }
    }
}

/// A Unix time (s) as an ISO 8601 UTC date and time, e.g. `2026-12-02T03:37:35Z` (proleptic Gregorian calendar).
pub fn iso8601_utc(unix_s: f64) -> String {
    if !unix_s.is_finite() {
        return "unknown".into();
    }
    let secs = unix_s.floor() as i64;
    let (days, rem) = (secs.div_euclid(86_400), secs.rem_euclid(86_400));
    // Days since 1970-01-01 to a civil date (H. Hinnant's algorithm, era of 400 years).
    let z = days + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z.rem_euclid(146_097);
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let day = doy - (153 * mp + 2) / 5 + 1;
    let month = if mp < 10 { mp + 3 } else { mp - 9 };
    let year = yoe + era * 400 + i64::from(month <= 2);
    format!(
        "{year:04}-{month:02}-{day:02}T{:02}:{:02}:{:02}Z",
        rem / 3600,
        rem % 3600 / 60,
        rem % 60
    )
}

/// The provenance of an export as (key, value) lines, in a fixed order (module doc). Every key is always
/// present; what is not known says "unknown".
pub fn provenance_lines(
    run: &Run,
    exported_by: &str,
    setup: Option<&ExportSetup>,
) -> Vec<(&'static str, String)> {
    let record = run.provenance.as_ref();
    let unknown = || "unknown (no run.json)".to_string();
    let mut lines = vec![
        ("campaign", run.name.clone()),
        (
            "run_id",
            record.map_or_else(unknown, |r| format!("store campaign {}", r.campaign.id)),
        ),
        (
            "run_created_utc",
            record
                .and_then(|r| r.campaign.created_unix_s)
                .map_or_else(|| "unknown".into(), iso8601_utc),
        ),
        (
            "run_state",
            record.map_or_else(unknown, |r| r.campaign.state.clone()),
        ),
        ("dry_run", run.dry_run.to_string()),
        (
            "instrument",
            setup.map_or_else(|| "unknown".into(), |s| s.instrument_name.clone()),
        ),
        (
            "instrument_file_sha256",
            record.map_or_else(unknown, |r| sha256_hex(r.config.instrument_toml.as_bytes())),
        ),
        (
            "campaign_file_sha256",
            record.map_or_else(unknown, |r| sha256_hex(r.config.campaign_toml.as_bytes())),
        ),
        (
            "calibration",
            setup.map_or_else(|| "unknown".into(), ExportSetup::calibration_words),
        ),
    ];
    let readings = record.map(|r| {
        let count = |kind: &str| r.calibrations.iter().filter(|c| c.kind == kind).count();
        format!(
            "{} direct-beam, {} reference, {} dark readings",
            count("direct-beam"),
            count("reference"),
            count("dark")
        )
    });
    lines.push(("calibration_readings", readings.unwrap_or_else(unknown)));
    lines.push((
        "alignment",
        match (setup, record) {
            (
                Some(ExportSetup {
                    alignment: Some(a), ..
                }),
                _,
            ) => a.clone(),
            (_, Some(r)) if r.config.alignment_toml.is_none() => "none applied".to_string(),
            (_, Some(_)) => "applied (its file is in the run record)".to_string(),
            (_, None) => unknown(),
        },
    ));
    lines.push((
        "measured_by",
        record.map_or_else(unknown, |r| r.software_version.clone()),
    ));
    lines.push(("exported_by", exported_by.to_string()));
    // One line each, whatever the texts hold.
    lines
        .into_iter()
        .map(|(k, v)| (k, v.replace(['\n', '\r'], " ")))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn unix_times_become_utc_dates() {
        assert_eq!(iso8601_utc(0.0), "1970-01-01T00:00:00Z");
        assert_eq!(iso8601_utc(951_782_400.5), "2000-02-29T00:00:00Z");
        assert_eq!(iso8601_utc(1_796_182_655.0), "2026-12-02T03:37:35Z");
        assert_eq!(iso8601_utc(-1.0), "1969-12-31T23:59:59Z");
        assert_eq!(iso8601_utc(f64::NAN), "unknown");
    }
}
/// The SHA-256 digest of `data` as 64 lowercase hex digits (names a configuration file exactly).
pub fn sha256_hex(data: &[u8]) -> String {
    use sha2::Digest;
    sha2::Sha256::digest(data)
        .iter()
        .map(|b| format!("{b:02x}"))
        .collect()
}

#[cfg(test)]
mod sha_tests {
    #[test]
    fn sha256_is_the_published_digest() {
        // FIPS 180-2 appendix B.1 ("abc").
        assert_eq!(
            super::sha256_hex(b"abc"),
            "ba7816bf8f01cfea414140de5dae2223b00361a396177a9cb410ff61f20015ad"
        );
    }
}
