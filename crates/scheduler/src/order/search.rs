//! The local search over a tour: 2-opt and Or-opt rounds over neighbour lists (exact costs from prefix sums of
//! forward and backward edge costs), the queue-driven variant, and the iterated local search that kicks and
//! repairs it.

use super::{ILS_MAX_KICKS, ILS_WORK, KICK_SPAN, MATRIX_MAX, NEIGHBOURS};
use crate::kinematics::Pose;
use crate::timing::TimeModel;

/// The search state: tour, positions, and prefix sums of forward and backward edge costs.
pub(super) struct Search<'a> {
    poses: &'a [Pose],
    start: Option<&'a Pose>,
    time: &'a TimeModel,
    pub(super) tour: Vec<usize>,
    pos: Vec<usize>,
    fwd: Vec<f64>,
    bwd: Vec<f64>,
    /// Successor of each node in the last refreshed tour, with the edge's cost both ways.
    succ: Vec<usize>,
    succ_f: Vec<f64>,
    succ_b: Vec<f64>,
    /// Scratch buffers for `refresh` (swapped with the three above).
    next_succ: Vec<usize>,
    next_f: Vec<f64>,
    next_b: Vec<f64>,
    /// All pairwise move costs, row-major, for plans small enough ([`MATRIX_MAX`]): the iterated search
    /// evaluates the same pairs many times and `fast_cost_s` takes a fraction of a microsecond.
    matrix: Option<Vec<f64>>,
    /// The move from the start pose to each node: a move from the start is weighed at every change near the
    /// tour's front, and `fast_cost_s` (with its check of the arms' paths) is the search's costliest call.
    from_start: Vec<f64>,
    /// What leaving the path from each node costs when it is the last (empty: nothing).
    exit_s: &'a [f64],
}

