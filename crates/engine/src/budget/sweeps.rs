//! The completion of a campaign's sweep readings, as `complete` does for its points:
//! - the dark: each reading net of the dark interpolated between its band's darks before and after it
//!   (super::dark);
//! - the source's drift: each reading normalised again between its band's readings before and after it, the
//!   drift's curvature in its uncertainty (`super::drift`);
//! - the aperture: a sweep reading, like a point, is the BRDF averaged over the detector's aperture; the models
//!   of gonio_results::aperture are fitted to the readings and each value is corrected to the BRDF at its
//!   arc's middle, the correction's own uncertainty added; a lobe narrower than the aperture is flagged
//!   `narrow-lobe` and its uncertainty covers the bias;
//! - pointing: as for points (super::positioning), the geometry's parameters each moved by its uncertainty (an
//!   applied alignment's, else the instrument file's priors) and the holder's re-seating, through the fitted
//!   model at the pose the reading's geometry asks for, added in quadrature (a reading's budget is one total);
//!   where no pose or parameter is known, the angles' uncertainty times the model's slopes;
//! - the smearing: a reading is the mean along the arc it covered; each value is taken to its arc's middle by
//!   the fitted model's value there against its mean along the arc, a quarter of that correction added to its
//!   uncertainty ([`U_OF_SMEARING_CORRECTION`]);
//! - timing: where along its arc a reading was is known to its segment's timing uncertainty (the meter's
//!   exchange, [`TIMING_U_S`], and the windows in which the controller took its position reports, as the run
//!   recorded it; [`TIMING_U_S`] alone for segments stored before it was kept): the sweep's speed times that,
//!   times the model's slope along the swept angle;
//! - the finite band (gonio_results::band_component): the leak's correction and the band component from the
//!   other bands' sweeps of the same arc: readings of every band within [`CORRECTION_SPACING_DEG`] of one angle
//!   count as one geometry; sweeps in one band (`[plan] sweep_bands_nm`) borrow the spectrum's shape from the
//!   campaign's points measured in several, the probes, and so do the ends of arcs swept in several bands from
//!   the nearest angle all their bands reached (without it an arc's last few tenths of a degree in a band went
//!   uncorrected: construction paper's 550 nm readings there 2.1 % above the rest of the arc on realistic.toml).
//!
//! Along a sweep the readings are far denser than the aperture is wide (a few hundredths of a degree against
//! about half a degree), and the correction changes on the aperture's scale: it is worked out at readings
//! [`CORRECTION_SPACING_DEG`] apart along each sweep and each reading takes that of the nearest one.
//! Components add in quadrature to each reading's own uncertainty (its measurement equation's).

use gonio_brdf::Direction;
use gonio_instrument::Instrument;
use gonio_results::aperture::{Correction, FLAG_NARROW_LOBE, corrections};
use gonio_results::band_component::band_estimates;
use gonio_results::points::Point;
use gonio_results::run::Run;
use gonio_results::sweeps::SweepReading;

use super::complete::RunContext;
use super::dark::{Darkened, redark};
use super::drift::{Lamp, Normalised, renormalise_values};
use crate::store::{CalibrationRecord, CampaignRecord, SweepCompletion, SweepSegmentRecord};

/// Readings at least this far apart along a sweep (deg, swept angle) carry the correction's work.
pub const CORRECTION_SPACING_DEG: f64 = 0.1;

/// How well the time of a reading's integration is known (s): one exchange with the meter.
pub const TIMING_U_S: f64 = 0.001;

/// The smearing correction's standard uncertainty, as a fraction of it: the fitted model's curvature along
/// the arc is an estimate (as the positioning correction's, crate::budget::positioning).
pub const U_OF_SMEARING_CORRECTION: f64 = 0.25;

/// Largest smearing corrected (relative): beyond it the arc is no longer short against the BRDF's features.
const MAX_SMEARING: f64 = 0.2;

/// The model's value at the middle of the arc `r` covered against its mean along the arc (Simpson's rule on
/// the arc's ends and middle): the factor that takes the reading to its arc's middle. The swept angle moves
/// `theta_i` (`light`) or `theta_o` away from its middle value, in the sense of the signed arc. `None` when the
/// model has no value there or the smearing is beyond [`MAX_SMEARING`].
fn smearing_ratio(model: &gonio_brdf::Material, r: &SweepReading, light: bool) -> Option<f64> {
    use gonio_brdf::{Brdf as _, Wavelength};
    let (a, b) = (r.arc_from_deg, r.arc_to_deg);
    if a == b || !(a.is_finite() && b.is_finite()) {
        return None;
    }
    let wavelength = Wavelength::from_nm(r.band_nm).ok()?;
    let m = 0.5 * (a + b);
    let sense = if m < 0.0 { -1.0 } else { 1.0 };
    let f = |x: f64| {
        let d = sense * (x - m);
        let (ti, to) = if light {
            (r.theta_i_deg + d, r.theta_o_deg)
        } else {
            (r.theta_i_deg, r.theta_o_deg + d)
        };
        let wi = Direction::from_spherical_deg(ti, r.phi_i_deg);
        let wo = Direction::from_spherical_deg(to, r.phi_o_deg);
        model.eval(&wi, &wo, wavelength).ok().filter(|v| v.is_finite())
    };
    let (fa, fm, fb) = (f(a)?, f(m)?, f(b)?);
    let mean = (fa + 4.0 * fm + fb) / 6.0;
    if !(mean > 0.0 && fm > 0.0) {
        return None;
    }
    let ratio = fm / mean;
    ((ratio - 1.0).abs() <= MAX_SMEARING).then_some(ratio)
}

