//! A minibatch of stored sequences as the recurrent learner takes it, and
//! the checks it passes before an update.

use rotorhive_msg::label_mask;

use crate::{ModelError, Result, Shapes};

/// A minibatch of stored sequences, each its own contiguous block (as a
/// replay keeps them). A sequence of `steps` transitions has `steps + 1`
/// observations: the last is the bootstrap's.
#[derive(Debug, Clone, Copy)]
pub struct SeqBatch<'a> {
    /// Sequences in the batch.
    pub sequences: usize,
    /// Transitions per sequence.
    pub steps: usize,
    /// Observations, `[sequences][steps + 1][obs_len]`.
    pub obs: &'a [f32],
    /// Actions taken, `[sequences][steps]`.
    pub actions: &'a [u8],
    /// Rewards, `[sequences][steps]`.
    pub rewards: &'a [f32],
    /// Whether the episode ended at a step, `[sequences][steps]`: the next
    /// observation starts a new episode, from a zeroed state.
    pub dones: &'a [bool],
    /// The state each sequence started from (its actor's there),
    /// `[sequences][width]`.
    pub states: &'a [f32],
    /// The teacher's action at each step ([`NO_EXPERT`](rotorhive_msg::NO_EXPERT): none),
    /// `[sequences][steps]`; empty: no step labelled.
    pub experts: &'a [f32],
    /// Each sequence's importance weight (prioritized replay),
    /// `[sequences]`; empty: all 1.
    pub weights: &'a [f32],
}

impl SeqBatch<'_> {
    /// Checks every length, action and value against a network of `shapes`
    /// and `width`, and that `burn_in` leaves a step to train.
    pub(super) fn check(&self, shapes: Shapes, width: usize, burn_in: usize) -> Result<()> {
        let (n, t) = (self.sequences, self.steps);
        let lens = [
            ("sequence observations", n * (t + 1) * shapes.obs_len(), self.obs.len()),
            ("sequence actions", n * t, self.actions.len()),
            ("sequence rewards", n * t, self.rewards.len()),
            ("sequence dones", n * t, self.dones.len()),
            ("sequence states", n * width, self.states.len()),
        ];
        for (what, expected, got) in lens {
            if expected != got {
                return Err(ModelError::Shape { what, expected, got });
            }
        }
        if burn_in >= t {
            return Err(ModelError::Shape {
                what: "sequence steps (more than the burn-in)",
                expected: burn_in + 1,
                got: t,
            });
        }
        if n == 0 {
            return Err(ModelError::Shape { what: "sequences", expected: 1, got: 0 });
        }
        if let Some(&a) = self.actions.iter().find(|&&a| a as usize >= shapes.actions) {
            return Err(ModelError::Shape {
                what: "sequence action (one of the actions)",
                expected: shapes.actions,
                got: a as usize,
            });
        }
        if !self.experts.is_empty() && self.experts.len() != n * t {
            return Err(ModelError::Shape {
                what: "sequence expert actions",
                expected: n * t,
                got: self.experts.len(),
            });
        }
        if !self.weights.is_empty() && self.weights.len() != n {
            return Err(ModelError::Shape {
                what: "sequence importance weights",
                expected: n,
                got: self.weights.len(),
            });
        }
        if let Some(&e) = self.experts.iter().find(|&&e| label_mask(e, shapes.actions).is_none()) {
            return Err(ModelError::Shape {
                what: "sequence label (none, one of the actions or a set of them)",
                expected: shapes.actions,
                got: e as usize,
            });
        }
        let finite = |v: &[f32]| v.iter().all(|x| x.is_finite());
        let weights_ok = finite(self.weights) && self.weights.iter().all(|w| *w >= 0.0);
        if !(finite(self.obs) && finite(self.rewards) && finite(self.states) && weights_ok) {
            return Err(ModelError::Shape {
                what: "sequence values (finite)",
                expected: 0,
                got: 1,
            });
        }
        Ok(())
    }
}
