//! The beam's observed line, split between its direction and its lateral offset.
//!
//! Scans through the direct beam and a mirror's reflection see the beam only along its line as the detector's
//! circle meets it, `beam_line_deg = beam_deg - asin(beam_lateral_mm / d)` (crate::align::fit): a beam tilted by
//! `a` and one passing the arms' axis at `h = d sin(-a)` look the same to them. A sample's reflection does not: the
//! incidence angle on the sample is the beam's direction, and the offset moves the spot the detector looks at.
//! On realistic.toml, taking the whole line as the beam's direction (as applying `beam_line_deg` alone did) left
//! a 0.02 degree error in the incidence angle on one seed, outside every uncertainty the budget stated, and
//! `gonio fit`'s chi2/dof on gold at 34 with the beam's imperfections alone.
//!
//! Which share is which comes from how the lab set the beam up: the instrument file's standard uncertainty of
//! the beam's direction against the light arm's axis (`[instrument.source] pointing_u_deg`, else the file's
//! `alignment_u_deg`) and of its offset from the arms' axis (`offset_u_mm`, else
//! [`gonio_instrument::DEFAULT_BEAM_OFFSET_U_MM`]). Taken as independent normal priors, the offset's as the
//! angle it subtends at the detector distance `so = asin(offset_u / d)`, the line `L` says the direction is
//! `w L` with `w = sa^2 / (sa^2 + so^2)` and the offset the rest; about that, the direction is uncertain by
//! `sa so / sqrt(sa^2 + so^2)` with the line held (what the scans cannot see), and the line's own uncertainty
//! moves both by their shares.

use gonio_instrument::Instrument;

/// How a beam's observed line is split (module doc).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BeamSplit {
    /// The direction's share of the line, `w` in [0, 1].
    pub direction_share: f64,
    /// The direction's standard uncertainty with the line held (deg).
    pub held_line_u_deg: f64,
    /// The detector's distance from the arms' axis (mm).
    pub distance_mm: f64,
}

impl BeamSplit {
    /// The split `instrument`'s priors give; `None` when they say nothing (both zero) or the detector distance
    /// is not positive.
    pub fn of(instrument: &Instrument) -> Option<BeamSplit> {
        let d = instrument.detector.distance_mm;
        let sa = instrument.source.pointing_u_or(instrument.alignment_u_deg());
        let offset_u_mm = instrument.source.offset_u_or_default();
        if !(d > 0.0 && d.is_finite() && sa.is_finite() && offset_u_mm.is_finite()) {
            return None;
        }
        let so = (offset_u_mm / d).clamp(-1.0, 1.0).asin().to_degrees();
        let total = sa * sa + so * so;
        if total <= 0.0 {
            return None;
        }
        Some(BeamSplit {
            direction_share: sa * sa / total,
            held_line_u_deg: sa * so / total.sqrt(),
            distance_mm: d,
        })
    }

    /// `(beam_deg, beam_lateral_mm)` for a line at `line_deg`, split by the shares.
    pub fn params(&self, line_deg: f64) -> (f64, f64) {
        self.with_direction(line_deg, self.direction_share * line_deg)
    }

    /// `(beam_deg, beam_lateral_mm)` with the direction moved by its uncertainty along the line held.
    pub fn moved_along_line(&self, line_deg: f64) -> (f64, f64) {
        self.with_direction(line_deg, self.direction_share * line_deg + self.held_line_u_deg)
    }

    /// The beam at `direction_deg` whose line is `line_deg`: the offset that keeps it.
    fn with_direction(&self, line_deg: f64, direction_deg: f64) -> (f64, f64) {
        let offset_mm = self.distance_mm * (direction_deg - line_deg).to_radians().sin();
        (direction_deg, offset_mm)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use gonio_instrument::InstrumentFile;

    fn line_of(d: f64, (beam_deg, lateral_mm): (f64, f64)) -> f64 {
        beam_deg - (lateral_mm / d).asin().to_degrees()
    }

    fn with_priors(pointing_u_deg: f64, offset_u_mm: f64) -> Instrument {
        let mut inst = InstrumentFile::simulated().instrument;
        inst.source.pointing_u_deg = Some(pointing_u_deg);
        inst.source.offset_u_mm = Some(offset_u_mm);
        inst
    }

    #[test]
    fn the_split_keeps_the_line_and_follows_the_priors() {
        // 0.01 deg of direction against 0.05 mm at 250 mm (0.0115 deg): a little less than half is direction.
        let inst = with_priors(0.01, 0.05);
        let d = inst.detector.distance_mm;
        let s = BeamSplit::of(&inst).expect("priors");
        let so = (0.05 / d).asin().to_degrees();
        assert!((s.direction_share - 1e-4 / (1e-4 + so * so)).abs() < 1e-12);
        assert!(
            s.direction_share > 0.4 && s.direction_share < 0.5,
            "{}",
            s.direction_share
        );
        let line = 0.031;
        let split = s.params(line);
        assert!((line_of(d, split) - line).abs() < 1e-12, "{split:?}");
        assert!((split.0 - s.direction_share * line).abs() < 1e-15);
        // Moved along the line: the direction by its uncertainty, the line where it was.
        let moved = s.moved_along_line(line);
        assert!((moved.0 - split.0 - s.held_line_u_deg).abs() < 1e-15);
        assert!((line_of(d, moved) - line).abs() < 1e-12);
        let want_u = 0.01 * so / (1e-4 + so * so).sqrt();
        assert!((s.held_line_u_deg - want_u).abs() < 1e-15);
    }

    #[test]
    fn a_beam_known_to_pass_the_axis_is_all_direction_and_one_known_parallel_all_offset() {
        let inst = with_priors(0.01, 0.0);
        let s = BeamSplit::of(&inst).expect("priors");
        assert_eq!(s.direction_share, 1.0);
        assert_eq!(s.held_line_u_deg, 0.0);
        assert_eq!(s.params(0.03), (0.03, 0.0));
        let inst = with_priors(0.0, 0.05);
        let s = BeamSplit::of(&inst).expect("priors");
        assert_eq!(s.direction_share, 0.0);
        let (beam_deg, lateral_mm) = s.params(0.03);
        assert_eq!(beam_deg, 0.0);
        // All offset: -d sin(0.03 deg).
        assert!(
            (lateral_mm + 250.0 * 0.03f64.to_radians().sin()).abs() < 1e-12,
            "{lateral_mm}"
        );
        assert_eq!(BeamSplit::of(&with_priors(0.0, 0.0)), None);
    }

    #[test]
    fn without_priors_in_the_file_the_alignment_tolerance_and_the_default_offset_serve() {
        let mut inst = InstrumentFile::simulated().instrument;
        inst.source.pointing_u_deg = None;
        inst.source.offset_u_mm = None;
        inst.alignment_u_deg = Some(0.05);
        let s = BeamSplit::of(&inst).expect("defaults");
        let sa = inst.alignment_u_deg();
        let so = (gonio_instrument::DEFAULT_BEAM_OFFSET_U_MM / inst.detector.distance_mm)
            .asin()
            .to_degrees();
        assert!((s.direction_share - sa * sa / (sa * sa + so * so)).abs() < 1e-12);
    }
}
