//! A measured point's uncertainty budget (GUM, JCGM 100): its standard-uncertainty components, each in 1/sr
//! (k = 1), each either independent from point to point or shared by a named group of points (fully correlated
//! within the group: the solid angle by every point of an absolute campaign, a band's filter centre by that
//! band's points, a range's gain by the readings on it). The point's `brdf_u_sr` is the root sum of squares of
//! all of them; a fit weights by the independent part and adds the shared ones to its parameters apart.
//!
//! One compact text form serves the store, points.csv's `budget` column and the exports:
//! `name=u;name@group=u;...` with `u` in 1/sr in shortest round-trip form, e.g.
//! `signal-noise=1.2e-6;solid-angle@campaign=3.1e-4`. Component names are [`components`]'; a reader keeps
//! names it does not know (a newer gonio's), so the total stays what was written.
//!
//! A shared entry may be negative: it is then the signed change one error of the group's size (its standard
//! uncertainty) makes to this point, where the same error moves the group's points different ways (an
//! alignment parameter raises a value on one side of the specular direction and lowers it on the other). Its
//! magnitude is the standard uncertainty; the sign is what lets a fit move the group's points together as the
//! error would (crate::fit). An independent entry is never negative.

use std::fmt::Write as _;

use serde_json::{Map, Value, json};

/// The component names gonio writes, with what each is (all standard uncertainties in 1/sr, k = 1).
pub mod components {
    /// The sample reading's noise (detector shot and Johnson noise, converter, source's white noise), from the
    /// instrument file's noise figures and the meter's averaging, or the characterisation's measured dark noise.
    pub const SIGNAL_NOISE: &str = "signal-noise";
    /// The dark reading subtracted from the signal (its noise, and the ambient light's change since it).
    pub const DARK: &str = "dark";
    /// The normalisation: the direct beam (absolute) or the reference sample's reading (relative), read and
    /// interpolated between references with the source's drift model; shared by a band's points.
    pub const NORMALISATION: &str = "normalisation";
    /// The source's slow fluctuation (the instrument file's `source.flicker_rel`, measured by `gonio selftest`):
    /// the lamp's power at the moment the value was read against the straight line between its normalisation
    /// readings (independent per point), and the fluctuation in those readings themselves (each shared by the
    /// points normalised from it).
    pub const FLICKER: &str = "flicker";
    /// The detector's solid angle from the instrument file's aperture and distance tolerances; shared by every
    /// point of an absolute campaign.
    pub const SOLID_ANGLE: &str = "solid-angle";
    /// The reference sample's certificate (relative campaigns); shared by every point.
    pub const CERTIFICATE: &str = "certificate";
    /// The angles' uncertainty (the alignment's, or the instrument file's tolerances without one) times the
    /// BRDF's local angular slope.
    pub const POINTING: &str = "pointing";
    /// Where the axes really stopped (read back, within their arrival tolerance and step size) against the pose
    /// of the nominal geometry: the value is corrected by the fitted model's ratio between the two geometries;
    /// this is the correction's own uncertainty (a quarter of it).
    pub const POSITIONING: &str = "positioning";
    /// The correction from the aperture average to the BRDF at the nominal geometry: its own uncertainty, or
    /// the whole bias where no honest correction is possible.
    pub const APERTURE: &str = "aperture";
    /// The meter's range gain and nonlinearity on the ranges the reading and its normalisation were taken on
    /// (the characterisation's, or the instrument file's without one); shared by the points on a range.
    pub const RANGE: &str = "range";
    /// The instrument signature (stray light) subtracted (independent), or left in without a characterisation
    /// (shared by the campaign: groups::SIGNATURE).
    pub const STRAY_LIGHT: &str = "stray-light";
    /// The finite filter band: the sample's spectral slope at the band times the uncertainty of the filter's
    /// centre, the passband's averaging of a curved spectrum, and the light the filter leaks outside its band
    /// against how much the sample's other bands differ (crate::band_component); shared by a band's points.
    pub const BAND: &str = "band";
    /// The sample's non-uniformity over the illuminated spot, and its re-seating between mountings.
    pub const SAMPLE: &str = "sample";
}