impl<'a> Search<'a> {
    pub(super) fn new(
        poses: &'a [Pose],
        start: Option<&'a Pose>,
        exit_s: &'a [f64],
        time: &'a TimeModel,
        tour: Vec<usize>,
    ) -> Search<'a> {
        let n = poses.len();
        let mut s = Search {
            poses,
            start,
            time,
            tour,
            pos: vec![0; n],
            fwd: Vec::new(),
            bwd: Vec::new(),
            succ: Vec::new(),
            succ_f: Vec::new(),
            succ_b: Vec::new(),
            next_succ: Vec::new(),
            next_f: Vec::new(),
            next_b: Vec::new(),
            matrix: None,
            from_start: start.map_or_else(Vec::new, |s| {
                poses.iter().map(|p| time.fast_cost_s(s, p)).collect()
            }),
            exit_s,
        };
        if n <= MATRIX_MAX {
            let mut m = Vec::with_capacity(n * n);
            for a in poses {
                for b in poses {
                    m.push(time.fast_cost_s(a, b));
                }
            }
            s.matrix = Some(m);
        }
        s.refresh();
        s
    }

    fn c(&self, a: usize, b: usize) -> f64 {
        match &self.matrix {
            Some(m) => m[a * self.poses.len() + b],
            None => self.time.fast_cost_s(&self.poses[a], &self.poses[b]),
        }
    }

    /// Cost of entering position `i` from its predecessor (the start pose, or nothing, at position 0).
    fn c_enter(&self, pred: Option<usize>, node: usize) -> f64 {
        match (pred, self.start) {
            (Some(p), _) => self.c(p, node),
            (None, Some(_)) => self.from_start[node],
            (None, None) => 0.0,
        }
    }

    /// Cost of leaving `node` by the edge to `next`, or, as the path's last node, of leaving the path.
    fn c_leave(&self, node: usize, next: Option<usize>) -> f64 {
        match next {
            Some(x) => self.c(node, x),
            None => self.exit_s.get(node).copied().unwrap_or(0.0),
        }
    }

    /// Exact cost of the current tour (after `refresh`).
    fn cost(&self) -> f64 {
        match (self.tour.first(), self.tour.last()) {
            (Some(&f), Some(&l)) => {
                self.c_enter(None, f) + self.fwd[self.tour.len() - 1] + self.c_leave(l, None)
            }
            _ => 0.0,
        }
    }

    /// Recompute positions and prefix sums after the tour changed. Edge costs are reused from the previous tour
    /// wherever the same pair of nodes is still adjacent (either way round), so a local change costs a few
    /// cost evaluations plus O(n) additions.
    fn refresh(&mut self) {
        let n = self.tour.len();
        for (k, &v) in self.tour.iter().enumerate() {
            self.pos[v] = k;
        }
        self.fwd.resize(n, 0.0);
        self.bwd.resize(n, 0.0);
        if n == 0 {
            return;
        }
        let mut succ = std::mem::take(&mut self.next_succ);
        let mut cf = std::mem::take(&mut self.next_f);
        let mut cb = std::mem::take(&mut self.next_b);
        succ.clear();
        succ.resize(n, usize::MAX);
        cf.clear();
        cf.resize(n, 0.0);
        cb.clear();
        cb.resize(n, 0.0);
        self.fwd[0] = 0.0;
        self.bwd[0] = 0.0;
        for k in 1..n {
            let (a, b) = (self.tour[k - 1], self.tour[k]);
            let (f, r) = if self.succ.get(a) == Some(&b) {
                (self.succ_f[a], self.succ_b[a])
            } else if self.succ.get(b) == Some(&a) {
                (self.succ_b[b], self.succ_f[b])
            } else {
                (self.c(a, b), self.c(b, a))
            };
            succ[a] = b;
            cf[a] = f;
            cb[a] = r;
            self.fwd[k] = self.fwd[k - 1] + f;
            self.bwd[k] = self.bwd[k - 1] + r;
        }
        self.next_succ = std::mem::replace(&mut self.succ, succ);
        self.next_f = std::mem::replace(&mut self.succ_f, cf);
        self.next_b = std::mem::replace(&mut self.succ_b, cb);
    }

    /// Gain of reversing positions i..=j (positive = better).
    fn two_opt_gain(&self, i: usize, j: usize) -> f64 {
        let pred = if i > 0 { Some(self.tour[i - 1]) } else { None };
        let (ti, tj) = (self.tour[i], self.tour[j]);
        let next = self.tour.get(j + 1).copied();
        let old = self.c_enter(pred, ti) + (self.fwd[j] - self.fwd[i]) + self.c_leave(tj, next);
        let new = self.c_enter(pred, tj) + (self.bwd[j] - self.bwd[i]) + self.c_leave(ti, next);
        if !new.is_finite() {
            return f64::NEG_INFINITY;
        }
        old - new
    }

    /// The best improving segment reversal with position `i` at one end of the segment, applied. Returns the
    /// nodes whose edges changed.
    fn two_opt_at(&mut self, i: usize, neigh: &[Vec<usize>]) -> Option<[usize; 4]> {
        let n = self.tour.len();
        let mut best: Option<(f64, usize, usize)> = None;
        // New edge pred(i) -> v, with v = tour[j], j > i.
        if i > 0 {
            for &v in &neigh[self.tour[i - 1]] {
                let j = self.pos[v];
                if j > i {
                    let g = self.two_opt_gain(i, j);
                    if g > 1e-9 && best.is_none_or(|b| g > b.0) {
                        best = Some((g, i, j));
                    }
                }
            }
        }
        // New edge tour[k] -> succ(i), with the reversed segment k..=i, k < i.
        if i + 1 < n {
            for &v in &neigh[self.tour[i + 1]] {
                let k = self.pos[v];
                if k < i {
                    let g = self.two_opt_gain(k, i);
                    if g > 1e-9 && best.is_none_or(|b| g > b.0) {
                        best = Some((g, k, i));
                    }
                }
            }
        } else {
            // Reversing a suffix: its new last node leaves the path.
            for k in 0..i.min(NEIGHBOURS) {
                let g = self.two_opt_gain(i - 1 - k, i);
                if g > 1e-9 && best.is_none_or(|b| g > b.0) {
                    best = Some((g, i - 1 - k, i));
                }
            }
        }
        let (_, a, b) = best?;
        let at = |p: Option<usize>| p.and_then(|p| self.tour.get(p)).copied().unwrap_or(usize::MAX);
        let touched = [at(a.checked_sub(1)), self.tour[a], self.tour[b], at(Some(b + 1))];
        self.tour[a..=b].reverse();
        self.refresh();
        Some(touched)
    }

    /// The best improving move of a run of 1-3 nodes starting at position `i` to another place (kept in its
    /// direction), applied. Returns the nodes whose edges changed.
    fn or_opt_at(&mut self, i: usize, neigh: &[Vec<usize>]) -> Option<[usize; 6]> {
        let n = self.tour.len();
        for len in 1..=3usize {
            if i + len > n || len >= n {
                break;
            }
            let (s0, s1) = (self.tour[i], self.tour[i + len - 1]);
            let pred = if i > 0 { Some(self.tour[i - 1]) } else { None };
            let next = self.tour.get(i + len).copied();
            // Taken out, its predecessor joins its successor, or becomes the last node.
            let joined = match (next, pred) {
                (Some(x), _) => self.c_enter(pred, x),
                (None, Some(p)) => self.c_leave(p, None),
                (None, None) => 0.0,
            };
            let removed = self.c_enter(pred, s0) + self.c_leave(s1, next) - joined;
            let mut best: Option<(f64, usize)> = None; // insert after position p (p = usize::MAX: at front)
            let consider = |after: Option<usize>, best: &mut Option<(f64, usize)>| {
                // after = position of the node the segment follows; it must lie outside the segment.
                if let Some(p) = after
                    && (i..i + len).contains(&p)
                {
                    return;
                }
                if after.map(|p| p + 1) == Some(i) || (after.is_none() && i == 0) {
                    return;
                }
                let a = after.map(|p| self.tour[p]);
                let b = match after {
                    Some(p) => self.tour.get(p + 1).copied(),
                    None => self.tour.first().copied(),
                };
                let b = b.filter(|x| *x != s0);
                // Put in after the last node, the run leaves the path instead of it.
                let split = match (b, a) {
                    (Some(x), _) => self.c_enter(a, x),
                    (None, Some(a)) => self.c_leave(a, None),
                    (None, None) => 0.0,
                };
                let added = self.c_enter(a, s0) + self.c_leave(s1, b) - split;
                let gain = removed - added;
                if gain.is_finite() && gain > 1e-9 && best.is_none_or(|(g, _)| gain > g) {
                    *best = Some((gain, after.unwrap_or(usize::MAX)));
                }
            };
            for &v in &neigh[s0] {
                consider(Some(self.pos[v]), &mut best);
            }
            for &v in &neigh[s1] {
                let p = self.pos[v];
                consider(if p == 0 { None } else { Some(p - 1) }, &mut best);
            }
            if let Some((_, after)) = best {
                let node = |p: usize| self.tour.get(p).copied().unwrap_or(usize::MAX);
                let (a, b) = if after == usize::MAX {
                    (usize::MAX, node(0))
                } else {
                    (node(after), node(after + 1))
                };
                let touched = [
                    pred.unwrap_or(usize::MAX),
                    next.unwrap_or(usize::MAX),
                    s0,
                    s1,
                    a,
                    b,
                ];
                let at = if after == usize::MAX {
                    0
                } else if after < i {
                    after + 1
                } else {
                    after + 1 - len
                };
                // Move the run: rotate the span between its old and new places.
                if at < i {
                    self.tour[at..i + len].rotate_right(len);
                } else {
                    self.tour[i..at + len].rotate_left(len);
                }
                self.refresh();
                return Some(touched);
            }
        }
        None
    }

    pub(super) fn two_opt_round(&mut self, neigh: &[Vec<usize>]) -> bool {
        let mut improved = false;
        for i in 0..self.tour.len() {
            improved |= self.two_opt_at(i, neigh).is_some();
        }
        improved
    }

    pub(super) fn or_opt_round(&mut self, neigh: &[Vec<usize>]) -> bool {
        let mut improved = false;
        let mut i = 0;
        while i < self.tour.len() {
            if self.or_opt_at(i, neigh).is_some() {
                improved = true;
            } else {
                i += 1;
            }
        }
        improved
    }

    /// Local search driven by a queue of nodes whose surroundings changed ("don't look bits"): each node is
    /// examined for a 2-opt move at its position and an Or-opt move of a run containing it; every applied move
    /// queues the nodes whose edges it changed. Stops when the queue is empty: no move around any queued node
    /// improves the path.
    fn queue_search(&mut self, neigh: &[Vec<usize>], queue: &mut Vec<usize>, queued: &mut [bool]) {
        let n = self.tour.len();
        while let Some(v) = queue.pop() {
            queued[v] = false;
            let i = self.pos[v];
            let mut touched: Vec<usize> = Vec::new();
            if let Some(t) = self.two_opt_at(i, neigh) {
                touched.extend(t);
            } else {
                for back in 0..3usize {
                    if let Some(start) = i.checked_sub(back)
                        && let Some(t) = self.or_opt_at(start, neigh)
                    {
                        touched.extend(t);
                        break;
                    }
                }
            }
            if touched.is_empty() {
                continue;
            }
            touched.push(v);
            for u in touched {
                if u < n && !queued[u] {
                    queued[u] = true;
                    queue.push(u);
                }
            }
        }
    }
}

