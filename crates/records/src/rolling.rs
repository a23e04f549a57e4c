//! The convergence clock: the rolling mean of the last `window` training
//! episodes and its first crossing of the threshold. One definition for
//! `hive train` (as episodes arrive) and `hive bench seeds` (recomputed from
//! `metrics.csv`), so that both give the same time to threshold.

use std::collections::VecDeque;

/// The rolling window of episode returns (and successes).
#[derive(Debug, Clone)]
pub struct Rolling {
    window: usize,
    threshold: f64,
    /// Only episodes acted with an exploration rate at or below this count
    /// (Ape-X's per-agent rates: the old schedule's floor); `None`: all.
    max_epsilon: Option<f32>,
    returns: VecDeque<f32>,
    successes: VecDeque<bool>,
    /// When the mean of a full window first reached the threshold.
    pub crossed_at: Option<f64>,
}

impl Rolling {
    /// A window of `window` episodes, converged at a mean of `threshold`.
    pub fn new(window: usize, threshold: f64, max_epsilon: Option<f32>) -> Self {
        Self {
            window,
            threshold,
            max_epsilon,
            returns: VecDeque::with_capacity(window),
            successes: VecDeque::with_capacity(window),
            crossed_at: None,
        }
    }

    /// Whether an episode acted with exploration rate `epsilon` counts.
    pub fn counts(&self, epsilon: f32) -> bool {
        self.max_epsilon.is_none_or(|m| epsilon <= m + 1e-6)
    }

    /// Adds an episode that ended at `wall`; true when the window has just
    /// reached the threshold for the first time.
    pub fn push(&mut self, wall: f64, ret: f32, success: bool, epsilon: f32) -> bool {
        if !self.counts(epsilon) {
            return false;
        }
        if self.returns.len() == self.window {
            self.returns.pop_front();
            self.successes.pop_front();
        }
        self.returns.push_back(ret);
        self.successes.push_back(success);
        if self.crossed_at.is_none()
            && self.returns.len() == self.window
            && self.mean() >= self.threshold
        {
            self.crossed_at = Some(wall);
            return true;
        }
        false
    }

    /// Mean return of the window (NaN before any episode).
    pub fn mean(&self) -> f64 {
        if self.returns.is_empty() {
            f64::NAN
        } else {
            self.returns.iter().map(|v| *v as f64).sum::<f64>() / self.returns.len() as f64
        }
    }

    /// Share of the window's episodes that reached the goal.
    pub fn success_rate(&self) -> Option<f64> {
        (!self.successes.is_empty()).then(|| {
            self.successes.iter().filter(|s| **s).count() as f64 / self.successes.len() as f64
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_clock_stops_at_the_first_full_window_at_the_threshold() {
        let mut r = Rolling::new(3, 300.0, None);
        // Two great episodes do not fill the window.
        assert!(!r.push(1.0, 400.0, true, 1.0));
        assert!(!r.push(2.0, 400.0, true, 1.0));
        assert!(r.crossed_at.is_none());
        assert!(r.push(3.0, 400.0, true, 1.0));
        assert!(!r.push(4.0, 400.0, true, 1.0), "only the first crossing counts");
        assert_eq!(r.crossed_at, Some(3.0));
        // With a floor, exploring agents' episodes are left out.
        let mut f = Rolling::new(2, 300.0, Some(0.1));
        assert!(!f.push(1.0, -100.0, false, 0.4));
        assert!(!f.push(2.0, 444.0, true, 0.1));
        assert!(f.push(3.0, 444.0, true, 0.01));
        assert_eq!((f.mean(), f.success_rate()), (444.0, Some(1.0)));
    }
}