/// The completion of `readings` (module doc): one entry per reading, in their order. `probes`: the campaign's
/// points, whose geometries measured in several bands lend their spectrum's shape to sweeps swept in one
/// (gonio_results::band_component).
pub fn sweep_completions(
    record: &CampaignRecord,
    readings: &[SweepReading],
    probes: &[Point],
    segments: &[SweepSegmentRecord],
    calibrations: &[CalibrationRecord],
    instrument: &Instrument,
    context: &RunContext<'_>,
) -> Vec<SweepCompletion> {
    let relative = context.relative;
    // The dark and the drift first: the readings net of the dark interpolated to their time and renormalised,
    // as the aperture's models are then fitted to them.
    let committed = readings;
    let redarked = redarked(readings, calibrations, context);
    let readings = &redarked[..];
    let timed: Vec<Normalised> = readings
        .iter()
        .map(|r| Normalised {
            band_nm: r.band_nm,
            has_value: r.brdf_sr.is_some_and(f64::is_finite),
            incident_w: r.incident_w.unwrap_or(f64::NAN),
            t_s: r.t_s,
        })
        .collect();
    let drift = renormalise_values(calibrations, &timed, Lamp::of(&instrument.source));
    let renormalised: Vec<SweepReading> = readings
        .iter()
        .zip(&drift)
        .map(|(r, d)| {
            let mut r = r.clone();
            if let (Some(d), Some(v), Some(u)) = (d, r.brdf_sr, r.brdf_u_sr) {
                let value = v * d.factor;
                r.brdf_sr = Some(value);
                // A sweep's readings are milliseconds apart: the lamp's flicker moves them together, so it
                // is not averaged away over a sweep; each carries it whole.
                let flicker = d
                    .flicker
                    .readings_rel
                    .iter()
                    .fold(d.flicker.own_rel, |a, (_, w)| a.hypot(*w));
                // The reading's own normalisation noise is in `u` already (the measurement equation's); the
                // lamp's drift since the last normalisation reading is not.
                r.brdf_u_sr = Some(
                    (u * d.factor)
                        .hypot(value * d.curvature_rel)
                        .hypot(value * flicker)
                        .hypot(value * d.carried_rel),
                );
            }
            r
        })
        .collect();
    let readings = &renormalised[..];
    // The readings that carry the work: per sweep, one every `step` readings.
    let mut carriers: Vec<usize> = Vec::new();
    let mut nearest: Vec<usize> = vec![0; readings.len()];
    // Per reading: whether its sweep turned the light arm (theta_i changes along it) rather than the detector.
    let mut light_sweep: Vec<bool> = vec![false; readings.len()];
    let mut start = 0;
    while start < readings.len() {
        let segment = readings[start].segment;
        let end = readings[start..]
            .iter()
            .position(|r| r.segment != segment)
            .map_or(readings.len(), |n| start + n);
        let sweep = &readings[start..end];
        let light = sweep
            .first()
            .zip(sweep.last())
            .is_some_and(|(a, b)| a.theta_i_deg != b.theta_i_deg);
        light_sweep[start..end].fill(light);
        let per_reading = arc_per_reading(sweep);
        let step = if per_reading > 0.0 {
            ((CORRECTION_SPACING_DEG / per_reading).floor() as usize).max(1)
        } else {
            1
        };
        let first = carriers.len();
        carriers.extend((start..end).step_by(step));
        let last = carriers.len() - 1;
        for (k, slot) in nearest[start..end].iter_mut().enumerate() {
            *slot = (first + (k + step / 2) / step).min(last);
        }
        start = end;
    }
    let run = Run {
        origin: format!("sweeps of campaign {} ({})", record.id, record.name),
        name: record.name.clone(),
        points: carriers.iter().map(|&i| point(&readings[i], i)).collect(),
        axis_names: Vec::new(),
        dry_run: false,
        provenance: None,
    };
    let fitted = corrections(&run, &super::optics::optics(instrument));
    if let Some(c) = &fitted {
        tracing::info!(campaign = %record.id, model = c.model.name(), residual_rms = c.residual_rms,
            readings = readings.len(), carriers = carriers.len(), "sweep readings' aperture correction");
    }
    let angle_u_rad = super::complete::angle_u_deg(record, instrument).to_radians();
    let pointed = super::positioning::Pointed::new(record.alignment_toml.as_deref(), instrument);
    // The band component on the carriers, their swept angle snapped to the correction's spacing so that the
    // bands' sweeps of one arc meet at common geometries.
    let snapped: Vec<Point> = carriers
        .iter()
        .map(|&i| {
            let mut p = point(&readings[i], i);
            let snap = |x: f64| (x / CORRECTION_SPACING_DEG).round() * CORRECTION_SPACING_DEG;
            if light_sweep[i] {
                p.theta_i_deg = snap(p.theta_i_deg);
            } else {
                p.theta_o_deg = snap(p.theta_o_deg);
            }
            p
        })
        .collect();
    // Each segment's timing uncertainty as the run recorded it.
    let timing_of: std::collections::HashMap<u32, f64> = segments
        .iter()
        .filter_map(|g| Some((g.segment, g.timing_u_s.filter(|u| u.is_finite() && *u >= 0.0)?)))
        .collect();
    let leak = super::complete::leak_spectrum(instrument);
    // Lenders for the carriers measured in one band: the campaign's probes, and the sweeps' own geometries
    // measured in several. The bands' sweeps of one arc do not end at the same angle (each starts after its
    // ramp, and they run alternately one way and the other), so an arc's last tenths of a degree in one band
    // have no other band there: they borrow the shape of the nearest geometry the arc's sweeps share.
    let lenders: Vec<Point> = probes.iter().chain(&snapped).cloned().collect();
    let band = band_estimates(
        &snapped,
        &lenders,
        super::complete::filter_bands(instrument),
        leak.as_ref(),
    );
    readings
        .iter()
        .zip(committed)
        .zip(&nearest)
        .zip(&light_sweep)
        .map(|(((r, was), &c), &light)| {
            let mut out = SweepCompletion {
                segment: r.segment,
                k: r.k,
                brdf_sr: r.brdf_sr,
                brdf_u_sr: r.brdf_u_sr,
                // The new dark may have put a reading below the noise floor or lifted it above.
                flags: (r.flags != was.flags).then(|| r.flags.clone()),
            };
            let (Some(value), Some(u), Some(fitted)) = (r.brdf_sr, r.brdf_u_sr, &fitted) else {
                return out;
            };
            let mut value = value;
            let mut var = u * u;
            match fitted.points.get(c).copied().flatten() {
                Some(Correction::Applied { factor, u_rel }) => {
                    value *= factor;
                    var *= factor * factor;
                    var += (value * u_rel).powi(2);
                }
                Some(Correction::NarrowLobe { u_rel }) => {
                    var += (value * u_rel).powi(2);
                    let mut flags = r.flags.clone();
                    flags.push(FLAG_NARROW_LOBE.to_string());
                    out.flags = Some(flags);
                }
                None => {}
            }
            // The smearing: the reading is the mean along the arc it covered; the model's value at the arc's
            // middle against its mean there (a reading's arc is far shorter than the model's features).
            if let Some(ratio) = smearing_ratio(&fitted.material, r, light) {
                let correction = ratio - 1.0;
                value *= ratio;
                var *= ratio * ratio;
                var += (value * correction * U_OF_SMEARING_CORRECTION).powi(2);
            }
            if let Some(e) = band.get(c).copied().flatten() {
                // The leak's correction and the component relative to the carrier's value, applied to this
                // reading's.
                if let Some(carrier) = readings[carriers[c]].brdf_sr.filter(|v| *v != 0.0) {
                    let ratio = 1.0 + e.shift_sr / carrier;
                    value *= ratio;
                    var *= ratio * ratio;
                    var += (value * e.u_sr / carrier).powi(2);
                }
            }
            if let Some([gi, go, gphi]) = fitted.slopes.get(c).copied().flatten() {
                let tan_o = if relative {
                    0.0
                } else {
                    r.theta_o_deg.to_radians().tan()
                };
                // The geometry's parameters by their uncertainties (an applied alignment's, else the file's
                // priors) and the holder's re-seating, through the fitted model at the pose the reading's
                // geometry asks for, as for a point (super::positioning); one angle uncertainty on each
                // angle times the model's slopes where that cannot be worked out.
                let wi = Direction::from_spherical_deg(r.theta_i_deg, r.phi_i_deg);
                let wo = Direction::from_spherical_deg(r.theta_o_deg, r.phi_o_deg);
                let propagated = pointed
                    .has_pointing_u()
                    .then(|| pointed.pose_for(&wi, &wo))
                    .flatten()
                    .and_then(|pose| pointed.all_shifts_at(&fitted.material, &pose, r.band_nm, !relative));
                let pointing = match propagated {
                    Some(shifts) => shifts.iter().fold(0.0f64, |a, (_, rel)| a.hypot(*rel)),
                    None => angle_u_rad * gi.hypot(go - tan_o).hypot(gphi),
                };
                // The swept angle moves theta_i (a light sweep) or theta_o, where the absolute equation's
                // cos(theta_o) moves with it; the speed from the reading's arc.
                let along = if light { gi } else { go - tan_o };
                let speed_rad_s = if r.integration_s > 0.0 {
                    ((r.arc_to_deg - r.arc_from_deg) / r.integration_s)
                        .abs()
                        .to_radians()
                } else {
                    0.0
                };
                let timing_u_s = timing_of.get(&r.segment).copied().unwrap_or(TIMING_U_S);
                let timing = along.abs() * speed_rad_s * timing_u_s;
                // The sample's non-uniformity over the footprint (super::uniformity), folded in as pointing is.
                let uniformity = super::uniformity::shifts(
                    context.sample,
                    r.theta_i_deg,
                    instrument.source.beam_radius_mm,
                    instrument.sample_holder.centring_u_mm(),
                )
                .iter()
                .fold(0.0f64, |a, (_, rel)| a.hypot(*rel));
                for rel in [pointing, timing, uniformity] {
                    if rel.is_finite() {
                        var += (value * rel).powi(2);
                    }
                }
            }
            out.brdf_sr = Some(value);
            out.brdf_u_sr = Some(var.sqrt());
            out
        })
        .collect()
}

