//! Measured BRDF from an RGL material file (`.bsdf`: the EPFL Realistic Graphics Lab's database and
//! `gonio export --format rgl`), evaluated as Mitsuba 3's `measured` BSDF evaluates it.
//!
//! The file is a tensor file: `tensor_file\0`, version 1.0, a `u32` field count, then per field a `u16` name
//! length, the name, a `u16` rank, a `u8` type (1 = uint8, 10 = float32), a `u64` data offset and `u64` extents;
//! data little-endian in C order. The fields and their shapes are those the renderers check: `theta_i`, `phi_i`,
//! `wavelengths` (1-D float32), `ndf`, `sigma` (2-D), `vndf`, `luminance` [phi_i, theta_i, n, n], `spectra`
//! [phi_i, theta_i, wavelength, n, n], `jacobian` and `description` (uint8).
//!
//! Evaluation (Dupuy and Jakob 2018; the layout and interpolation follow Mitsuba 3's plugin, which defines the
//! format in practice): the half vector m of (wi, wo) in unit-square coordinates
//! `u = (sqrt(theta_m / (pi/2)), (phi_m - phi_i + pi) / (2 pi))` (phi_m absolute for an anisotropic file) is
//! mapped back through the `vndf` warp to the sample space ([`Warp2D::invert`]: the inverse of sampling a
//! bilinear density by its marginal and conditional CDFs), where `spectra` is interpolated bilinearly, and
//! linearly in phi_i, theta_i and wavelength (held constant beyond the end nodes). With `jacobian` = 1 the value
//! is multiplied by ndf(u_m) / (4 sigma(u_wi)). The result is f cos(theta_o), so f is it divided by
//! cos(theta_o). Incidence angles are those of `wi` (gonio's direction towards the source). Files whose
//! `phi_i` covers less than the full circle (symmetry reductions) are refused.

use std::collections::HashMap;
use std::f64::consts::{FRAC_PI_2, PI};
use std::path::{Path, PathBuf};

use crate::brdf::Brdf;
use crate::geometry::Direction;
use crate::spectrum::{SpectrumError, Wavelength};

/// Why an RGL file cannot be used.
#[derive(Debug, thiserror::Error)]
pub enum RglError {
    #[error("cannot read {}: {source}", path.display())]
    Read { path: PathBuf, source: std::io::Error },
    #[error("{}: not a usable RGL material file: {message}", path.display())]
    Invalid { path: PathBuf, message: String },
    /// Bytes that are not a usable RGL file (no file named: [`RglBrdf::from_bytes`]).
    #[error("not a usable RGL material file: {message}")]
    Malformed { message: String },
}

/// A field: type code, shape, raw bytes.
struct RawField<'a> {
    dtype: u8,
    shape: Vec<usize>,
    data: &'a [u8],
}

/// Parses the container (module doc); every length is checked against the file.
fn parse_fields(bytes: &[u8]) -> Result<HashMap<String, RawField<'_>>, String> {
    let mut at = 0usize;
    let mut take = |n: usize| -> Result<&[u8], String> {
        let end = at
            .checked_add(n)
            .filter(|e| *e <= bytes.len())
            .ok_or("the file is truncated")?;
        let s = &bytes[at..end];
        at = end;
        Ok(s)
    };
    let le = |s: &[u8]| s.iter().rev().fold(0u64, |acc, b| (acc << 8) | u64::from(*b));
    if take(12)? != b"tensor_file\0" {
        return Err("it does not start with `tensor_file`".into());
    }
    let version = take(2)?;
    if version != [1, 0] {
        return Err(format!(
            "unknown tensor file version {}.{}",
            version[0], version[1]
        ));
    }
    let count = le(take(4)?);
    let mut fields = HashMap::new();
    for _ in 0..count {
        let name_len = le(take(2)?) as usize;
        let name = String::from_utf8_lossy(take(name_len)?).into_owned();
        let ndim = le(take(2)?) as usize;
        let dtype = take(1)?[0];
        let offset = le(take(8)?) as usize;
        let mut shape = Vec::with_capacity(ndim.min(8));
        for _ in 0..ndim {
            shape.push(le(take(8)?) as usize);
        }
        let item = match dtype {
            1 => 1usize,
            10 => 4,
            other => {
                return Err(format!(
                    "field `{name}` has type {other}; gonio reads uint8 and float32"
                ));
            }
        };
        let size = shape
            .iter()
            .try_fold(item, |acc, d| acc.checked_mul(*d))
            .ok_or_else(|| format!("field `{name}` is too large"))?;
        let data = offset
            .checked_add(size)
            .filter(|end| *end <= bytes.len())
            .map(|end| &bytes[offset..end])
            .ok_or_else(|| format!("field `{name}` lies beyond the end of the file"))?;
        fields.insert(name, RawField { dtype, shape, data });
    }
    Ok(fields)
}

