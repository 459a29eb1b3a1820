//! Quantities that may vary with wavelength: a single number, or a table nm -> value with linear interpolation.
//!
//! In TOML a spectral value is written either as a number (`albedo = 0.8`) or as an inline table whose keys are
//! wavelengths in nanometres (`eta = { 450 = 1.509, 550 = 0.350, 650 = 0.168 }`; a fractional wavelength must be
//! quoted, `"632.8" = 0.95`, because TOML reads `632.8 = ...` as a dotted key). A table is never extrapolated:
//! asking for a wavelength outside it is an error that names the range.

use std::collections::BTreeMap;
use std::fmt;

use serde::de::{self, Deserializer, MapAccess, Visitor};
use serde::{Deserialize, Serialize, Serializer};

/// A wavelength in nanometres. The unit is in the name of every accessor so that it cannot be lost.
#[derive(Debug, Clone, Copy, PartialEq, PartialOrd)]
pub struct Wavelength(f64);

impl Wavelength {
    /// The wavelength used when a caller does not say: 550 nm, the middle of the visible.
    pub const DEFAULT: Wavelength = Wavelength(550.0);

    /// A wavelength in nm; must be finite and positive.
    pub fn from_nm(nm: f64) -> Result<Wavelength, SpectrumError> {
        if nm.is_finite() && nm > 0.0 {
            Ok(Wavelength(nm))
        } else {
            Err(SpectrumError::BadWavelength(nm))
        }
    }

    pub fn nm(&self) -> f64 {
        self.0
    }
}

impl fmt::Display for Wavelength {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{} nm", self.0)
    }
}

#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum SpectrumError {
    #[error("wavelength {nm} nm is outside the table's range {min_nm}..{max_nm} nm")]
    OutOfRange { nm: f64, min_nm: f64, max_nm: f64 },
    #[error("wavelength must be a positive number of nanometres, got {0}")]
    BadWavelength(f64),
    #[error("a spectral table needs at least one entry")]
    EmptyTable,
    #[error("spectral table key {0:?} is not a wavelength in nm (a positive number)")]
    BadKey(String),
    #[error("spectral table value at {nm} nm is not finite")]
    NonFinite { nm: f64 },
}

/// A value that may depend on wavelength.
#[derive(Debug, Clone, PartialEq)]
pub enum Spectral {
    Constant(f64),
    /// Sorted by wavelength (nm), strictly increasing, at least one entry.
    Table(Vec<(f64, f64)>),
}

impl Spectral {
    /// A table from (nm, value) pairs in any order. Duplicate wavelengths keep the last value.
    pub fn table(entries: impl IntoIterator<Item = (f64, f64)>) -> Result<Spectral, SpectrumError> {
        let mut map = BTreeMap::new();
        for (nm, value) in entries {
            if !(nm.is_finite() && nm > 0.0) {
                return Err(SpectrumError::BadKey(nm.to_string()));
            }
            if !value.is_finite() {
                return Err(SpectrumError::NonFinite { nm });
            }
            map.insert(OrderedNm(nm), value);
        }
        if map.is_empty() {
            return Err(SpectrumError::EmptyTable);
        }
        Ok(Spectral::Table(map.into_iter().map(|(k, v)| (k.0, v)).collect()))
    }

    /// The value at a wavelength: the constant, or linear interpolation in the table.
    pub fn at(&self, wavelength: Wavelength) -> Result<f64, SpectrumError> {
        match self {
            Spectral::Constant(v) => Ok(*v),
            Spectral::Table(t) => interpolate(t, wavelength.nm()),
        }
    }

    /// This value frozen at one wavelength (used to resolve a material once before many evaluations).
    pub fn resolved(&self, wavelength: Wavelength) -> Result<Spectral, SpectrumError> {
        self.at(wavelength).map(Spectral::Constant)
    }

    pub fn is_constant(&self) -> bool {
        match self {
            Spectral::Constant(_) => true,
            Spectral::Table(t) => t.windows(2).all(|w| w[0].1 == w[1].1),
        }
    }

    /// Smallest and largest value anywhere in the spectrum (for range checks).
    pub fn min_max(&self) -> (f64, f64) {
        match self {
            Spectral::Constant(v) => (*v, *v),
            Spectral::Table(t) => t
                .iter()
                .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), &(_, v)| {
                    (lo.min(v), hi.max(v))
                }),
        }
    }

    /// The wavelength range over which the value is defined; `None` for a constant.
    pub fn range_nm(&self) -> Option<(f64, f64)> {
        match self {
            Spectral::Constant(_) => None,
            Spectral::Table(t) => Some((t[0].0, t[t.len() - 1].0)),
        }
    }
}

