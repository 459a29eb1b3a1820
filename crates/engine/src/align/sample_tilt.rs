//! Alignment on the sample itself: its specular lobe's peak at several rotations of the stage gives the tilt of
//! the sample as it sits on the holder, which is not the mirror's (another object, seated otherwise).
//!
//! Each scan walks the detector through the lobe at one rotation. The peak is the vertex of a parabola fitted to
//! `ln(P / cos(theta_o))` near the largest reading (the cosine is the view's, known; what is left is the BRDF's
//! own lobe). A rough sample's lobe peaks off the specular direction by an amount its material sets: the same at
//! every rotation of an isotropic sample, so it is fitted as one common offset beside the tilt, which the
//! rotations turn. A reflection with no peak (a diffuse sample) is refused.

// Dense matrix code reads best with explicit indices.
#![allow(clippy::needless_range_loop)]

use gonio_instrument::AxisRole;
use gonio_scheduler::kinematics::Pose;

use super::centre::{CentreError, Located};
use super::model::{Model, Observation};
use super::scan::read_along;
use super::{AlignError, Estimate};
use crate::motion::Motion;

/// The detector's walk about the specular direction (deg) and its step.
const HALF_WIDTH_DEG: f64 = 8.0;
const STEP_DEG: f64 = 0.1;
/// The parabola is fitted to the readings within this much of the peak in `ln(P / cos)` (about 10 %).
const PEAK_DEPTH: f64 = 0.1;
/// A lobe whose readings vary by less than this over the scan (relative) is no peak to align on.
const MIN_CONTRAST: f64 = 0.05;

/// The lobe's peak from readings (detector angle deg, W); pure.
pub fn lobe_peak(samples: &[(f64, f64)]) -> Result<Located, CentreError> {
    let pts: Vec<(f64, f64)> = samples
        .iter()
        .filter(|(x, p)| x.is_finite() && *p > 0.0 && x.to_radians().cos() > 0.05)
        .map(|&(x, p)| (x, (p / x.to_radians().cos()).ln()))
        .collect();
    let (max_k, max_y) = pts
        .iter()
        .enumerate()
        .max_by(|a, b| a.1.1.total_cmp(&b.1.1))
        .map(|(k, p)| (k, p.1))
        .ok_or(CentreError::NoBeam { max_w: 0.0 })?;
    let min_y = pts.iter().map(|p| p.1).fold(f64::INFINITY, f64::min);
    let contrast = (max_y - min_y).exp() - 1.0;
    if contrast < MIN_CONTRAST {
        return Err(CentreError::NoSpecularPeak {
            contrast_percent: 100.0 * contrast,
        });
    }
    if max_k == 0 || max_k + 1 == pts.len() {
        return Err(CentreError::NotInside {
            side: if max_k == 0 { "low" } else { "high" },
        });
    }
    let near: Vec<(f64, f64)> = pts
        .iter()
        .copied()
        .filter(|p| p.1 >= max_y - PEAK_DEPTH)
        .collect();
    if near.len() < 5 {
        return Err(CentreError::FewEdgePoints {
            side: "peak",
            count: near.len(),
        });
    }
    // y = a + b (x - x0) + c (x - x0)^2 about the largest reading, by least squares.
    let x0 = pts[max_k].0;
    let mut m = [[0.0; 3]; 3];
    let mut v = [0.0; 3];
    for &(x, y) in &near {
        let t = x - x0;
        let row = [1.0, t, t * t];
        for i in 0..3 {
            v[i] += row[i] * y;
            for j in 0..3 {
                m[i][j] += row[i] * row[j];
            }
        }
    }
    let m_vec: Vec<Vec<f64>> = m.iter().map(|r| r.to_vec()).collect();
    let inv = gonio_results::fit::lm::spd_inverse(&m_vec).ok_or(CentreError::FewEdgePoints {
        side: "peak",
        count: near.len(),
    })?;
    let coef: Vec<f64> = (0..3).map(|i| (0..3).map(|j| inv[i][j] * v[j]).sum()).collect();
    let (b, c) = (coef[1], coef[2]);
    let ssr: f64 = near
        .iter()
        .map(|&(x, y)| {
            let t = x - x0;
            (y - (coef[0] + b * t + c * t * t)).powi(2)
        })
        .sum();
    let s2 = ssr / (near.len() as f64 - 3.0).max(1.0);
    if c.is_nan() || c >= 0.0 || c * c < 25.0 * s2 * inv[2][2] {
        return Err(CentreError::NoSpecularPeak {
            contrast_percent: 100.0 * contrast,
        });
    }
    let vertex = -b / (2.0 * c);
    // Variance of -b / 2c from the coefficients' covariance.
    let (db, dc) = (-1.0 / (2.0 * c), b / (2.0 * c * c));
    let var = s2 * (db * db * inv[1][1] + 2.0 * db * dc * inv[1][2] + dc * dc * inv[2][2]);
    Ok(Located {
        value: x0 + vertex,
        u: var.max(0.0).sqrt().max(1e-5),
    })
}