fn f32s(field: &RawField) -> Vec<f32> {
    field
        .data
        .chunks_exact(4)
        .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
        .collect()
}

/// A 2-D piecewise-bilinear function on [0, 1]^2 (nodes at k / (n - 1)), optionally depending linearly on
/// parameters; with `cdf`, normalised per parameter slice and with the marginal (rows) and conditional
/// (columns) CDFs of its trapezoid integrals, so that it can be inverted as a sample warp.
#[derive(Debug, Clone)]
struct Warp2D {
    nx: usize,
    ny: usize,
    params: Vec<Vec<f64>>,
    strides: Vec<usize>,
    data: Vec<f64>,
    marginal: Vec<f64>,
    conditional: Vec<f64>,
}

impl Warp2D {
    fn new(values: &[f32], nx: usize, ny: usize, params: Vec<Vec<f64>>, cdf: bool) -> Result<Warp2D, String> {
        if nx < 2 || ny < 2 {
            return Err("a table needs at least 2 x 2 nodes".into());
        }
        if params.iter().any(|p| {
            p.is_empty()
                || p.windows(2)
                    .any(|w| w[1].partial_cmp(&w[0]) != Some(std::cmp::Ordering::Greater))
        }) {
            return Err("parameter nodes must be ascending".into());
        }
        // Strides: the last parameter varies fastest (C order), a parameter with one node has none.
        let mut strides = vec![0; params.len()];
        let mut slices = 1usize;
        for d in (0..params.len()).rev() {
            strides[d] = if params[d].len() > 1 { slices } else { 0 };
            slices *= params[d].len();
        }
        if values.len() != slices * nx * ny {
            return Err(format!(
                "a table of {} values where {} were expected",
                values.len(),
                slices * nx * ny
            ));
        }
        let mut data: Vec<f64> = values.iter().map(|v| f64::from(*v)).collect();
        if data.iter().any(|v| !v.is_finite()) {
            return Err("a table holds a value that is not finite".into());
        }
        let (mut marginal, mut conditional) = (Vec::new(), Vec::new());
        if cdf {
            marginal = vec![0.0; slices * ny];
            conditional = vec![0.0; slices * nx * ny];
            for s in 0..slices {
                let d = &mut data[s * nx * ny..(s + 1) * nx * ny];
                let cc = &mut conditional[s * nx * ny..(s + 1) * nx * ny];
                for y in 0..ny {
                    let mut sum = 0.0;
                    for x in 0..nx - 1 {
                        sum += 0.5 * (d[y * nx + x] + d[y * nx + x + 1]);
                        cc[y * nx + x + 1] = sum;
                    }
                }
                let m = &mut marginal[s * ny..(s + 1) * ny];
                let mut sum = 0.0;
                for y in 0..ny - 1 {
                    sum += 0.5 * (cc[(y + 1) * nx - 1] + cc[(y + 2) * nx - 1]);
                    m[y + 1] = sum;
                }
                if !(sum > 0.0 && sum.is_finite()) {
                    return Err("a density slice has no mass".into());
                }
                for v in cc.iter_mut().chain(m.iter_mut()).chain(d.iter_mut()) {
                    *v /= sum;
                }
            }
        }
        Ok(Warp2D {
            nx,
            ny,
            params: params.clone(),
            strides,
            data,
            marginal,
            conditional,
        })
    }

