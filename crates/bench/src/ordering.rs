//! Benchmark (item 2, ordering): the ordered plan's motion time against raster order on the shipped demo
//! campaigns, with a lower bound that says how much any order could still gain.
//!
//! - Schedule ratio: `gonio plan`'s own comparison, (motion + settle) of the measure steps in the ordered schedule
//!   over the same in request (raster) order (`schedule::Schedule::{breakdown, raster}`), bands and calibration
//!   steps included as the daemon would run them.
//! - Path ratio: the visiting order alone (`order::order` on the representative poses, `order::path_cost`) over
//!   raster order, on the exact move-time metric.
//! - Assignment bound: the minimum-cost assignment (each pose entered once and left once, a dummy node closing the
//!   open path), solved exactly by the Hungarian algorithm on the same metric. Every path is such an assignment,
//!   so no order can be cheaper: `bound / raster` is the best path ratio any ordering could reach.

use std::path::Path;

use gonio_campaign::Sources;
use gonio_instrument::InstrumentFile;
use gonio_scheduler::kinematics::Pose;
use gonio_scheduler::order;
use gonio_scheduler::schedule::BandMode;
use gonio_scheduler::timing::TimeModel;

#[derive(Debug, Clone)]
pub struct OrderingResult {
    pub campaign: String,
    pub geometries: usize,
    pub points: usize,
    pub mode: BandMode,
    pub schedule_ratio: f64,
    pub ordered_motion_s: f64,
    pub raster_motion_s: f64,
    pub path_s: f64,
    pub raster_path_s: f64,
    pub bound_s: f64,
    pub order_time_s: f64,
}

/// Order one campaign file, prepared as `gonio plan` and `gonio run` prepare it (its material decides isotropy
/// and flatness; its acquisition settings the time model).
pub fn run(file: &InstrumentFile, path: &Path) -> Result<OrderingResult, String> {
    let text = std::fs::read_to_string(path).map_err(|e| format!("{}: {e}", path.display()))?;
    let base = path.parent().map(Path::to_path_buf).unwrap_or_default();
    let prepared =
        gonio_campaign::load_and_prepare(&text, &path.display().to_string(), &Sources::Local(base), file)
            .map_err(|e| e.to_string())?;
    let (plan, time, sched) = (&prepared.plan, &prepared.time, &prepared.schedule);
    let (o, r) = (&sched.breakdown, &sched.raster);
    let reps: Vec<Pose> = plan
        .geometries
        .iter()
        .filter_map(|g| g.candidates.first().map(|c| c.0))
        .collect();
    let start = std::time::Instant::now();
    let tour = order::order(&reps, None, time);
    let order_time_s = start.elapsed().as_secs_f64();
    let raster: Vec<usize> = (0..reps.len()).collect();
    Ok(OrderingResult {
        campaign: path
            .file_name()
            .map_or_else(String::new, |f| f.to_string_lossy().into_owned()),
        geometries: plan.geometries.len(),
        points: plan.kept(),
        mode: sched.mode,
        schedule_ratio: (o.motion_s + o.settle_s) / (r.motion_s + r.settle_s),
        ordered_motion_s: o.motion_s + o.settle_s,
        raster_motion_s: r.motion_s + r.settle_s,
        path_s: order::path_cost(&tour, &reps, None, time),
        raster_path_s: order::path_cost(&raster, &reps, None, time),
        bound_s: assignment_bound(&reps, time),
        order_time_s,
    })
}

/// The assignment lower bound on an open path through `poses` (module doc). O(n^3): for plans of a few hundred
/// poses.
pub fn assignment_bound(poses: &[Pose], time: &TimeModel) -> f64 {
    let n = poses.len() + 1;
    // Forbidden pairs (a pose to itself, moves the arms cannot make) cost more than any path.
    let big = 1e9;
    let cost = |i: usize, j: usize| -> f64 {
        if i == j {
            big
        } else if i == n - 1 || j == n - 1 {
            0.0
        } else {
            let c = time.fast_cost_s(&poses[i], &poses[j]);
            if c.is_finite() { c } else { big }
        }
    };
    // Hungarian algorithm with potentials (rows assigned one by one, shortest augmenting paths), 1-based.
    let mut u = vec![0.0; n + 1];
    let mut v = vec![0.0; n + 1];
    let mut p = vec![0usize; n + 1];
    let mut way = vec![0usize; n + 1];
    for i in 1..=n {
        p[0] = i;
        let mut j0 = 0usize;
        let mut minv = vec![f64::INFINITY; n + 1];
        let mut used = vec![false; n + 1];
        loop {
            used[j0] = true;
            let i0 = p[j0];
            let mut delta = f64::INFINITY;
            let mut j1 = 0usize;
            for j in 1..=n {
                if !used[j] {
                    let cur = cost(i0 - 1, j - 1) - u[i0] - v[j];
                    if cur < minv[j] {
                        minv[j] = cur;
                        way[j] = j0;
                    }
                    if minv[j] < delta {
                        delta = minv[j];
                        j1 = j;
                    }
                }
            }
            for j in 0..=n {
                if used[j] {
                    u[p[j]] += delta;
                    v[j] -= delta;
                } else {
                    minv[j] -= delta;
                }
            }
            j0 = j1;
            if p[j0] == 0 {
                break;
            }
        }
        loop {
            let j1 = way[j0];
            p[j0] = p[j1];
            j0 = j1;
            if j0 == 0 {
                break;
            }
        }
    }
    (1..=n).map(|j| cost(p[j] - 1, j - 1)).sum()
}
