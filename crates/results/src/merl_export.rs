//! A run resampled onto the MERL grid (the binary format of [`gonio_brdf::merl`]), so that renderers and tools that
//! read the MERL database can use the measured material.
//!
//! Channels: red, green and blue each take one measured band, by default the band nearest to 650, 550 and
//! 450 nm ([`nominal_nm`]); a run with one band fills all three with it (a grey material).
//!
//! Resampling: every cell's centre ([`merl::cell_centre`], the half/difference angles of the MERL binning) is
//! turned into a pair of directions, reduced to (theta_i, theta_o, delta_phi) and looked up in the run's
//! piecewise-linear interpolant ([`crate::iso::IsoGrid`]: trilinear between measured nodes, with reciprocity,
//! no extrapolation; within [`EDGE_MARGIN_RAD`] of a measured node on the edge of the measured region or
//! beside a hole, the node's value). A cell whose centre is below the horizon or outside the measured region
//! is written as -1, the MERL convention for an invalid cell (negative values; [`gonio_brdf::merl`]);
//! readers, including `model = "measured"` materials, treat it as "no data". A negative measured value (noise
//! around a zero signal) is written as 0, since a negative one would read as "no data".
//!
//! Error budget: the table is exact at the measured nodes only up to the MERL grid's own resolution (cells of
//! about 1 degree in theta_d and phi_d, and 0.02 to 2 degrees in theta_h); between nodes the linear interpolation
//! error of the measurement grid applies. Reading the file back (trilinear between cell centres) reproduces
//! each measured value to within the spread of the measured values around it; the test
//! `merl_round_trip_reproduces_the_measurement` in tests/cli/export.rs quantifies it for the seed's materials.

use gonio_brdf::geometry::IsotropicAngles;
use gonio_brdf::merl::{self, CELLS, MerlChannel, MerlData, PHI_D_BINS, THETA_D_BINS, THETA_H_BINS};

use crate::error::ResultsError;
use crate::iso::{IsoGrid, IsoPoint};
use crate::run::{Run, list_nm};

/// How far beside a measured node (radians) a cell centre still takes the node's value where linear
/// interpolation has none (at the edge of the measured region, beside a hole): 2 degrees, the widest MERL cell
/// (theta_h cells grow to 2 degrees near grazing; a cell's centre can lie 1.5 degrees from a geometry inside
/// it). Without it the cell holding a measured geometry on the edge could be marked invalid, and the
/// measurement lost.
pub const EDGE_MARGIN_RAD: f64 = 2.0 * std::f64::consts::PI / 180.0;

/// The three channels, in file order.
pub const CHANNELS: [MerlChannel; 3] = [MerlChannel::Red, MerlChannel::Green, MerlChannel::Blue];

/// The wavelength a channel stands for when choosing the band that fills it, nm.
pub fn nominal_nm(channel: MerlChannel) -> f64 {
    match channel {
        MerlChannel::Red => 650.0,
        MerlChannel::Green => 550.0,
        MerlChannel::Blue => 450.0,
    }
}

/// What one channel holds.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ChannelReport {
    pub channel: MerlChannel,
    /// The measured band written into the channel, nm.
    pub band_nm: f64,
    /// Cells with a value (the rest are -1).
    pub covered_cells: usize,
}

/// The resampled table and what it holds.
#[derive(Debug, Clone)]
pub struct MerlExport {
    pub data: MerlData,
    pub channels: [ChannelReport; 3],
    /// Cells whose centre has both directions above the horizon (the most that can be covered).
    pub cells_above_horizon: usize,
    /// Number of distinct azimuth differences measured per band (in the order of `channels`).
    pub azimuth_nodes: [usize; 3],
}

impl MerlExport {
    /// Share of the above-horizon cells a channel covers, in [0, 1].
    pub fn coverage(&self, channel: usize) -> f64 {
        let c = self.channels.get(channel).map_or(0, |c| c.covered_cells);
        c as f64 / self.cells_above_horizon.max(1) as f64
    }
}

/// The bands for red, green and blue: `chosen` (each must be a band of the run), or the run's bands nearest to
/// the channels' nominal wavelengths.
pub fn channel_bands(run: &Run, chosen: Option<[f64; 3]>) -> Result<[f64; 3], ResultsError> {
    let bands = run.bands_nm();
    if bands.is_empty() {
        return Err(ResultsError::NoData {
            origin: run.origin.clone(),
            message: "no valid points to export".into(),
        });
    }
    match chosen {
        Some(c) => {
            let mut out = [0.0; 3];
            for (slot, nm) in out.iter_mut().zip(c) {
                *slot = run.band(nm).map_err(|_| {
                    ResultsError::Invalid(format!(
                        "channel band {nm} nm is not a band of {} (its bands: {})",
                        run.origin,
                        list_nm(&bands)
                    ))
                })?;
            }
            Ok(out)
        }
        None => {
            let nearest = |target: f64| {
                bands
                    .iter()
                    .copied()
                    .min_by(|a, b| (a - target).abs().total_cmp(&(b - target).abs()))
                    .unwrap_or(target)
            };
            Ok(CHANNELS.map(|c| nearest(nominal_nm(c))))
        }
    }
}