    /// Base slice and (lower, upper) weights per parameter: linear between the nodes around `param`, clamped.
    fn weights(&self, param: &[f64]) -> (usize, Vec<(f64, f64)>) {
        let mut base = 0;
        let weights = self
            .params
            .iter()
            .zip(&self.strides)
            .zip(param)
            .map(|((nodes, stride), &x)| {
                if nodes.len() == 1 {
                    return (1.0, 0.0);
                }
                let i = nodes
                    .partition_point(|n| *n < x)
                    .saturating_sub(1)
                    .min(nodes.len() - 2);
                base += stride * i;
                let t = ((x - nodes[i]) / (nodes[i + 1] - nodes[i])).clamp(0.0, 1.0);
                (1.0 - t, t)
            })
            .collect();
        (base, weights)
    }

    /// `table[i]` of every slice, blended over the parameters; `per_slice` entries per slice.
    fn lookup(&self, table: &[f64], per_slice: usize, i: usize, base: usize, w: &[(f64, f64)]) -> f64 {
        let mut total = 0.0;
        for corner in 0..(1usize << w.len()) {
            let mut weight = 1.0;
            let mut slice = base;
            for (d, (w0, w1)) in w.iter().enumerate() {
                if corner >> d & 1 == 1 {
                    weight *= w1;
                    slice += self.strides[d];
                } else {
                    weight *= w0;
                }
            }
            if weight != 0.0 {
                total += weight * table.get(slice * per_slice + i).copied().unwrap_or(0.0);
            }
        }
        total
    }

    /// Cell and position within it of a point of [0, 1]^2.
    fn cell(&self, p: [f64; 2]) -> ([usize; 2], [f64; 2]) {
        let mut cell = [0; 2];
        let mut frac = [0.0; 2];
        for (k, n) in [self.nx, self.ny].into_iter().enumerate() {
            let x = p[k].clamp(0.0, 1.0) * (n - 1) as f64;
            cell[k] = (x.floor() as usize).min(n - 2);
            frac[k] = x - cell[k] as f64;
        }
        (cell, frac)
    }

    /// The bilinear interpolant at `p` (values as stored).
    fn eval(&self, p: [f64; 2], param: &[f64]) -> f64 {
        let (base, w) = self.weights(param);
        let ([cx, cy], [fx, fy]) = self.cell(p);
        let n = self.nx * self.ny;
        let at = |x: usize, y: usize| self.lookup(&self.data, n, y * self.nx + x, base, &w);
        (1.0 - fy) * ((1.0 - fx) * at(cx, cy) + fx * at(cx + 1, cy))
            + fy * ((1.0 - fx) * at(cx, cy + 1) + fx * at(cx + 1, cy + 1))
    }

    /// The sample in [0, 1]^2 that the warp maps to `p`: the conditional CDF of the column position within its
    /// row blend, then the marginal CDF of the row position (module doc).
    fn invert(&self, p: [f64; 2], param: &[f64]) -> [f64; 2] {
        let (base, w) = self.weights(param);
        let ([cx, cy], [fx, fy]) = self.cell(p);
        let (nx, n) = (self.nx, self.nx * self.ny);
        let d = |x: usize, y: usize| self.lookup(&self.data, n, y * nx + x, base, &w);
        let cc = |x: usize, y: usize| self.lookup(&self.conditional, n, y * nx + x, base, &w);
        let (c0, c1) = (
            (1.0 - fy) * d(cx, cy) + fy * d(cx, cy + 1),
            (1.0 - fy) * d(cx + 1, cy) + fy * d(cx + 1, cy + 1),
        );
        let mut sx = fx * (c0 + 0.5 * fx * (c1 - c0)) + (1.0 - fy) * cc(cx, cy) + fy * cc(cx, cy + 1);
        let (r0, r1) = (cc(nx - 1, cy), cc(nx - 1, cy + 1));
        let row = (1.0 - fy) * r0 + fy * r1;
        if row > 0.0 {
            sx /= row;
        }
        let sy = fy * (r0 + 0.5 * fy * (r1 - r0)) + self.lookup(&self.marginal, self.ny, cy, base, &w);
        [sx.clamp(0.0, 1.0), sy.clamp(0.0, 1.0)]
    }
}

