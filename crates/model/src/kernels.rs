//! The learner's CPU path: the network's forward and backward passes written
//! out over raw `f32` slices, with every buffer allocated once in a
//! [`Workspace`] and every product a `gemm` call.
//!
//! The element-wise passes (bias and ReLU, masks, im2col, pooling and their
//! gradients) are compiled for AVX2 beside the baseline and picked at run
//! time (`multiversion`): the baseline x86-64 build left them scalar, and
//! they were a fifth of an update's time (`perf record` on `hive bench
//! learner --threads 1`). AVX-512 versions of these passes measured slower
//! on this Zen 4 machine and were dropped; the products use gemm's AVX-512
//! kernels.
//!
//! It replaced a chain of candle custom ops (im2col gather, fused linear,
//! pooling, TD-Huber) driven by candle's autograd. Measured side by side
//! (`taskset -c 0 hive bench learner --threads 1`, this 2-core Zen 4 VM),
//! half of that path's time was outside the products: copies of gradients
//! into fresh tensors, autograd's gradient sums, allocation and zeroing.
//! Here the minibatch's observations are read straight from the transition
//! rows into the first layer's patch matrix, the target network's forward
//! keeps nothing, the online network runs `s` and `s'` (double DQN) as one
//! batch, ReLU masks and biases are fused into single passes, the pooling
//! keeps its argmax for the backward pass, and the gradients land in one
//! flat vector in canonical order. The weights stay the candle variables of
//! [`crate::QNet`]; this module only reads them.
//!
//! Activations are channels-last: conv1's output `[B·14·14, 16]`, conv2's
//! `[B·12·12, 32]`, the features `[B, 6·6·32 + 16]` (pooled map, then the
//! velocity branch).

use multiversion::multiversion;

use crate::ops::{View, matmul};
use crate::{C1, C2, FEAT, H1, H2, HID, HP, K1, K2, S1, SIDE, Shapes, VEL_H};

/// Columns of conv1's patch matrix: (frame, ky, kx).
const fn p1(shapes: Shapes) -> usize {
    shapes.frames * K1 * K1
}
/// Columns of conv2's patch matrix: (ky, kx, channel).
const P2: usize = K2 * K2 * C1;
/// Features entering fc1: the pooled map and the velocity branch.
const F: usize = FEAT + VEL_H;

/// The ten parameter slices, in canonical order, and the network's shapes.
pub(crate) struct Weights<'a>(pub(crate) [&'a [f32]; 10], pub(crate) Shapes);

/// Offsets of each parameter in the flat gradient vector of a network for
/// `shapes`.
pub(crate) fn offsets(shapes: Shapes) -> [usize; 11] {
    let (vel, actions, p1) = (shapes.scalars, shapes.actions, p1(shapes));
    let sizes =
        [C1 * p1, C1, C2 * P2, C2, VEL_H * vel, VEL_H, HID * F, HID, actions * HID, actions];
    let mut off = [0; 11];
    for i in 0..10 {
        off[i + 1] = off[i] + sizes[i];
    }
    off
}

/// Observations to read: rows `i < n` at `data[i * stride + offset ..][.. len]`.
#[derive(Clone, Copy)]
pub(crate) struct Rows<'a> {
    pub(crate) data: &'a [f32],
    pub(crate) stride: usize,
    pub(crate) offset: usize,
    pub(crate) n: usize,
    /// Floats per observation.
    pub(crate) len: usize,
}

impl<'a> Rows<'a> {
    /// Contiguous observations of `len` floats.
    pub(crate) fn packed(data: &'a [f32], len: usize) -> Self {
        Self { data, stride: len, offset: 0, n: data.len() / len, len }
    }

    fn row(&self, i: usize) -> &'a [f32] {
        &self.data[i * self.stride + self.offset..][..self.len]
    }
}

/// Every buffer of one forward and backward pass, grown on demand and then
/// reused: no buffer of the passes is allocated per update.
#[derive(Default)]
pub(crate) struct Workspace {
    rows: usize,
    /// The shapes the buffers were sized for.
    shapes: Option<Shapes>,
    cols1: Vec<f32>,
    a1: Vec<f32>,
    cols2: Vec<f32>,
    a2: Vec<f32>,
    arg: Vec<u8>,
    feat: Vec<f32>,
    vel: Vec<f32>,
    h: Vec<f32>,
    /// Q-values of the last forward pass, `[rows, 2]`.
    pub(crate) q: Vec<f32>,
    /// Q-values kept from an earlier pass ([`Workspace::keep_q`]).
    q_kept: Vec<f32>,
    dq: Vec<f32>,
    dh: Vec<f32>,
    dfeat: Vec<f32>,
    da2: Vec<f32>,
    dcols2: Vec<f32>,
    da1: Vec<f32>,
    /// Gradients of the last backward pass, flat in canonical order.
    pub(crate) grads: Vec<f32>,
    /// Per row of the last loss: the absolute TD error.
    pub(crate) td: Vec<f32>,
}

