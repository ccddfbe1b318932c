//! The priority queue of [`super::route`]'s erosion and routing passes: the keys known when a
//! pass starts (its seeds) as one **sorted run**, sorted in parallel, and a binary heap for the
//! keys pushed while it runs; each pop takes the first of the two heads.
//!
//! Why: on the Stanford bunny a step starts each pass with ≈ 55 k seeds, and pushing them one
//! by one into a binary heap, then popping each (a sift of ~17 levels with a cache miss each),
//! was serial work that a parallel sort does on both cores; the heap then holds only the keys
//! the pass discovers. The keys come out in exactly a single binary heap's order (every key,
//! duplicates included, smallest first, or largest for [`Order::Max`]; of two equal keys it does
//! not matter which comes first), so the passes' results are unchanged to the bit. The same
//! scheme as [`super::settle`]'s sweep.

use std::cmp::Reverse;
use std::collections::BinaryHeap;

use rayon::prelude::*;

/// Which key comes out first.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum Order {
    /// The smallest (a min-heap).
    Min,
    /// The largest (a max-heap).
    Max,
}

/// A sorted run of seed keys and a binary heap of later ones (module doc). Keys are stored
/// complemented for [`Order::Max`], so both parts are kept smallest first.
#[derive(Debug, Clone)]
pub(super) struct SeededQueue {
    order: Order,
    /// The seed keys ([`SeededQueue::seed`]), sorted by [`SeededQueue::sort_seeds`].
    run: Vec<u64>,
    /// The next key of `run` to take out.
    next: usize,
    /// The keys pushed after the seeds were sorted.
    heap: BinaryHeap<Reverse<u64>>,
    /// The run is sorted: keys pushed now go to the heap.
    sorted: bool,
}

impl SeededQueue {
    pub(super) fn new(order: Order) -> Self {
        Self {
            order,
            run: Vec::new(),
            next: 0,
            heap: BinaryHeap::new(),
            sorted: false,
        }
    }

    /// The key as stored (ascending order).
    #[inline(always)]
    fn stored(&self, key: u64) -> u64 {
        match self.order {
            Order::Min => key,
            Order::Max => !key,
        }
    }

    /// Empty, keeping the allocations; the next keys are seeds again.
    pub(super) fn clear(&mut self) {
        self.run.clear();
        self.next = 0;
        self.heap.clear();
        self.sorted = false;
    }

    /// Add a seed key (before [`SeededQueue::sort_seeds`]; after it, the same as `push`).
    #[inline]
    pub(super) fn seed(&mut self, key: u64) {
        if self.sorted {
            self.push(key);
        } else {
            let x = self.stored(key);
            self.run.push(x);
        }
    }

    /// Sort the seeds (rayon); keys pushed from now on go to the heap.
    pub(super) fn sort_seeds(&mut self) {
        if !self.sorted {
            self.run.par_sort_unstable();
            self.sorted = true;
        }
    }

    #[inline]
    pub(super) fn push(&mut self, key: u64) {
        debug_assert!(self.sorted, "seeds not sorted");
        let x = self.stored(key);
        self.heap.push(Reverse(x));
    }

    /// Take out the first key (smallest, or largest for [`Order::Max`]).
    #[inline]
    pub(super) fn pop(&mut self) -> Option<u64> {
        debug_assert!(self.sorted, "seeds not sorted");
        let x = match (self.run.get(self.next), self.heap.peek()) {
            (Some(&a), Some(&Reverse(b))) if b < a => self.heap.pop().map(|r| r.0)?,
            (Some(&a), _) => {
                self.next += 1;
                a
            }
            (None, Some(_)) => self.heap.pop().map(|r| r.0)?,
            (None, None) => return None,
        };
        Some(self.stored(x))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A small deterministic generator (xorshift64*).
    fn next(s: &mut u64) -> u64 {
        *s ^= *s >> 12;
        *s ^= *s << 25;
        *s ^= *s >> 27;
        s.wrapping_mul(0x2545_F491_4F6C_DD1D)
    }

    /// The same keys out, in the same order, as one `BinaryHeap` holding them all: seeds, then
    /// pushes interleaved with pops, keys on both sides of the last one out, duplicates, both
    /// orders, and reuse after `clear`.
    #[test]
    fn pops_in_binary_heap_order() {
        for order in [Order::Min, Order::Max] {
            let mut s = 0x9E37_79B9_7F4A_7C15u64;
            let mut q = SeededQueue::new(order);
            // The reference holds keys in ascending order of "comes out first".
            let as_min = |k: u64| if order == Order::Min { k } else { !k };
            for round in 0..4 {
                q.clear();
                let mut reference: BinaryHeap<Reverse<u64>> = BinaryHeap::new();
                let mut keys = Vec::new();
                for _ in 0..2_000 * round {
                    let k = next(&mut s) % 50_000;
                    keys.push(k);
                    // Some duplicates.
                    if k % 7 == 0 {
                        keys.push(k);
                    }
                }
                for &k in &keys {
                    q.seed(as_min(k));
                    reference.push(Reverse(k));
                }
                q.sort_seeds();
                let mut popped = 0;
                for step in 0..20_000 {
                    if next(&mut s) % 5 < 2 {
                        let k = next(&mut s) % 60_000;
                        q.push(as_min(k));
                        reference.push(Reverse(k));
                    } else {
                        let want = reference.pop().map(|Reverse(k)| as_min(k));
                        assert_eq!(q.pop(), want, "round {round}, step {step}");
                        popped += usize::from(want.is_some());
                    }
                }
                assert!(popped > 1_000);
                while let Some(Reverse(k)) = reference.pop() {
                    assert_eq!(q.pop(), Some(as_min(k)));
                }
                assert_eq!(q.pop(), None);
            }
        }
    }
}