/// An RGL material (module doc).
#[derive(Debug, Clone)]
pub struct RglBrdf {
    isotropic: bool,
    jacobian: bool,
    ndf: Warp2D,
    sigma: Warp2D,
    vndf: Warp2D,
    spectra: Warp2D,
    description: String,
}

fn theta2u(theta: f64) -> f64 {
    (theta / FRAC_PI_2).max(0.0).sqrt()
}

fn phi2u(phi: f64) -> f64 {
    (phi + PI) / (2.0 * PI)
}

impl RglBrdf {
    /// Reads an RGL file.
    pub fn from_file(path: &Path) -> Result<RglBrdf, RglError> {
        let bytes = std::fs::read(path).map_err(|source| RglError::Read {
            path: path.to_path_buf(),
            source,
        })?;
        RglBrdf::parse(&bytes).map_err(|message| RglError::Invalid {
            path: path.to_path_buf(),
            message,
        })
    }

    /// Reads the bytes of an RGL file; the error says what is wrong.
    pub fn from_bytes(bytes: &[u8]) -> Result<RglBrdf, RglError> {
        RglBrdf::parse(bytes).map_err(|message| RglError::Malformed { message })
    }

    fn parse(bytes: &[u8]) -> Result<RglBrdf, String> {
        let fields = parse_fields(bytes)?;
        let get = |name: &str, dtype: u8, rank: usize| -> Result<&RawField, String> {
            let f = fields
                .get(name)
                .ok_or_else(|| format!("field `{name}` is missing"))?;
            if f.dtype != dtype || f.shape.len() != rank {
                return Err(format!(
                    "field `{name}` should be {} of rank {rank}, found type {} of rank {}",
                    if dtype == 1 { "uint8" } else { "float32" },
                    f.dtype,
                    f.shape.len()
                ));
            }
            Ok(f)
        };
        let nodes = |name: &str| -> Result<Vec<f64>, String> {
            Ok(f32s(get(name, 10, 1)?).into_iter().map(f64::from).collect())
        };
        let (theta_i, phi_i, wavelengths) = (nodes("theta_i")?, nodes("phi_i")?, nodes("wavelengths")?);
        let (ndf, sigma) = (get("ndf", 10, 2)?, get("sigma", 10, 2)?);
        let (vndf, spectra) = (get("vndf", 10, 4)?, get("spectra", 10, 5)?);
        let (np, nt, nw) = (phi_i.len(), theta_i.len(), wavelengths.len());
        if vndf.shape[..2] != [np, nt] || spectra.shape[..3] != [np, nt, nw] {
            return Err("the vndf and spectra tables do not match theta_i, phi_i and wavelengths".into());
        }
        let isotropic = np <= 2;
        if !isotropic && (phi_i[np - 1] - phi_i[0] - 2.0 * PI).abs() > 1e-3 {
            return Err(
                "phi_i does not cover the full circle (a symmetry reduction gonio does not read)".into(),
            );
        }
        let jacobian = get("jacobian", 1, 1)?.data.first().is_some_and(|j| *j != 0);
        let description = String::from_utf8_lossy(get("description", 1, 1)?.data).into_owned();
        let warp = |f: &RawField, params: Vec<Vec<f64>>, cdf: bool, what: &str| {
            let r = f.shape.len();
            Warp2D::new(&f32s(f), f.shape[r - 1], f.shape[r - 2], params, cdf)
                .map_err(|e| format!("{what}: {e}"))
        };
        Ok(RglBrdf {
            isotropic,
            jacobian,
            ndf: warp(ndf, Vec::new(), false, "ndf")?,
            sigma: warp(sigma, Vec::new(), false, "sigma")?,
            vndf: warp(vndf, vec![phi_i.clone(), theta_i.clone()], true, "vndf")?,
            spectra: warp(spectra, vec![phi_i, theta_i, wavelengths], false, "spectra")?,
            description,
        })
    }

