//! A measured point's uncertainty budget ([`gonio_results::budget`]) from the measurement equation's parts, the
//! characterisation's corrections and the signature: each component named, and those every point of a group
//! shares (the solid angle or the reference's certificate by the whole campaign, a band's normalisation by its
//! points, a range's gain by the readings on it) kept apart from what is independent per point.
//!
//! Where each part comes from today:
//! - `signal-noise`, `dark`: the meter's reading uncertainty (crate::acquisition::meter_reading) through the
//!   equation; when the campaign completes, the dark is interpolated between the darks around the value and
//!   `dark` becomes the interpolation's uncertainty ([`dark`]).
//! - `normalisation` (shared by the band): the direct-beam or reference readings carried to the point's time
//!   (crate::calibration), through the equation; when the campaign completes, the value is normalised again
//!   between the readings around it: their noise, by nearness, shared by the values interpolated from each
//!   reading, and the drift's curvature added, independent per point ([`drift`]).
//! - `flicker`: the lamp's slow fluctuation (the instrument file's `source.flicker_rel`, measured by the
//!   self-test), added when the campaign completes: at the value's moment (independent) and at the two
//!   normalisation readings it was interpolated from (each shared by the values interpolated from it) ([`drift`]).
//! - `solid-angle` (absolute) or `certificate` (relative), shared by the campaign.
//! - `pointing`: the axes' arrival tolerance through the equation's angular sensitivity; when the campaign
//!   completes and the read-back pose has brought the value to its nominal geometry, the read-back's resolution
//!   instead, with the alignment's uncertainty times the fitted model's slope ([`complete`]).
//! - `range` (shared by the range): the characterisation's range-gain and linearity correction, relative to
//!   the reading, carried to the value.
//! - `stray-light`: the uncertainty of the subtracted signature (characterised instruments, independent), or
//!   the instrument file's `signature_u_sr` where none was subtracted (shared by the campaign: [`StrayLight`]).
//! - `sample`: the sample's re-seating between mountings (the holder's repeatability through the fitted model),
//!   shared by a mounting's points, and its non-uniformity over the footprint (the campaign's `[sample]
//!   non_uniformity`: [`uniformity`]), shared by the campaign, added when the campaign completes ([`complete`]).
//! - `aperture`: the correction from the aperture average to the BRDF at the nominal geometry, or the whole
//!   bias of a lobe narrower than the aperture, added when the campaign completes ([`complete`]).
//! - `band` (shared by the band): the finite filter band, from the bands measured at the same geometry, added
//!   when the campaign completes ([`complete`]).

mod complete;
mod dark;
mod drift;
mod optics;
mod positioning;
mod sweeps;
mod uniformity;

pub use complete::{NoiseFloor, RunContext, completions};
pub use dark::{DarkSensitivity, Darkened};
pub use sweeps::{TIMING_U_S, sweep_completions};
pub use uniformity::SampleSpec;

use gonio_brdf::measurement::BrdfValue;
use gonio_results::budget::{Budget, components, groups};

/// Everything a point's budget is made of.
#[derive(Debug, Clone, Copy)]
pub struct Parts<'a> {
    /// The measurement equation's value and its per-input contributions.
    pub equation: &'a BrdfValue,
    /// Normalised by a reference sample (its certificate is the scale) rather than the direct beam.
    pub relative: bool,
    pub band_nm: f64,
    /// The range the sample reading was taken on (index into the instrument's `ranges_w`).
    pub range: Option<usize>,
    /// The characterisation's range correction's relative standard uncertainty on the reading (0 without).
    pub range_rel: f64,
    /// The instrument signature's uncertainty in the value.
    pub stray_light: StrayLight,
}

/// The instrument signature (stray light) in a value, as a standard uncertainty (1/sr).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum StrayLight {
    /// A measured signature was subtracted: the measurement's own uncertainty at this geometry, independent per
    /// point.
    Subtracted(f64),
    /// None was subtracted: the instrument file's `signature_u_sr`, the light the instrument itself scatters
    /// into the detector, left in. It is one unknown function of the angle between source and detector, the
    /// same for every point at that angle, so it is shared by the campaign (one unknown level of the file's
    /// profile, adding light to every value: positive entries), not scatter a fit could average away.
    Unmeasured(f64),
}

impl StrayLight {
    /// The standard uncertainty (1/sr).
    pub fn u_sr(self) -> f64 {
        match self {
            StrayLight::Subtracted(u) | StrayLight::Unmeasured(u) => u,
        }
    }
}

