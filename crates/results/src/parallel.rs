//! Independent work items on the machine's cores, results in the items' order.
//!
//! A campaign's completion fits several models and then evaluates each point's aperture correction: pure
//! computations on shared data, run after the instrument is free. On a lab PC's few cores they split without a
//! thread pool crate: scoped threads take the next item from a shared counter (so a few long items, the model
//! fits, spread as well as many short ones, the points), and the results are put back in order, so the output
//! is the same whatever the number of threads.

use std::sync::atomic::{AtomicUsize, Ordering};

/// `items.iter().map(f).collect()`, computed on up to the machine's available parallelism (at most one thread
/// per item); one item or one core runs in the calling thread.
pub fn map<T: Sync, R: Send>(items: &[T], f: impl Fn(&T) -> R + Sync) -> Vec<R> {
    let threads = std::thread::available_parallelism()
        .map_or(1, usize::from)
        .min(items.len());
    if threads <= 1 {
        return items.iter().map(f).collect();
    }
    let next = AtomicUsize::new(0);
    let work = || {
        let mut done = Vec::new();
        loop {
            let i = next.fetch_add(1, Ordering::Relaxed);
            let Some(item) = items.get(i) else { break };
            done.push((i, f(item)));
        }
        done
    };
    let mut indexed: Vec<(usize, R)> = std::thread::scope(|scope| {
        let helpers: Vec<_> = (1..threads).map(|_| scope.spawn(work)).collect();
        let mut all = work();
        for h in helpers {
            // A panic in `f` is a bug; it is raised here as it would have been without threads.
            match h.join() {
                Ok(done) => all.extend(done),
                Err(panic) => std::panic::resume_unwind(panic),
            }
        }
        all
    });
    indexed.sort_unstable_by_key(|(i, _)| *i);
    indexed.into_iter().map(|(_, r)| r).collect()
}

#[cfg(test)]
mod tests {
    use super::map;

    #[test]
    fn results_come_back_in_the_items_order_whatever_their_cost() {
        // Items of very different cost finish out of order on several threads.
        let items: Vec<u64> = (0..200).rev().collect();
        let slow_square = |&n: &u64| {
            let mut x = 0u64;
            for _ in 0..n * 1000 {
                x = std::hint::black_box(x + 1);
            }
            (n * n, x)
        };
        let serial: Vec<(u64, u64)> = items.iter().map(slow_square).collect();
        assert_eq!(map(&items, slow_square), serial);
    }

    #[test]
    fn no_items_and_one_item() {
        assert!(map(&[] as &[u8], |x| *x).is_empty());
        assert_eq!(map(&[7u8], |x| x + 1), vec![8]);
    }
}
