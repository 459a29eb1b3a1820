//! Visiting order of a plan's poses: a short path through all of them on the true move-time metric
//! ([`TimeModel::fast_cost_s`], asymmetric because of backlash, infinite for moves the arms cannot make).
//!
//! 1. Constructive: the best of raster order, a serpentine over the slowest axis, and nearest neighbour (over
//!    k-nearest neighbour lists found by a pruned sweep along the slowest axis; a full scan only when every
//!    neighbour of the current node is already visited).
//! 2. Local search until no move improves: 2-opt (segment reversal; the reversed segment's cost is exact thanks
//!    to prefix sums of forward and backward edge costs) and Or-opt (move a run of 1-3 nodes elsewhere), both
//!    over neighbour lists. Every accepted move strictly lowers the exact path cost, so the result is never
//!    worse than the best starting tour, and in particular never worse than raster order.
//! 3. Iterated local search: a local search driven by a queue of the nodes whose edges changed, converged fully,
//!    then a fixed number of kicks (swap two adjacent runs of a few nodes, repair locally, keep the result only
//!    if strictly cheaper; count fixed by the plan's size, seeded generator: reproducible). Only for plans of
//!    8 to [`MATRIX_MAX`] poses, which cache the whole cost matrix for it.
//!
//! The path is open: it starts at `start` (or anywhere, at no cost, when no start is given) and ends anywhere,
//! or, with [`order_towards`], where leaving it costs least: the move after the last node (`exit_s`, per node)
//! is part of the path's cost (a schedule that closes with normalisation readings at the reference pose).
//!
//! # Lower bound ([`lower_bound_s`])
//! Every node except the first visited is entered at least once by a move from another node's pose (or from the
//! start pose, or from a reference pose). For node v let `LB(v)` be the minimum, over all candidate poses c of v
//! and all possible predecessors u (any candidate pose of any other node, the start pose, the reference arms),
//! of `TimeModel::lower_bound_s(u, c)`, which is itself <= any real move from u to c (each axis that moves needs
//! at least its direct trapezoidal time plus its settle time; backlash and two-phase moves only add). Hence
//! total move time >= sum_v LB(v) - max_v LB(v) (the first node may be entered for free when no start pose is
//! given; with a start pose, the start is one of the predecessors and nothing is subtracted). The minimum is
//! found exactly by a sweep over the poses sorted by the slowest axis, stopped once that axis alone needs more
//! time than the best found so far.

//!
//! The constructive heuristics, [`order`] and [`lower_bound_s`] live here; the local search (2-opt, Or-opt and
//! the iterated search) in `search`.

mod search;

use search::{Search, iterated_local_search};

use crate::kinematics::{Pose, ROLES};
use crate::timing::{TimeModel, trapezoid_time_s};

/// Neighbours kept per node.
const NEIGHBOURS: usize = 10;
/// Local search rounds at most (each round is a full 2-opt and Or-opt sweep).
const MAX_ROUNDS: usize = 50;
/// Relative gain below which the local search stops.
const MIN_ROUND_GAIN: f64 = 2e-3;
/// Iterated local search budget: kicks x nodes at most this (so about the same work at every size). On the
/// 104-geometry plan-demo campaign, 500 kicks take the path from 88.1 s to 85.9 s (the assignment lower bound is
/// 82.2 s) in about 0.1 s; 20,000 kicks only reach 85.7 s.
const ILS_WORK: usize = 50_000;
/// Kicks at most.
const ILS_MAX_KICKS: usize = 1_000;
/// Plans up to this many poses keep the whole cost matrix (8 MB at the limit).
const MATRIX_MAX: usize = 1000;
/// Longest run moved by one kick.
const KICK_SPAN: usize = 10;

/// The role index (into [`ROLES`]) whose travel over the poses' spread takes longest.
fn key_axis(poses: &[Pose], time: &TimeModel) -> usize {
    let mut best = (0usize, -1.0f64);
    for (k, m) in time.axes.iter().enumerate() {
        let Some(m) = m else { continue };
        let (lo, hi) = poses
            .iter()
            .map(|p| p.get(ROLES[k]))
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), v| {
                (lo.min(v), hi.max(v))
            });
        let t = if hi >= lo {
            trapezoid_time_s(hi - lo, m.max_speed_deg_s, m.accel_deg_s2)
        } else {
            0.0
        };
        if t > best.1 {
            best = (k, t);
        }
    }
    best.0
}