/// The point's budget; its [`Budget::total_sr`] is the point's `brdf_u_sr`.
pub fn of_point(p: &Parts<'_>) -> Budget {
    let e = &p.equation.budget;
    let mut b = Budget::default();
    let add = |b: &mut Budget, name: &str, u: f64, shared: Option<String>| {
        if u > 0.0 {
            b.add(name, u, shared);
        }
    };
    add(&mut b, components::SIGNAL_NOISE, e.signal_per_sr, None);
    add(&mut b, components::DARK, e.signal_dark_per_sr, None);
    add(
        &mut b,
        components::NORMALISATION,
        e.normalisation_per_sr.hypot(e.normalisation_dark_per_sr),
        Some(groups::band(p.band_nm)),
    );
    let scale = if p.relative {
        components::CERTIFICATE
    } else {
        components::SOLID_ANGLE
    };
    add(&mut b, scale, e.scale_per_sr, Some(groups::CAMPAIGN.to_string()));
    add(&mut b, components::POINTING, e.angles_per_sr, None);
    let range_u = (p.equation.value_per_sr * p.range_rel).abs();
    add(&mut b, components::RANGE, range_u, p.range.map(groups::range));
    let stray_group = match p.stray_light {
        StrayLight::Subtracted(_) => None,
        StrayLight::Unmeasured(_) => Some(groups::SIGNATURE.to_string()),
    };
    add(&mut b, components::STRAY_LIGHT, p.stray_light.u_sr(), stray_group);
    b
}

#[cfg(test)]
mod tests {
    use super::*;
    use gonio_brdf::measurement::UncertaintyBudget;

    fn value() -> BrdfValue {
        BrdfValue {
            value_per_sr: 0.3,
            std_per_sr: 0.0,
            budget: UncertaintyBudget {
                signal_per_sr: 3e-5,
                signal_dark_per_sr: 1e-6,
                normalisation_per_sr: 4e-5,
                normalisation_dark_per_sr: 3e-5,
                scale_per_sr: 3e-4,
                angles_per_sr: 2e-5,
            },
        }
    }

    #[test]
    fn every_part_is_named_and_the_shared_ones_grouped() {
        let v = value();
        let b = of_point(&Parts {
            equation: &v,
            relative: false,
            band_nm: 550.0,
            range: Some(3),
            range_rel: 1e-3,
            stray_light: StrayLight::Subtracted(0.0),
        });
        let find = |name: &str| b.entries.iter().find(|e| e.component == name).cloned();
        assert_eq!(find(components::NORMALISATION).unwrap().u_sr, 5e-5);
        assert_eq!(
            find(components::NORMALISATION).unwrap().shared.as_deref(),
            Some("band-550")
        );
        assert_eq!(
            find(components::SOLID_ANGLE).unwrap().shared.as_deref(),
            Some("campaign")
        );
        assert!(find(components::CERTIFICATE).is_none());
        assert!((find(components::RANGE).unwrap().u_sr - 3e-4).abs() < 1e-15);
        assert_eq!(
            find(components::RANGE).unwrap().shared.as_deref(),
            Some("range-3")
        );
        // No signature subtracted: no stray-light entry.
        assert!(find(components::STRAY_LIGHT).is_none());
        let independent = (3e-5f64.powi(2) + 1e-6f64.powi(2) + 2e-5f64.powi(2)).sqrt();
        assert!((b.independent_sr() - independent).abs() < 1e-15);
        let total = (independent.powi(2) + 5e-5f64.powi(2) + 3e-4f64.powi(2) * 2.0).sqrt();
        assert!((b.total_sr() - total).abs() < 1e-15);
    }

    #[test]
    fn a_relative_campaign_names_the_certificate() {
        let v = value();
        let b = of_point(&Parts {
            equation: &v,
            relative: true,
            band_nm: 450.0,
            range: None,
            range_rel: 0.0,
            stray_light: StrayLight::Subtracted(1e-5),
        });
        let names: Vec<&str> = b.entries.iter().map(|e| e.component.as_str()).collect();
        assert!(names.contains(&components::CERTIFICATE), "{names:?}");
        assert!(!names.contains(&components::SOLID_ANGLE), "{names:?}");
        assert!(!names.contains(&components::RANGE), "{names:?}");
        assert!(names.contains(&components::STRAY_LIGHT), "{names:?}");
    }

    #[test]
    fn a_signature_left_in_is_shared_by_the_campaign_and_a_subtracted_one_is_not() {
        let v = value();
        let parts = |stray_light| Parts {
            equation: &v,
            relative: false,
            band_nm: 550.0,
            range: None,
            range_rel: 0.0,
            stray_light,
        };
        let stray = |b: &Budget| {
            b.entries
                .iter()
                .find(|e| e.component == components::STRAY_LIGHT)
                .cloned()
                .expect("a stray-light entry")
        };
        let left_in = of_point(&parts(StrayLight::Unmeasured(4e-5)));
        let e = stray(&left_in);
        assert_eq!((e.u_sr, e.shared.as_deref()), (4e-5, Some(groups::SIGNATURE)));
        let subtracted = of_point(&parts(StrayLight::Subtracted(4e-5)));
        let e = stray(&subtracted);
        assert_eq!((e.u_sr, e.shared), (4e-5, None));
        // The same size either way: only what a fit may average away differs.
        assert_eq!(left_in.total_sr(), subtracted.total_sr());
        assert!(left_in.independent_sr() < subtracted.independent_sr());
    }
}
