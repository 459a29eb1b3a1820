//! A run as an RGL material file (`.bsdf`, the EPFL Realistic Graphics Lab's measured-material format), read by
//! Mitsuba 3's `measured` BSDF and pbrt-v4's `MeasuredBxDF`.
//!
//! Container ([`write_tensor_file`], as both renderers' `TensorFile` readers parse it): the 12 bytes
//! `tensor_file\0`, the version (1, 0), a `u32` field count, then per field a `u16` name length, the name, a
//! `u16` rank, a `u8` type (1 = uint8, 10 = float32), a `u64` byte offset of the data and the `u64` extent of
//! each dimension; then the data, little-endian, C order. Fields and their meaning (Dupuy and Jakob 2018, "An
//! adaptive parameterization for efficient material acquisition and rendering"):
//! - `theta_i`, `phi_i` (float32, radians): the incidences the tables are given at (one `phi_i`: isotropic);
//! - `wavelengths` (float32, nm) and `spectra` [phi_i, theta_i, wavelength, n, n]: the BSDF times the cosine of
//!   the outgoing direction, on a grid over the *sample space*, which the `vndf` warp maps to the half vector's
//!   unit-square coordinates `u = (sqrt(theta_m / (pi / 2)), (phi_m - phi_i + pi) / (2 pi))`;
//! - `vndf` [phi_i, theta_i, n, n]: the density of that warp; `luminance` [phi_i, theta_i, n, n]: a density in
//!   sample space for importance sampling; `ndf` and `sigma` [n, n]: the microfacet distribution D(m) and the
//!   projected area sigma(wi), which multiply the spectra by D / (4 sigma) when `jacobian` (uint8) is 1;
//! - `description` (uint8): UTF-8 text.
//!
//! What gonio writes, and why: the RGL pipeline derives D from retro-reflection measurements and warps the
//! sample grid by the visible-normal distribution. A gonioreflectometer with two arms cannot measure
//! retro-reflection (the arms collide), so neither is measured here: `vndf` is uniform (the warp is the
//! identity, sample space = half-vector coordinates), `ndf` is 1 and `sigma` 1/4 everywhere so that
//! D / (4 sigma) = 1 and `spectra` hold f cos(theta_o) directly, `jacobian` is 1 as in the database's files.
//! `spectra` are gonio's interpolant of the run ([`IsoGrid::eval`]: log-trilinear between measured nodes, never
//! extrapolated; 0 where not measured) times cos(theta_o) at the grid's nodes ([`table`]), with one guard band:
//! a node without a value that shares a bilinear cell with a node that has one holds the interpolant's value at
//! the nearest point of the measured region (at most [`GUARD_MARGIN_RAD`] of node moves away,
//! [`IsoGrid::eval_held`]). Without it the renderer's bilinear cells across the edge of the measured region (and
//! around the retro-reflection hole) mix the 0 of the unmeasured node into measured directions: on the export
//! tests' plan (10 degree polar, 45 degree azimuth steps) that put the file up to 58 % below the measurement at
//! measured nodes beside the hole and up to 38 % below it at theta_o = 80 degrees (tests/cli/export_rgl.rs). With
//! it the measured directions keep their values up to the edge, and the renderer fades to 0 within one cell
//! beyond it (at most 5.7 degrees of theta_o, about 11 degrees of delta_phi away from the pole), as the
//! description says. Tables for every measured band; `luminance` is their mean over the bands (with a floor of
//! 1e-6 of the largest value, so that no direction with a value has zero sampling density); `theta_i` are the interpolant's polar nodes with each interval divided into steps of at
//! most [`INCIDENCE_STEP_RAD`] (the values there are gonio's interpolation, as everywhere). The renderers
//! interpolate bilinearly between nodes and linearly between incidences and wavelengths, and hold the end
//! values beyond the measured incidences and bands: the description says so, with the run's provenance.

use gonio_brdf::geometry::Direction;

use crate::error::ResultsError;
use gonio_brdf::geometry::IsotropicAngles;

use crate::iso::{IsoGrid, IsoPoint};
use crate::run::{BAND_TOLERANCE_NM, Run, list_nm};