/// The error of a workspace whose lock a panicking thread left poisoned.
pub(crate) fn poisoned<T>(_: T) -> crate::ModelError {
    crate::ModelError::Poisoned
}

fn fit(v: &mut Vec<f32>, len: usize) {
    if v.len() < len {
        v.resize(len, 0.0);
    }
}

/// `y = max(y + b, 0)` for every row of `y`.
#[multiversion(targets("x86_64+avx2+fma+avx"))]
fn bias_relu<const C: usize>(y: &mut [f32], b: &[f32]) {
    let b: &[f32; C] = b.try_into().expect("a bias of the layer's width");
    for row in y.chunks_exact_mut(C) {
        for c in 0..C {
            row[c] = (row[c] + b[c]).max(0.0);
        }
    }
}

/// `g = 0` where the layer's output `y ≤ 0` (ReLU's gradient).
#[multiversion(targets("x86_64+avx2+fma+avx"))]
fn mask(g: &mut [f32], y: &[f32]) {
    g.iter_mut().zip(y).for_each(|(g, y)| *g = if *y > 0.0 { *g } else { 0.0 });
}

/// `g = 0` where the layer's output `y ≤ 0` (ReLU's gradient), and
/// `db += Σ_rows g`.
#[multiversion(targets("x86_64+avx2+fma+avx"))]
fn mask_and_sum<const C: usize>(g: &mut [f32], y: &[f32], db: &mut [f32]) {
    // Two passes: LLVM left the fused loop scalar at C = 16.
    mask(g, y);
    let mut acc = [0f32; C];
    for row in g.as_chunks::<C>().0 {
        for c in 0..C {
            acc[c] += row[c];
        }
    }
    db.iter_mut().zip(acc).for_each(|(d, a)| *d += a);
}

/// conv1's patch rows of one observation: for every output pixel (oy, ox),
/// runs of K1 pixels per (frame, ky).
#[multiversion(targets("x86_64+avx2+fma+avx"))]
fn im2col1(obs: &[f32], frames: usize, out: &mut [f32]) {
    let mut o = 0;
    for oy in 0..H1 {
        for ox in 0..H1 {
            for c in 0..frames {
                for ky in 0..K1 {
                    let s = c * SIDE * SIDE + (oy * S1 + ky) * SIDE + ox * S1;
                    out[o..o + K1].copy_from_slice(&obs[s..s + K1]);
                    o += K1;
                }
            }
        }
    }
}

/// The runs of conv2's im2col for one map: `f(at, o)` for each run of
/// K2·C1 values, `at` its start in the channels-last conv1 map and `o` in
/// the patch matrix.
#[inline(always)]
fn conv2_runs(mut f: impl FnMut(usize, usize)) {
    let mut o = 0;
    for oy in 0..H2 {
        for ox in 0..H2 {
            for ky in 0..K2 {
                f(((oy + ky) * H1 + ox) * C1, o);
                o += K2 * C1;
            }
        }
    }
}

/// The four conv2 positions (rows of its channels-last map) under pooled
/// output (py, px).
#[inline(always)]
fn window(py: usize, px: usize) -> [usize; 4] {
    let r = 2 * py * H2 + 2 * px;
    [r, r + 1, r + H2, r + H2 + 1]
}

/// conv2's patch rows of `n` channels-last maps: runs of K2·C1 values.
#[multiversion(targets("x86_64+avx2+fma+avx"))]
fn im2col2(a1: &[f32], cols: &mut [f32], n: usize) {
    let (hw1, hw2) = (H1 * H1, H2 * H2);
    for s in 0..n {
        let src = &a1[s * hw1 * C1..(s + 1) * hw1 * C1];
        let out = &mut cols[s * hw2 * P2..(s + 1) * hw2 * P2];
        conv2_runs(|at, o| out[o..o + K2 * C1].copy_from_slice(&src[at..at + K2 * C1]));
    }
}

