//! The MERL BRDF binary format (the 100-material MERL database; read by many renderers and tools).
//!
//! Layout (all little-endian):
//! - a header of three int32: the bin counts (theta_h, theta_d, phi_d) = (90, 90, 180);
//! - 3 x 1,458,000 float64, channel-major: all red, then all green, then all blue;
//! - within a channel the cell index is `phi_d_idx + 180 * theta_d_idx + 180 * 90 * theta_h_idx`.
//!
//! Stored values are scaled: the BRDF in 1/sr is `stored * scale`, with scale red 1/1500, green 1.15/1500,
//! blue 1.66/1500 ([`MerlChannel::scale`]). Negative stored values mark invalid cells (not measured, below the
//! horizon).
//!
//! Binning of the half/difference angles ([`crate::geometry::HalfDiff`], radians):
//! - theta_h, non-linear: `floor(sqrt(theta_h / (pi/2)) * 90)`, clamped to [0, 89];
//! - theta_d: `floor(theta_d / (pi/2) * 90)`, clamped to [0, 89];
//! - phi_d: add pi if negative, then `floor(phi_d / pi * 180)`; phi_d and phi_d + pi are the same cell
//!   (reciprocity), so the index wraps modulo 180 (phi_d = pi exactly is cell 0, the same cell as phi_d = 0).
//!
//! [`MerlData`] holds the three channels exactly as stored; writing then reading gives back the same f64 bits.

use std::f64::consts::{FRAC_PI_2, PI};
use std::io::Write;
use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use crate::geometry::{Direction, HalfDiff};

/// Bins in theta_h.
pub const THETA_H_BINS: usize = 90;
/// Bins in theta_d.
pub const THETA_D_BINS: usize = 90;
/// Bins in phi_d (over [0, pi): the other half follows by reciprocity).
pub const PHI_D_BINS: usize = 180;
/// Cells per channel: 90 * 90 * 180.
pub const CELLS: usize = THETA_H_BINS * THETA_D_BINS * PHI_D_BINS;
/// Header bytes: three int32.
pub const HEADER_BYTES: usize = 12;
/// Size of a complete file: header plus three channels of f64.
pub const FILE_BYTES: usize = HEADER_BYTES + 3 * CELLS * 8;

/// One colour channel of a MERL file.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum MerlChannel {
    Red,
    Green,
    Blue,
}

impl MerlChannel {
    /// The factor from stored values to BRDF values in 1/sr.
    pub fn scale(self) -> f64 {
        match self {
            MerlChannel::Red => 1.0 / 1500.0,
            MerlChannel::Green => 1.15 / 1500.0,
            MerlChannel::Blue => 1.66 / 1500.0,
        }
    }

    /// Position of the channel in the file (red 0, green 1, blue 2).
    pub fn position(self) -> usize {
        match self {
            MerlChannel::Red => 0,
            MerlChannel::Green => 1,
            MerlChannel::Blue => 2,
        }
    }

    pub fn name(self) -> &'static str {
        match self {
            MerlChannel::Red => "red",
            MerlChannel::Green => "green",
            MerlChannel::Blue => "blue",
        }
    }
}

/// Errors reading or writing a MERL file; each names the file.
#[derive(Debug, thiserror::Error)]
pub enum MerlError {
    /// The file could not be opened, read or written.
    #[error("{}: {source}", path.display())]
    Io { path: PathBuf, source: std::io::Error },
    /// The file is shorter than a MERL file (or longer).
    #[error("{}: not a MERL file of the expected size: {actual_bytes} bytes, expected {expected_bytes} (header + 3 x 90 x 90 x 180 float64){}", path.display(), if actual_bytes < expected_bytes { " - the file is truncated" } else { "" })]
    WrongSize {
        path: PathBuf,
        actual_bytes: usize,
        expected_bytes: usize,
    },
    /// The header does not announce 90 x 90 x 180 bins.
    #[error("{}: MERL header announces {found:?} bins, expected [90, 90, 180]", path.display())]
    BadHeader { path: PathBuf, found: [i32; 3] },
    /// A stored value is NaN or infinite.
    #[error("{}: {channel} channel value at cell {cell} (theta_h bin {}, theta_d bin {}, phi_d bin {}) is not finite ({value})", path.display(), cell / (THETA_D_BINS * PHI_D_BINS), (cell / PHI_D_BINS) % THETA_D_BINS, cell % PHI_D_BINS)]
    NonFinite {
        path: PathBuf,
        channel: &'static str,
        cell: usize,
        value: f64,
    },
    /// A table given in memory does not have 90 x 90 x 180 cells.
    #[error("{what}: a MERL channel has {CELLS} cells, got {actual}")]
    WrongLength { what: String, actual: usize },
}