/// Nodes per side of the sample-space grid.
pub const RESOLUTION: usize = 64;

/// The largest step between the incidences of the tables, radians (2.5 degrees).
pub const INCIDENCE_STEP_RAD: f64 = 2.5 * std::f64::consts::PI / 180.0;

/// How far (radians, 15 degrees) a guard node's angles may move onto the measured region's nodes: more than a
/// table cell spans away from the pole (theta_m cells are at most 2.9 degrees wide, so theta_o moves by at most
/// 5.7; phi_m cells 5.7 degrees, delta_phi moves by about twice that), so that every guard node beside an edge
/// finds its held value (estimate from the cell sizes; near the pole an azimuth cell spans more of delta_phi, but
/// the directions move little there).
pub const GUARD_MARGIN_RAD: f64 = 15.0 * std::f64::consts::PI / 180.0;

/// The tensor file's magic bytes.
pub const MAGIC: &[u8; 12] = b"tensor_file\0";

/// A field's data.
#[derive(Debug, Clone, PartialEq)]
pub enum FieldData {
    U8(Vec<u8>),
    F32(Vec<f32>),
}

impl FieldData {
    fn type_code(&self) -> u8 {
        match self {
            FieldData::U8(_) => 1,
            FieldData::F32(_) => 10,
        }
    }

    fn bytes(&self) -> Vec<u8> {
        match self {
            FieldData::U8(v) => v.clone(),
            FieldData::F32(v) => v.iter().flat_map(|x| x.to_le_bytes()).collect(),
        }
    }

    fn len(&self) -> usize {
        match self {
            FieldData::U8(v) => v.len(),
            FieldData::F32(v) => v.len(),
        }
    }
}

/// A named field: its shape and data (C order).
#[derive(Debug, Clone, PartialEq)]
pub struct Field {
    pub name: String,
    pub shape: Vec<u64>,
    pub data: FieldData,
}

/// The tensor file of these fields (module doc); each field's data starts on an 8-byte boundary.
pub fn write_tensor_file(fields: &[Field]) -> Vec<u8> {
    let header_len: usize = 12
        + 2
        + 4
        + fields
            .iter()
            .map(|f| 2 + f.name.len() + 2 + 1 + 8 + 8 * f.shape.len())
            .sum::<usize>();
    let align = |x: usize| x.div_ceil(8) * 8;
    let mut offsets = Vec::with_capacity(fields.len());
    let mut at = align(header_len);
    for f in fields {
        offsets.push(at);
        at = align(at + f.data.bytes().len());
    }
    let mut out = Vec::with_capacity(at);
    out.extend_from_slice(MAGIC);
    out.extend_from_slice(&[1, 0]);
    out.extend_from_slice(&(fields.len() as u32).to_le_bytes());
    for (f, offset) in fields.iter().zip(&offsets) {
        out.extend_from_slice(&(f.name.len() as u16).to_le_bytes());
        out.extend_from_slice(f.name.as_bytes());
        out.extend_from_slice(&(f.shape.len() as u16).to_le_bytes());
        out.push(f.data.type_code());
        out.extend_from_slice(&(*offset as u64).to_le_bytes());
        for d in &f.shape {
            out.extend_from_slice(&d.to_le_bytes());
        }
    }
    for (f, offset) in fields.iter().zip(&offsets) {
        out.resize(*offset, 0);
        out.extend_from_slice(&f.data.bytes());
    }
    out
}

/// The half vector at sample-space node (x, y) of an incidence at azimuth 0: theta_m = x^2 pi / 2,
/// phi_m = (2 y - 1) pi.
pub fn half_vector(x: f64, y: f64) -> Direction {
    let theta_m = x * x * std::f64::consts::FRAC_PI_2;
    let phi_m = (2.0 * y - 1.0) * std::f64::consts::PI;
    Direction::from_spherical(theta_m, phi_m)
}

/// The outgoing direction of incidence `wi` about half vector `m` (the mirror of wi about m), when above the
/// horizon.
pub fn outgoing(wi: &Direction, m: &Direction) -> Option<Direction> {
    let c = wi.dot(m);
    if c <= 0.0 {
        return None;
    }
    Direction::new(
        2.0 * c * m.x() - wi.x(),
        2.0 * c * m.y() - wi.y(),
        2.0 * c * m.z() - wi.z(),
    )
    .filter(Direction::is_above_horizon)
}

