//! Overlap of two cones (spherical caps): how much of a reflected beam's divergence cone enters the aperture.
//!
//! A delta lobe sends the reflected beam along the mirror direction, spread by the source's divergence. The beam is
//! modelled as uniform in solid angle over a cone of half-angle `divergence / 2` (a top hat); the detector accepts
//! the cone of half-angle `beta = atan(r / d)` about its axis. The fraction collected is the solid angle of the
//! intersection of the two caps over the beam cap's solid angle, from the closed form for two caps
//! (e.g. Tovchigrechko & Vakser 2001) with radii t1, t2 and separation g:
//! `Omega = 2 [pi - acos X - cos t1 acos Y - cos t2 acos Z]`, written here with differences of cosines turned into
//! products of sines so that tiny caps (0.05 degrees) keep their digits.

use std::f64::consts::PI;

/// Solid angle of a cap of half-angle `t`: `2 pi (1 - cos t) = 4 pi sin^2(t/2)`.
pub fn cap_solid_angle(t: f64) -> f64 {
    let s = (t / 2.0).sin();
    4.0 * PI * s * s
}

/// Fraction of cap A (half-angle `ta`) that lies inside cap B (half-angle `tb`), centres `g` radians apart.
/// A zero-width cap A is a single direction: 1 when it lies inside B (boundary included), else 0.
pub fn fraction_inside(ta: f64, tb: f64, g: f64) -> f64 {
    if ta <= 0.0 {
        return if g <= tb { 1.0 } else { 0.0 };
    }
    if g + ta <= tb {
        return 1.0;
    }
    if g >= ta + tb {
        return 0.0;
    }
    if g + tb <= ta {
        // B lies wholly inside A.
        return cap_solid_angle(tb) / cap_solid_angle(ta);
    }
    (intersection_solid_angle(ta, tb, g) / cap_solid_angle(ta)).clamp(0.0, 1.0)
}

/// Solid angle of the intersection of two caps in the partial-overlap case |t1 - t2| < g < t1 + t2.
fn intersection_solid_angle(t1: f64, t2: f64, g: f64) -> f64 {
    // X = (cos g - cos t1 cos t2) / (sin t1 sin t2)
    //   = 1 - (cos(t1 - t2) - cos g) / (sin t1 sin t2)
    //   = 1 - 2 sin((g + t1 - t2)/2) sin((g - t1 + t2)/2) / (sin t1 sin t2).
    let x = 1.0 - 2.0 * ((g + t1 - t2) / 2.0).sin() * ((g - t1 + t2) / 2.0).sin() / (t1.sin() * t2.sin());
    // Y = (cos t2 - cos g cos t1) / (sin g sin t1) = 1 - 2 sin((t2 + g - t1)/2) sin((t2 - g + t1)/2)/(sin g sin t1).
    let y = 1.0 - 2.0 * ((t2 + g - t1) / 2.0).sin() * ((t2 - g + t1) / 2.0).sin() / (g.sin() * t1.sin());
    let z = 1.0 - 2.0 * ((t1 + g - t2) / 2.0).sin() * ((t1 - g + t2) / 2.0).sin() / (g.sin() * t2.sin());
    let (ax, ay, az) = (
        x.clamp(-1.0, 1.0).acos(),
        y.clamp(-1.0, 1.0).acos(),
        z.clamp(-1.0, 1.0).acos(),
    );
    // cos t = 1 - 2 sin^2(t/2): split so that the small spherical excess pi - ax - ay - az stands alone.
    let h1 = (t1 / 2.0).sin();
    let h2 = (t2 / 2.0).sin();
    2.0 * (PI - ax - ay - az) + 4.0 * h1 * h1 * ay + 4.0 * h2 * h2 * az
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Brute force: fraction of cap A's solid angle inside cap B, on a fine polar grid about A's centre.
    fn brute_force(ta: f64, tb: f64, g: f64) -> f64 {
        // A centred on +z, B centred at polar angle g in the x-z plane.
        let b = [g.sin(), 0.0, g.cos()];
        let cos_tb = tb.cos();
        let (nr, np) = (2000, 2000);
        let (mut total, mut inside) = (0.0, 0.0);
        for i in 0..nr {
            let t = (i as f64 + 0.5) * ta / nr as f64;
            let w = t.sin();
            for j in 0..np {
                let p = (j as f64 + 0.5) * 2.0 * PI / np as f64;
                let v = [t.sin() * p.cos(), t.sin() * p.sin(), t.cos()];
                total += w;
                if v[0] * b[0] + v[2] * b[2] >= cos_tb {
                    inside += w;
                }
            }
        }
        inside / total
    }

    #[test]
    fn containment_and_separation_are_exact() {
        assert_eq!(fraction_inside(0.001, 0.01, 0.005), 1.0);
        assert_eq!(fraction_inside(0.001, 0.01, 0.0111), 0.0);
        assert_eq!(fraction_inside(0.0, 0.01, 0.01), 1.0);
        assert_eq!(fraction_inside(0.0, 0.01, 0.010_000_1), 0.0);
        let r = fraction_inside(0.2, 0.1, 0.05);
        assert!((r - cap_solid_angle(0.1) / cap_solid_angle(0.2)).abs() < 1e-15);
    }

    #[test]
    fn symmetric_half_overlap_of_equal_caps_is_below_one_half() {
        // Two equal caps whose centres are one radius apart: the planar limit is the lens area
        // (2 pi/3 - sqrt(3)/2) / pi = 0.391002...
        let t = 1e-3;
        let f = fraction_inside(t, t, t);
        let planar = (2.0 * PI / 3.0 - 3f64.sqrt() / 2.0) / PI;
        assert!((f - planar).abs() < 1e-6, "{f} vs {planar}");
    }

    #[test]
    fn partial_overlaps_match_brute_force() {
        for (ta, tb, g) in [
            (0.3, 0.2, 0.25),
            (0.02, 0.05, 0.06),
            (4.4e-4, 1e-2, 1e-2),
            (0.5, 0.5, 0.7),
            (1.0, 0.4, 1.2),
        ] {
            let f = fraction_inside(ta, tb, g);
            let bf = brute_force(ta, tb, g);
            assert!((f - bf).abs() < 2e-5, "({ta}, {tb}, {g}): {f} vs {bf}");
        }
    }

    #[test]
    fn fraction_is_continuous_at_the_regime_boundaries() {
        let (ta, tb) = (0.01, 0.03);
        let eps = 1e-12;
        assert!((fraction_inside(ta, tb, tb - ta + eps) - 1.0).abs() < 1e-5);
        assert!(fraction_inside(ta, tb, ta + tb - eps) < 1e-5);
    }
}
