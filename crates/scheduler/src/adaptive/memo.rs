//! Each fixed candidate's nearest measured points, kept from one batch to the next.
//!
//! A batch needs, for every candidate of the grid (tens of thousands at a 2.5-degree resolution), its `K`
//! nearest measured points. Between two batches only the last pass's points are new, so a candidate's
//! neighbours change only where a new point comes closer than its `K`-th: the memo keeps every candidate's
//! neighbours and compares it with the new points alone. An adaptive campaign's rehearsals (eight, each placing
//! every pass) spent two thirds of their time querying the tree again for every candidate at every batch.
//!
//! The neighbours are the `K` smallest by (squared distance, index of the measured point), the order the k-d tree
//! breaks ties in too, so the memo's rows are exactly what the tree would find; a call whose measured points do
//! not extend the memo's (a value changed, a resumed run) starts the rows afresh.

use super::K;
use super::dist2;
use super::neighbours::KdTree;

/// Up to this many new points, each candidate is compared with each; above it, a k-d tree over the new points
/// is queried (a first pass of sweeps brings thousands of binned readings at once).
const COMPARE_ALL_MAX: usize = 64;

/// An unused entry of a row: sorts after every real neighbour.
const EMPTY: (f64, u32) = (f64::INFINITY, u32::MAX);

/// The planner's memory between batches: hold one per run (or rehearsal) and pass it to every batch. A fresh
/// memo gives the same batches; it only makes the later ones cheaper.
#[derive(Debug, Clone, Default)]
pub struct BatchMemo {
    /// The candidates the rows are for (embeddings): a memo handed to another planner starts afresh.
    candidates: Vec<[f64; 6]>,
    /// The measured points the rows were made from: (embedding, ln(1 + f)).
    seen: Vec<([f64; 6], f64)>,
    /// `K` entries per fixed candidate: (squared distance, index into `seen`), ascending by (distance, index),
    /// unused ones [`EMPTY`].
    rows: Vec<(f64, u32)>,
}

/// Whether neighbour `a` comes before `b`: nearer, or as near and measured first.
fn before(a: (f64, u32), b: (f64, u32)) -> bool {
    a.0 < b.0 || (a.0 == b.0 && a.1 < b.1)
}

/// Puts `e` into the sorted row if it is among the `K` first.
fn insert(row: &mut [(f64, u32)], e: (f64, u32)) {
    let last = row.len() - 1;
    if !before(e, row[last]) {
        return;
    }
    let at = row.partition_point(|x| before(*x, e));
    row.copy_within(at..last, at + 1);
    row[at] = e;
}

impl BatchMemo {
    /// A memo that has seen nothing yet.
    pub fn new() -> BatchMemo {
        BatchMemo::default()
    }

    /// Brings every candidate's row up to `points` (embedding, ln(1 + f)), in the planner's order.
    pub(super) fn update(&mut self, candidates: &[[f64; 6]], points: &[([f64; 6], f64)]) {
        let same_point =
            |a: &[f64; 6], b: &[f64; 6]| a.iter().zip(b).all(|(x, y)| x.to_bits() == y.to_bits());
        let same = |a: &([f64; 6], f64), b: &([f64; 6], f64)| {
            a.1.to_bits() == b.1.to_bits() && same_point(&a.0, &b.0)
        };
        let extends = self.candidates.len() == candidates.len()
            && self
                .candidates
                .iter()
                .zip(candidates)
                .all(|(a, b)| same_point(a, b))
            && self.seen.len() <= points.len()
            && self.seen.iter().zip(points).all(|(a, b)| same(a, b));
        if !extends {
            self.candidates = candidates.to_vec();
            self.seen.clear();
            self.rows.clear();
            self.rows.resize(candidates.len() * K, EMPTY);
        }
        let from = self.seen.len();
        let new = &points[from..];
        if new.is_empty() {
            return;
        }
        // Indices past u32 cannot be told apart; no campaign comes near (a budget is points of instrument time).
        let index = |o: usize| u32::try_from(from + o).unwrap_or(u32::MAX - 1);
        if new.len() <= COMPARE_ALL_MAX {
            for (row, c) in self.rows.chunks_exact_mut(K).zip(candidates) {
                for (o, (p, _)) in new.iter().enumerate() {
                    insert(row, (dist2(c, p), index(o)));
                }
            }
        } else {
            let tree = KdTree::new(new.to_vec());
            let mut near = Vec::with_capacity(K + 1);
            for (row, c) in self.rows.chunks_exact_mut(K).zip(candidates) {
                tree.nearest_ids(c, K, &mut near);
                for &(d2, slot) in &near {
                    insert(row, (d2, index(tree.ids[slot])));
                }
            }
        }
        self.seen.extend_from_slice(new);
    }

