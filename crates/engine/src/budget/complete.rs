//! What a point's value and budget need the campaign's other points for, done once it has completed:
//! - the dark's drift: each value net of the dark interpolated between its band's darks before and after it,
//!   the interpolation's uncertainty its `dark` component ([`super::dark`]);
//! - the source's drift: each value normalised again between the readings before and after it, the drift's
//!   curvature in the budget ([`super::drift`]);
//! - pointing: an applied alignment's parameters, each by its uncertainty, through its model and the fitted
//!   model at the read-back pose (super::positioning::Pointed::pointing_shifts); without an alignment, the
//!   geometric model's parameters by the instrument file's priors the same way (crate::align::priors); without
//!   a read-back, the file's `alignment_u_deg` on theta_i, theta_o and the azimuth times the fitted model's
//!   slopes and the absolute equation's `tan(theta_o)`; added to `pointing`, one signed entry per parameter or angle
//!   shared by the campaign's points (one error moves them all); the holder's re-seating repeatability through
//!   the same models, the `sample` component, shared and signed the same way;
//! - positioning: each value brought from where the axes really stopped (read back) to the nominal geometry by
//!   the fitted model's ratio between the two, part of it as the `positioning` component
//!   ([`super::positioning`]), the run's arrival tolerance in `pointing` then the read-back's resolution;
//! - the aperture: each value corrected from the aperture average to the BRDF at the nominal geometry with a
//!   model fitted to the campaign's data (gonio_results::aperture), the correction's own uncertainty added as
//!   the `aperture` component, the average kept beside it (`brdf_aperture_sr`); a lobe narrower than the
//!   aperture is flagged `narrow-lobe` instead and its uncertainty covers the bias;
//! - the finite band (gonio_results::band_component): each value corrected for the light its filter leaks from
//!   outside its band (the leaked fraction from the instrument file, the sample's spectrum there from the bands
//!   measured at the same geometry); the sample's spectral slope times each filter's centre uncertainty, and the
//!   correction's own uncertainty, the `band` component, shared by a band's points.
//!
//! It always starts again from the committed rows (Store::committed_points) and replaces the campaign's earlier
//! completion whole, so completing twice (a resumed campaign that completes again) gives the same result. The
//! work needs no store: [`completions`] is pure, so the runner does it without holding the store's lock
//! (crate::runner: read with Store::committed_points, written with Store::update_completions).

use gonio_instrument::Instrument;
use gonio_results::aperture::{Correction, FLAG_NARROW_LOBE, corrections};
use gonio_results::band_component::{FilterBand, LeakSpectrum, band_estimates};
use gonio_results::budget::{components, groups};
use gonio_results::run::{BAND_TOLERANCE_NM, Run};

use super::dark::{DarkSensitivity, Darkened, redark};
use crate::characterise::correction::{DetectorCorrection, FLAG_BELOW_NEBRDF};
use crate::store::{CalibrationRecord, CampaignRecord, PointCompletion, PointRecord};

/// The angles' standard uncertainty (deg): an applied alignment's (the root sum of squares of the uncertainties
/// of its observable zeros and sample tilts), else the instrument file's `alignment_u_deg`.
pub(super) fn angle_u_deg(record: &CampaignRecord, instrument: &Instrument) -> f64 {
    let applied = record
        .alignment_toml
        .as_deref()
        .and_then(|text| crate::align::file::CalibrationFile::parse(text, "the stored alignment").ok());
    match applied {
        Some(cal) => cal
            .values
            .iter()
            .filter(|v| v.observable && v.unit == "deg")
            .filter(|v| v.name.ends_with("_zero_deg") || v.name.starts_with("sample_tilt_"))
            .map(|v| v.u * v.u)
            .sum::<f64>()
            .sqrt(),
        None => instrument.alignment_u_deg(),
    }
}

/// Adds `component` to `budget` once per normalisation reading of band `nm`: `value` times each reading's
/// relative weight (index among the band's readings, weight), shared by the values interpolated from it.
fn add_per_reading(
    budget: &mut gonio_results::budget::Budget,
    component: &str,
    value: f64,
    nm: f64,
    readings_rel: &[(usize, f64)],
) {
    for (k, rel) in readings_rel {
        let u = (value * rel).abs();
        if u > 0.0 {
            budget.add(component, u, Some(groups::normalisation_reading(nm, *k)));
        }
    }
}

/// Adds `component` to `budget` once per shared error: `value` times each signed relative shift, in the group
/// of the parameter or angle it moves (a shift that is not finite or is 0 adds nothing).
fn add_shifts(
    budget: &mut gonio_results::budget::Budget,
    component: &str,
    value: f64,
    shifts: &[(&str, f64)],
) {
    for (name, rel) in shifts {
        let u = value * rel;
        if u.is_finite() && u != 0.0 {
            budget.add(component, u, Some((*name).to_string()));
        }
    }
}