/// `readings` net of their band's dark interpolated to their time (super::dark), the reading's share of the
/// dark it was net of replaced in its uncertainty by the interpolation's, and flagged `below-nebrdf` again by
/// the new value on a characterised detector (as points are, super::complete).
fn redarked(
    readings: &[SweepReading],
    calibrations: &[CalibrationRecord],
    context: &RunContext<'_>,
) -> Vec<SweepReading> {
    let sensitivity = context.dark_sensitivity;
    let darkened: Vec<Darkened> = readings
        .iter()
        .map(|r| Darkened {
            band_nm: r.band_nm,
            t_s: r.t_s,
            dark_w: None,
            geometry_deg: [r.theta_i_deg, r.phi_i_deg, r.theta_o_deg, r.phi_o_deg],
            incident_w: r.incident_w.unwrap_or(f64::NAN),
        })
        .collect();
    readings
        .iter()
        .zip(&darkened)
        .zip(redark(calibrations, &darkened))
        .map(|((r, darkened), d)| {
            let mut r = r.clone();
            if let (Some(d), Some(v), Some(u)) = (d, r.brdf_sr, r.brdf_u_sr)
                && let Some(per_w) = sensitivity(darkened)
            {
                let value = v - per_w * (d.dark_w - d.used_w);
                r.brdf_sr = Some(value);
                let others = (u * u - (per_w * d.used_u_w).powi(2)).max(0.0);
                r.brdf_u_sr = Some((others + (per_w * d.u_w()).powi(2)).sqrt());
                if let Some(floor) = context.floor {
                    floor.reflag(&mut r.flags, value, r.band_nm, r.theta_o_deg);
                }
            }
            r
        })
        .collect()
}

