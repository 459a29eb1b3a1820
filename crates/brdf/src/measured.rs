//! Measured BRDF: an isotropic table on the MERL grid of half/difference angles, one channel, in 1/sr.
//!
//! Lookup ([`Interpolation`]):
//! - `Nearest`: the documented MERL binning ([`crate::merl`]): the value of the cell that holds the point.
//! - `Trilinear` (the default): linear interpolation between cell centres in the binned coordinates
//!   (`sqrt(theta_h / (pi/2)) * 90`, `theta_d / (pi/2) * 90`, `phi_d / pi * 180`, centres at `index + 1/2`).
//!   theta_h and theta_d are clamped at the first and last centres (constant beyond them); phi_d is periodic
//!   with period pi, so the interpolation is continuous across phi_d = 0 = pi and reciprocal: swapping wi and wo
//!   adds pi to phi_d and lands on the same interpolated value (up to rounding of the angles).
//!
//! Invalid cells (negative values) give 0: a point whose nearest cell is invalid evaluates to 0; otherwise the
//! interpolation uses only the valid corners, with their weights renormalised. Directions at or below the
//! horizon give 0, as for every model. The table is one colour channel and does not depend on wavelength.
//!
//! The values are shared (`Arc`): cloning a `MeasuredBrdf` does not copy its 11 MB.

use std::f64::consts::{FRAC_PI_2, PI};
use std::path::Path;
use std::sync::Arc;

use crate::brdf::Brdf;
use crate::geometry::{Direction, HalfDiff};
use crate::merl::{self, CELLS, MerlChannel, MerlData, MerlError, PHI_D_BINS, THETA_D_BINS, THETA_H_BINS};
use crate::spectrum::{SpectrumError, Wavelength};

/// How a [`MeasuredBrdf`] reads between its cells.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Interpolation {
    /// The value of the cell holding the point (the MERL reference lookup).
    Nearest,
    /// Trilinear between cell centres; see the module documentation.
    #[default]
    Trilinear,
}

/// An isotropic tabulated BRDF on the MERL grid (one channel, 1/sr, negative = invalid cell).
#[derive(Debug, Clone)]
pub struct MeasuredBrdf {
    values: Arc<[f64]>,
    interpolation: Interpolation,
    lobe_width_rad: Option<f64>,
}

impl MeasuredBrdf {
    /// Reads one channel of a MERL binary file (scaled to 1/sr).
    pub fn from_merl_file(path: &Path, channel: MerlChannel) -> Result<MeasuredBrdf, MerlError> {
        Ok(MeasuredBrdf::from_merl(&MerlData::read(path)?, channel))
    }

    /// One channel of MERL data already in memory.
    pub fn from_merl(data: &MerlData, channel: MerlChannel) -> MeasuredBrdf {
        MeasuredBrdf::from_valid_values(data.brdf_values(channel))
    }

    /// From a table of [`CELLS`] values in 1/sr in MERL cell order (negative marks an invalid cell).
    /// Errors on a wrong length or a non-finite value.
    pub fn from_table(values: Vec<f64>) -> Result<MeasuredBrdf, MerlError> {
        if values.len() != CELLS {
            return Err(MerlError::WrongLength {
                what: "measured BRDF table".into(),
                actual: values.len(),
            });
        }
        if let Some(cell) = values.iter().position(|v| !v.is_finite()) {
            return Err(MerlError::NonFinite {
                path: "<memory>".into(),
                channel: "table",
                cell,
                value: values[cell],
            });
        }
        Ok(MeasuredBrdf::from_valid_values(values))
    }

    /// Tabulates `brdf` at the centre of every cell (see [`merl::cell_centre`]); cells whose centre has a
    /// direction at or below the horizon are marked invalid (-1).
    pub fn tabulate(brdf: &dyn Brdf, wavelength: Wavelength) -> Result<MeasuredBrdf, SpectrumError> {
        let mut values = vec![-1.0; CELLS];
        for h in 0..THETA_H_BINS {
            for d in 0..THETA_D_BINS {
                for p in 0..PHI_D_BINS {
                    let (wi, wo) = merl::cell_centre(h, d, p).to_directions();
                    if wi.is_above_horizon() && wo.is_above_horizon() {
                        values[merl::cell_index(h, d, p)] = brdf.eval(&wi, &wo, wavelength)?;
                    }
                }
            }
        }
        Ok(MeasuredBrdf::from_valid_values(values))
    }

    fn from_valid_values(values: Vec<f64>) -> MeasuredBrdf {
        let lobe_width_rad = estimate_lobe_width(&values);
        MeasuredBrdf {
            values: values.into(),
            interpolation: Interpolation::default(),
            lobe_width_rad,
        }
    }

    /// The same table with another lookup.
    pub fn with_interpolation(mut self, interpolation: Interpolation) -> MeasuredBrdf {
        self.interpolation = interpolation;
        self
    }

    pub fn interpolation(&self) -> Interpolation {
        self.interpolation
    }

    /// The table in MERL cell order, 1/sr (negative = invalid).
    pub fn values(&self) -> &[f64] {
        &self.values
    }

    /// The value of one cell, 1/sr (negative = invalid); `None` outside the table.
    pub fn cell(&self, theta_h_idx: usize, theta_d_idx: usize, phi_d_idx: usize) -> Option<f64> {
        if theta_h_idx >= THETA_H_BINS || theta_d_idx >= THETA_D_BINS || phi_d_idx >= PHI_D_BINS {
            return None;
        }
        self.values
            .get(merl::cell_index(theta_h_idx, theta_d_idx, phi_d_idx))
            .copied()
    }

