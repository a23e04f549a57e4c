//! The teacher's losses, for both learners: how an update weighs the
//! labels ([`Teaching`]), DQfD's large margin and the imitation loss, as
//! the fused path's per-row gradients and in stock candle ops (the generic
//! path, and the reference the fused path is tested against).

use candle_core::{D, Tensor};
use rotorhive_msg::{label_action, label_mask};

use crate::Result;

/// How the teacher's labels weigh in an update, against the TD loss (the
/// learner sets it at every minibatch from `[teacher]`, its fade and
/// `learner.td_weight`). The default is the plain TD update.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Teaching {
    /// Weight of the TD loss (1: as without a teacher).
    pub td: f32,
    /// Weight of DQfD's large-margin loss on rows labelled with one action.
    pub margin: f32,
    /// Weight of the imitation loss on labelled rows: the cross-entropy of
    /// the softmax of the Q-values over `temperature` toward the actions
    /// the label allows, `logsumexp_a z_a − logsumexp_{a ∈ E} z_a` with
    /// z = Q / temperature (0 where every action is allowed: ties are not
    /// broken).
    pub imitation: f32,
    /// The imitation loss's temperature, in the network's units (scaled
    /// rewards): a Q-value gap of a few temperatures satisfies it.
    pub temperature: f32,
}

impl Default for Teaching {
    fn default() -> Self {
        Self { td: 1.0, margin: 0.0, imitation: 0.0, temperature: 1.0 }
    }
}

impl Teaching {
    /// The margin loss at `weight` alone beside the full TD loss.
    pub fn margin(weight: f32) -> Self {
        Self { margin: weight, ..Self::default() }
    }
}

/// The imitation loss of one row's Q-values `q` at temperature `tau`
/// toward the actions in `mask` (bit `a`: action `a` allowed), and its
/// gradient added into `grad` (softmax − the softmax renormalised over the
/// allowed actions, over `tau`) scaled by `k`.
pub(crate) fn imitation_row(q: &[f32], mask: u8, tau: f32, k: f32, grad: &mut [f32]) -> f32 {
    let top = q.iter().fold(f32::NEG_INFINITY, |m, v| m.max(*v));
    let e: Vec<f32> = q.iter().map(|v| ((v - top) / tau).exp()).collect();
    let k = k / tau;
    let all: f32 = e.iter().sum();
    let allowed: f32 =
        e.iter().enumerate().filter(|(a, _)| mask >> a & 1 == 1).map(|(_, v)| v).sum();
    for (a, g) in grad.iter_mut().enumerate() {
        let inside = if mask >> a & 1 == 1 { e[a] / allowed } else { 0.0 };
        *g += k * (e[a] / all - inside);
    }
    all.ln() - allowed.ln()
}

/// The imitation loss `logsumexp_a z_a − logsumexp_{a ∈ E} z_a` (z = Q /
/// `tau`) summed over the rows of `q` (`[rows][actions]`) whose label `labels[i]`
/// allows some actions (see [`label_mask`]; the others masked out), in
/// stock candle ops (the generic path of both learners, and the reference
/// the fused path is tested against); none where no row is labelled.
pub(crate) fn imitation_sum(q: &Tensor, labels: &[f32], tau: f32) -> Result<Option<Tensor>> {
    let (n, na, dev) = (labels.len(), q.dim(D::Minus1)?, q.device());
    let masks: Vec<u8> = labels.iter().map(|l| label_mask(*l, na).unwrap_or(0)).collect();
    if masks.iter().all(|m| *m == 0) {
        return Ok(None);
    }
    // Disallowed actions drop out of the second log-sum-exp by a large
    // negative offset; unlabelled rows count 0 through the row mask.
    let mut off = vec![0f32; n * na];
    for (i, m) in masks.iter().enumerate() {
        for a in 0..na {
            off[i * na + a] = if *m == 0 || m >> a & 1 == 1 { 0.0 } else { -1e4 };
        }
    }
    let rows: Vec<f32> = masks.iter().map(|m| (*m != 0) as u8 as f32).collect();
    let off = Tensor::from_vec(off, (n, na), dev)?;
    let q = q.affine(1.0 / tau as f64, 0.0)?;
    let lse = |t: &Tensor| -> Result<Tensor> {
        let top = t.max_keepdim(D::Minus1)?.detach();
        Ok((t.broadcast_sub(&top)?.exp()?.sum_keepdim(D::Minus1)?.log()? + top)?)
    };
    let per_row = (lse(&q)? - lse(&(&q + off)?)?)?;
    Ok(Some((per_row * Tensor::from_vec(rows, (n, 1), dev)?)?.sum_all()?))
}

/// DQfD's large-margin loss `max_a [Q(s,a) + l(a_E,a)] − Q(s,a_E)` summed
/// over the rows of `q` (`[rows][actions]`) whose label `experts[i]` names
/// one action (the others masked out), in stock candle ops (the generic
/// path of both learners); none where no row is labelled so.
pub(crate) fn margin_sum(q: &Tensor, experts: &[f32], margin: f32) -> Result<Option<Tensor>> {
    if experts.iter().all(|e| label_action(*e).is_none()) {
        return Ok(None);
    }
    let (n, na, dev) = (experts.len(), q.dim(D::Minus1)?, q.device());
    let (mut l, mut mask, mut ae) = (vec![0f32; n * na], vec![0f32; n], vec![0u32; n]);
    for (i, e) in experts.iter().enumerate().filter_map(|(i, e)| Some((i, label_action(*e)?))) {
        (mask[i], ae[i]) = (1.0, e as u32);
        l[i * na..(i + 1) * na].iter_mut().enumerate().for_each(|(a, v)| {
            *v = if a == e { 0.0 } else { margin };
        });
    }
    let l = Tensor::from_vec(l, (n, na), dev)?;
    let best = (q + l)?.max_keepdim(D::Minus1)?;
    let qe = q.gather(&Tensor::from_vec(ae, (n, 1), dev)?, D::Minus1)?;
    Ok(Some(((best - qe)? * Tensor::from_vec(mask, (n, 1), dev)?)?.sum_all()?))
}