    /// Candidate `j`'s nearest measured points as (squared distance, ln(1 + f)), nearest first.
    pub(super) fn nearest(&self, j: usize) -> impl Iterator<Item = (f64, f64)> + '_ {
        self.rows
            .get(j * K..(j + 1) * K)
            .unwrap_or_default()
            .iter()
            .filter_map(|&(d2, i)| self.seen.get(i as usize).map(|p| (d2, p.1)))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};

    fn random_points(rng: &mut rand_chacha::ChaCha8Rng, n: usize, grid: bool) -> Vec<([f64; 6], f64)> {
        (0..n)
            .map(|_| {
                let mut p = [0.0; 6];
                for x in &mut p {
                    // On a coarse grid many distances tie: the order of ties is what is tested.
                    *x = if grid {
                        f64::from(rng.random_range(0..4u8))
                    } else {
                        rng.random_range(-1.0..1.0)
                    };
                }
                (p, rng.random_range(0.0..3.0))
            })
            .collect()
    }

    /// The rows a memo builds in steps (small and large, so both ways of adding points) are the k-d tree's
    /// neighbours over all the points at once, ties included.
    #[test]
    fn rows_built_pass_by_pass_are_the_trees_neighbours_over_every_point() {
        for grid in [false, true] {
            let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
            let candidates: Vec<[f64; 6]> = random_points(&mut rng, 300, grid).iter().map(|p| p.0).collect();
            let points = random_points(&mut rng, 400, grid);
            let mut memo = BatchMemo::new();
            for end in [3, 40, 41, 200, 230, 400] {
                memo.update(&candidates, &points[..end]);
                let tree = KdTree::new(points[..end].to_vec());
                let mut near = Vec::new();
                for (j, c) in candidates.iter().enumerate() {
                    tree.nearest(c, K, &mut near);
                    let rows: Vec<(f64, f64)> = memo.nearest(j).collect();
                    assert_eq!(rows, near, "grid {grid}, {end} points, candidate {j}");
                }
            }
            // Other candidates of the same number (another planner) start the rows afresh.
            let others: Vec<[f64; 6]> = random_points(&mut rng, 300, grid).iter().map(|p| p.0).collect();
            memo.update(&others, &points);
            let tree = KdTree::new(points.clone());
            let mut near = Vec::new();
            for (j, c) in others.iter().enumerate() {
                tree.nearest(c, K, &mut near);
                assert_eq!(
                    memo.nearest(j).collect::<Vec<_>>(),
                    near,
                    "grid {grid}, other candidates"
                );
            }
            memo.update(&candidates, &points);
            // A changed value starts the rows afresh rather than keeping a stale neighbour.
            let mut changed = points.clone();
            changed[5].1 += 1.0;
            memo.update(&candidates, &changed);
            let tree = KdTree::new(changed.clone());
            let mut near = Vec::new();
            for (j, c) in candidates.iter().enumerate() {
                tree.nearest(c, K, &mut near);
                assert_eq!(memo.nearest(j).collect::<Vec<_>>(), near);
            }
        }
    }

    /// The tree's neighbours are the K smallest by (distance, input index), whatever the tree's shape.
    #[test]
    fn the_trees_neighbours_are_the_nearest_in_input_order_among_ties() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        let points = random_points(&mut rng, 500, true);
        let tree = KdTree::new(points.clone());
        let mut near = Vec::new();
        for q in random_points(&mut rng, 100, true) {
            let mut all: Vec<(f64, usize)> = points
                .iter()
                .enumerate()
                .map(|(i, p)| (dist2(&q.0, &p.0), i))
                .collect();
            all.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
            let want: Vec<(f64, f64)> = all[..K].iter().map(|&(d2, i)| (d2, points[i].1)).collect();
            tree.nearest(&q.0, K, &mut near);
            assert_eq!(near, want);
        }
    }
}