/// Which points share a component's error. `None` in [`BudgetEntry::shared`]: independent per point.
pub mod groups {
    /// Every point of the campaign.
    pub const CAMPAIGN: &str = "campaign";

    /// The points of one band (nanometres, as in points.csv's `band_nm`).
    pub fn band(nm: f64) -> String {
        format!("band-{}", nm + 0.0)
    }

    /// The points read on one range (index into the instrument file's `ranges_w`).
    pub fn range(index: usize) -> String {
        format!("range-{index}")
    }

    /// The points whose dark was interpolated from one dark reading: the `k`-th of a band's darks (nm), in time
    /// order.
    pub fn dark(nm: f64, k: usize) -> String {
        format!("dark-{}-{k}", nm + 0.0)
    }

    /// The points normalised from one normalisation reading (direct beam or reference sample): the `k`-th of a
    /// band's (nm), in time order.
    pub fn normalisation_reading(nm: f64, k: usize) -> String {
        format!("normalisation-{}-{k}", nm + 0.0)
    }

    /// The points measured in one of the sample's mountings (`k`: how many normalisation readings came before
    /// them; the sample leaves the holder for each) under one of its tilt components (`sample`: re-seating).
    pub fn mounting(k: usize, name: &str) -> String {
        format!("mounting-{k}-{name}")
    }

    /// Without an applied alignment, the instrument file's angle uncertainty taken as one unknown offset of
    /// the incidence angle shared by the campaign's points (`pointing`); with one, each of its parameters is a
    /// group under its own name (`detector_zero_deg`, `sample_tilt_x_deg`, ...: crates/engine's alignment
    /// model), and the sample's re-seating (`sample`) its two tilts under theirs.
    pub const THETA_I: &str = "theta_i";
    /// As [`THETA_I`], for the detection angle.
    pub const THETA_O: &str = "theta_o";
    /// As [`THETA_I`], for the azimuth between source and detector.
    pub const PHI: &str = "phi";

    /// The instrument signature left in a value (no characterisation subtracted it): one unknown level of the
    /// instrument file's `signature_u_sr` profile, shared by the campaign's points.
    pub const SIGNATURE: &str = "signature";
}

/// One component of a point's budget.
#[derive(Debug, Clone, PartialEq)]
pub struct BudgetEntry {
    pub component: String,
    /// Standard uncertainty, 1/sr (k = 1).
    pub u_sr: f64,
    /// The group of points sharing this error (fully correlated within it); `None`: independent.
    pub shared: Option<String>,
}

/// A point's budget: its components, in the order they were added.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Budget {
    pub entries: Vec<BudgetEntry>,
}

/// Why a budget's text does not read.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("uncertainty budget `{text}`: {reason}")]
pub struct BudgetParseError {
    pub text: String,
    pub reason: String,
}

fn rss<'a>(entries: impl Iterator<Item = &'a BudgetEntry>) -> f64 {
    entries.map(|e| e.u_sr * e.u_sr).sum::<f64>().sqrt()
}

impl Budget {
    /// Adds a component (a non-finite or negative `u_sr` is a caller's bug and is kept as is, so that the total
    /// shows it rather than hiding it). A component added twice with the same group is combined in quadrature.
    pub fn add(&mut self, component: &str, u_sr: f64, shared: Option<String>) {
        if let Some(e) = self
            .entries
            .iter_mut()
            .find(|e| e.component == component && e.shared == shared)
        {
            e.u_sr = e.u_sr.hypot(u_sr);
            return;
        }
        self.entries.push(BudgetEntry {
            component: component.to_string(),
            u_sr,
            shared,
        });
    }

