//! How far from the specular direction a lobe narrower than the instrument resolves still reaches the detector
//! ([`gonio_results::aperture::Optics`]), from the instrument file alone.
//!
//! A mirror's reflection is the beam itself: a tube of the beam's radius, widened by its divergence on the way
//! to the detector, that overlaps the aperture while the angle between its direction and the aperture's centre
//! is below the two half-angles together. Where the reflected direction really lies depends on the geometry's
//! errors; the sample's tilt turns it twice. The instrument file's priors for those errors (crate::align::priors)
//! are taken even after an alignment: the reach only decides which points of a lobe no model resolves are
//! flagged, and there a wider reach flags a point that may have seen the beam rather than vouching for it.

use gonio_instrument::Instrument;
use gonio_results::aperture::Optics;

use crate::align::model::PARAM_NAMES;

/// How many standard uncertainties of the reflected direction the reach allows for.
pub(super) const MISALIGNMENT_K: f64 = 3.0;

/// The instrument's optics as the aperture correction needs them.
pub(super) fn optics(instrument: &Instrument) -> Optics {
    let d = &instrument.detector;
    let s = &instrument.source;
    let aperture_half_angle_rad =
        gonio_brdf::radiometry::aperture_half_angle_rad(d.aperture_radius_mm, d.distance_mm);
    // The beam's radius at the detector: its own, and the divergence's (a full angle) half over the path.
    let beam_at_detector_mm = s.beam_radius_mm + d.distance_mm * (0.5 * s.divergence_deg).to_radians().tan();
    let beam_half_angle_rad = (beam_at_detector_mm / d.distance_mm).atan();
    Optics {
        aperture_half_angle_rad,
        beam_half_angle_rad: if beam_half_angle_rad.is_finite() {
            beam_half_angle_rad.max(0.0)
        } else {
            0.0
        },
        misalignment_rad: MISALIGNMENT_K * reflected_direction_u_rad(instrument),
    }
}

/// The standard uncertainty of the reflected direction from the instrument file's priors (rad): the sample's
/// tilt (both components) and the tilt axis's zero turn it twice, the beam's direction, elevation and the
/// detector's zero once; the beam's offsets and the sample's eccentricity move it sideways, by their size over
/// the detector's distance (the eccentricity twice: it moves where the beam meets the surface along it).
fn reflected_direction_u_rad(instrument: &Instrument) -> f64 {
    let prior = crate::align::priors::prior_u(instrument);
    let distance_mm = instrument.detector.distance_mm;
    let mut variance = 0.0;
    for ((name, unit), u) in PARAM_NAMES.iter().zip(prior) {
        if !(u.is_finite() && u > 0.0) {
            continue;
        }
        let rad = match (*name, *unit) {
            ("sample_tilt_x_deg" | "sample_tilt_y_deg" | "tilt_zero_deg", _) => 2.0 * u.to_radians(),
            ("eccentricity_x_mm" | "eccentricity_y_mm", _) => 2.0 * u / distance_mm,
            (_, "deg") => u.to_radians(),
            (_, "mm") => u / distance_mm,
            _ => 0.0,
        };
        variance += rad * rad;
    }
    variance.sqrt()
}

#[cfg(test)]
mod tests {
    use super::*;
    use gonio_instrument::InstrumentFile;

    #[test]
    fn the_reach_is_the_aperture_and_the_beam_with_the_geometry_s_doubt() {
        let mut inst = InstrumentFile::simulated().instrument;
        inst.detector.aperture_radius_mm = 2.5;
        inst.detector.distance_mm = 250.0;
        inst.source.beam_radius_mm = 1.5;
        inst.source.divergence_deg = 0.05;
        inst.alignment_u_deg = Some(0.0);
        inst.source.pointing_u_deg = Some(0.0);
        inst.source.offset_u_mm = Some(0.0);
        inst.sample_holder.centring_u_mm = Some(0.0);
        inst.sample_holder.tilt_u_deg = Some(0.0);
        let o = optics(&inst);
        assert!((o.aperture_half_angle_rad - 0.01).abs() < 1e-4, "{o:?}");
        // 1.5 mm and 250 mm x tan(0.025 deg) = 0.109 mm, over 250 mm.
        assert!((o.beam_half_angle_rad - 1.609 / 250.0).abs() < 1e-5, "{o:?}");
        assert_eq!(o.misalignment_rad, 0.0);
        // A sample tilt known to 0.05 deg per component turns the reflection by twice that, each: three
        // standard uncertainties of sqrt(2) x 0.1 deg.
        inst.sample_holder.tilt_u_deg = Some(0.05);
        let o = optics(&inst);
        let expected = 3.0 * (2.0f64 * 0.1f64.powi(2)).sqrt().to_radians();
        assert!(
            (o.misalignment_rad - expected).abs() < 1e-9,
            "{o:?} vs {expected}"
        );
        assert!(o.delta_reach_rad() > o.resolution_rad());
    }
}