    /// The file's description.
    pub fn description(&self) -> &str {
        &self.description
    }

    /// f(wi, wo) in 1/sr at `nm` (module doc).
    pub fn value(&self, wi: &Direction, wo: &Direction, nm: f64) -> f64 {
        if !(wi.is_above_horizon() && wo.is_above_horizon()) {
            return 0.0;
        }
        let Some(m) = Direction::new(wi.x() + wo.x(), wi.y() + wo.y(), wi.z() + wo.z()) else {
            return 0.0;
        };
        let (theta_i, phi_i) = (wi.theta(), wi.y().atan2(wi.x()));
        let (theta_m, phi_m) = (m.theta(), m.y().atan2(m.x()));
        let u_wi = [theta2u(theta_i), phi2u(phi_i)];
        let mut u_m = [
            theta2u(theta_m),
            phi2u(if self.isotropic { phi_m - phi_i } else { phi_m }),
        ];
        u_m[1] -= u_m[1].floor();
        let sample = self.vndf.invert(u_m, &[phi_i, theta_i]);
        let mut v = self.spectra.eval(sample, &[phi_i, theta_i, nm]).max(0.0);
        if self.jacobian {
            let s = self.sigma.eval(u_wi, &[]);
            v = if s > 0.0 {
                v * self.ndf.eval(u_m, &[]) / (4.0 * s)
            } else {
                0.0
            };
        }
        v / wo.cos_theta()
    }
}