/// The resampled run.
#[derive(Debug, Clone)]
pub struct RglExport {
    /// Incidences, radians.
    pub theta_i: Vec<f64>,
    pub bands_nm: Vec<f64>,
    /// [theta_i][band][y][x], f cos(theta_o) in 1/sr.
    pub spectra: Vec<f64>,
    /// Share of the grid nodes (over incidences and bands) with a measured value.
    pub covered: f64,
    /// Share of the grid nodes (over incidences and bands) in the guard band (module doc).
    pub guard: f64,
}

/// Resamples every band of the run onto the sample-space grid (module doc).
pub fn to_rgl(run: &Run) -> Result<RglExport, ResultsError> {
    let bands = run.bands_nm();
    if bands.is_empty() {
        return Err(ResultsError::NoData {
            origin: run.origin.clone(),
            message: "no valid points to export".into(),
        });
    }
    let grids: Vec<IsoGrid> = bands
        .iter()
        .map(|&band| {
            let pts: Vec<IsoPoint> = run
                .points
                .iter()
                .filter(|p| (p.band_nm - band).abs() <= BAND_TOLERANCE_NM)
                .filter_map(IsoPoint::from_point)
                .collect();
            IsoGrid::build(&pts)
        })
        .collect();
    // The incidences: the polar nodes of the bands' grids (they share the plan's geometry), merged, and each
    // interval between them divided into steps of at most INCIDENCE_STEP_RAD, so that the renderer's linear
    // interpolation between incidences follows gonio's interpolant (on the lobe, linear interpolation at a
    // fixed half vector between nodes 15 degrees apart differs from it by up to tens of percent).
    let nodes = crate::iso::cluster(
        grids
            .iter()
            .flat_map(|g| g.theta_nodes().iter().copied())
            .collect(),
    );
    let mut theta_i: Vec<f64> = Vec::new();
    for pair in nodes.windows(2) {
        let parts = ((pair[1] - pair[0]) / INCIDENCE_STEP_RAD).ceil().max(1.0) as usize;
        theta_i.extend((0..parts).map(|k| pair[0] + (pair[1] - pair[0]) * k as f64 / parts as f64));
    }
    theta_i.extend(nodes.last().copied());
    // The file stores the incidences as float32: the tables are computed at exactly those values.
    let theta_i: Vec<f64> = theta_i.into_iter().map(|t| f64::from(t as f32)).collect();
    if theta_i.is_empty() {
        return Err(ResultsError::NoData {
            origin: run.origin.clone(),
            message: format!("no valid point above the horizon in {}", list_nm(&bands)),
        });
    }
    let mut spectra = Vec::with_capacity(theta_i.len() * bands.len() * RESOLUTION * RESOLUTION);
    let (mut covered, mut guard) = (0usize, 0usize);
    for &ti in &theta_i {
        let wi = Direction::from_spherical(ti, 0.0);
        for grid in &grids {
            let table = table(grid, &wi);
            covered += table.iter().filter(|v| matches!(v, Node::Measured(_))).count();
            guard += table.iter().filter(|v| matches!(v, Node::Guard(_))).count();
            spectra.extend(table.iter().map(Node::value));
        }
    }
    // The format stores float32: a value beyond its range would be written as infinity.
    if let Some(v) = spectra
        .iter()
        .find(|v| v.is_nan() || v.abs() > f64::from(f32::MAX))
    {
        return Err(ResultsError::Invalid(format!(
            "{}: a resampled value ({v:e} 1/sr x cos) lies beyond the float32 range the RGL format stores",
            run.origin
        )));
    }
    let total = spectra.len().max(1) as f64;
    Ok(RglExport {
        theta_i,
        bands_nm: bands,
        spectra,
        covered: covered as f64 / total,
        guard: guard as f64 / total,
    })
}