/// SplitMix64: a small deterministic generator for the perturbations (the order must be reproducible).
struct SplitMix(u64);

impl SplitMix {
    fn next(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    /// Uniform in 0..n (n > 0).
    fn below(&mut self, n: usize) -> usize {
        (self.next() % n as u64) as usize
    }
}

/// Iterated local search: from the best tour so far, swap two adjacent runs of at most [`KICK_SPAN`] nodes
/// (a "double bridge" restricted to a window, which keeps the direction of every run: the right kick for
/// asymmetric costs), repair with [`Search::queue_search`] from the nodes around the cut points, and keep the
/// result if it is strictly cheaper. The number of kicks is fixed by the size (no clock), so the order is
/// reproducible.
pub(super) fn iterated_local_search(s: &mut Search, neigh: &[Vec<usize>]) {
    let n = s.tour.len();
    // Large plans: the rounds already took most of the gain (on a 10,206-pose grid, converging fully and kicking
    // gained 0.1% for 2.4 times the time); their cost matrix would not fit either.
    if !(8..=MATRIX_MAX).contains(&n) {
        return;
    }
    let kicks = (ILS_WORK / n).min(ILS_MAX_KICKS);
    let mut rng = SplitMix(0x5EED ^ n as u64);
    // Converge fully first (the rounds stop early): every node starts queued.
    let mut queued = vec![true; n];
    let mut queue: Vec<usize> = (0..n).collect();
    s.queue_search(neigh, &mut queue, &mut queued);
    let mut best = s.tour.clone();
    let mut best_cost = s.cost();
    for _ in 0..kicks {
        let span = KICK_SPAN.min(n / 3).max(1);
        let l1 = 1 + rng.below(span);
        let l2 = 1 + rng.below(span);
        if l1 + l2 > n {
            continue;
        }
        let a = rng.below(n - l1 - l2 + 1);
        let c = a + l1 + l2;
        s.tour[a..c].rotate_left(l1);
        s.refresh();
        for p in [a.wrapping_sub(1), a, a + l2 - 1, a + l2, c - 1, c] {
            if let Some(&v) = s.tour.get(p)
                && !queued[v]
            {
                queued[v] = true;
                queue.push(v);
            }
        }
        s.queue_search(neigh, &mut queue, &mut queued);
        let cost = s.cost();
        if cost < best_cost - 1e-9 {
            best_cost = cost;
            best.clone_from(&s.tour);
        } else {
            s.tour.clone_from(&best);
            s.refresh();
        }
    }
    s.tour = best;
    s.refresh();
}
