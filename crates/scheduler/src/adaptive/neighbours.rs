//! Nearest measured points in the embedding: the k-d tree behind the error estimate's K-nearest queries, and the
//! inverse-distance interpolation over the neighbours it finds.

use super::dist2;

pub(super) fn reconstruct_embedded(near: &[(f64, f64)]) -> f64 {
    let mut wsum = 0.0;
    let mut vsum = 0.0;
    for (d2, u) in near {
        if *d2 < 1e-18 {
            return *u;
        }
        let w = 1.0 / d2;
        wsum += w;
        vsum += w * u;
    }
    if wsum > 0.0 { vsum / wsum } else { 0.0 }
}

/// A k-d tree over embedded points with their values (implicit layout: each range's median is its node), for the
/// K-nearest queries of the estimate and the interpolation: O(log n) per query instead of a scan of every
/// measured point, which made a 3,000-point campaign's batches cost minutes.
pub(super) struct KdTree {
    /// (point, value, index in the input).
    pts: Vec<([f64; 6], f64, usize)>,
    /// Input index of the point at each slot.
    pub(super) ids: Vec<usize>,
    /// Split axis of the node at each index.
    axis: Vec<u8>,
}

impl KdTree {
    pub(super) fn new(pts: Vec<([f64; 6], f64)>) -> KdTree {
        let mut pts: Vec<([f64; 6], f64, usize)> =
            pts.into_iter().enumerate().map(|(i, (p, u))| (p, u, i)).collect();
        let mut axis = vec![0u8; pts.len()];
        Self::build(&mut pts, &mut axis);
        let ids = pts.iter().map(|p| p.2).collect();
        KdTree { pts, ids, axis }
    }

    fn build(pts: &mut [([f64; 6], f64, usize)], axis: &mut [u8]) {
        if pts.len() <= 1 {
            return;
        }
        // Split on the coordinate of largest spread.
        let mut best = (0usize, -1.0f64);
        for a in 0..6 {
            let (lo, hi) = pts
                .iter()
                .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), p| {
                    (lo.min(p.0[a]), hi.max(p.0[a]))
                });
            if hi - lo > best.1 {
                best = (a, hi - lo);
            }
        }
        let a = best.0;
        let m = pts.len() / 2;
        pts.select_nth_unstable_by(m, |x, y| x.0[a].total_cmp(&y.0[a]));
        axis[m] = a as u8;
        let (left, right) = pts.split_at_mut(m);
        let (al, ar) = axis.split_at_mut(m);
        Self::build(left, al);
        Self::build(&mut right[1..], &mut ar[1..]);
    }

    /// The `k` nearest points to `q` as (squared distance, value), nearest first, into `out`. Points at equal
    /// distances are taken in their input order ([`KdTree::nearest_ids`]).
    pub(super) fn nearest(&self, q: &[f64; 6], k: usize, out: &mut Vec<(f64, f64)>) {
        let mut slots = Vec::with_capacity(k + 1);
        self.nearest_ids(q, k, &mut slots);
        out.clear();
        out.extend(slots.iter().map(|&(d2, slot)| (d2, self.pts[slot].1)));
    }

    /// The `k` nearest points to `q` as (squared distance, slot), nearest first; `ids[slot]` is the input index.
    /// Points at equal distances come in their input order, so that the set does not depend on the tree's shape:
    /// the batches' memo ([`super::memo`]) finds the same neighbours without it.
    pub(super) fn nearest_ids(&self, q: &[f64; 6], k: usize, out: &mut Vec<(f64, usize)>) {
        out.clear();
        if k > 0 {
            self.search(0, self.pts.len(), q, k, out);
        }
    }

    fn search(&self, lo: usize, hi: usize, q: &[f64; 6], k: usize, out: &mut Vec<(f64, usize)>) {
        if lo >= hi {
            return;
        }
        let m = lo + (hi - lo) / 2;
        let p = &self.pts[m].0;
        let d = dist2(q, p);
        let key = |(d2, slot): (f64, usize)| (d2, self.pts[slot].2);
        let new = (d, self.pts[m].2);
        let before = |e: &(f64, usize)| {
            let (x, i) = key(*e);
            x < new.0 || (x == new.0 && i < new.1)
        };
        if out.len() < k || !before(&out[out.len() - 1]) {
            let at = out.partition_point(before);
            out.insert(at, (d, m));
            out.truncate(k);
        }
        let a = usize::from(self.axis[m]);
        let diff = q[a] - p[a];
        let (first, second) = if diff < 0.0 {
            ((lo, m), (m + 1, hi))
        } else {
            ((m + 1, hi), (lo, m))
        };
        self.search(first.0, first.1, q, k, out);
        // A point exactly as far as the k-th may still come before it in input order.
        if out.len() < k || diff * diff <= out[out.len() - 1].0 {
            self.search(second.0, second.1, q, k, out);
        }
    }
}
