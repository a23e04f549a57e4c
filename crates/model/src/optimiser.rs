//! The update policy both learners share ([`Optimiser`]): Adam over flat
//! moments, the learning rate's linear decay, the gradient's global-norm
//! clipping, skip-and-count of an update whose loss or gradient is not
//! finite, and the target network's cadence. The feedforward update
//! ([`crate::Dqn`]) and the recurrent one ([`crate::SeqDqn`]) differ in
//! their losses only.

use std::sync::Mutex;

use candle_core::{Tensor, Var};

use crate::Result;
use crate::ops::{AdamHyper, AdamStep, adam};

/// The settings of the update policy.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Schedule {
    /// Adam's learning rate at the first step.
    pub lr: f32,
    /// The learning rate reached after `decay` steps (held from then on).
    pub lr_final: f32,
    /// Steps over which the rate falls from `lr` to `lr_final`; 0 keeps `lr`.
    pub decay: u64,
    /// The gradient's global L2 norm is clipped to this; 0 = no clipping.
    pub max_grad_norm: f32,
    /// Updates between target-network copies (skipped ones count).
    pub target_update: u64,
}

/// Adam without weight decay; the moments are plain vectors so that the
/// fused path updates every parameter in place in one pass.
pub(crate) struct Adam {
    lr: f32,
    lr_final: f32,
    decay: u64,
    pub(crate) t: u64,
    pub(crate) m: Vec<Vec<f32>>,
    pub(crate) v: Vec<Vec<f32>>,
}

impl Adam {
    /// Adam at `s.lr` falling to `s.lr_final` over `s.decay` steps, for
    /// parameters of `sizes` floats each (in canonical order).
    fn new(s: &Schedule, sizes: impl Iterator<Item = usize> + Clone) -> Self {
        Self {
            lr: s.lr,
            lr_final: s.lr_final,
            decay: s.decay,
            t: 0,
            m: sizes.clone().map(|n| vec![0.0; n]).collect(),
            v: sizes.map(|n| vec![0.0; n]).collect(),
        }
    }

    /// The learning rate of step `t` (from 1): linear from `lr` to `lr_final`
    /// over `decay` steps.
    pub(crate) fn lr_at(&self, t: u64) -> f32 {
        if self.decay == 0 {
            return self.lr;
        }
        let frac = ((t - 1) as f64 / self.decay as f64).min(1.0) as f32;
        self.lr + (self.lr_final - self.lr) * frac
    }

    /// One step of `vars` (in canonical order) with their gradients, flat in
    /// the same order: in place on the CPU.
    pub(crate) fn step_vars(&mut self, vars: &[Var], grads: &[f32]) -> Result<()> {
        self.t += 1;
        let hyper =
            AdamHyper { lr: self.lr_at(self.t), beta1: 0.9, beta2: 0.999, eps: 1e-8, t: self.t };
        let mut off = 0;
        for ((var, m), v) in vars.iter().zip(&mut self.m).zip(&mut self.v) {
            let g = &grads[off..off + m.len()];
            off += m.len();
            if var.device().is_cpu() {
                var.as_tensor().inplace_op1(&AdamStep {
                    grad: g,
                    moments: Mutex::new((m.as_mut_slice(), v.as_mut_slice())),
                    hyper,
                })?;
            } else {
                let mut p = var.as_tensor().flatten_all()?.to_vec1::<f32>()?;
                adam(&mut p, g, m, v, hyper);
                var.set(&Tensor::from_vec(p, var.shape(), var.device())?)?;
            }
        }
        Ok(())
    }
}

/// What one update did.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Step {
    /// The gradient's global L2 norm before clipping (NaN where none was
    /// computed).
    pub grad_norm: f64,
    /// False where the update was skipped: its loss or gradient was not
    /// finite, so the weights and Adam's moments stayed as they were.
    pub applied: bool,
    /// The target network is due a copy of the online one.
    pub sync_target: bool,
}

impl Step {
    /// The loss an update reports for `loss`: itself, or NaN where a
    /// finite loss was skipped for its gradient, so that a skip always
    /// reads as a loss that is not finite.
    pub(crate) fn reported(&self, loss: f32) -> f32 {
        if self.applied || !loss.is_finite() { loss } else { f32::NAN }
    }
}

/// Adam, its schedule, clipping, skip-and-count and the target's cadence:
/// the one update policy of both learners.
pub(crate) struct Optimiser {
    pub(crate) adam: Adam,
    max_grad_norm: f32,
    target_update: u64,
    /// Updates made, skipped ones included (the target's and a
    /// deterministic run's schedules go on through a skip).
    pub(crate) updates: u64,
    /// Updates skipped for a non-finite loss or gradient.
    pub(crate) skipped: u64,
}

impl Optimiser {
    /// The policy of `s` for parameters of `sizes` floats each (in
    /// canonical order).
    pub(crate) fn new(s: Schedule, sizes: impl Iterator<Item = usize> + Clone) -> Self {
        Self {
            adam: Adam::new(&s, sizes),
            max_grad_norm: s.max_grad_norm,
            target_update: s.target_update.max(1),
            updates: 0,
            skipped: 0,
        }
    }

    /// One update of `vars` with the loss `loss` and its gradient `grads`
    /// (flat in canonical order; `None` where the loss was not finite and
    /// none was computed): counted; skipped and counted where the loss or
    /// the gradient's norm is not finite; else the gradient clipped to
    /// `max_grad_norm` and Adam's step taken.
    pub(crate) fn step(
        &mut self,
        vars: &[Var],
        grads: Option<&mut [f32]>,
        loss: f32,
    ) -> Result<Step> {
        self.updates += 1;
        let sync_target = self.updates.is_multiple_of(self.target_update);
        let norm = grads
            .as_deref()
            .map_or(f64::NAN, |g| g.iter().map(|g| (*g as f64) * (*g as f64)).sum::<f64>().sqrt());
        let Some(grads) = grads.filter(|_| loss.is_finite() && norm.is_finite()) else {
            self.skipped += 1;
            return Ok(Step { grad_norm: norm, applied: false, sync_target });
        };
        let max = self.max_grad_norm as f64;
        if max > 0.0 && norm > max {
            let k = (max / norm) as f32;
            grads.iter_mut().for_each(|g| *g *= k);
        }
        self.adam.step_vars(vars, grads)?;
        Ok(Step { grad_norm: norm, applied: true, sync_target })
    }
}
