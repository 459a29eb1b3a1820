//! The sample's non-uniformity (`sample` component): its reflectance varies over its area, and a value is its
//! BRDF averaged over the beam's footprint, not at the sample's centre.
//!
//! The campaign states how much the reflectance may change from the centre to the edge (`[sample]
//! non_uniformity`, a relative standard uncertainty `u`), taken both as a linear gradient across the sample
//! (each component of size `u`) and as a change towards its rim (`u`): the reflectance at `(x, y)` relative to
//! the centre's is `1 + (g_x x + g_y y) / R + q (x^2 + y^2) / R^2`, R the sample's radius. Over a footprint of
//! semi-axes `a = r / cos(theta_i)` and `b = r` (r the beam's radius) centred `c` off the sample's centre, its
//! mean is `1 + g.c / R + q (|c|^2 + (a^2 + b^2) / 4) / R^2`: the rim term grows with the footprint towards
//! grazing incidence, the gradient term with how far off the centre the beam lands (the sample's centring,
//! `[instrument.sample_holder] centring_u_mm`, each component). One sample serves the campaign: both are signed
//! entries every point shares (`non-uniformity-rim`, `non-uniformity-gradient`), which a fit propagates apart.
//! The direct beam does not see the sample, so nothing cancels; a reference sample's own non-uniformity is its
//! certificate's business.

/// The group of the rim term.
pub const RIM: &str = "non-uniformity-rim";
/// The group of the gradient term.
pub const GRADIENT: &str = "non-uniformity-gradient";

/// The sample as the non-uniformity needs it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SampleSpec {
    /// The sample's radius (mm).
    pub radius_mm: f64,
    /// The reflectance's relative change from centre to edge (standard uncertainty); 0: uniform.
    pub non_uniformity: f64,
}

/// The relative change of a value at incidence `theta_i_deg` that each term of size `u` makes: `(group,
/// relative change)`; empty for a uniform sample or a geometry without a footprint.
pub(super) fn shifts(
    sample: SampleSpec,
    theta_i_deg: f64,
    beam_radius_mm: f64,
    centring_u_mm: f64,
) -> Vec<(&'static str, f64)> {
    let (u, r_s) = (sample.non_uniformity, sample.radius_mm);
    let cos_i = theta_i_deg.to_radians().cos();
    // At 90 degrees (cos of 6e-17) the footprint is a line to infinity: no mean over it.
    if !(u > 0.0 && r_s > 0.0 && cos_i > 1e-9 && beam_radius_mm > 0.0) {
        return Vec::new();
    }
    let a = beam_radius_mm / cos_i;
    let b = beam_radius_mm;
    // The spot's expected squared offset: two components of the centring's standard uncertainty.
    let offset_sq = 2.0 * centring_u_mm.max(0.0).powi(2);
    let rim = u * (offset_sq + (a * a + b * b) / 4.0) / (r_s * r_s);
    let gradient = u * offset_sq.sqrt() / r_s;
    [(RIM, rim), (GRADIENT, gradient)]
        .into_iter()
        .filter(|(_, rel)| rel.is_finite() && *rel != 0.0)
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_rim_term_grows_with_the_footprint_towards_grazing() {
        let sample = SampleSpec {
            radius_mm: 12.5,
            non_uniformity: 0.003,
        };
        let at = |theta_i: f64| shifts(sample, theta_i, 1.5, 0.0);
        // Normal incidence, a 1.5 mm beam on a 12.5 mm sample: 0.003 x (2.25 + 2.25) / 4 / 156.25.
        let normal = at(0.0);
        assert_eq!(normal.len(), 1, "centred exactly: no gradient term");
        assert!(
            (normal[0].1 - 0.003 * 4.5 / 4.0 / 156.25).abs() < 1e-12,
            "{normal:?}"
        );
        // At 75 degrees the footprint is 3.9 times longer: the term (1 + 1 / cos^2) / 2, about 8 times larger.
        let grazing = at(75.0)[0].1;
        let a = 1.5 / 75f64.to_radians().cos();
        assert!((grazing - 0.003 * (a * a + 2.25) / 4.0 / 156.25).abs() < 1e-12);
        assert!(grazing > 7.9 * normal[0].1);
        // The gradient term: how far off the centre the spot lands.
        let off = shifts(sample, 0.0, 1.5, 0.1);
        let gradient = off
            .iter()
            .find(|(g, _)| *g == GRADIENT)
            .expect("a gradient term")
            .1;
        assert!((gradient - 0.003 * 0.02f64.sqrt() / 12.5).abs() < 1e-12);
    }

    #[test]
    fn a_uniform_sample_adds_nothing_and_nonsense_adds_nothing() {
        let uniform = SampleSpec {
            radius_mm: 12.5,
            non_uniformity: 0.0,
        };
        assert!(shifts(uniform, 30.0, 1.5, 0.1).is_empty());
        let sample = SampleSpec {
            non_uniformity: 0.003,
            ..uniform
        };
        assert!(shifts(sample, 90.0, 1.5, 0.1).is_empty());
        assert!(shifts(sample, f64::NAN, 1.5, 0.1).is_empty());
        let both = shifts(sample, 30.0, 1.5, 0.1);
        assert_eq!(both.len(), 2);
        assert!(both.iter().all(|(_, rel)| *rel > 0.0));
    }
}
