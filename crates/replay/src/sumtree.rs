//! A sum-tree over the replay memory's rows: each leaf holds a row's
//! priority (already raised to alpha), each inner node the sum of its two
//! children, so that drawing a row with probability proportional to its
//! priority and changing one priority both cost O(log capacity). Written
//! here rather than taken from a crate: the ones on crates.io (e.g.
//! `sum-tree`) are generic trees of other shape; this one is a flat array of
//! f64 in the usual layout (root at 1, children of i at 2i and 2i + 1).

/// Sums of priorities over a power-of-two number of leaves.
#[derive(Debug, Clone)]
pub struct SumTree {
    leaves: usize,
    nodes: Vec<f64>,
}

impl SumTree {
    /// A tree of at least `capacity` leaves, all zero.
    pub fn new(capacity: usize) -> Self {
        let leaves = capacity.max(1).next_power_of_two();
        Self { leaves, nodes: vec![0.0; 2 * leaves] }
    }

    /// Sets leaf `i` to `value` (finite, non-negative) and updates the sums above it.
    pub fn set(&mut self, i: usize, value: f64) {
        let mut at = self.leaves + i;
        self.nodes[at] = value;
        while at > 1 {
            at /= 2;
            self.nodes[at] = self.nodes[2 * at] + self.nodes[2 * at + 1];
        }
    }

    /// The value of leaf `i`.
    pub fn get(&self, i: usize) -> f64 {
        self.nodes[self.leaves + i]
    }

    /// The sum of every leaf.
    pub fn total(&self) -> f64 {
        self.nodes[1]
    }

    /// The leaf whose cumulative range holds `u` (0 ≤ u < total): leaf i is
    /// found for u in [sum of leaves before i, that sum + leaf i). A `u` at
    /// or past the total (rounding) gives the last leaf with a value.
    pub fn find(&self, mut u: f64) -> usize {
        let mut at = 1;
        while at < self.leaves {
            let left = self.nodes[2 * at];
            // Never descend into an empty subtree, whatever the rounding.
            if (u < left && left > 0.0) || self.nodes[2 * at + 1] <= 0.0 {
                at *= 2;
            } else {
                u -= left;
                at = 2 * at + 1;
            }
        }
        at - self.leaves
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sums_and_finds_by_cumulative_priority() {
        let mut t = SumTree::new(5);
        for (i, v) in [1.0, 0.0, 2.0, 3.0, 4.0].into_iter().enumerate() {
            t.set(i, v);
        }
        assert_eq!(t.total(), 10.0);
        // Ranges: leaf 0 [0, 1), leaf 2 [1, 3), leaf 3 [3, 6), leaf 4 [6, 10).
        let found: Vec<usize> = [0.0, 0.99, 1.0, 2.5, 3.0, 5.99, 6.0, 9.99, 10.0, 50.0]
            .iter()
            .map(|u| t.find(*u))
            .collect();
        assert_eq!(found, vec![0, 0, 2, 2, 3, 3, 4, 4, 4, 4]);
        t.set(4, 0.0);
        assert_eq!((t.total(), t.find(9.0)), (6.0, 3), "an empty leaf is never found");
        assert_eq!(t.get(3), 3.0);
    }
}