fn key_time(time: &TimeModel, k: usize, d: f64) -> f64 {
    time.axes[k]
        .as_ref()
        .map_or(0.0, |m| trapezoid_time_s(d, m.max_speed_deg_s, m.accel_deg_s2))
}

/// For each node, up to `k` other nodes nearest on the lower-bound metric.
fn neighbour_lists(poses: &[Pose], k: usize, time: &TimeModel) -> Vec<Vec<usize>> {
    let n = poses.len();
    let axis = key_axis(poses, time);
    let role = ROLES[axis];
    let mut sorted: Vec<usize> = (0..n).collect();
    sorted.sort_by(|a, b| poses[*a].get(role).total_cmp(&poses[*b].get(role)));
    let mut out = vec![Vec::new(); n];
    for (s, &i) in sorted.iter().enumerate() {
        let mut best: Vec<(f64, usize)> = Vec::with_capacity(k + 1);
        let worst = |best: &Vec<(f64, usize)>| {
            if best.len() < k {
                f64::INFINITY
            } else {
                best[best.len() - 1].0
            }
        };
        for dir in [-1i64, 1] {
            let mut t = s as i64 + dir;
            while t >= 0 && (t as usize) < n {
                let j = sorted[t as usize];
                let dk = (poses[j].get(role) - poses[i].get(role)).abs();
                if key_time(time, axis, dk) >= worst(&best) {
                    break;
                }
                let c = time.lower_bound_s(&poses[i], &poses[j]);
                if c < worst(&best) {
                    let at = best.partition_point(|(d, _)| *d <= c);
                    best.insert(at, (c, j));
                    best.truncate(k);
                }
                t += dir;
            }
        }
        out[i] = best.into_iter().map(|(_, j)| j).collect();
    }
    out
}

/// Exact cost of a path through `tour`, and of leaving its last node (`exit_s[node]`; empty: leaving is free).
pub fn path_cost_towards(
    tour: &[usize],
    poses: &[Pose],
    start: Option<&Pose>,
    exit_s: &[f64],
    time: &TimeModel,
) -> f64 {
    let exit = tour.last().and_then(|l| exit_s.get(*l)).copied().unwrap_or(0.0);
    path_cost(tour, poses, start, time) + exit
}

/// Exact cost of a path through `tour`.
pub fn path_cost(tour: &[usize], poses: &[Pose], start: Option<&Pose>, time: &TimeModel) -> f64 {
    let mut c = match (start, tour.first()) {
        (Some(s), Some(&f)) => time.fast_cost_s(s, &poses[f]),
        _ => 0.0,
    };
    for w in tour.windows(2) {
        c += time.fast_cost_s(&poses[w[0]], &poses[w[1]]);
    }
    c
}