/// Which of the sample's mountings each point was measured in, in the points' order: how many normalisation
/// readings (direct beam or reference sample; the sample leaves the holder for each, and a dark does not move it)
/// came before it. Points between the same two readings share a number, and no two mountings do.
pub(super) fn mountings(calibrations: &[CalibrationRecord], committed: &[PointRecord]) -> Vec<usize> {
    let mut times: Vec<f64> = calibrations
        .iter()
        .filter(|c| c.kind != "dark")
        .map(|c| c.t_s)
        .collect();
    times.sort_by(f64::total_cmp);
    committed
        .iter()
        .map(|p| times.partition_point(|t| *t < p.t_s))
        .collect()
}

/// What the instrument file says of each band's filter, looked up by band (nm): each filter's leakage worked out
/// once (an integral over the spectra), not once per geometry.
pub(super) fn filter_bands(instrument: &Instrument) -> impl Fn(f64) -> Option<FilterBand> + use<> {
    let filters: Vec<FilterBand> = instrument
        .filter_wheel
        .iter()
        .flat_map(|w| &w.positions)
        .filter_map(|p| {
            let leakage = gonio_instrument::leakage::out_of_band_fraction(instrument, p).unwrap_or(0.0);
            // The leak is reckoned against the band's width: its relative uncertainty is the width's.
            let leakage_u_rel = p
                .bandwidth_nm
                .filter(|b| *b > 0.0)
                .map_or(0.0, |b| p.bandwidth_u_nm() / b);
            Some(FilterBand {
                band_nm: p.band_nm?,
                centre_u_nm: p.centre_u_nm(),
                leakage,
                leakage_u_rel,
                passband_variance_nm2: gonio_instrument::passband::variance_nm2(p.bandwidth_nm),
                centroid_offset_nm: gonio_instrument::passband::centroid_offset_nm(instrument, p)
                    .unwrap_or(0.0),
            })
        })
        .collect();
    move |nm: f64| {
        filters
            .iter()
            .find(|f| (f.band_nm - nm).abs() <= BAND_TOLERANCE_NM)
            .map(|f| FilterBand { band_nm: nm, ..*f })
    }
}

/// Where the instrument's filters leak their light (gonio_instrument::leakage::leak_spectrum).
pub(super) fn leak_spectrum(instrument: &Instrument) -> Option<LeakSpectrum> {
    gonio_instrument::leakage::leak_spectrum(instrument).and_then(LeakSpectrum::new)
}

/// A characterised detector's noise floor as the campaign read it: each value re-darkened is flagged
/// `below-nebrdf` again by its new value (the flag first went by the value net of a stale dark).
#[derive(Debug, Clone, Copy)]
pub struct NoiseFloor<'a> {
    pub detector: &'a DetectorCorrection,
    /// Samples averaged per reading.
    pub averaging: u32,
}

/// What the completion needs of the run besides its stored records.
pub struct RunContext<'a> {
    /// Normalised by a reference sample rather than the direct beam.
    pub relative: bool,
    /// The measurement equation's sensitivity to a value's dark.
    pub dark_sensitivity: &'a DarkSensitivity<'a>,
    /// A characterised detector's noise floor; `None` without a characterisation.
    pub floor: Option<NoiseFloor<'a>>,
    /// The sample's radius and non-uniformity (super::uniformity).
    pub sample: super::SampleSpec,
}

impl NoiseFloor<'_> {
    /// `flags` with `below-nebrdf` as `value` (1/sr, in `band_nm`, viewed at `theta_o_deg`) now says; whether
    /// that changed them.
    pub(super) fn reflag(&self, flags: &mut Vec<String>, value: f64, band_nm: f64, theta_o_deg: f64) -> bool {
        let below = self
            .detector
            .below_nebrdf(value, band_nm, self.averaging, theta_o_deg);
        let flagged = flags.iter().any(|f| f == FLAG_BELOW_NEBRDF);
        if below != flagged {
            flags.retain(|f| f != FLAG_BELOW_NEBRDF);
            if below {
                flags.push(FLAG_BELOW_NEBRDF.to_string());
            }
        }
        below != flagged
    }
}

impl std::fmt::Debug for RunContext<'_> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("RunContext")
            .field("relative", &self.relative)
            .field("floor", &self.floor)
            .finish_non_exhaustive()
    }
}