/// The gradient of [`im2col2`]: every run added back where it was read (col2im).
#[multiversion(targets("x86_64+avx2+fma+avx"))]
fn col2im2(dcols: &[f32], da1: &mut [f32], n: usize) {
    let (hw1, hw2) = (H1 * H1, H2 * H2);
    da1[..n * hw1 * C1].fill(0.0);
    for s in 0..n {
        let src = &dcols[s * hw2 * P2..(s + 1) * hw2 * P2];
        let out = &mut da1[s * hw1 * C1..(s + 1) * hw1 * C1];
        conv2_runs(|at, o| {
            let (d, g) = (&mut out[at..at + K2 * C1], &src[o..o + K2 * C1]);
            for j in 0..K2 * C1 {
                d[j] += g[j];
            }
        });
    }
}

/// 2×2 max-pooling of `n` channels-last conv2 maps into the features' head,
/// with the argmax (0..4, the window's first maximum) of every output.
#[multiversion(targets("x86_64+avx2+fma+avx"))]
fn pool(a2: &[f32], feat: &mut [f32], arg: &mut [u8], n: usize) {
    let hw2 = H2 * H2;
    for s in 0..n {
        let x = &a2[s * hw2 * C2..(s + 1) * hw2 * C2];
        let out = &mut feat[s * F..s * F + FEAT];
        let arg = &mut arg[s * FEAT..(s + 1) * FEAT];
        for py in 0..HP {
            for px in 0..HP {
                let [x0, x1, x2, x3] = window(py, px).map(|r| &x[r * C2..(r + 1) * C2]);
                let o = (py * HP + px) * C2;
                let (out, arg) = (&mut out[o..o + C2], &mut arg[o..o + C2]);
                for c in 0..C2 {
                    let (mut best, mut at) = (x0[c], 0u8);
                    (best, at) = if x1[c] > best { (x1[c], 1) } else { (best, at) };
                    (best, at) = if x2[c] > best { (x2[c], 2) } else { (best, at) };
                    (best, at) = if x3[c] > best { (x3[c], 3) } else { (best, at) };
                    out[c] = best;
                    arg[c] = at;
                }
            }
        }
    }
}

/// The gradient of [`pool`]: each pooled gradient to its argmax (`da2` is
/// zeroed first); conv2's bias gradient is their sum, since every pooled
/// gradient lands on exactly one position.
#[multiversion(targets("x86_64+avx2+fma+avx"))]
fn unpool(dfeat: &[f32], arg: &[u8], da2: &mut [f32], db2: &mut [f32], n: usize) {
    let hw2 = H2 * H2;
    da2[..n * hw2 * C2].fill(0.0);
    let mut acc = [0f32; C2];
    for s in 0..n {
        let d = &dfeat[s * F..s * F + FEAT];
        let arg = &arg[s * FEAT..(s + 1) * FEAT];
        let out = &mut da2[s * hw2 * C2..(s + 1) * hw2 * C2];
        for py in 0..HP {
            for px in 0..HP {
                let rows = window(py, px);
                let o = (py * HP + px) * C2;
                for c in 0..C2 {
                    out[rows[arg[o + c] as usize] * C2 + c] = d[o + c];
                    acc[c] += d[o + c];
                }
            }
        }
    }
    db2.iter_mut().zip(acc).for_each(|(b, a)| *b += a);
}

impl Workspace {
    fn reserve(&mut self, rows: usize, shapes: Shapes) {
        if rows <= self.rows && self.shapes == Some(shapes) {
            return;
        }
        (self.rows, self.shapes) = (rows.max(self.rows), Some(shapes));
        let rows = self.rows;
        let (vel, actions) = (shapes.scalars, shapes.actions);
        let hw1 = H1 * H1;
        let hw2 = H2 * H2;
        for (v, len) in [
            (&mut self.cols1, rows * hw1 * p1(shapes)),
            (&mut self.a1, rows * hw1 * C1),
            (&mut self.cols2, rows * hw2 * P2),
            (&mut self.a2, rows * hw2 * C2),
            (&mut self.feat, rows * F),
            (&mut self.vel, rows * vel),
            (&mut self.h, rows * HID),
            (&mut self.q, rows * actions),
            (&mut self.dq, rows * actions),
            (&mut self.dh, rows * HID),
            (&mut self.dfeat, rows * F),
            (&mut self.da2, rows * hw2 * C2),
            (&mut self.dcols2, rows * hw2 * P2),
            (&mut self.da1, rows * hw1 * C1),
        ] {
            fit(v, len);
        }
        self.arg.resize(rows * FEAT, 0);
        fit(&mut self.grads, offsets(shapes)[10]);
    }