fn nearest_neighbour(
    poses: &[Pose],
    start: Option<&Pose>,
    neigh: &[Vec<usize>],
    time: &TimeModel,
) -> Vec<usize> {
    let n = poses.len();
    let axis = key_axis(poses, time);
    let role = ROLES[axis];
    // Unvisited nodes as a doubly linked list in key-axis order, for the fallback search.
    let mut sorted: Vec<usize> = (0..n).collect();
    sorted.sort_by(|a, b| poses[*a].get(role).total_cmp(&poses[*b].get(role)));
    let mut rank = vec![0usize; n];
    for (r, &v) in sorted.iter().enumerate() {
        rank[v] = r;
    }
    let mut prev: Vec<usize> = (0..n).map(|r| r.wrapping_sub(1)).collect();
    let mut next: Vec<usize> = (0..n).map(|r| r + 1).collect();
    let mut visited = vec![false; n];
    let first = match start {
        Some(s) => (0..n).min_by(|a, b| {
            time.fast_cost_s(s, &poses[*a])
                .total_cmp(&time.fast_cost_s(s, &poses[*b]))
        }),
        None => sorted.first().copied(),
    };
    let Some(mut cur) = first else { return Vec::new() };
    let mut tour = Vec::with_capacity(n);
    loop {
        visited[cur] = true;
        let r = rank[cur];
        let (p, q) = (prev[r], next[r]);
        if p != usize::MAX {
            next[p] = q;
        }
        if q < n {
            prev[q] = p;
        }
        // Neighbours of the removed rank must skip it: keep the nearest unvisited ranks reachable from r too.
        prev[r] = p;
        next[r] = q;
        tour.push(cur);
        if tour.len() == n {
            break;
        }
        let mut best: Option<(f64, usize)> = None;
        for &j in &neigh[cur] {
            if !visited[j] {
                let c = time.fast_cost_s(&poses[cur], &poses[j]);
                if best.is_none_or(|(b, _)| c < b) {
                    best = Some((c, j));
                }
            }
        }
        if best.is_none() {
            // Sweep outwards along the key axis over unvisited nodes only, stopping once that axis alone needs
            // more time than the best move found.
            let here = poses[cur].get(role);
            let mut lo = p;
            let mut hi = q;
            loop {
                let bound = best.map_or(f64::INFINITY, |(b, _)| b);
                let dl = (lo != usize::MAX).then(|| (here - poses[sorted[lo]].get(role)).abs());
                let dh = (hi < n).then(|| (poses[sorted[hi]].get(role) - here).abs());
                let take_low = match (dl, dh) {
                    (None, None) => break,
                    (Some(a), Some(b)) => a <= b,
                    (Some(_), None) => true,
                    (None, Some(_)) => false,
                };
                let (r, d) = if take_low {
                    (lo, dl.unwrap_or(0.0))
                } else {
                    (hi, dh.unwrap_or(0.0))
                };
                if key_time(time, axis, d) >= bound {
                    break;
                }
                let j = sorted[r];
                let c = time.fast_cost_s(&poses[cur], &poses[j]);
                if best.is_none_or(|(b, _)| c < b) {
                    best = Some((c, j));
                }
                if take_low {
                    lo = prev[lo];
                } else {
                    hi = next[hi];
                }
            }
        }
        match best {
            Some((_, j)) => cur = j,
            None => break,
        }
    }
    tour
}

/// Serpentine: sweep the slowest axis in groups of equal value, alternating the direction of the next one.
fn serpentine(poses: &[Pose], time: &TimeModel) -> Vec<usize> {
    let a = key_axis(poses, time);
    let second = (0..4)
        .filter(|k| *k != a && time.axes[*k].is_some())
        .max_by(|x, y| {
            let spread = |k: usize| {
                let (lo, hi) = poses
                    .iter()
                    .map(|p| p.get(ROLES[k]))
                    .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), v| {
                        (lo.min(v), hi.max(v))
                    });
                key_time(time, k, hi - lo)
            };
            spread(*x).total_cmp(&spread(*y))
        })
        .unwrap_or(a);
    let q = |v: f64| (v * 1e6).round() as i64;
    let mut idx: Vec<usize> = (0..poses.len()).collect();
    idx.sort_by(|i, j| {
        q(poses[*i].get(ROLES[a])).cmp(&q(poses[*j].get(ROLES[a]))).then(
            poses[*i]
                .get(ROLES[second])
                .total_cmp(&poses[*j].get(ROLES[second])),
        )
    });
    let mut out = Vec::with_capacity(idx.len());
    let mut group: Vec<usize> = Vec::new();
    let mut forward = true;
    let flush = |group: &mut Vec<usize>, forward: &mut bool, out: &mut Vec<usize>| {
        if !*forward {
            group.reverse();
        }
        out.append(group);
        *forward = !*forward;
    };
    for i in idx {
        if let Some(&g) = group.first()
            && q(poses[g].get(ROLES[a])) != q(poses[i].get(ROLES[a]))
        {
            flush(&mut group, &mut forward, &mut out);
        }
        group.push(i);
    }
    flush(&mut group, &mut forward, &mut out);
    out
}

/// An order of `poses` (indices) minimising the total move time from `start`. Never worse than raster order.
pub fn order(poses: &[Pose], start: Option<&Pose>, time: &TimeModel) -> Vec<usize> {
    order_towards(poses, start, &[], time)
}