/// The median arc (deg) between consecutive readings of one sweep.
fn arc_per_reading(sweep: &[SweepReading]) -> f64 {
    let mid = |r: &SweepReading| 0.5 * (r.arc_from_deg + r.arc_to_deg);
    let mut steps: Vec<f64> = sweep
        .windows(2)
        .map(|w| (mid(&w[1]) - mid(&w[0])).abs())
        .collect();
    if steps.is_empty() {
        return 0.0;
    }
    steps.sort_by(f64::total_cmp);
    steps[steps.len() / 2]
}

/// A sweep reading as a point of the run the aperture's models are fitted to.
fn point(r: &SweepReading, index: usize) -> Point {
    Point {
        index: index as u64,
        band_nm: r.band_nm,
        theta_i_deg: r.theta_i_deg,
        phi_i_deg: r.phi_i_deg,
        theta_o_deg: r.theta_o_deg,
        phi_o_deg: r.phi_o_deg,
        signal_w: r.signal_w,
        dark_w: None,
        incident_w: None,
        brdf_sr: r.brdf_sr,
        brdf_u_sr: r.brdf_u_sr,
        flags: r.flags.clone(),
        t_s: Some(r.t_s),
        readback_deg: Vec::new(),
        brdf_aperture_sr: None,
        budget: Default::default(),
        truth_point_sr: None,
        truth_aperture_sr: None,
    }
}
