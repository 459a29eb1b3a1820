//! Quantities that may vary with wavelength: a single number, or a table nm -> value interpolated by a monotone
//! piecewise cubic (PCHIP).
//!
//! Why not linear: a material's spectrum is smooth, and a table is a sampling of it, often every 50 nm. Linear
//! interpolation puts a kink at every entry, and a finite filter band centred on one (simulator, the filters
//! group) averages that kink: its mean moves by half the slope's jump times the band's mean distance from its
//! centre (2.9 nm for a 10 nm three-cavity band). On coloured plastic's 550 nm entry (slope -0.004 then -0.001
//! per nm, value 0.10) that is 4.3 % of the value, about ten times what a smooth curve through the same values
//! gives (its curvature, about the slope's jump over 50 nm, times the band's variance of 12.5 nm^2, over 2). The Fritsch-Carlson monotone cubic (Fritsch & Carlson,
//! "Monotone piecewise cubic interpolation", SIAM J. Numer. Anal. 17(2):238-246, 1980, with the Fritsch-Butland
//! weighted harmonic mean of the neighbouring slopes at interior entries, as SciPy's `PchipInterpolator` does) has a
//! continuous slope, passes through every entry, reproduces straight lines exactly, and never overshoots: between two
//! entries it stays between their values, so an albedo in [0, 1] stays there and a local extremum is an entry.
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

    /// The value at a wavelength: the constant, or the table's monotone cubic (module doc).
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
    let k = upper - 1;
    let (w0, v0) = table[k];
    let (w1, v1) = table[upper];
    let h = w1 - w0;
    let t = (nm - w0) / h;
    let (d0, d1) = (slope_at(table, k), slope_at(table, upper));
    // Cubic Hermite basis on [w0, w1].
    let (t2, t3) = (t * t, t * t * t);
    Ok((2.0 * t3 - 3.0 * t2 + 1.0) * v0
        + (t3 - 2.0 * t2 + t) * h * d0
        + (-2.0 * t3 + 3.0 * t2) * v1
        + (t3 - t2) * h * d1)
}

/// The slope at entry `k` of the monotone cubic through `table` (nm ascending, module doc): what this module
/// interpolates with, for anyone who needs a smooth spectrum's slope at the wavelengths it was sampled at
/// (gonio_results::band_component). `None` for fewer than two entries, `k` beyond the table, or wavelengths not
/// strictly ascending.
pub fn monotone_cubic_slope(table: &[(f64, f64)], k: usize) -> Option<f64> {
    let ascending = table
        .windows(2)
        .all(|w| w[1].0.partial_cmp(&w[0].0) == Some(std::cmp::Ordering::Greater));
    (table.len() >= 2 && k < table.len() && ascending).then(|| slope_at(table, k))
}