/// Resamples the run onto the MERL grid (module doc); `bands` as for [`channel_bands`].
pub fn to_merl(run: &Run, bands: Option<[f64; 3]>) -> Result<MerlExport, ResultsError> {
    let chosen = channel_bands(run, bands)?;
    // One interpolant per distinct band.
    let mut distinct: Vec<f64> = Vec::new();
    for b in chosen {
        if !distinct.contains(&b) {
            distinct.push(b);
        }
    }
    let grids: Vec<IsoGrid> = distinct
        .iter()
        .map(|&band| {
            let pts: Vec<IsoPoint> = run
                .points
                .iter()
                .filter(|p| (p.band_nm - band).abs() <= crate::run::BAND_TOLERANCE_NM)
                .filter_map(IsoPoint::from_point)
                .collect();
            IsoGrid::build(&pts)
        })
        .collect();
    let slot = chosen.map(|b| distinct.iter().position(|d| *d == b).unwrap_or(0));

    let mut channels = [vec![-1.0; CELLS], vec![-1.0; CELLS], vec![-1.0; CELLS]];
    let mut covered = [0usize; 3];
    let mut above = 0usize;
    let mut per_band = vec![None; grids.len()];
    for h in 0..THETA_H_BINS {
        for d in 0..THETA_D_BINS {
            for p in 0..PHI_D_BINS {
                let (wi, wo) = merl::cell_centre(h, d, p).to_directions();
                if !(wi.is_above_horizon() && wo.is_above_horizon()) {
                    continue;
                }
                above += 1;
                let angles = IsotropicAngles::from_directions(&wi, &wo);
                for (value, grid) in per_band.iter_mut().zip(&grids) {
                    *value = grid.eval_near(&angles, EDGE_MARGIN_RAD);
                }
                let cell = merl::cell_index(h, d, p);
                for c in 0..3 {
                    if let Some(v) = per_band.get(slot[c]).copied().flatten() {
                        channels[c][cell] = v.max(0.0);
                        covered[c] += 1;
                    }
                }
            }
        }
    }
    let [red, green, blue] = channels;
    let data = MerlData::from_brdf_values(&red, &green, &blue)?;
    let report = |c: usize| ChannelReport {
        channel: CHANNELS[c],
        band_nm: chosen[c],
        covered_cells: covered[c],
    };
    Ok(MerlExport {
        data,
        channels: [report(0), report(1), report(2)],
        cells_above_horizon: above,
        azimuth_nodes: slot.map(|s| grids.get(s).map_or(0, |g| g.dphi_nodes().len())),
    })
}

/// A material file (`[material]` with `model = "measured"`) that reads `file_name` (relative to the material
/// file's directory), for `gonio brdf eval --material` and the simulator.
pub fn material_toml(
    export: &MerlExport,
    run: &Run,
    file_name: &str,
    channel: MerlChannel,
    provenance: &[(&str, String)],
) -> String {
    let mut s = format!(
        "# Measured material exported by `gonio export --format merl` from {} (campaign {}).\n",
        run.origin, run.name
    );
    // The MERL binary has no room for text: its provenance lives here, beside it.
    for (k, v) in provenance {
        s.push_str(&format!("# provenance.{k}: {v}\n"));
    }
    s.push_str("# MERL channels: ");
    s.push_str(
        &export
            .channels
            .iter()
            .enumerate()
            .map(|(i, c)| {
                format!(
                    "{} = {} nm ({:.1}% of the cells above the horizon covered)",
                    c.channel.name(),
                    c.band_nm,
                    100.0 * export.coverage(i)
                )
            })
            .collect::<Vec<_>>()
            .join(", "),
    );
    s.push_str(
        ".\n# Uncovered cells hold -1 (no data) and evaluate to 0. Choose the channel of the band you need.\n\n",
    );
    s.push_str(&format!(
        "[material]\nmodel = \"measured\"\nformat = \"merl\"\nfile = {}\nchannel = \"{}\"\n",
        toml_string(file_name),
        channel.name()
    ));
    s
}

/// A TOML basic string.
fn toml_string(s: &str) -> String {
    let mut out = String::from("\"");
    for c in s.chars() {
        match c {
            '"' => out.push_str("\\\""),
            '\\' => out.push_str("\\\\"),
            c if c.is_control() => out.push_str(&format!("\\u{:04X}", c as u32)),
            c => out.push(c),
        }
    }
    out.push('"');
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn toml_strings_are_escaped() {
        assert_eq!(toml_string("a\"b\\c"), "\"a\\\"b\\\\c\"");
        let doc = format!("x = {}", toml_string("we\u{1}ird\"name.binary"));
        let parsed: toml::Table = toml::from_str(&doc).expect("valid TOML");
        assert_eq!(parsed["x"].as_str(), Some("we\u{1}ird\"name.binary"));
    }
}