    /// Replaces every entry of `component` by one (or removes it when `u_sr` is 0).
    pub fn set(&mut self, component: &str, u_sr: f64, shared: Option<String>) {
        self.entries.retain(|e| e.component != component);
        if u_sr != 0.0 {
            self.add(component, u_sr, shared);
        }
    }

    /// One component's standard uncertainty (1/sr), its entries in quadrature; 0 when it has none.
    pub fn component_sr(&self, component: &str) -> f64 {
        rss(self.entries.iter().filter(|e| e.component == component))
    }

    /// Every component scaled by `factor` (a value rescaled by a correction carries its budget along).
    pub fn scaled(&self, factor: f64) -> Budget {
        Budget {
            entries: self
                .entries
                .iter()
                .map(|e| BudgetEntry {
                    u_sr: e.u_sr * factor.abs(),
                    ..e.clone()
                })
                .collect(),
        }
    }

    /// The combined standard uncertainty (1/sr): root sum of squares of every component.
    pub fn total_sr(&self) -> f64 {
        rss(self.entries.iter())
    }

    /// The part independent from point to point (1/sr).
    pub fn independent_sr(&self) -> f64 {
        rss(self.entries.iter().filter(|e| e.shared.is_none()))
    }

    /// The part shared with other points (1/sr).
    pub fn shared_sr(&self) -> f64 {
        rss(self.entries.iter().filter(|e| e.shared.is_some()))
    }

    /// Each component's standard uncertainty (1/sr; its entries in quadrature, whatever their groups), in the
    /// order the components were first added.
    pub fn by_component(&self) -> Vec<(&str, f64)> {
        let mut names: Vec<&str> = Vec::new();
        for e in &self.entries {
            if !names.contains(&e.component.as_str()) {
                names.push(&e.component);
            }
        }
        names.into_iter().map(|n| (n, self.component_sr(n))).collect()
    }

    /// The `n` largest components ([`Budget::by_component`]), largest first.
    pub fn largest(&self, n: usize) -> Vec<(&str, f64)> {
        let mut v = self.by_component();
        v.sort_by(|a, b| b.1.total_cmp(&a.1));
        v.truncate(n);
        v
    }

    /// The compact text form (module docs); empty for an empty budget.
    pub fn to_compact(&self) -> String {
        let mut s = String::new();
        for (k, e) in self.entries.iter().enumerate() {
            if k > 0 {
                s.push(';');
            }
            s.push_str(&e.component);
            if let Some(g) = &e.shared {
                s.push('@');
                s.push_str(g);
            }
            let _ = write!(s, "={}", e.u_sr + 0.0);
        }
        s
    }

    /// Reads the compact text form; an empty text is an empty budget.
    pub fn parse_compact(text: &str) -> Result<Budget, BudgetParseError> {
        let err = |reason: String| BudgetParseError {
            text: text.to_string(),
            reason,
        };
        let mut b = Budget::default();
        for item in text.split(';').map(str::trim).filter(|i| !i.is_empty()) {
            let (key, value) = item
                .split_once('=')
                .ok_or_else(|| err(format!("`{item}` has no `=`")))?;
            let u_sr: f64 = value
                .trim()
                .parse()
                .map_err(|_| err(format!("`{value}` is not a number")))?;
            let (component, shared) = match key.split_once('@') {
                Some((c, g)) => (c.trim(), Some(g.trim().to_string())),
                None => (key.trim(), None),
            };
            if !u_sr.is_finite() || (u_sr < 0.0 && shared.is_none()) {
                return Err(err(format!(
                    "`{item}`: an uncertainty is a finite number, >= 0 unless shared"
                )));
            }
            if component.is_empty() || shared.as_deref() == Some("") {
                return Err(err(format!("`{item}` has an empty name")));
            }
            b.entries.push(BudgetEntry {
                component: component.to_string(),
                u_sr,
                shared,
            });
        }
        Ok(b)
    }