    /// Q-values of every row of `parts` (in order) into `self.q`, keeping the
    /// activations for [`Workspace::backward`]. Returns the rows forwarded.
    pub(crate) fn forward(&mut self, w: &Weights, parts: &[Rows]) -> crate::Result<usize> {
        let n: usize = parts.iter().map(|p| p.n).sum();
        self.reserve(n, w.1);
        let [w1, b1, w2, b2, wv, bv, w3, b3, w4, b4] = w.0;
        let (vel, actions) = (w.1.scalars, w.1.actions);
        let (hw1, hw2, p1) = (H1 * H1, H2 * H2, p1(w.1));
        // conv1: patches straight from the observation rows, runs of K1 pixels.
        let mut i = 0;
        for p in parts {
            for r in 0..p.n {
                let obs = p.row(r);
                im2col1(obs, w.1.frames, &mut self.cols1[i * hw1 * p1..(i + 1) * hw1 * p1]);
                // The velocity branch (and the goal's), 3 or 6 → 16, into
                // the features' tail.
                let v = &obs[w.1.obs_depth()..];
                self.vel[i * vel..(i + 1) * vel].copy_from_slice(v);
                let tail = &mut self.feat[i * F + FEAT..(i + 1) * F];
                for (j, t) in tail.iter_mut().enumerate() {
                    let s = bv[j] + (0..vel).map(|k| wv[j * vel + k] * v[k]).sum::<f32>();
                    *t = s.max(0.0);
                }
                i += 1;
            }
        }
        let a1 = &mut self.a1[..n * hw1 * C1];
        matmul(n * hw1, C1, p1, View::rows(&self.cols1, p1), View::transposed(w1, p1), a1, false)?;
        bias_relu::<C1>(a1, b1);
        im2col2(&self.a1, &mut self.cols2, n);
        let a2 = &mut self.a2[..n * hw2 * C2];
        matmul(n * hw2, C2, P2, View::rows(&self.cols2, P2), View::transposed(w2, P2), a2, false)?;
        bias_relu::<C2>(a2, b2);
        pool(&self.a2, &mut self.feat, &mut self.arg, n);
        let h = &mut self.h[..n * HID];
        matmul(n, HID, F, View::rows(&self.feat, F), View::transposed(w3, F), h, false)?;
        bias_relu::<HID>(h, b3);
        for (q, h) in self.q[..n * actions].chunks_exact_mut(actions).zip(h.chunks_exact(HID)) {
            for (a, q) in q.iter_mut().enumerate() {
                *q = b4[a]
                    + w4[a * HID..(a + 1) * HID].iter().zip(h).map(|(w, x)| w * x).sum::<f32>();
            }
        }
        Ok(n)
    }

    /// Keeps the Q-values of the last forward pass's first `n` rows (the
    /// target network's, of `s'`) for [`Workspace::loss_view`].
    pub(crate) fn keep_q(&mut self, n: usize, actions: usize) {
        self.q_kept.clear();
        self.q_kept.extend_from_slice(&self.q[..n * actions]);
    }

    /// What the loss reads and writes: the last forward pass's Q-values,
    /// the kept ones, and the gradient with respect to the Q-values of the
    /// first `n` rows (`[n, 2]`, zeroed) for the caller to write before
    /// [`Workspace::backward`].
    pub(crate) fn loss_view(&mut self, n: usize, actions: usize) -> (&[f32], &[f32], &mut [f32]) {
        let dq = &mut self.dq[..n * actions];
        dq.fill(0.0);
        (&self.q, &self.q_kept, dq)
    }

    /// Gradients of the loss over the first `n` rows of the last forward
    /// pass into `self.grads`, from the `dq` written through
    /// [`Workspace::loss_view`].
    pub(crate) fn backward(&mut self, w: &Weights, n: usize) -> crate::Result<()> {
        let w4 = w.0[8];
        let actions = w.1.actions;
        let off = offsets(w.1);
        let (g4, gb4) = self.grads[off[8]..off[10]].split_at_mut(actions * HID);
        g4.fill(0.0);
        gb4.fill(0.0);
        // fc2 (2 outputs): by hand.
        let (dq, h, dh) = (&self.dq[..n * actions], &self.h[..n * HID], &mut self.dh[..n * HID]);
        for ((dq, h), dh) in
            dq.chunks_exact(actions).zip(h.chunks_exact(HID)).zip(dh.chunks_exact_mut(HID))
        {
            dh.fill(0.0);
            for (a, &d) in dq.iter().enumerate() {
                gb4[a] += d;
                if d != 0.0 {
                    for j in 0..HID {
                        g4[a * HID + j] += d * h[j];
                        dh[j] += d * w4[a * HID + j];
                    }
                }
            }
        }
        self.backward_trunk(w, n)
    }