/// The three channels of a MERL file, as stored (unscaled; negative = invalid cell).
#[derive(Debug, Clone, PartialEq)]
pub struct MerlData {
    channels: [Vec<f64>; 3],
}

impl MerlData {
    /// From three channels of stored (unscaled) values, each of [`CELLS`] finite values.
    pub fn from_stored(red: Vec<f64>, green: Vec<f64>, blue: Vec<f64>) -> Result<MerlData, MerlError> {
        let channels = [red, green, blue];
        let what = Path::new("<memory>");
        for (channel, values) in [MerlChannel::Red, MerlChannel::Green, MerlChannel::Blue]
            .iter()
            .zip(&channels)
        {
            if values.len() != CELLS {
                return Err(MerlError::WrongLength {
                    what: format!("{} channel", channel.name()),
                    actual: values.len(),
                });
            }
            check_finite(values, *channel, what)?;
        }
        Ok(MerlData { channels })
    }

    /// From three channels of BRDF values in 1/sr (divided by each channel's scale to be stored).
    /// Stored values are then `value / scale`: reading back and scaling gives the value to within an ulp or two.
    pub fn from_brdf_values(red: &[f64], green: &[f64], blue: &[f64]) -> Result<MerlData, MerlError> {
        let unscale = |values: &[f64], ch: MerlChannel| -> Vec<f64> {
            values
                .iter()
                .map(|v| if *v < 0.0 { -1.0 } else { v / ch.scale() })
                .collect()
        };
        MerlData::from_stored(
            unscale(red, MerlChannel::Red),
            unscale(green, MerlChannel::Green),
            unscale(blue, MerlChannel::Blue),
        )
    }

    /// Reads a MERL file.
    pub fn read(path: &Path) -> Result<MerlData, MerlError> {
        let bytes = std::fs::read(path).map_err(|source| MerlError::Io {
            path: path.to_path_buf(),
            source,
        })?;
        MerlData::from_bytes(&bytes, path)
    }

    /// Parses the bytes of a MERL file; `path` only names the source in errors.
    pub fn from_bytes(bytes: &[u8], path: &Path) -> Result<MerlData, MerlError> {
        let wrong_size = || MerlError::WrongSize {
            path: path.to_path_buf(),
            actual_bytes: bytes.len(),
            expected_bytes: FILE_BYTES,
        };
        let header = bytes.get(..HEADER_BYTES).ok_or_else(wrong_size)?;
        let mut found = [0i32; 3];
        for (slot, chunk) in found.iter_mut().zip(header.chunks_exact(4)) {
            let mut word = [0u8; 4];
            word.copy_from_slice(chunk);
            *slot = i32::from_le_bytes(word);
        }
        if found != [THETA_H_BINS as i32, THETA_D_BINS as i32, PHI_D_BINS as i32] {
            return Err(MerlError::BadHeader {
                path: path.to_path_buf(),
                found,
            });
        }
        if bytes.len() != FILE_BYTES {
            return Err(wrong_size());
        }
        let body = &bytes[HEADER_BYTES..];
        let mut channels: [Vec<f64>; 3] = [Vec::new(), Vec::new(), Vec::new()];
        for (ch, (slot, block)) in [MerlChannel::Red, MerlChannel::Green, MerlChannel::Blue]
            .iter()
            .zip(channels.iter_mut().zip(body.chunks_exact(CELLS * 8)))
        {
            let values: Vec<f64> = block
                .chunks_exact(8)
                .map(|c| {
                    let mut word = [0u8; 8];
                    word.copy_from_slice(c);
                    f64::from_le_bytes(word)
                })
                .collect();
            check_finite(&values, *ch, path)?;
            *slot = values;
        }
        Ok(MerlData { channels })
    }

    /// The bytes of the file: header and three channels, little-endian.
    pub fn to_bytes(&self) -> Vec<u8> {
        let mut out = Vec::with_capacity(FILE_BYTES);
        for n in [THETA_H_BINS, THETA_D_BINS, PHI_D_BINS] {
            out.extend_from_slice(&(n as i32).to_le_bytes());
        }
        for channel in &self.channels {
            for v in channel {
                out.extend_from_slice(&v.to_le_bytes());
            }
        }
        out
    }

    /// Writes the file (creating or truncating it).
    pub fn write(&self, path: &Path) -> Result<(), MerlError> {
        let io = |source| MerlError::Io {
            path: path.to_path_buf(),
            source,
        };
        let mut file = std::io::BufWriter::new(std::fs::File::create(path).map_err(io)?);
        file.write_all(&self.to_bytes()).map_err(io)?;
        file.flush().map_err(io)
    }