/// [`order`], the move after the last node counted: `exit_s[v]` is what leaving the path from node `v` costs
/// (s), for every node; empty, leaving is free (an open end).
pub fn order_towards(poses: &[Pose], start: Option<&Pose>, exit_s: &[f64], time: &TimeModel) -> Vec<usize> {
    let exit_s = if exit_s.len() == poses.len() { exit_s } else { &[] };
    let path_cost = |tour: &[usize], poses: &[Pose], start: Option<&Pose>, time: &TimeModel| {
        path_cost_towards(tour, poses, start, exit_s, time)
    };
    let n = poses.len();
    if n <= 2 {
        let raster: Vec<usize> = (0..n).collect();
        let rev: Vec<usize> = (0..n).rev().collect();
        return if path_cost(&rev, poses, start, time) < path_cost(&raster, poses, start, time) {
            rev
        } else {
            raster
        };
    }
    let neigh = neighbour_lists(poses, NEIGHBOURS, time);
    let candidates = [
        (0..n).collect::<Vec<_>>(),
        serpentine(poses, time),
        nearest_neighbour(poses, start, &neigh, time),
    ];
    let mut best = candidates[0].clone();
    let mut best_cost = path_cost(&best, poses, start, time);
    for c in &candidates[1..] {
        if c.len() != n {
            continue;
        }
        let cost = path_cost(c, poses, start, time);
        if cost < best_cost {
            best = c.clone();
            best_cost = cost;
        }
    }
    let mut s = Search::new(poses, start, exit_s, time, best);
    // Stop when a round gains less than MIN_ROUND_GAIN of the path: the tail of tiny improvements costs a lot of
    // time for nothing.
    let mut cost = path_cost(&s.tour, poses, start, time);
    for _ in 0..MAX_ROUNDS {
        let a = s.two_opt_round(&neigh);
        let b = s.or_opt_round(&neigh);
        let now = path_cost(&s.tour, poses, start, time);
        if (!a && !b) || now > cost * (1.0 - MIN_ROUND_GAIN) {
            break;
        }
        cost = now;
    }
    iterated_local_search(&mut s, &neigh);
    let searched = path_cost(&s.tour, poses, start, time);
    if searched <= best_cost {
        s.tour
    } else {
        candidates[0].clone()
    }
}

/// The provable lower bound on total move time (module doc). `nodes[v]` lists node v's candidate poses;
/// `extra` are further possible predecessors of every node (the start pose); `arms_only` are poses of which only
/// the arm angles are known (reference poses: the other axes stay where they were).
pub fn lower_bound_s(
    nodes: &[Vec<Pose>],
    start: Option<&Pose>,
    arms_only: Option<&Pose>,
    time: &TimeModel,
) -> f64 {
    let mut entries: Vec<(usize, Pose)> = Vec::new();
    for (v, cands) in nodes.iter().enumerate() {
        for c in cands {
            entries.push((v, *c));
        }
    }
    if entries.is_empty() {
        return 0.0;
    }
    let poses: Vec<Pose> = entries.iter().map(|e| e.1).collect();
    let axis = key_axis(&poses, time);
    let role = ROLES[axis];
    let mut sorted: Vec<usize> = (0..entries.len()).collect();
    sorted.sort_by(|a, b| entries[*a].1.get(role).total_cmp(&entries[*b].1.get(role)));
    let mut lb = vec![f64::INFINITY; nodes.len()];
    for (s, &e) in sorted.iter().enumerate() {
        let (v, c) = entries[e];
        let mut best = f64::INFINITY;
        if let Some(st) = start {
            best = best.min(time.lower_bound_s(st, &c));
        }
        if let Some(r) = arms_only {
            let mut p = c;
            p.light_deg = r.light_deg;
            p.detector_deg = r.detector_deg;
            best = best.min(time.lower_bound_s(&p, &c));
        }
        for dir in [-1i64, 1] {
            let mut t = s as i64 + dir;
            while t >= 0 && (t as usize) < sorted.len() {
                let (u, cu) = entries[sorted[t as usize]];
                let dk = (cu.get(role) - c.get(role)).abs();
                if key_time(time, axis, dk) >= best {
                    break;
                }
                if u != v {
                    best = best.min(time.lower_bound_s(&cu, &c));
                }
                t += dir;
            }
        }
        lb[v] = lb[v].min(best);
    }
    if nodes.len() == 1 && start.is_none() {
        return 0.0;
    }
    let lb: Vec<f64> = lb
        .into_iter()
        .map(|x| if x.is_finite() { x } else { 0.0 })
        .collect();
    let sum: f64 = lb.iter().sum();
    if start.is_some() {
        sum
    } else {
        sum - lb.iter().copied().fold(0.0, f64::max)
    }
}
