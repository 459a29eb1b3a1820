//! From the raw readings to the calibration (pure): the ranges fitted from the darks and every overlap, then
//! the direct beam, the signature and the NEBRDF with the ranges' correction, and the source's drift.

use super::drift::fit_drift;
use super::empty::EmptyHolder;
use super::ranges::{Overlap, RangesCalibration, fit_ranges};
use super::signature::BandSignature;
use super::{CharacterisationReport, DetectorCalibration};
use crate::acquisition::auto_range_index;

/// The raw reading `power_w`, read under auto-range, corrected by `ranges` (unchanged without them).
fn corrected(ranges: Option<&RangesCalibration>, ranges_w: &[f64], power_w: f64) -> f64 {
    match (ranges, auto_range_index(power_w, ranges_w)) {
        (Some(c), Some(k)) => c.correct(power_w, k).0,
        _ => power_w,
    }
}

/// The characterisation from the empty-holder readings and the sample's overlaps on instrument `inst`.
pub fn finish(
    empty: EmptyHolder,
    sample_overlaps: Vec<Overlap>,
    inst: &gonio_instrument::Instrument,
    instrument_s: f64,
) -> CharacterisationReport {
    let ranges_w = &inst.detector.ranges_w[..];
    let omega_sr = gonio_brdf::radiometry::aperture_solid_angle_sr(
        inst.detector.aperture_radius_mm,
        inst.detector.distance_mm,
    );
    let mut not_done = empty.not_done.clone();
    let sample_count = sample_overlaps.len();
    let overlaps: Vec<Overlap> = empty.overlaps.iter().copied().chain(sample_overlaps).collect();
    let ranges = if empty.darks.is_empty() {
        None
    } else {
        match fit_ranges(ranges_w, &empty.darks, &overlaps) {
            Ok(c) => {
                for r in c.ranges.iter().filter(|r| !r.observable) {
                    not_done.push(if r.index == c.reference_range {
                        format!(
                            "range {} ({:.0e} W): the gains' reference; no range above it to see its nonlinearity \
                             against, so only its offset is corrected",
                            r.index, r.full_scale_w
                        )
                    } else {
                        format!(
                            "range {} ({:.0e} W): no overlap reached it, so only its offset is corrected",
                            r.index, r.full_scale_w
                        )
                    });
                }
                Some(c)
            }
            Err(e) => {
                not_done.push(format!("ranges: {e}"));
                None
            }
        }
    };
    let correct = |w: f64| corrected(ranges.as_ref(), ranges_w, w);
    let direct_beam_w: Vec<(f64, f64)> = empty
        .direct
        .iter()
        .map(|d| {
            let value = match (&ranges, d.range) {
                (Some(c), Some(k)) => c.correct(d.power_w, k).0,
                _ => correct(d.power_w),
            };
            (d.band_nm, value)
        })
        .collect();
    let source = fit_drift(
        empty.overlap_nm,
        &empty.drift_readings,
        inst.source.drift_per_hour,
    );
    // The source's relative power at `t` against `t_ref` (the drift fit's, 1 without one): a signature
    // reading minutes after its band's direct beam sees the source warmer by as much as its own few 1e-3.
    let drift = |t: f64, t_ref: f64| {
        source
            .as_ref()
            .map_or(1.0, |d| d.relative_power(t) / d.relative_power(t_ref))
    };
    let beam_in = |nm: f64| {
        direct_beam_w
            .iter()
            .zip(&empty.direct)
            .find(|(d, _)| (d.0 - nm).abs() < 1e-9)
            .map_or((f64::NAN, 0.0), |(d, raw)| (d.1, raw.t_s))
    };
    let signature = empty
        .signature
        .iter()
        .map(|s| {
            let (beam_w, beam_t) = beam_in(s.band_nm);
            let norm = beam_w * omega_sr;
            // Three readings per point say little of their own scatter; the meter's noise is about the same at
            // every angle (the dark's), so each point's is at least the band's pooled one.
            let pooled =
                |v: &[(f64, f64)]| (v.iter().map(|x| x.1 * x.1).sum::<f64>() / v.len().max(1) as f64).sqrt();
            let (lit_pooled, dark_pooled) = (pooled(&s.lit_w), pooled(&s.dark_w));
            let (brdf_sr, u_sr) = s
                .lit_w
                .iter()
                .zip(&s.dark_w)
                .zip(&s.t_s)
                .map(|((&(lit, lit_u), &(dark, dark_u)), &t)| {
                    let at = norm * drift(t, beam_t);
                    let u = lit_u.max(lit_pooled).hypot(dark_u.max(dark_pooled));
                    ((correct(lit) - correct(dark)) / at, u / at)
                })
                .unzip();
            BandSignature {
                band_nm: s.band_nm,
                alpha_deg: s.alpha_deg.clone(),
                brdf_sr,
                u_sr,
                nebrdf_one_sample_sr: s.noise_one_sample_w / norm,
                dark_noise_one_sample_w: Some(s.noise_one_sample_w).filter(|w| w.is_finite()),
            }
        })
        .collect();
    if source.is_none() {
        not_done.push(format!(
            "source drift: {} direct-beam readings are too few to fit a warm-up (watch longer)",
            empty.drift_readings.len()
        ));
    }
    CharacterisationReport {
        detector: DetectorCalibration { ranges, signature },
        source,
        direct_beam_w,
        darks: empty.darks,
        overlaps,
        sample_overlaps: sample_count,
        walk: empty.walk,
        fine: empty.fine,
        drift_readings: empty.drift_readings,
        signature_readings: empty.signature,
        not_done,
        instrument_s,
    }
}