    /// The stored (unscaled) values of a channel.
    pub fn stored(&self, channel: MerlChannel) -> &[f64] {
        &self.channels[channel.position()]
    }

    /// A channel as BRDF values in 1/sr (stored times scale; invalid cells stay negative).
    pub fn brdf_values(&self, channel: MerlChannel) -> Vec<f64> {
        let scale = channel.scale();
        self.stored(channel)
            .iter()
            .map(|v| if *v < 0.0 { *v } else { v * scale })
            .collect()
    }
}

fn check_finite(values: &[f64], channel: MerlChannel, path: &Path) -> Result<(), MerlError> {
    match values.iter().position(|v| !v.is_finite()) {
        None => Ok(()),
        Some(cell) => Err(MerlError::NonFinite {
            path: path.to_path_buf(),
            channel: channel.name(),
            cell,
            value: values[cell],
        }),
    }
}

/// theta_h bin: `floor(sqrt(theta_h / (pi/2)) * 90)`, clamped to [0, 89] (NaN and negative go to 0).
pub fn theta_h_index(theta_h_rad: f64) -> usize {
    if theta_h_rad.is_nan() || theta_h_rad <= 0.0 {
        return 0;
    }
    let idx = ((theta_h_rad / FRAC_PI_2).sqrt() * THETA_H_BINS as f64).floor();
    (idx as usize).min(THETA_H_BINS - 1)
}

/// theta_d bin: `floor(theta_d / (pi/2) * 90)`, clamped to [0, 89].
pub fn theta_d_index(theta_d_rad: f64) -> usize {
    if theta_d_rad.is_nan() || theta_d_rad <= 0.0 {
        return 0;
    }
    let idx = (theta_d_rad / FRAC_PI_2 * THETA_D_BINS as f64).floor();
    (idx as usize).min(THETA_D_BINS - 1)
}

/// phi_d bin: add pi if negative, then `floor(phi_d / pi * 180)`, wrapped modulo 180 (phi_d and phi_d + pi are
/// the same cell).
pub fn phi_d_index(phi_d_rad: f64) -> usize {
    if !phi_d_rad.is_finite() {
        return 0;
    }
    let folded = phi_d_rad.rem_euclid(PI);
    let idx = (folded / PI * PHI_D_BINS as f64).floor();
    (idx as usize) % PHI_D_BINS
}

/// The flat cell index `phi_d_idx + 180 * theta_d_idx + 180 * 90 * theta_h_idx`.
pub fn cell_index(theta_h_idx: usize, theta_d_idx: usize, phi_d_idx: usize) -> usize {
    phi_d_idx + PHI_D_BINS * theta_d_idx + PHI_D_BINS * THETA_D_BINS * theta_h_idx
}

/// The cell holding the half/difference angles `hd` (phi_h is ignored: the data are isotropic).
pub fn cell_of(hd: &HalfDiff) -> usize {
    cell_index(
        theta_h_index(hd.theta_h),
        theta_d_index(hd.theta_d),
        phi_d_index(hd.phi_d),
    )
}

/// The cell for a pair of directions; `None` when they are opposite (no half vector).
pub fn cell_for_directions(wi: &Direction, wo: &Direction) -> Option<usize> {
    HalfDiff::from_directions(wi, wo).map(|hd| cell_of(&hd))
}

/// The (theta_h_idx, theta_d_idx, phi_d_idx) of a flat index (which must be < [`CELLS`]).
pub fn split_index(cell: usize) -> (usize, usize, usize) {
    (
        cell / (THETA_D_BINS * PHI_D_BINS),
        (cell / PHI_D_BINS) % THETA_D_BINS,
        cell % PHI_D_BINS,
    )
}

/// The centre of a cell in half/difference angles (radians, phi_h = 0), the centre being taken in the binned
/// coordinates: `theta_h = ((i + 1/2) / 90)^2 pi/2`, `theta_d = (j + 1/2) / 90 * pi/2`, `phi_d = (k + 1/2) / 180 * pi`.
/// Useful to tabulate a model on the MERL grid: every such point falls in its own cell.
pub fn cell_centre(theta_h_idx: usize, theta_d_idx: usize, phi_d_idx: usize) -> HalfDiff {
    let u = (theta_h_idx as f64 + 0.5) / THETA_H_BINS as f64;
    HalfDiff {
        theta_h: u * u * FRAC_PI_2,
        phi_h: 0.0,
        theta_d: (theta_d_idx as f64 + 0.5) / THETA_D_BINS as f64 * FRAC_PI_2,
        phi_d: (phi_d_idx as f64 + 0.5) / PHI_D_BINS as f64 * PI,
    }
}