impl Brdf for RglBrdf {
    fn eval(&self, wi: &Direction, wo: &Direction, wavelength: Wavelength) -> Result<f64, SpectrumError> {
        Ok(self.value(wi, wo, wavelength.nm()))
    }
    fn is_isotropic(&self) -> bool {
        self.isotropic
    }
    fn is_spectrally_flat(&self) -> bool {
        false
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A tensor file written here from the layout (module doc).
    fn file(fields: &[(&str, u8, Vec<u64>, Vec<u8>)]) -> Vec<u8> {
        let mut head = b"tensor_file\0".to_vec();
        head.extend([1, 0]);
        head.extend((fields.len() as u32).to_le_bytes());
        let head_len = head.len()
            + fields
                .iter()
                .map(|(n, _, s, _)| 2 + n.len() + 2 + 1 + 8 + 8 * s.len())
                .sum::<usize>();
        let mut offset = head_len;
        let mut body: Vec<u8> = Vec::new();
        for (name, dtype, shape, data) in fields {
            head.extend((name.len() as u16).to_le_bytes());
            head.extend(name.as_bytes());
            head.extend((shape.len() as u16).to_le_bytes());
            head.push(*dtype);
            head.extend((offset as u64).to_le_bytes());
            for d in shape {
                head.extend(d.to_le_bytes());
            }
            body.extend(data);
            offset += data.len();
        }
        head.extend(body);
        head
    }

    fn f(v: &[f32]) -> Vec<u8> {
        v.iter().flat_map(|x| x.to_le_bytes()).collect()
    }

    /// A file with a uniform vndf: spectra over the half-vector coordinates directly.
    fn uniform(value: impl Fn(f64, f64) -> f32, vndf: Vec<f32>) -> Vec<u8> {
        let n = 5u64;
        let spectra: Vec<f32> = (0..2)
            .flat_map(|_| (0..n).flat_map(move |y| (0..n).map(move |x| (x, y))))
            .map(|(x, y)| value(x as f64 / 4.0, y as f64 / 4.0))
            .collect();
        file(&[
            ("description", 1, vec![2], b"hi".to_vec()),
            ("jacobian", 1, vec![1], vec![1]),
            ("theta_i", 10, vec![2], f(&[0.0, 1.0])),
            ("phi_i", 10, vec![1], f(&[0.0])),
            ("wavelengths", 10, vec![1], f(&[550.0])),
            ("ndf", 10, vec![2, 2], f(&[1.0; 4])),
            ("sigma", 10, vec![2, 2], f(&[0.25; 4])),
            ("vndf", 10, vec![1, 2, n, n], f(&vndf)),
            ("luminance", 10, vec![1, 2, n, n], f(&[1.0; 50])),
            ("spectra", 10, vec![1, 2, 1, n, n], f(&spectra)),
        ])
    }

    #[test]
    fn a_uniform_warp_reads_spectra_at_the_half_vector() {
        // spectra = 0.5 + u_x: at the mirror direction (m = normal) u_x = 0.
        let b = RglBrdf::from_bytes(&uniform(|ux, _| 0.5 + ux as f32, vec![1.0; 50])).expect("valid");
        assert_eq!(b.description(), "hi");
        let wi = Direction::from_spherical(0.4, 0.3);
        let mirror = Direction::from_spherical(0.4, 0.3 + PI);
        let v = b.value(&wi, &mirror, 550.0);
        assert!((v * mirror.cos_theta() - 0.5).abs() < 1e-6, "{v}");
        // Half vector at theta_m = pi/8: u_x = 0.5, value 1.0 (bilinear in x is exact for a linear function).
        let m = Direction::from_spherical(PI / 8.0, 0.3);
        let c = wi.dot(&m);
        let wo = Direction::new(
            2.0 * c * m.x() - wi.x(),
            2.0 * c * m.y() - wi.y(),
            2.0 * c * m.z() - wi.z(),
        )
        .expect("unit");
        assert!((b.value(&wi, &wo, 550.0) * wo.cos_theta() - 1.0).abs() < 1e-6);
        assert_eq!(b.value(&wi, &Direction::from_spherical(1.7, 0.0), 550.0), 0.0);
    }

    #[test]
    fn the_inverse_warp_is_monotone_and_maps_the_square_onto_itself() {
        // A density growing along x and y: the inverse warp pulls points towards the origin.
        let vndf: Vec<f32> = (0..50)
            .map(|k| 1.0 + (k % 5) as f32 + ((k / 5) % 5) as f32)
            .collect();
        let b = RglBrdf::from_bytes(&uniform(|_, _| 1.0, vndf)).expect("valid");
        let w = &b.vndf;
        for p in [[0.0, 0.0], [1.0, 1.0]] {
            let s = w.invert(p, &[0.0, 0.5]);
            assert!(
                (s[0] - p[0]).abs() < 1e-12 && (s[1] - p[1]).abs() < 1e-12,
                "{s:?}"
            );
        }
        let mut last = [-1.0, -1.0];
        for k in 0..=20 {
            let t = k as f64 / 20.0;
            let s = w.invert([t, t], &[0.0, 0.5]);
            assert!(s[0] >= last[0] && s[1] >= last[1], "{s:?} after {last:?}");
            assert!(
                s[0] <= t + 1e-12 && s[1] <= t + 1e-12,
                "more mass near 1: {s:?} at {t}"
            );
            last = s;
        }
    }

    #[test]
    fn damaged_files_are_refused_without_panicking() {
        let good = uniform(|_, _| 1.0, vec![1.0; 50]);
        for cut in (0..good.len()).step_by(7) {
            assert!(RglBrdf::from_bytes(&good[..cut]).is_err(), "cut at {cut}");
        }
        let mut bad = good.clone();
        bad[14] = 200; // an absurd field count
        assert!(RglBrdf::from_bytes(&bad).is_err());
        let mut x = 0x2545_f491_4f6c_dd1du64;
        for _ in 0..200 {
            let mut b = good.clone();
            for _ in 0..4 {
                x ^= x << 13;
                x ^= x >> 7;
                x ^= x << 17;
                let i = (x % b.len() as u64) as usize;
                b[i] = (x >> 32) as u8;
            }
            let _ = RglBrdf::from_bytes(&b).map(|r| r.value(&Direction::NORMAL, &Direction::NORMAL, 550.0));
        }
    }
}
