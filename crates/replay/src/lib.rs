//! FIFO replay memory over flat transition storage, with uniform sampling of
//! minibatches. Pure data structure: the `hive replay` role feeds it from the
//! transport and serves minibatches from it.

use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64Mcg;

/// A fixed-capacity FIFO of equally long transitions stored back to back.
#[derive(Debug, Clone)]
pub struct Replay {
    data: Vec<f32>,
    width: usize,
    capacity: usize,
    len: usize,
    head: usize,
    inserted: u64,
    sampled: u64,
    rng: Pcg64Mcg,
}

impl Replay {
    /// A memory of `capacity` transitions of `width` floats each.
    pub fn new(capacity: usize, width: usize, seed: u64) -> Self {
        assert!(capacity > 0 && width > 0, "replay capacity and width must be positive");
        Self { data: vec![0.0; capacity * width], width, capacity, len: 0, head: 0, inserted: 0, sampled: 0, rng: Pcg64Mcg::seed_from_u64(seed) }
    }

    /// Transitions held.
    pub fn len(&self) -> usize {
        self.len
    }

    /// True when empty.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// Capacity in transitions.
    pub fn capacity(&self) -> usize {
        self.capacity
    }

    /// Transitions inserted since creation.
    pub fn inserted(&self) -> u64 {
        self.inserted
    }

    /// Transitions sampled since creation.
    pub fn sampled(&self) -> u64 {
        self.sampled
    }

    /// Appends transitions (a multiple of `width` floats), overwriting the oldest when full.
    pub fn insert(&mut self, transitions: &[f32]) {
        assert_eq!(transitions.len() % self.width, 0, "transition batch is not a whole number of transitions");
        for t in transitions.chunks_exact(self.width) {
            self.data[self.head * self.width..(self.head + 1) * self.width].copy_from_slice(t);
            self.head = (self.head + 1) % self.capacity;
            self.len = (self.len + 1).min(self.capacity);
            self.inserted += 1;
        }
    }

    /// Fills `out` (a multiple of `width` floats) with transitions drawn
    /// uniformly with replacement. Panics when empty.
    pub fn sample_into(&mut self, out: &mut [f32]) {
        assert!(self.len > 0, "cannot sample an empty replay memory");
        for o in out.chunks_exact_mut(self.width) {
            let i = self.rng.random_range(0..self.len);
            o.copy_from_slice(&self.data[i * self.width..(i + 1) * self.width]);
            self.sampled += 1;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fifo_overwrites_the_oldest() {
        let mut r = Replay::new(3, 2, 1);
        r.insert(&[1.0, 1.0, 2.0, 2.0, 3.0, 3.0, 4.0, 4.0]);
        assert_eq!(r.len(), 3);
        assert_eq!(r.inserted(), 4);
        let mut seen = std::collections::BTreeSet::new();
        let mut out = vec![0.0; 2 * 200];
        r.sample_into(&mut out);
        for t in out.chunks(2) {
            assert_eq!(t[0], t[1]);
            seen.insert(t[0] as i32);
        }
        assert_eq!(seen.into_iter().collect::<Vec<_>>(), vec![2, 3, 4]);
    }

    #[test]
    fn sampling_is_roughly_uniform() {
        let mut r = Replay::new(10, 1, 2);
        r.insert(&(0..10).map(|i| i as f32).collect::<Vec<_>>());
        let mut out = vec![0.0; 10_000];
        r.sample_into(&mut out);
        let mut counts = [0; 10];
        for v in out {
            counts[v as usize] += 1;
        }
        assert!(counts.iter().all(|c| (800..1200).contains(c)), "{counts:?}");
        assert_eq!(r.sampled(), 10_000);
    }
}