    /// The BRDF at half/difference angles (phi_h ignored), 1/sr, by the chosen lookup.
    pub fn lookup(&self, hd: &HalfDiff) -> f64 {
        if !(hd.theta_h.is_finite() && hd.theta_d.is_finite() && hd.phi_d.is_finite()) {
            return 0.0;
        }
        let nearest = self.values.get(merl::cell_of(hd)).copied().unwrap_or(-1.0);
        if nearest < 0.0 {
            return 0.0;
        }
        match self.interpolation {
            Interpolation::Nearest => nearest,
            Interpolation::Trilinear => self.trilinear(hd),
        }
    }

    fn trilinear(&self, hd: &HalfDiff) -> f64 {
        let (h0, th) = clamped_axis(
            (hd.theta_h.max(0.0) / FRAC_PI_2).sqrt() * THETA_H_BINS as f64,
            THETA_H_BINS,
        );
        let (d0, td) = clamped_axis(
            hd.theta_d.max(0.0) / FRAC_PI_2 * THETA_D_BINS as f64,
            THETA_D_BINS,
        );
        let up = hd.phi_d.rem_euclid(PI) / PI * PHI_D_BINS as f64 - 0.5;
        let floor = up.floor();
        let tp = up - floor;
        let p0 = (floor as i64).rem_euclid(PHI_D_BINS as i64) as usize;
        let p1 = (p0 + 1) % PHI_D_BINS;
        let h1 = (h0 + 1).min(THETA_H_BINS - 1);
        let d1 = (d0 + 1).min(THETA_D_BINS - 1);
        let mut sum = 0.0;
        let mut weight_sum = 0.0;
        for (h, wh) in [(h0, 1.0 - th), (h1, th)] {
            for (d, wd) in [(d0, 1.0 - td), (d1, td)] {
                for (p, wp) in [(p0, 1.0 - tp), (p1, tp)] {
                    let w = wh * wd * wp;
                    if w == 0.0 {
                        continue;
                    }
                    let v = self
                        .values
                        .get(merl::cell_index(h, d, p))
                        .copied()
                        .unwrap_or(-1.0);
                    if v >= 0.0 {
                        sum += w * v;
                        weight_sum += w;
                    }
                }
            }
        }
        if weight_sum > 0.0 { sum / weight_sum } else { 0.0 }
    }
}

/// Lower corner and fraction along one clamped axis, from a binned coordinate whose cell centres are at
/// `index + 1/2`.
fn clamped_axis(binned: f64, bins: usize) -> (usize, f64) {
    let last = (bins - 1) as f64;
    let u = (binned - 0.5).clamp(0.0, last);
    let lower = u.floor().min(last - 1.0).max(0.0);
    (lower as usize, u - lower)
}

/// A rough width of the specular peak, for integrators ([`Brdf::lobe_width`]): the theta_h (radians) at which
/// the value near normal incidence (theta_d bins 0-9, averaged over phi_d) falls to half its theta_h = 0 value,
/// if that happens below 0.3 rad; `None` for a table without a narrow peak.
fn estimate_lobe_width(values: &[f64]) -> Option<f64> {
    let profile = |h: usize| -> Option<f64> {
        let mut sum = 0.0;
        let mut count = 0usize;
        for d in 0..10 {
            for p in 0..PHI_D_BINS {
                let v = values.get(merl::cell_index(h, d, p)).copied().unwrap_or(-1.0);
                if v >= 0.0 {
                    sum += v;
                    count += 1;
                }
            }
        }
        (count > 0).then(|| sum / count as f64)
    };
    let peak = profile(0)?;
    if peak.is_nan() || peak <= 0.0 {
        return None;
    }
    for h in 1..THETA_H_BINS {
        let centre = merl::cell_centre(h, 0, 0).theta_h;
        if centre > 0.3 {
            return None;
        }
        if let Some(v) = profile(h) {
            if v < 0.5 * peak {
                return Some(centre);
            }
        }
    }
    None
}

impl Brdf for MeasuredBrdf {
    fn eval(&self, wi: &Direction, wo: &Direction, _wavelength: Wavelength) -> Result<f64, SpectrumError> {
        if !(wi.is_above_horizon() && wo.is_above_horizon()) {
            return Ok(0.0);
        }
        // Reciprocity bit for bit: `HalfDiff` takes theta_d and phi_d from its first argument, and the two orders
        // can round to opposite sides of a bin edge (tests/stress/pointwise.rs found wi at the pole, wo on
        // the horizon: theta_d = pi/4 -+ 1 ulp, cells 44 and 45, one valid and one not: f = 0.0092 one way
        // and 0 the other). Evaluating the pair in a canonical order makes f(wi, wo) and f(wo, wi) the same
        // computation.
        let (a, b) = if (wi.z(), wi.x(), wi.y()) <= (wo.z(), wo.x(), wo.y()) {
            (wi, wo)
        } else {
            (wo, wi)
        };
        Ok(HalfDiff::from_directions(a, b).map_or(0.0, |hd| self.lookup(&hd)))
    }

    fn is_isotropic(&self) -> bool {
        true
    }

    fn is_spectrally_flat(&self) -> bool {
        true
    }

    fn lobe_width(&self) -> Option<f64> {
        self.lobe_width_rad
    }
}
