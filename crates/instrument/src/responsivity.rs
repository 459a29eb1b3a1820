//! The photodiode's spectral responsivity (A/W), from `[instrument.detector] responsivity_a_per_w`: what the
//! simulated power meter converts light with (simulator/src/pm100), what weights a finite filter band
//! (simulator/src/optics/spectral.rs), and what the self-test turns the meter's watts back into the head's
//! current with (crates/engine/src/selftest/noise.rs).

use crate::Detector;

/// Photodiode responsivity (A/W) as a function of wavelength.
#[derive(Debug, Clone)]
pub enum Responsivity {
    Constant(f64),
    Table(Vec<(f64, f64)>),
}

impl Responsivity {
    /// The table of `[instrument.detector] responsivity_a_per_w`, or why it is not one.
    pub fn from_detector(d: &Detector) -> Result<Responsivity, crate::InvalidInstrument> {
        Responsivity::read(d).map_err(crate::InvalidInstrument)
    }

    fn read(d: &Detector) -> Result<Responsivity, String> {
        match &d.responsivity_a_per_w {
            None => Ok(Responsivity::Constant(0.5)),
            Some(toml::Value::Float(x)) if *x > 0.0 => Ok(Responsivity::Constant(*x)),
            Some(toml::Value::Integer(x)) if *x > 0 => Ok(Responsivity::Constant(*x as f64)),
            Some(toml::Value::Table(t)) => {
                let mut pts = Vec::new();
                for (k, v) in t {
                    let nm: f64 = k.trim().parse().map_err(|_| {
                        format!(
                            "[instrument.detector] responsivity_a_per_w: key {k:?} is not a wavelength in nm"
                        )
                    })?;
                    let r = v
                        .as_float()
                        .or_else(|| v.as_integer().map(|i| i as f64))
                        .filter(|r| *r > 0.0)
                        .ok_or_else(|| {
                            format!("[instrument.detector] responsivity_a_per_w: value at {k} nm must be > 0")
                        })?;
                    pts.push((nm, r));
                }
                pts.sort_by(|a, b| a.0.total_cmp(&b.0));
                if pts.is_empty() {
                    return Err("[instrument.detector] responsivity_a_per_w: empty table".into());
                }
                Ok(Responsivity::Table(pts))
            }
            Some(v) => Err(format!(
                "[instrument.detector] responsivity_a_per_w: expected a number > 0 or a table, got {v}"
            )),
        }
    }

    /// The table's wavelengths (nm); none for a constant responsivity.
    pub fn wavelengths_nm(&self) -> Vec<f64> {
        match self {
            Responsivity::Constant(_) => Vec::new(),
            Responsivity::Table(pts) => pts.iter().map(|p| p.0).collect(),
        }
    }

    /// Linear interpolation, constant beyond the table's ends.
    pub fn at(&self, nm: f64) -> f64 {
        match self {
            Responsivity::Constant(r) => *r,
            Responsivity::Table(pts) => {
                let (Some(first), Some(last)) = (pts.first(), pts.last()) else {
                    return 0.5;
                };
                if nm <= first.0 {
                    return first.1;
                }
                if nm >= last.0 {
                    return last.1;
                }
                for w in pts.windows(2) {
                    let (a, b) = (w[0], w[1]);
                    if nm <= b.0 {
                        let f = (nm - a.0) / (b.0 - a.0);
                        return a.1 + f * (b.1 - a.1);
                    }
                }
                last.1
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn responsivity_interpolates_linearly_and_clamps() {
        let r = Responsivity::Table(vec![(400.0, 0.1), (500.0, 0.3)]);
        assert!((r.at(450.0) - 0.2).abs() < 1e-12);
        assert_eq!(r.at(300.0), 0.1);
        assert_eq!(r.at(900.0), 0.3);
    }
}