    /// The JSON form of the exports: `{"<component>": {"u_sr": u, "shared": "<group>"|null}, ...}`, with the
    /// group in the key when one component has several (`"range@range-2"`).
    pub fn to_json(&self) -> Value {
        let mut m = Map::new();
        for e in &self.entries {
            let several = self.entries.iter().filter(|o| o.component == e.component).count() > 1;
            let key = match (&e.shared, several) {
                (Some(g), true) => format!("{}@{g}", e.component),
                _ => e.component.clone(),
            };
            m.insert(key, json!({"u_sr": e.u_sr, "shared": e.shared}));
        }
        Value::Object(m)
    }
}

/// Serialised as its compact text (one form everywhere: the store, the CSV, the event stream).
impl serde::Serialize for Budget {
    fn serialize<S: serde::Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        serializer.serialize_str(&self.to_compact())
    }
}

impl<'de> serde::Deserialize<'de> for Budget {
    fn deserialize<D: serde::Deserializer<'de>>(deserializer: D) -> Result<Budget, D::Error> {
        let text = String::deserialize(deserializer)?;
        Budget::parse_compact(&text).map_err(serde::de::Error::custom)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_total_is_the_root_sum_of_squares_and_the_parts_split_by_sharing() {
        let mut b = Budget::default();
        b.add(components::SIGNAL_NOISE, 3.0, None);
        b.add(components::SOLID_ANGLE, 4.0, Some(groups::CAMPAIGN.into()));
        b.add(components::POINTING, 12.0, None);
        assert_eq!(b.total_sr(), 13.0);
        assert_eq!(b.shared_sr(), 4.0);
        assert!((b.independent_sr() - 153f64.sqrt()).abs() < 1e-12);
        assert_eq!(b.largest(1)[0].0, components::POINTING);
        // The same component and group twice: combined.
        b.add(components::POINTING, 5.0, None);
        assert_eq!(
            b.entries
                .iter()
                .filter(|e| e.component == components::POINTING)
                .count(),
            1
        );
        assert_eq!(b.largest(1)[0].1, 13.0);
        b.set(components::POINTING, 0.0, None);
        assert_eq!(b.total_sr(), 5.0);
        // A component split over groups (one per alignment parameter, signed) counts as one, its entries in
        // quadrature.
        b.add(components::POINTING, -6.0, Some("detector_zero_deg".into()));
        b.add(components::POINTING, 8.0, Some("sample_tilt_x_deg".into()));
        assert_eq!(b.largest(1)[0], (components::POINTING, 10.0));
        assert_eq!(b.shared_sr(), 116f64.sqrt());
        assert_eq!(b.by_component().len(), 3);
    }

    #[test]
    fn the_compact_form_round_trips_and_refuses_nonsense() {
        let mut b = Budget::default();
        b.add(components::SIGNAL_NOISE, 1.25e-6, None);
        b.add(components::RANGE, 3.0e-5, Some(groups::range(2)));
        b.add(components::BAND, 7.5e-4, Some(groups::band(550.0)));
        let text = b.to_compact();
        assert_eq!(
            text,
            "signal-noise=0.00000125;range@range-2=0.00003;band@band-550=0.00075"
        );
        assert_eq!(Budget::parse_compact(&text).unwrap(), b);
        assert_eq!(Budget::parse_compact("").unwrap(), Budget::default());
        for bad in [
            "noise",
            "noise=x",
            "noise=-1",
            "=1",
            "noise@=1",
            "noise=inf",
            "pointing@theta_o=nan",
        ] {
            assert!(Budget::parse_compact(bad).is_err(), "{bad}");
        }
        // A shared entry keeps its sign through the text.
        let signed = Budget::parse_compact("pointing@theta_o=-0.0002").unwrap();
        assert_eq!(signed.entries[0].u_sr, -2e-4);
        assert_eq!(signed.to_compact(), "pointing@theta_o=-0.0002");
        assert_eq!(signed.total_sr(), 2e-4);
        let j = b.to_json();
        assert_eq!(j["range"]["shared"], "range-2");
        assert_eq!(j["signal-noise"]["shared"], Value::Null);
    }
}