fn interpolate(table: &[(f64, f64)], nm: f64) -> Result<f64, SpectrumError> {
    let (first, last) = (table[0], table[table.len() - 1]);
    if !(nm >= first.0 && nm <= last.0) {
        return Err(SpectrumError::OutOfRange {
            nm,
            min_nm: first.0,
            max_nm: last.0,
        });
    }
    // Tables are short (a handful of entries): a linear scan beats a binary search here.
    let upper = table
        .iter()
        .position(|&(w, _)| w >= nm)
        .unwrap_or(table.len() - 1);
    if upper == 0 || table[upper].0 == nm {
        return Ok(table[upper].1);
    }
    let (w0, v0) = table[upper - 1];
    let (w1, v1) = table[upper];
    let t = (nm - w0) / (w1 - w0);
    Ok(v0 + t * (v1 - v0))
}

/// A wavelength key with a total order, so tables can be sorted and deduplicated in a BTreeMap.
#[derive(Debug, Clone, Copy)]
struct OrderedNm(f64);
impl PartialEq for OrderedNm {
    fn eq(&self, other: &Self) -> bool {
        self.cmp(other) == std::cmp::Ordering::Equal
    }
}
impl Eq for OrderedNm {}
impl PartialOrd for OrderedNm {
    fn partial_cmp(&self, other: &Self) -> Option<std::cmp::Ordering> {
        Some(self.cmp(other))
    }
}
impl Ord for OrderedNm {
    fn cmp(&self, other: &Self) -> std::cmp::Ordering {
        self.0.total_cmp(&other.0)
    }
}

impl<'de> Deserialize<'de> for Spectral {
    fn deserialize<D: Deserializer<'de>>(deserializer: D) -> Result<Spectral, D::Error> {
        struct SpectralVisitor;
        impl<'de> Visitor<'de> for SpectralVisitor {
            type Value = Spectral;
            fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
                f.write_str("a number, or a table of wavelength in nm = value, e.g. { 450 = 0.2, 650 = 0.8 }")
            }
            fn visit_f64<E: de::Error>(self, v: f64) -> Result<Spectral, E> {
                if v.is_finite() {
                    Ok(Spectral::Constant(v))
                } else {
                    Err(E::custom("value is not finite"))
                }
            }
            fn visit_i64<E: de::Error>(self, v: i64) -> Result<Spectral, E> {
                Ok(Spectral::Constant(v as f64))
            }
            fn visit_u64<E: de::Error>(self, v: u64) -> Result<Spectral, E> {
                Ok(Spectral::Constant(v as f64))
            }
            fn visit_map<A: MapAccess<'de>>(self, mut map: A) -> Result<Spectral, A::Error> {
                let mut entries = Vec::new();
                while let Some((key, value)) = map.next_entry::<String, f64>()? {
                    let nm: f64 = key
                        .trim()
                        .parse()
                        .map_err(|_| de::Error::custom(SpectrumError::BadKey(key.clone())))?;
                    entries.push((nm, value));
                }
                Spectral::table(entries).map_err(de::Error::custom)
            }
        }
        deserializer.deserialize_any(SpectralVisitor)
    }
}

impl Serialize for Spectral {
    fn serialize<S: Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        match self {
            Spectral::Constant(v) => serializer.serialize_f64(*v),
            Spectral::Table(t) => {
                use serde::ser::SerializeMap;
                let mut map = serializer.serialize_map(Some(t.len()))?;
                for (nm, v) in t {
                    map.serialize_entry(&format!("{nm}"), v)?;
                }
                map.end()
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn nm(v: f64) -> Wavelength {
        Wavelength::from_nm(v).expect("valid wavelength")
    }

    #[test]
    fn table_interpolates_linearly_and_refuses_extrapolation() {
        let s = Spectral::table([(650.0, 0.168), (450.0, 1.509), (550.0, 0.350)]).expect("table");
        assert_eq!(s.at(nm(550.0)), Ok(0.350));
        assert!((s.at(nm(500.0)).expect("in range") - (1.509 + 0.350) / 2.0).abs() < 1e-15);
        assert_eq!(s.at(nm(450.0)), Ok(1.509));
        assert_eq!(s.at(nm(650.0)), Ok(0.168));
        assert!(matches!(s.at(nm(700.0)), Err(SpectrumError::OutOfRange { .. })));
        assert!(matches!(s.at(nm(449.999)), Err(SpectrumError::OutOfRange { .. })));
    }

    #[test]
    fn parses_numbers_and_tables_from_toml() {
        #[derive(Deserialize)]
        struct T {
            a: Spectral,
            b: Spectral,
            c: Spectral,
        }
        let t: T = toml::from_str("a = 0.5\nb = 1\nc = { 450 = 1.0, \"650.5\" = 2.0 }").expect("parses");
        assert_eq!(t.a, Spectral::Constant(0.5));
        assert_eq!(t.b, Spectral::Constant(1.0));
        assert_eq!(t.c, Spectral::Table(vec![(450.0, 1.0), (650.5, 2.0)]));
        let bad = toml::from_str::<T>("a = 0.5\nb = 1\nc = { blue = 1.0 }");
        assert!(bad.is_err());
    }
}
