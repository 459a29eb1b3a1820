//! The instrument signature as known before a characterisation measures it, from `[instrument.detector]
//! signature_u_sr`: a standard uncertainty (1/sr, BRDF-equivalent along the normal) on every value no measured
//! signature was subtracted from. The signature is what the detector reads with the holder empty (ASTM E2387):
//! light scattered by the source's optics, the mounts and the room, strongest near the undeviated beam and
//! falling away from it (Stover, "Optical Scattering", 2nd ed., SPIE 1995, ch. 6), so the file gives either one
//! level or a table from the angle between the detector and the beam's forward direction (deg) to the level
//! there, interpolated linearly in the logarithms of both and held beyond its ends.

use crate::{DEFAULT_SIGNATURE_U_SR, Detector, InvalidInstrument};

/// The unmeasured signature's standard uncertainty against the angle from the beam.
#[derive(Debug, Clone, PartialEq)]
pub enum SignatureUncertainty {
    Level(f64),
    /// (angle from the beam in deg, level in 1/sr), ascending in angle; angles and levels > 0.
    ByAngle(Vec<(f64, f64)>),
}

const KEY: &str = "[instrument.detector] signature_u_sr";

impl SignatureUncertainty {
    /// The file's `signature_u_sr`, or why it is not one; absent: [`DEFAULT_SIGNATURE_U_SR`].
    pub fn from_detector(d: &Detector) -> Result<SignatureUncertainty, InvalidInstrument> {
        SignatureUncertainty::read(d).map_err(InvalidInstrument)
    }

    fn read(d: &Detector) -> Result<SignatureUncertainty, String> {
        let number = |v: &toml::Value| v.as_float().or_else(|| v.as_integer().map(|i| i as f64));
        match &d.signature_u_sr {
            None => Ok(SignatureUncertainty::Level(DEFAULT_SIGNATURE_U_SR)),
            Some(toml::Value::Table(t)) => {
                let mut points = Vec::new();
                for (k, v) in t {
                    let alpha: f64 = k
                        .trim()
                        .parse()
                        .ok()
                        .filter(|a: &f64| a.is_finite() && *a > 0.0 && *a <= 180.0)
                        .ok_or_else(|| format!("{KEY}: key {k:?} is not an angle from the beam in (0, 180] deg"))?;
                    let level = number(v)
                        .filter(|u| u.is_finite() && *u > 0.0 && *u < 1.0)
                        .ok_or_else(|| format!("{KEY}: the level at {k} deg must be in (0, 1) (1/sr), got {v}"))?;
                    points.push((alpha, level));
                }
                points.sort_by(|a, b| a.0.total_cmp(&b.0));
                if points.is_empty() {
                    return Err(format!("{KEY}: empty table"));
                }
                Ok(SignatureUncertainty::ByAngle(points))
            }
            Some(v) => number(v)
                .filter(|u| u.is_finite() && (0.0..1.0).contains(u))
                .map(SignatureUncertainty::Level)
                .ok_or_else(|| {
                    format!("{KEY}: expected a level in [0, 1) (1/sr) or a table from angles (deg) to levels, got {v}")
                }),
        }
    }

    /// The level (1/sr, along the normal) at `alpha_deg` from the beam's forward direction.
    pub fn at(&self, alpha_deg: f64) -> f64 {
        match self {
            SignatureUncertainty::Level(u) => *u,
            SignatureUncertainty::ByAngle(points) => {
                let (first, last) = (points[0], points[points.len() - 1]);
                if alpha_deg.is_nan() || alpha_deg <= first.0 {
                    return first.1;
                }
                if alpha_deg >= last.0 {
                    return last.1;
                }
                let k = points.partition_point(|p| p.0 <= alpha_deg);
                let ((a0, u0), (a1, u1)) = (points[k - 1], points[k]);
                let x = (alpha_deg.ln() - a0.ln()) / (a1.ln() - a0.ln());
                (u0.ln() + x * (u1.ln() - u0.ln())).exp()
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn detector(value: Option<&str>) -> Detector {
        let mut d = crate::InstrumentFile::simulated().instrument.detector;
        d.signature_u_sr =
            value.map(|v| toml::from_str::<toml::Table>(&format!("x = {v}")).expect("TOML")["x"].clone());
        d
    }

    #[test]
    fn a_table_is_interpolated_in_the_logarithms_and_held_beyond_its_ends() {
        let u =
            SignatureUncertainty::from_detector(&detector(Some("{ 10 = 4e-4, 90 = 1e-5 }"))).expect("valid");
        assert_eq!(u.at(5.0), 4e-4);
        assert_eq!(u.at(120.0), 1e-5);
        // A power law between the keys: at the geometric mean of the angles, the geometric mean of the levels.
        let mid = u.at(30.0);
        assert!((mid - (4e-4f64 * 1e-5).sqrt()).abs() < 1e-15, "{mid}");
        assert_eq!(u.at(f64::NAN), 4e-4);
    }

    #[test]
    fn a_number_is_one_level_and_absent_is_the_default() {
        assert_eq!(
            SignatureUncertainty::from_detector(&detector(Some("2e-6")))
                .expect("valid")
                .at(45.0),
            2e-6
        );
        assert_eq!(
            SignatureUncertainty::from_detector(&detector(None))
                .expect("valid")
                .at(45.0),
            DEFAULT_SIGNATURE_U_SR
        );
    }

    #[test]
    fn nonsense_is_refused_with_the_key() {
        for bad in [
            "-1e-5",
            "{ 0 = 1e-5 }",
            "{ 10 = -1.0 }",
            "{ ten = 1e-5 }",
            "{}",
            "\"high\"",
        ] {
            let e = SignatureUncertainty::from_detector(&detector(Some(bad))).expect_err(bad);
            assert!(e.0.contains("signature_u_sr"), "{bad}: {e}");
        }
    }
}