    /// The `fc1` activations `[n, 64]` of the last forward pass: what the
    /// recurrent network's GRU reads.
    pub(crate) fn trunk_out(&self, n: usize) -> &[f32] {
        &self.h[..n * HID]
    }

    /// The gradient with respect to the `fc1` activations of the first `n`
    /// rows, for the caller to write before [`Workspace::backward_trunk`].
    pub(crate) fn trunk_grad(&mut self, n: usize) -> &mut [f32] {
        &mut self.dh[..n * HID]
    }

    /// Gradients of the layers up to `fc1` (the first eight parameters, at
    /// their offsets in `self.grads`) from the gradient with respect to the
    /// `fc1` activations written through [`Workspace::trunk_grad`] (or by
    /// [`Workspace::backward`]'s head).
    pub(crate) fn backward_trunk(&mut self, w: &Weights, n: usize) -> crate::Result<()> {
        let [_, _, w2, _, _, _, w3, _, _, _] = w.0;
        let vel = w.1.scalars;
        let (hw1, hw2, p1) = (H1 * H1, H2 * H2, p1(w.1));
        let off = offsets(w.1);
        let g = &mut self.grads[..off[8]];
        let (g1, rest) = g.split_at_mut(off[1]);
        let (gb1, rest) = rest.split_at_mut(C1);
        let (g2, rest) = rest.split_at_mut(C2 * P2);
        let (gb2, rest) = rest.split_at_mut(C2);
        let (gv, rest) = rest.split_at_mut(VEL_H * vel);
        let (gbv, rest) = rest.split_at_mut(VEL_H);
        let (g3, gb3) = rest.split_at_mut(HID * F);
        // The products overwrite g1, g2 and g3; the rest accumulates.
        for acc in [&mut *gb1, gb2, gv, gbv, gb3] {
            acc.fill(0.0);
        }
        let (h, dh) = (&self.h[..n * HID], &mut self.dh[..n * HID]);
        mask_and_sum::<HID>(dh, h, gb3);
        // fc1: dW = dhᵀ·features, dfeatures = dh·W.
        let feat = &self.feat[..n * F];
        matmul(HID, F, n, View::transposed(dh, HID), View::rows(feat, F), g3, false)?;
        let dfeat = &mut self.dfeat[..n * F];
        matmul(n, F, HID, View::rows(dh, HID), View::rows(w3, F), dfeat, false)?;
        mask(dfeat, feat);
        // The velocity branch, from the inputs the forward pass kept.
        for s in 0..n {
            let d = &dfeat[s * F + FEAT..(s + 1) * F];
            let v = &self.vel[s * vel..(s + 1) * vel];
            for j in 0..VEL_H {
                gbv[j] += d[j];
                for k in 0..vel {
                    gv[j * vel + k] += d[j] * v[k];
                }
            }
        }
        // Pooling (the ReLU's mask is in `feat > 0`).
        let da2 = &mut self.da2[..n * hw2 * C2];
        unpool(dfeat, &self.arg, da2, gb2, n);
        // conv2: dW = da2ᵀ·patches, dpatches = da2·W, then col2im.
        matmul(C2, P2, n * hw2, View::transposed(da2, C2), View::rows(&self.cols2, P2), g2, false)?;
        let dcols2 = &mut self.dcols2[..n * hw2 * P2];
        matmul(n * hw2, P2, C2, View::rows(da2, C2), View::rows(w2, P2), dcols2, false)?;
        let da1 = &mut self.da1[..n * hw1 * C1];
        col2im2(dcols2, da1, n);
        mask_and_sum::<C1>(da1, &self.a1[..n * hw1 * C1], gb1);
        // conv1: dW = da1ᵀ·patches (the image needs no gradient).
        matmul(C1, p1, n * hw1, View::transposed(da1, C1), View::rows(&self.cols1, p1), g1, false)?;
        Ok(())
    }
}