/// The monotone cubic's slope at entry `k` (module doc): 0 where the neighbouring secants change sign, their
/// weighted harmonic mean elsewhere, and at the ends the shape-preserving three-point estimate.
fn slope_at(table: &[(f64, f64)], k: usize) -> f64 {
    let n = table.len();
    let secant = |i: usize| (table[i + 1].1 - table[i].1) / (table[i + 1].0 - table[i].0);
    let width = |i: usize| table[i + 1].0 - table[i].0;
    if n == 2 {
        return secant(0);
    }
    let end = |(h0, d0): (f64, f64), (h1, d1): (f64, f64)| {
        let d = ((2.0 * h0 + h1) * d0 - h0 * d1) / (h0 + h1);
        if d.signum() != d0.signum() || d0 == 0.0 {
            0.0
        } else if d0.signum() != d1.signum() && d.abs() > 3.0 * d0.abs() {
            3.0 * d0
        } else {
            d
        }
    };
    if k == 0 {
        return end((width(0), secant(0)), (width(1), secant(1)));
    }
    if k == n - 1 {
        return end((width(n - 2), secant(n - 2)), (width(n - 3), secant(n - 3)));
    }
    let (h0, h1, d0, d1) = (width(k - 1), width(k), secant(k - 1), secant(k));
    if d0 * d1 <= 0.0 {
        return 0.0;
    }
    let (a, b) = (2.0 * h1 + h0, h1 + 2.0 * h0);
    (a + b) / (a / d0 + b / d1)
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
    fn table_passes_through_its_entries_and_refuses_extrapolation() {
        let s = Spectral::table([(650.0, 0.168), (450.0, 1.509), (550.0, 0.350)]).expect("table");
        assert_eq!(s.at(nm(550.0)), Ok(0.350));
        assert_eq!(s.at(nm(450.0)), Ok(1.509));
        assert_eq!(s.at(nm(650.0)), Ok(0.168));
        assert!(matches!(s.at(nm(700.0)), Err(SpectrumError::OutOfRange { .. })));
        assert!(matches!(s.at(nm(449.999)), Err(SpectrumError::OutOfRange { .. })));
    }

    /// The monotone cubic, against values worked out by hand from Fritsch-Carlson's rules (module doc).
    #[test]
    fn the_monotone_cubic_matches_a_hand_computed_case() {
        // (0, 0), (1, 1), (2, 0) (nm shifted by 400 to stay positive): at the start the three-point estimate
        // ((2 h0 + h1) d0 - h0 d1) / (h0 + h1) = (3 + 1) / 2 = 2 (same sign as d0, within 3 d0); at the peak 0
        // (the secants change sign). Hermite at t = 1/2: 0.125 h d0 + 0.5 v1 = 0.25 + 0.5 = 0.75.
        let s = Spectral::table([(400.0, 0.0), (401.0, 1.0), (402.0, 0.0)]).expect("table");
        assert!((s.at(nm(400.5)).expect("in") - 0.75).abs() < 1e-15);
        assert!((s.at(nm(401.5)).expect("in") - 0.75).abs() < 1e-15, "symmetric");
        // Interior weighted harmonic mean: (0,0), (1,1), (3,2): secants 1 and 0.5, h 1 and 2:
        // a = 2*2 + 1 = 5, b = 2 + 2*1 = 4, slope 9 / (5/1 + 4/0.5) = 9/13 at x = 1.
        let s = Spectral::table([(400.0, 0.0), (401.0, 1.0), (403.0, 2.0)]).expect("table");
        let (x, h) = (402.0, 2.0);
        let t: f64 = (x - 401.0) / h;
        let d1 = 9.0 / 13.0;
        // End slope at x = 3: ((2*2 + 1) 0.5 - 2 * 1) / 3 = 0.5/3, same sign as 0.5.
        let d2 = 0.5 / 3.0;
        let want = (2.0 * t.powi(3) - 3.0 * t * t + 1.0) * 1.0
            + (t.powi(3) - 2.0 * t * t + t) * h * d1
            + (-2.0 * t.powi(3) + 3.0 * t * t) * 2.0
            + (t.powi(3) - t * t) * h * d2;
        assert!((s.at(nm(x)).expect("in") - want).abs() < 1e-15);
    }

    #[test]
    fn the_public_slope_is_the_cubic_s_own_and_refuses_what_it_cannot_take() {
        // The hand-computed cases above: 9/13 inside, 0.5/3 at the end, 2 at the start of the peak, 0 on it.
        let t = [(400.0, 0.0), (401.0, 1.0), (403.0, 2.0)];
        assert!((monotone_cubic_slope(&t, 1).expect("inside") - 9.0 / 13.0).abs() < 1e-15);
        assert!((monotone_cubic_slope(&t, 2).expect("end") - 0.5 / 3.0).abs() < 1e-15);
        let peak = [(400.0, 0.0), (401.0, 1.0), (402.0, 0.0)];
        assert_eq!(monotone_cubic_slope(&peak, 0), Some(2.0));
        assert_eq!(monotone_cubic_slope(&peak, 1), Some(0.0));
        // Two entries: their secant.
        assert_eq!(
            monotone_cubic_slope(&[(450.0, 0.1), (550.0, 0.3)], 0),
            Some((0.3 - 0.1) / 100.0)
        );
        assert_eq!(monotone_cubic_slope(&t, 3), None);
        assert_eq!(monotone_cubic_slope(&[(450.0, 0.1)], 0), None);
        assert_eq!(monotone_cubic_slope(&[(550.0, 0.1), (450.0, 0.2)], 0), None);
    }

    #[test]
    fn the_cubic_keeps_lines_straight_and_values_between_their_entries() {
        let line = Spectral::table([(400.0, 0.1), (450.0, 0.2), (600.0, 0.5), (700.0, 0.7)]).expect("table");
        for x in [410.0, 449.0, 500.0, 650.5, 699.0] {
            let want = 0.1 + (x - 400.0) * 0.002;
            assert!((line.at(nm(x)).expect("in") - want).abs() < 1e-14, "{x}");
        }
        // Coloured plastic's albedo: no value leaves the range of the two entries around it.
        let t = [
            (400.0, 0.35),
            (450.0, 0.45),
            (500.0, 0.30),
            (550.0, 0.10),
            (600.0, 0.05),
            (650.0, 0.04),
            (700.0, 0.04),
        ];
        let s = Spectral::table(t).expect("table");
        for w in t.windows(2) {
            let (lo, hi) = (w[0].1.min(w[1].1), w[0].1.max(w[1].1));
            for i in 1..50 {
                let x = w[0].0 + (w[1].0 - w[0].0) * f64::from(i) / 50.0;
                let v = s.at(nm(x)).expect("in");
                assert!(
                    v >= lo - 1e-15 && v <= hi + 1e-15,
                    "{x}: {v} outside [{lo}, {hi}]"
                );
            }
        }
        // The slope is continuous at an entry (no kink): left and right difference quotients agree.
        let e = 1e-4;
        let left = (s.at(nm(550.0)).expect("in") - s.at(nm(550.0 - e)).expect("in")) / e;
        let right = (s.at(nm(550.0 + e)).expect("in") - s.at(nm(550.0)).expect("in")) / e;
        assert!((left - right).abs() < 1e-5, "{left} vs {right}");
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