/// The sample's own tilt and its lobe's common offset from the peaks `centres` (rotation deg, peak) at light
/// angle `light_deg`, with every other parameter at the model's: (tilt x, tilt y, offset) and their standard
/// uncertainties (deg). Gauss-Newton, the derivatives by central differences. None when the model cannot
/// predict the scans or they do not determine the three.
pub fn fit_sample_tilt(
    model: &Model,
    light_deg: f64,
    centres: &[(f64, Located)],
) -> Option<([f64; 3], [f64; 3])> {
    let predict = |x: &[f64; 3], rotation_deg: f64| {
        let mut m = *model;
        m.p.sample_tilt_x_deg = x[0];
        m.p.sample_tilt_y_deg = x[1];
        m.predict(&Observation::MirrorDetector {
            light_deg,
            tilt_deg: 0.0,
            rotation_deg,
        })
        .map(|d| d + x[2])
    };
    let mut x = [model.p.sample_tilt_x_deg, model.p.sample_tilt_y_deg, 0.0];
    let mut inv = [[0.0; 3]; 3];
    let mut chi2 = 0.0;
    for _ in 0..20 {
        let mut a = [[0.0; 3]; 3];
        let mut g = [0.0; 3];
        chi2 = 0.0;
        for &(rotation, c) in centres {
            let r = (c.value - predict(&x, rotation)?) / c.u;
            chi2 += r * r;
            let mut row = [0.0; 3];
            for k in 0..3 {
                let h = 1e-4;
                let (mut xp, mut xm) = (x, x);
                xp[k] += h;
                xm[k] -= h;
                row[k] = (predict(&xp, rotation)? - predict(&xm, rotation)?) / (2.0 * h) / c.u;
            }
            for i in 0..3 {
                g[i] += row[i] * r;
                for j in 0..3 {
                    a[i][j] += row[i] * row[j];
                }
            }
        }
        let a_vec: Vec<Vec<f64>> = a.iter().map(|r| r.to_vec()).collect();
        let inv_vec = gonio_results::fit::lm::spd_inverse(&a_vec)?;
        for i in 0..3 {
            for j in 0..3 {
                inv[i][j] = inv_vec[i][j];
            }
        }
        let step: Vec<f64> = (0..3).map(|i| (0..3).map(|j| inv[i][j] * g[j]).sum()).collect();
        for k in 0..3 {
            x[k] += step[k];
        }
        if step.iter().all(|s| s.abs() < 1e-9) {
            break;
        }
    }
    let dof = centres.len().saturating_sub(3).max(1) as f64;
    let scale = (chi2 / dof).max(1.0);
    let u = [0, 1, 2].map(|k| (inv[k][k] * scale).max(0.0).sqrt());
    Some((x, u))
}

/// Rotations of the sample's lobe scans.
const ROTATIONS_DEG: [f64; 4] = [0.0, 180.0, 90.0, -90.0];

/// The sample step: its lobe scanned at `light_deg` at every rotation the stage can make (`rotation_ok`), and
/// its own tilt fitted with the rest of `model`: the estimates `sample_own_tilt_x_deg`, `sample_own_tilt_y_deg`
/// and `sample_lobe_offset_deg`.
pub(super) async fn align_on_sample(
    motion: &mut Motion<'_>,
    model: &Model,
    light_deg: f64,
    rotation_ok: &(dyn Fn(f64) -> bool + Sync),
) -> Result<Vec<Estimate>, AlignError> {
    let specular = -light_deg;
    let steps = (HALF_WIDTH_DEG / STEP_DEG).round() as i32;
    let mut centres = Vec::new();
    for rotation in ROTATIONS_DEG.into_iter().filter(|r| rotation_ok(*r)) {
        let name = format!("sample's specular lobe, light {light_deg} deg, rotation {rotation} deg");
        tracing::info!("alignment: {name}");
        let xs: Vec<f64> = (-steps..=steps)
            .map(|k| specular + f64::from(k) * STEP_DEG)
            .collect();
        let at = |x: f64| Pose::new(light_deg, x, 0.0, rotation);
        let readings = read_along(motion, &name, AxisRole::DetectorArm, &xs, &at).await?;
        let peak = lobe_peak(&readings).map_err(|cause| AlignError::Scan {
            scan: name.clone(),
            cause,
        })?;
        centres.push((rotation, peak));
    }
    if centres.len() < 4 {
        return Err(AlignError::Instrument(
            "aligning on the sample needs the stage at 0, 180 and +-90 deg of rotation".into(),
        ));
    }
    let (x, u) = fit_sample_tilt(model, light_deg, &centres).ok_or_else(|| {
        AlignError::Instrument("the sample's lobe peaks do not fit the instrument's geometry".into())
    })?;
    Ok([
        ("sample_own_tilt_x_deg", x[0], u[0]),
        ("sample_own_tilt_y_deg", x[1], u[1]),
        ("sample_lobe_offset_deg", x[2], u[2]),
    ]
    .into_iter()
    .map(|(name, value, u)| Estimate {
        name: name.into(),
        unit: "deg".into(),
        value,
        u,
        observable: true,
    })
    .collect())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_lobe_is_found_at_its_peak_and_a_flat_reflection_refused() {
        // A Gaussian lobe of 2 deg on a diffuse floor, viewed at cos(theta_o), peaking at 30.3 deg.
        let lobe = |x: f64| (0.2 + (-((x - 30.3) / 2.0f64).powi(2)).exp()) * x.to_radians().cos();
        let samples: Vec<(f64, f64)> = (0..=160)
            .map(|k| 22.0 + 0.1 * f64::from(k))
            .map(|x| (x, lobe(x)))
            .collect();
        let peak = lobe_peak(&samples).expect("a peak");
        assert!((peak.value - 30.3).abs() < 0.01, "{peak:?}");
        let flat: Vec<(f64, f64)> = samples
            .iter()
            .map(|&(x, _)| (x, 1e-8 * x.to_radians().cos()))
            .collect();
        assert!(matches!(
            lobe_peak(&flat),
            Err(CentreError::NoSpecularPeak { .. })
        ));
    }
}