/// The completion of a campaign's committed points (module doc): one entry per point it changes.
pub fn completions(
    record: &CampaignRecord,
    committed: &[PointRecord],
    calibrations: &[CalibrationRecord],
    instrument: &Instrument,
    context: &RunContext<'_>,
) -> Vec<PointCompletion> {
    let (relative, floor) = (context.relative, context.floor);
    // The points as a run, which the aperture's model is fitted to; each step below updates its values.
    let mut run = Run {
        origin: format!("campaign {} ({})", record.id, record.name),
        name: record.name.clone(),
        points: crate::export::points_table(record, committed).points,
        axis_names: Vec::new(),
        dry_run: false,
        provenance: None,
    };
    let mut done: Vec<PointCompletion> = committed
        .iter()
        .map(|p| PointCompletion {
            index: p.index,
            budget: p.budget.clone(),
            brdf_sr: None,
            brdf_aperture_sr: None,
            flags: None,
        })
        .collect();

    let darkened: Vec<Darkened> = committed
        .iter()
        .map(|p| Darkened {
            band_nm: p.band_nm,
            t_s: p.t_s,
            dark_w: Some(p.dark_w),
            geometry_deg: [p.theta_i_deg, p.phi_i_deg, p.theta_o_deg, p.phi_o_deg],
            incident_w: p.incident_w,
        })
        .collect();
    for (index, ((point, completion), d)) in run
        .points
        .iter_mut()
        .zip(&mut done)
        .zip(redark(calibrations, &darkened))
        .enumerate()
    {
        let (Some(d), Some(value)) = (d, point.brdf_sr) else {
            continue;
        };
        let Some(per_w) = (context.dark_sensitivity)(&darkened[index]) else {
            continue;
        };
        let redarked = value - per_w * (d.dark_w - d.used_w);
        // The curvature is the value's own; the two readings' noise is shared by every value between them.
        completion
            .budget
            .set(components::DARK, per_w * d.curvature_u_w, None);
        for (k, u_w) in d.readings_u_w {
            if u_w > 0.0 {
                completion.budget.add(
                    components::DARK,
                    per_w * u_w,
                    Some(groups::dark(darkened[index].band_nm, k)),
                );
            }
        }
        completion.brdf_sr = Some(redarked);
        point.brdf_sr = Some(redarked);
        if let (Some(floor), Some(c)) = (floor, committed.get(index))
            && floor.reflag(&mut point.flags, redarked, c.band_nm, c.theta_o_deg)
        {
            completion.flags = Some(point.flags.clone());
        }
    }

    for (((point, completion), r), c) in run
        .points
        .iter_mut()
        .zip(&mut done)
        .zip(super::drift::renormalise(
            calibrations,
            committed,
            super::drift::Lamp::of(&instrument.source),
        ))
        .zip(committed)
    {
        let (Some(r), Some(value)) = (r, point.brdf_sr) else {
            continue;
        };
        let readings_known = r.readings_rel.iter().any(|(_, w)| *w > 0.0);
        if r.factor == 1.0 && r.curvature_rel == 0.0 && r.flicker.own_rel == 0.0 && !readings_known {
            continue;
        }
        let renormalised = value * r.factor;
        completion.budget = completion.budget.scaled(r.factor);
        if readings_known {
            // Each reading's noise is shared by the values interpolated from it, not by the whole band.
            completion.budget.set(components::NORMALISATION, 0.0, None);
            add_per_reading(
                &mut completion.budget,
                components::NORMALISATION,
                renormalised,
                c.band_nm,
                &r.readings_rel,
            );
        }
        let curvature_u = (renormalised * r.curvature_rel).abs();
        if curvature_u > 0.0 {
            completion
                .budget
                .add(components::NORMALISATION, curvature_u, None);
        }
        let own_u = (renormalised * r.flicker.own_rel).abs();
        if own_u > 0.0 {
            completion.budget.add(components::FLICKER, own_u, None);
        }
        add_per_reading(
            &mut completion.budget,
            components::FLICKER,
            renormalised,
            c.band_nm,
            &r.flicker.readings_rel,
        );
        completion.brdf_sr = Some(renormalised);
        point.brdf_sr = Some(renormalised);
    }

    if let Some(c) = corrections(&run, &super::optics::optics(instrument)) {
        tracing::info!(
            campaign = %record.id,
            model = c.model.name(),
            residual_rms = c.residual_rms,
            "aperture correction from the fitted model"
        );
        // Where the axes really stopped against the nominal geometry (super::positioning): the value brought
        // to the nominal geometry by the fitted model's ratio, a quarter of the correction its uncertainty.
        // Once the read-back says where the axes stopped, the arrival tolerance the run's pointing component
        // took is no longer unknown: what is left of it is the encoder's resolution.
        let pointed = super::positioning::Pointed::new(record.alignment_toml.as_deref(), instrument);
        let read_back_share = instrument.read_back_u_deg() / instrument.arrival_u_deg();
        for ((point, completion), committed) in run.points.iter_mut().zip(&mut done).zip(committed) {
            let Some(value) = point.brdf_sr else { continue };
            let Some(rel) = pointed.relative_deviation(&c.material, committed, !relative) else {
                continue;
            };
            if rel.abs() > super::positioning::MAX_REL_CORRECTION {
                continue;
            }
            if read_back_share.is_finite() {
                let arrival = completion.budget.component_sr(components::POINTING);
                completion
                    .budget
                    .set(components::POINTING, arrival * read_back_share, None);
            }
            if rel == 0.0 {
                continue;
            }
            let factor = 1.0 / (1.0 + rel);
            let corrected = value * factor;
            completion.budget = completion.budget.scaled(factor);
            completion.budget.add(
                components::POSITIONING,
                (corrected * rel * super::positioning::U_OF_CORRECTION).abs(),
                None,
            );
            completion.brdf_sr = Some(corrected);
            point.brdf_sr = Some(corrected);
        }
        // The angles' uncertainty through the value: an applied alignment's parameters (or the file's priors
        // for them) one by one through the geometric model (super::positioning), else (no read-back) one angle
        // uncertainty on each of theta_i, theta_o and the azimuth times the fitted model's slopes. Either way one error per parameter or angle, the same for every
        // point of the campaign: a signed component shared by the campaign's points under that parameter's
        // name (crate::budget), which a fit propagates apart instead of taking it for scatter.
        let angle_u_rad = angle_u_deg(record, instrument).to_radians();
        for (((point, completion), slopes), committed) in
            run.points.iter().zip(&mut done).zip(&c.slopes).zip(committed)
        {
            let Some(value) = point.brdf_sr else { continue };
            let propagated = pointed
                .has_pointing_u()
                .then(|| pointed.pointing_shifts(&c.material, committed, !relative))
                .flatten();
            let shifts = match (propagated, slopes) {
                (Some(shifts), _) => shifts,
                (None, Some([gi, go, gphi])) => {
                    // The absolute equation divides by the nominal cos(theta_o): a detector angle off by d
                    // moves the value by -tan(theta_o) d besides the BRDF's own slope.
                    let tan_o = if !relative {
                        committed.theta_o_deg.to_radians().tan()
                    } else {
                        0.0
                    };
                    vec![
                        (groups::THETA_I, angle_u_rad * gi),
                        (groups::THETA_O, angle_u_rad * (go - tan_o)),
                        (groups::PHI, angle_u_rad * gphi),
                    ]
                }
                (None, None) => continue,
            };
            add_shifts(&mut completion.budget, components::POINTING, value, &shifts);
        }
        // The sample's re-seating between mountings, which no alignment measures (super::positioning): signed
        // as the alignment's parameters are, and shared by the points of one mounting only: the sample leaves
        // the holder for every normalisation reading and sits differently each time it goes back.
        let mounting = mountings(calibrations, committed);
        for ((((point, completion), committed), slopes), mounting) in run
            .points
            .iter()
            .zip(&mut done)
            .zip(committed)
            .zip(&c.slopes)
            .zip(&mounting)
        {
            let (Some(value), Some(_)) = (point.brdf_sr, slopes) else {
                continue;
            };
            if let Some(shifts) = pointed.reseat_shifts(&c.material, committed, !relative) {
                for (name, rel) in shifts {
                    let u = value * rel;
                    if u.is_finite() && u != 0.0 {
                        completion
                            .budget
                            .add(components::SAMPLE, u, Some(groups::mounting(*mounting, name)));
                    }
                }
            }
        }
        for ((point, completion), correction) in run.points.iter_mut().zip(&mut done).zip(&c.points) {
            let Some(value) = point.brdf_sr else { continue };
            match correction {
                Some(Correction::Applied { factor, u_rel }) => {
                    let corrected = value * factor;
                    completion.budget = completion.budget.scaled(*factor);
                    completion
                        .budget
                        .set(components::APERTURE, (corrected * u_rel).abs(), None);
                    completion.brdf_sr = Some(corrected);
                    completion.brdf_aperture_sr = Some(value);
                    point.brdf_sr = Some(corrected);
                }
                Some(Correction::NarrowLobe { u_rel }) => {
                    completion
                        .budget
                        .set(components::APERTURE, (value * u_rel).abs(), None);
                    completion.brdf_aperture_sr = Some(value);
                    let mut flags = point.flags.clone();
                    flags.push(FLAG_NARROW_LOBE.to_string());
                    point.flags.clone_from(&flags);
                    completion.flags = Some(flags);
                }
                None => {}
            }
        }
    }

    // The sample's non-uniformity over the footprint (super::uniformity), on the value at the nominal geometry.
    for ((point, completion), c) in run.points.iter().zip(&mut done).zip(committed) {
        let Some(value) = point.brdf_sr else { continue };
        let shifts = super::uniformity::shifts(
            context.sample,
            c.theta_i_deg,
            instrument.source.beam_radius_mm,
            instrument.sample_holder.centring_u_mm(),
        );
        add_shifts(&mut completion.budget, components::SAMPLE, value, &shifts);
    }

    // The finite band last: the leak's correction compares the bands at one geometry, each at its nominal
    // geometry by now.
    let leak = leak_spectrum(instrument);
    // A geometry measured in one band borrows its spectrum's shape from those measured in several.
    let estimates = band_estimates(&run.points, &run.points, filter_bands(instrument), leak.as_ref());
    for ((completion, point), estimate) in done.iter_mut().zip(&mut run.points).zip(estimates) {
        let (Some(e), Some(value)) = (estimate, point.brdf_sr) else {
            continue;
        };
        if e.shift_sr != 0.0 {
            let corrected = value + e.shift_sr;
            completion.budget = completion.budget.scaled(e.scale);
            // The aperture's average beside it is the same reading through the same filter.
            if value != 0.0 {
                completion.brdf_aperture_sr = completion.brdf_aperture_sr.map(|a| a * corrected / value);
            }
            completion.brdf_sr = Some(corrected);
            point.brdf_sr = Some(corrected);
        }
        completion
            .budget
            .set(components::BAND, e.u_sr, Some(groups::band(point.band_nm)));
    }
    done.into_iter()
        .zip(committed)
        .filter(|(c, p)| c.budget != p.budget || c.brdf_sr.is_some() || c.flags.is_some())
        .map(|(c, _)| c)
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn points_between_the_same_two_normalisations_share_a_mounting_and_a_dark_does_not_move_the_sample() {
        let record = |kind: &str, t_s: f64| CalibrationRecord {
            kind: kind.into(),
            band_nm: Some(550.0),
            t_s,
            value_w: 1e-3,
            u_w: 1e-7,
        };
        // Two bands' direct beam at 0 and 1 s, a dark at 50 s, both bands again at 100 and 101 s.
        let calibrations = [
            record("direct-beam", 0.0),
            record("direct-beam", 1.0),
            record("dark", 50.0),
            record("direct-beam", 101.0),
            record("direct-beam", 100.0),
        ];
        let at = |t_s: f64| crate::budget::drift::tests::point_at(t_s, 550.0);
        let points: Vec<PointRecord> = [10.0, 49.0, 60.0, 99.0, 150.0, 200.0].map(at).to_vec();
        let m = mountings(&calibrations, &points);
        assert_eq!(m[0], m[1]);
        assert_eq!(m[1], m[2], "a dark leaves the sample where it is");
        assert_eq!(m[2], m[3]);
        assert_ne!(m[3], m[4], "the sample went out for the direct beam at 100 s");
        assert_eq!(m[4], m[5]);
        // Before any reading: a mounting of its own.
        assert_ne!(mountings(&calibrations, &[at(-1.0)])[0], m[0]);
    }

    #[test]
    fn a_value_is_flagged_below_the_noise_floor_by_what_it_now_is() {
        // One NEBRDF of 1e-4 1/sr for one sample at normal viewing: averaging 4, 5e-5; three of them 1.5e-4.
        let detector = crate::characterise::correction::tests::correction();
        let floor = NoiseFloor {
            detector: &detector,
            averaging: 4,
        };
        let ne3 = 3.0 * detector.nebrdf_sr(550.0, 4, 0.0).expect("measured");
        let mut flags = vec!["other".to_string()];
        // Below: flagged, once.
        assert!(floor.reflag(&mut flags, 0.5 * ne3, 550.0, 0.0));
        assert!(!floor.reflag(&mut flags, 0.5 * ne3, 550.0, 0.0));
        assert_eq!(flags, ["other", FLAG_BELOW_NEBRDF]);
        // Lifted above it by a new dark: the flag goes, the others stay.
        assert!(floor.reflag(&mut flags, 2.0 * ne3, 550.0, 0.0));
        assert_eq!(flags, ["other"]);
        // A band the characterisation did not measure says nothing.
        assert!(!floor.reflag(&mut flags, 0.0, 650.0, 0.0));
    }
}
