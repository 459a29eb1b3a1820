//! The first pass: its incidences as the campaign lists them, its points without repeats, and, with
//! `first_pass_sweeps`, its sweeps and the bins their readings count in (the parent module's doc).

use super::{Adaptive, SAME_GEOMETRY, canonical, dist2, embed};
use crate::kinematics::Geometry;
use crate::plan::{PlanError, SweepSpec, SweptArm, angle_list};

/// Most incidence angles `first_pass_theta_i_deg` may list: a sweep each, so more than one per half degree
/// up to grazing is no first pass (the first pass is capped at a quarter of the budget anyway).
pub const MAX_FIRST_PASS_INCIDENCES: usize = 181;

/// `first_pass_theta_i_deg`: a list or a range of finite angles, at most [`MAX_FIRST_PASS_INCIDENCES`] of them,
/// duplicates dropped (the first occurrence kept, in order).
pub(super) fn first_pass_incidences(value: &toml::Value) -> Result<Vec<f64>, PlanError> {
    let bad = |message: String| PlanError::Invalid {
        table: ".adaptive".into(),
        key: "first_pass_theta_i_deg".into(),
        message,
    };
    // Count before converting: a hostile list of a million entries is refused at once.
    if let toml::Value::Array(items) = value
        && items.len() > MAX_FIRST_PASS_INCIDENCES
    {
        return Err(bad(format!(
            "{} incidences given; at most {MAX_FIRST_PASS_INCIDENCES} (one sweep each)",
            items.len()
        )));
    }
    let list = angle_list("adaptive", "first_pass_theta_i_deg", value)?;
    if list.len() > MAX_FIRST_PASS_INCIDENCES {
        return Err(bad(format!(
            "the range gives {} incidences; at most {MAX_FIRST_PASS_INCIDENCES} (one sweep each)",
            list.len()
        )));
    }
    if let Some(x) = list.iter().find(|x| !x.is_finite()) {
        return Err(bad(format!("expected finite degrees, got {x}")));
    }
    // Duplicates by sorting (n log n), keeping the first occurrence of each angle in the given order.
    let mut order: Vec<usize> = (0..list.len()).collect();
    order.sort_by(|&a, &b| list[a].total_cmp(&list[b]).then(a.cmp(&b)));
    let mut keep = vec![false; list.len()];
    let mut last: Option<f64> = None;
    for &i in &order {
        if last.is_none_or(|l| list[i] - l > 1e-9) {
            keep[i] = true;
        }
        last = Some(list[i]);
    }
    Ok(list
        .into_iter()
        .zip(keep)
        .filter_map(|(x, k)| k.then_some(x))
        .collect())
}

/// `geometries` without repeats (embeddings within [`SAME_GEOMETRY`] of an earlier one), in their order.
/// Sorted along a projection of the embedding, so that each geometry is compared only with those whose
/// projection is within the tolerance: n log n, not n^2.
pub(super) fn dedup_geometries(geometries: Vec<Geometry>) -> Vec<Geometry> {
    // Any direction works; this one separates the sweeps' embeddings well (no two coordinates weigh alike).
    const AXIS: [f64; 6] = [0.31, 0.43, 0.17, 0.59, 0.53, 0.29];
    let embedded: Vec<[f64; 6]> = geometries.iter().map(embed).collect();
    let norm = AXIS.iter().map(|c| c * c).sum::<f64>().sqrt();
    let key: Vec<f64> = embedded
        .iter()
        .map(|e| e.iter().zip(AXIS).map(|(x, c)| x * c).sum::<f64>() / norm)
        .collect();
    let mut order: Vec<usize> = (0..geometries.len()).collect();
    order.sort_by(|&a, &b| key[a].total_cmp(&key[b]));
    // A repeat lies within SAME_GEOMETRY of its original, hence within it along any unit direction.
    let mut repeat = vec![false; geometries.len()];
    for (pos, &i) in order.iter().enumerate() {
        for &j in order[pos + 1..]
            .iter()
            .take_while(|&&j| key[j] - key[i] <= SAME_GEOMETRY)
        {
            if dist2(&embedded[i], &embedded[j]) < SAME_GEOMETRY * SAME_GEOMETRY {
                // The later one in the given order repeats the earlier.
                repeat[i.max(j)] = true;
            }
        }
    }
    geometries
        .into_iter()
        .zip(repeat)
        .filter_map(|(g, r)| (!r).then_some(g))
        .collect()
}

impl Adaptive {
    /// With `first_pass_sweeps`: the first pass as `[[plan.sweeps]]` entries, one detector sweep through the
    /// plane of incidence (phi = 0) per first-pass incidence, from grazing on the source's side to grazing on
    /// the specular side (the sweeps' path check cuts what the instrument cannot sweep, the source's own
    /// direction among it). None for a first pass of points.
    pub fn first_pass_sweeps(&self) -> Option<Vec<SweepSpec>> {
        let f = self.spec.first_pass_sweeps?;
        // An arc is open at +-90 degrees (crate::sweep::spec).
        let edge = self.theta_max_deg.min(89.9);
        let arc = toml::Value::Table(toml::Table::from_iter([
            ("from".to_string(), toml::Value::Float(-edge)),
            ("to".to_string(), toml::Value::Float(edge)),
        ]));
        Some(vec![SweepSpec {
            arm: SweptArm::Detector,
            theta_i_deg: toml::Value::Array(self.incidences.iter().map(|t| toml::Value::Float(*t)).collect()),
            theta_o_deg: arc,
            plane_phi_deg: None,
            speed_deg_s: f.speed_deg_s,
            averaging: f.averaging,
            follow: None,
            isotropic: false,
        }])
    }

    /// The width of [`Adaptive::sweep_bin`]'s bins in theta (degrees): half of `resolution_deg` (module doc).
    pub fn sweep_bin_deg(&self) -> f64 {
        self.spec.resolution_deg / 2.0
    }

    /// The geometry a sweep reading at `g` counts at: theta_i and theta_o rounded to [`Adaptive::sweep_bin_deg`],
    /// delta_phi to a millidegree, in the canonical frame
    /// (phi_i = 0, theta_i <= theta_o). Readings in one bin (bands, directions, neighbouring readings) become
    /// one value: thousands of readings a sweep would otherwise outweigh every point near them.
    pub fn sweep_bin(&self, g: &Geometry) -> Geometry {
        let w = self.sweep_bin_deg();
        let [ti, to, dp] = canonical(g);
        let round = |x: f64, step: f64| (x / step).round() * step;
        Geometry::new(round(ti, w), 0.0, round(to, w), round(dp, 1e-3))
    }
}