/// A node of a table: inside the measured region, in the guard band beside it, or neither.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Node {
    /// gonio's interpolant times cos(theta_o).
    Measured(f64),
    /// Beside a measured node and outside the measured region: the held value (module doc) times cos(theta_o).
    Guard(f64),
    /// Neither: 0 in the file.
    Empty,
}

impl Node {
    /// The value the file stores.
    pub fn value(&self) -> f64 {
        match self {
            Node::Measured(v) | Node::Guard(v) => *v,
            Node::Empty => 0.0,
        }
    }
}

/// One band's table at incidence `wi` ([y][x], module doc): the interpolant where it has a value, the held
/// value at the nodes that are not measured but share a bilinear cell with a measured one.
pub fn table(grid: &IsoGrid, wi: &Direction) -> Vec<Node> {
    let n = RESOLUTION;
    let node = |k: usize| k as f64 / (n - 1) as f64;
    let angles = |x: usize, y: usize| {
        outgoing(wi, &half_vector(node(x), node(y)))
            .map(|wo| (IsotropicAngles::from_directions(wi, &wo), wo.cos_theta()))
    };
    let mut table: Vec<Node> = (0..n * n)
        .map(|k| {
            angles(k % n, k / n)
                .and_then(|(a, cos)| grid.eval(&a).map(|f| Node::Measured(f.max(0.0) * cos)))
                .unwrap_or(Node::Empty)
        })
        .collect();
    let measured: Vec<bool> = table.iter().map(|v| matches!(v, Node::Measured(_))).collect();
    for y in 0..n {
        for x in 0..n {
            let beside = (y.saturating_sub(1)..=(y + 1).min(n - 1))
                .any(|yy| (x.saturating_sub(1)..=(x + 1).min(n - 1)).any(|xx| measured[yy * n + xx]));
            if measured[y * n + x] || !beside {
                continue;
            }
            if let Some(v) = angles(x, y)
                .and_then(|(a, cos)| grid.eval_held(&a, GUARD_MARGIN_RAD).map(|f| f.max(0.0) * cos))
            {
                table[y * n + x] = Node::Guard(v);
            }
        }
    }
    table
}

impl RglExport {
    /// The file's bytes, with `description` (the provenance and what was derived, module doc).
    pub fn to_bytes(&self, description: &str) -> Vec<u8> {
        let n = RESOLUTION as u64;
        let (nt, nb) = (self.theta_i.len() as u64, self.bands_nm.len() as u64);
        let f32s = |v: &[f64]| v.iter().map(|x| *x as f32).collect::<Vec<f32>>();
        let cells = RESOLUTION * RESOLUTION;
        let largest = self.spectra.iter().fold(0.0f64, |m, v| m.max(*v));
        let floor = (1e-6 * largest).max(f64::MIN_POSITIVE);
        let mut luminance = Vec::with_capacity(self.theta_i.len() * cells);
        for t in 0..self.theta_i.len() {
            for c in 0..cells {
                let sum: f64 = (0..self.bands_nm.len())
                    .map(|b| self.spectra[(t * self.bands_nm.len() + b) * cells + c])
                    .sum();
                luminance.push(sum / self.bands_nm.len() as f64 + floor);
            }
        }
        let field = |name: &str, shape: Vec<u64>, data: FieldData| Field {
            name: name.to_string(),
            shape,
            data,
        };
        let fields = vec![
            field(
                "description",
                vec![description.len() as u64],
                FieldData::U8(description.as_bytes().to_vec()),
            ),
            field("jacobian", vec![1], FieldData::U8(vec![1])),
            field("theta_i", vec![nt], FieldData::F32(f32s(&self.theta_i))),
            field("phi_i", vec![1], FieldData::F32(vec![0.0])),
            field("wavelengths", vec![nb], FieldData::F32(f32s(&self.bands_nm))),
            field("ndf", vec![n, n], FieldData::F32(vec![1.0; cells])),
            field("sigma", vec![n, n], FieldData::F32(vec![0.25; cells])),
            field(
                "vndf",
                vec![1, nt, n, n],
                FieldData::F32(vec![1.0; self.theta_i.len() * cells]),
            ),
            field("luminance", vec![1, nt, n, n], FieldData::F32(f32s(&luminance))),
            field(
                "spectra",
                vec![1, nt, nb, n, n],
                FieldData::F32(f32s(&self.spectra)),
            ),
        ];
        debug_assert!(
            fields
                .iter()
                .all(|f| f.shape.iter().product::<u64>() == f.data.len() as u64)
        );
        write_tensor_file(&fields)
    }
}

/// The description the file carries: what it is, what was derived and how, and the provenance lines.
pub fn description(export: &RglExport, run: &Run, provenance: &[(&str, String)]) -> String {
    let mut s = format!(
        "gonio measurement of campaign {} ({}), exported as an RGL material. Bands: {}. Incidences: {} deg. \
         spectra = BRDF x cos(theta_o) from gonio's interpolant of the measured points (log-trilinear between \
         measured nodes, with reciprocity, isotropic; {:.1}% of the nodes), 0 where not measured, except a guard \
         band ({:.1}% of the nodes): a node outside the measured region that shares a bilinear cell with a \
         measured one holds the value of the nearest measured point (within 15 degrees of node moves), so that \
         interpolation keeps the measured values up to the edge and fades to 0 within one cell beyond it; \
         incidences between measured ones are gonio's interpolation; renderers hold the values of the first and \
         last incidence and band beyond them. NOT MEASURED and \
         therefore not derived: the microfacet distribution (the arms cannot reach retro-reflection), so vndf is \
         uniform (sample space = half-vector coordinates), ndf = 1 and sigma = 1/4 (D / (4 sigma) = 1); \
         luminance is the mean of the spectra over the bands.",
        run.name,
        run.origin,
        list_nm(&export.bands_nm),
        export
            .theta_i
            .iter()
            .map(|t| format!("{:.2}", t.to_degrees()))
            .collect::<Vec<_>>()
            .join(", "),
        100.0 * export.covered,
        100.0 * export.guard
    );
    for (k, v) in provenance {
        s.push_str(&format!(" provenance.{k}: {v};"));
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_container_has_the_documented_layout() {
        let bytes = write_tensor_file(&[
            Field {
                name: "ab".into(),
                shape: vec![2],
                data: FieldData::F32(vec![1.5, -2.0]),
            },
            Field {
                name: "c".into(),
                shape: vec![1, 3],
                data: FieldData::U8(vec![7, 8, 9]),
            },
        ]);
        assert_eq!(&bytes[..12], b"tensor_file\0");
        assert_eq!(&bytes[12..14], &[1, 0]);
        assert_eq!(
            u32::from_le_bytes([bytes[14], bytes[15], bytes[16], bytes[17]]),
            2
        );
        // First field: name length, name, rank, type, offset, shape.
        assert_eq!(&bytes[18..20], &[2, 0]);
        assert_eq!(&bytes[20..22], b"ab");
        assert_eq!(&bytes[22..24], &[1, 0]);
        assert_eq!(bytes[24], 10);
        let offset = u64::from_le_bytes(bytes[25..33].try_into().expect("8 bytes")) as usize;
        assert_eq!(offset % 8, 0);
        assert_eq!(u64::from_le_bytes(bytes[33..41].try_into().expect("8 bytes")), 2);
        assert_eq!(
            f32::from_le_bytes(bytes[offset..offset + 4].try_into().expect("4")),
            1.5
        );
        assert_eq!(
            f32::from_le_bytes(bytes[offset + 4..offset + 8].try_into().expect("4")),
            -2.0
        );
        assert_eq!(&bytes[bytes.len() - 3..], &[7, 8, 9]);
    }

    #[test]
    fn the_grid_reflects_about_the_half_vector() {
        let wi = Direction::from_spherical(0.5, 0.0);
        // x = 0: the normal is the half vector, wo is the mirror direction.
        let wo = outgoing(&wi, &half_vector(0.0, 0.3)).expect("above");
        assert!((wo.theta() - 0.5).abs() < 1e-12 && (wo.x() + wi.x()).abs() < 1e-12);
        // Half vector at the horizon: nothing.
        assert!(outgoing(&wi, &half_vector(1.0, 0.5)).is_none());
    }
}
