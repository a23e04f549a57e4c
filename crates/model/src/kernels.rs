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
//! Activations are channels-last: conv1's output `[B·14·14, c1]`, conv2's
//! `[B·12·12, c2]`, the features `[B, 6·6·c2 + 16]` on 32×32 depth (other
//! sizes: [`Geometry`]; the pooled map, then the
//! velocity branch), then each hidden layer's `[B, width]` ([`Layers`]; the
//! design's 16, 32 and 64 on loops of those constant widths).

use multiversion::multiversion;

use crate::layers::Geometry;
use crate::layers::vel_units;
use crate::ops::{View, matmul};
use crate::{K1, K2, Layers, S1, Shapes};

/// Columns of conv1's patch matrix: (frame, ky, kx).
const fn p1(shapes: Shapes) -> usize {
    shapes.frames * K1 * K1
}

/// Columns of conv2's patch matrix: (ky, kx, channel).
const fn p2(c1: usize) -> usize {
    K2 * K2 * c1
}

/// The parameter slices in canonical order (the trunk's, then the Q
/// head's two where the network has one), the network's shapes and widths.
pub(crate) struct Weights<'a> {
    pub(crate) p: Vec<&'a [f32]>,
    pub(crate) shapes: Shapes,
    pub(crate) layers: Layers,
}

impl<'a> Weights<'a> {
    /// The slices `p` of a network for `shapes` of widths `layers`: all of
    /// them, or the trunk's alone (whose forward pass stops before the head).
    pub(crate) fn new(p: &[&'a [f32]], shapes: Shapes, layers: Layers) -> Self {
        Self { p: p.to_vec(), shapes, layers }
    }

    /// The Q head's weight and bias, where they were given.
    fn head(&self) -> Option<(&'a [f32], &'a [f32])> {
        let t = self.layers.trunk_len();
        Some((*self.p.get(t)?, *self.p.get(t + 1)?))
    }
}

/// Offsets of each parameter in the flat gradient vector of a network for
/// `shapes` of widths `layers` (one more than the parameters: the last is
/// the total).
pub(crate) fn offsets(shapes: Shapes, layers: Layers) -> Vec<usize> {
    let mut off = vec![0];
    for (_, shape) in crate::params(shapes, layers) {
        off.push(off[off.len() - 1] + shape.iter().product::<usize>());
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
    /// The shapes and widths the buffers were sized for.
    sized: Option<(Shapes, Layers)>,
    cols1: Vec<f32>,
    a1: Vec<f32>,
    cols2: Vec<f32>,
    a2: Vec<f32>,
    arg: Vec<u8>,
    feat: Vec<f32>,
    vel: Vec<f32>,
    /// Each hidden layer's activations.
    h: Vec<Vec<f32>>,
    /// Q-values of the last forward pass, `[rows, actions]`.
    pub(crate) q: Vec<f32>,
    /// Q-values kept from an earlier pass ([`Workspace::keep_q`]).
    q_kept: Vec<f32>,
    dq: Vec<f32>,
    /// The gradient with respect to each hidden layer's activations.
    dh: Vec<Vec<f32>>,
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

/// `y = max(y + b, 0)` for every row of `y` (rows of `b.len()`): the
/// design's widths on loops of a constant width, which LLVM vectorises
/// whole, any other on [`bias_relu_any`].
fn bias_relu(y: &mut [f32], b: &[f32]) {
    match b.len() {
        16 => bias_relu_of::<16>(y, b),
        32 => bias_relu_of::<32>(y, b),
        64 => bias_relu_of::<64>(y, b),
        _ => bias_relu_any(y, b),
    }
}

#[multiversion(targets("x86_64+avx2+fma+avx"))]
fn bias_relu_of<const C: usize>(y: &mut [f32], b: &[f32]) {
    let b: &[f32; C] = b.try_into().expect("a bias of the layer's width");
    for row in y.chunks_exact_mut(C) {
        for c in 0..C {
            row[c] = (row[c] + b[c]).max(0.0);
        }
    }
}

#[multiversion(targets("x86_64+avx2+fma+avx"))]
fn bias_relu_any(y: &mut [f32], b: &[f32]) {
    for row in y.chunks_exact_mut(b.len()) {
        row.iter_mut().zip(b).for_each(|(y, b)| *y = (*y + b).max(0.0));
    }
}

/// `g = 0` where the layer's output `y ≤ 0` (ReLU's gradient).
#[multiversion(targets("x86_64+avx2+fma+avx"))]
fn mask(g: &mut [f32], y: &[f32]) {
    g.iter_mut().zip(y).for_each(|(g, y)| *g = if *y > 0.0 { *g } else { 0.0 });
}

/// `g = 0` where the layer's output `y ≤ 0` (ReLU's gradient), and
/// `db += Σ_rows g` (rows of `db.len()`).
fn mask_and_sum(g: &mut [f32], y: &[f32], db: &mut [f32]) {
    // Two passes: LLVM left the fused loop scalar at C = 16.
    mask(g, y);
    match db.len() {
        16 => sum_rows_of::<16>(g, db),
        32 => sum_rows_of::<32>(g, db),
        64 => sum_rows_of::<64>(g, db),
        _ => sum_rows_any(g, db),
    }
}

#[multiversion(targets("x86_64+avx2+fma+avx"))]
fn sum_rows_of<const C: usize>(g: &[f32], db: &mut [f32]) {
    let mut acc = [0f32; C];
    for row in g.as_chunks::<C>().0 {
        for c in 0..C {
            acc[c] += row[c];
        }
    }
    db.iter_mut().zip(acc).for_each(|(d, a)| *d += a);
}

#[multiversion(targets("x86_64+avx2+fma+avx"))]
fn sum_rows_any(g: &[f32], db: &mut [f32]) {
    for row in g.chunks_exact(db.len()) {
        db.iter_mut().zip(row).for_each(|(d, g)| *d += g);
    }
}

/// conv1's patch rows of one observation: for every output pixel (oy, ox),
/// runs of K1 pixels per (frame, ky).
#[multiversion(targets("x86_64+avx2+fma+avx"))]
fn im2col1(obs: &[f32], frames: usize, g: Geometry, out: &mut [f32]) {
    let mut o = 0;
    for oy in 0..g.h1 {
        for ox in 0..g.w1 {
            for c in 0..frames {
                for ky in 0..K1 {
                    let s = c * g.h * g.w + (oy * S1 + ky) * g.w + ox * S1;
                    out[o..o + K1].copy_from_slice(&obs[s..s + K1]);
                    o += K1;
                }
            }
        }
    }
}

/// The runs of conv2's im2col for one map of `c1` channels: `f(at, o)` for
/// each run of K2·c1 values, `at` its start in the channels-last conv1 map
/// and `o` in the patch matrix.
#[inline(always)]
fn conv2_runs(c1: usize, g: Geometry, mut f: impl FnMut(usize, usize)) {
    let mut o = 0;
    for oy in 0..g.h2 {
        for ox in 0..g.w2 {
            for ky in 0..K2 {
                f(((oy + ky) * g.w1 + ox) * c1, o);
                o += K2 * c1;
            }
        }
    }
}

/// The four conv2 positions (rows of its channels-last map) under pooled
/// output (py, px).
#[inline(always)]
fn window(py: usize, px: usize, w2: usize) -> [usize; 4] {
    let r = 2 * py * w2 + 2 * px;
    [r, r + 1, r + w2, r + w2 + 1]
}

/// conv2's patch rows of `n` channels-last maps of `c1` channels: runs of
/// K2·c1 values.
#[multiversion(targets("x86_64+avx2+fma+avx"))]
fn im2col2(a1: &[f32], cols: &mut [f32], n: usize, c1: usize, g: Geometry) {
    let (hw1, hw2, p2) = (g.cells1(), g.cells2(), p2(c1));
    for s in 0..n {
        let src = &a1[s * hw1 * c1..(s + 1) * hw1 * c1];
        let out = &mut cols[s * hw2 * p2..(s + 1) * hw2 * p2];
        conv2_runs(c1, g, |at, o| out[o..o + K2 * c1].copy_from_slice(&src[at..at + K2 * c1]));
    }
}

/// The gradient of [`im2col2`]: every run added back where it was read (col2im).
#[multiversion(targets("x86_64+avx2+fma+avx"))]
fn col2im2(dcols: &[f32], da1: &mut [f32], n: usize, c1: usize, g: Geometry) {
    let (hw1, hw2, p2) = (g.cells1(), g.cells2(), p2(c1));
    da1[..n * hw1 * c1].fill(0.0);
    for s in 0..n {
        let src = &dcols[s * hw2 * p2..(s + 1) * hw2 * p2];
        let out = &mut da1[s * hw1 * c1..(s + 1) * hw1 * c1];
        conv2_runs(c1, g, |at, o| {
            let (d, g) = (&mut out[at..at + K2 * c1], &src[o..o + K2 * c1]);
            d.iter_mut().zip(g).for_each(|(d, g)| *d += g);
        });
    }
}

/// 2×2 max-pooling of `n` channels-last conv2 maps of `c2` channels into
/// the features' head (rows of `f`), with the argmax (0..4, the window's
/// first maximum) of every output.
#[multiversion(targets("x86_64+avx2+fma+avx"))]
fn pool(a2: &[f32], feat: &mut [f32], arg: &mut [u8], n: usize, c2: usize, f: usize, g: Geometry) {
    let (hw2, pooled) = (g.cells2(), g.cells_pooled() * c2);
    for s in 0..n {
        let x = &a2[s * hw2 * c2..(s + 1) * hw2 * c2];
        let out = &mut feat[s * f..s * f + pooled];
        let arg = &mut arg[s * pooled..(s + 1) * pooled];
        for py in 0..g.hp {
            for px in 0..g.wp {
                let [x0, x1, x2, x3] = window(py, px, g.w2).map(|r| &x[r * c2..(r + 1) * c2]);
                let o = (py * g.wp + px) * c2;
                let (out, arg) = (&mut out[o..o + c2], &mut arg[o..o + c2]);
                for c in 0..c2 {
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
/// zeroed first); conv2's bias gradient `db2` (of `c2`) is their sum, since
/// every pooled gradient lands on exactly one position.
#[multiversion(targets("x86_64+avx2+fma+avx"))]
fn unpool(
    dfeat: &[f32],
    arg: &[u8],
    (da2, db2): (&mut [f32], &mut [f32]),
    n: usize,
    f: usize,
    g: Geometry,
) {
    let c2 = db2.len();
    let (hw2, pooled) = (g.cells2(), g.cells_pooled() * c2);
    da2[..n * hw2 * c2].fill(0.0);
    for s in 0..n {
        let d = &dfeat[s * f..s * f + pooled];
        let arg = &arg[s * pooled..(s + 1) * pooled];
        let out = &mut da2[s * hw2 * c2..(s + 1) * hw2 * c2];
        for py in 0..g.hp {
            for px in 0..g.wp {
                let rows = window(py, px, g.w2);
                let o = (py * g.wp + px) * c2;
                for c in 0..c2 {
                    out[rows[arg[o + c] as usize] * c2 + c] = d[o + c];
                    db2[c] += d[o + c];
                }
            }
        }
    }
}

impl Workspace {
    fn reserve(&mut self, rows: usize, shapes: Shapes, layers: Layers) {
        if rows <= self.rows && self.sized == Some((shapes, layers)) {
            return;
        }
        (self.rows, self.sized) = (rows.max(self.rows), Some((shapes, layers)));
        let rows = self.rows;
        let (vel, actions, f) = (shapes.scalars, shapes.actions, layers.features(shapes));
        let [c1, c2] = layers.conv();
        let g = Geometry::of(shapes);
        let (hw1, hw2) = (g.cells1(), g.cells2());
        for (v, len) in [
            (&mut self.cols1, rows * hw1 * p1(shapes)),
            (&mut self.a1, rows * hw1 * c1),
            (&mut self.cols2, rows * hw2 * p2(c1)),
            (&mut self.a2, rows * hw2 * c2),
            (&mut self.feat, rows * f),
            (&mut self.vel, rows * vel),
            (&mut self.q, rows * actions),
            (&mut self.dq, rows * actions),
            (&mut self.dfeat, rows * f),
            (&mut self.da2, rows * hw2 * c2),
            (&mut self.dcols2, rows * hw2 * p2(c1)),
            (&mut self.da1, rows * hw1 * c1),
        ] {
            fit(v, len);
        }
        let depth = layers.hidden().len();
        self.h.resize_with(depth, Vec::new);
        self.dh.resize_with(depth, Vec::new);
        for (k, &w) in layers.hidden().iter().enumerate() {
            fit(&mut self.h[k], rows * w);
            fit(&mut self.dh[k], rows * w);
        }
        self.arg.resize(rows * layers.pooled(shapes), 0);
        fit(&mut self.grads, offsets(shapes, layers).last().copied().unwrap_or(0));
    }

    /// Q-values of every row of `parts` (in order) into `self.q` (none
    /// where `w` has no Q head), keeping the activations for
    /// [`Workspace::backward`]. Returns the rows forwarded.
    pub(crate) fn forward(&mut self, w: &Weights, parts: &[Rows]) -> crate::Result<usize> {
        let n: usize = parts.iter().map(|p| p.n).sum();
        let (shapes, layers) = (w.shapes, w.layers);
        self.reserve(n, shapes, layers);
        let [w1, b1, w2, b2, wv, bv] = [0, 1, 2, 3, 4, 5].map(|i| w.p[i]);
        let [c1, c2] = layers.conv();
        let (vel, f, pooled) = (shapes.scalars, layers.features(shapes), layers.pooled(shapes));
        let g = Geometry::of(shapes);
        let (hw1, hw2, p1, p2) = (g.cells1(), g.cells2(), p1(shapes), p2(c1));
        // conv1: patches straight from the observation rows, runs of K1 pixels.
        let mut i = 0;
        for p in parts {
            for r in 0..p.n {
                let obs = p.row(r);
                im2col1(obs, shapes.frames, g, &mut self.cols1[i * hw1 * p1..(i + 1) * hw1 * p1]);
                // The velocity branch (and the goal's), 3 or 6 → 16, into
                // the features' tail.
                let v = &obs[shapes.obs_depth()..];
                self.vel[i * vel..(i + 1) * vel].copy_from_slice(v);
                let tail = &mut self.feat[i * f + pooled..(i + 1) * f];
                for (j, t) in tail.iter_mut().enumerate() {
                    let s = bv[j] + (0..vel).map(|k| wv[j * vel + k] * v[k]).sum::<f32>();
                    *t = s.max(0.0);
                }
                i += 1;
            }
        }
        let a1 = &mut self.a1[..n * hw1 * c1];
        matmul(n * hw1, c1, p1, View::rows(&self.cols1, p1), View::transposed(w1, p1), a1, false)?;
        bias_relu(a1, b1);
        im2col2(&self.a1, &mut self.cols2, n, c1, g);
        let a2 = &mut self.a2[..n * hw2 * c2];
        matmul(n * hw2, c2, p2, View::rows(&self.cols2, p2), View::transposed(w2, p2), a2, false)?;
        bias_relu(a2, b2);
        pool(&self.a2, &mut self.feat, &mut self.arg, n, c2, f, g);
        // The hidden layers, each on the one before (the first on the features).
        let mut input = f;
        for (k, &out) in layers.hidden().iter().enumerate() {
            let (before, rest) = self.h.split_at_mut(k);
            let x = if k == 0 { &self.feat[..n * f] } else { &before[k - 1][..n * input] };
            let h = &mut rest[0][..n * out];
            let (wk, bk) = (w.p[6 + 2 * k], w.p[7 + 2 * k]);
            matmul(n, out, input, View::rows(x, input), View::transposed(wk, input), h, false)?;
            bias_relu(h, bk);
            input = out;
        }
        if let Some((w4, b4)) = w.head() {
            let (actions, hid) = (shapes.actions, layers.out());
            let h = &self.h[self.h.len() - 1][..n * hid];
            for (q, h) in self.q[..n * actions].chunks_exact_mut(actions).zip(h.chunks_exact(hid)) {
                for (a, q) in q.iter_mut().enumerate() {
                    *q = b4[a]
                        + w4[a * hid..(a + 1) * hid].iter().zip(h).map(|(w, x)| w * x).sum::<f32>();
                }
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
    /// first `n` rows (`[n, actions]`, zeroed) for the caller to write
    /// before [`Workspace::backward`].
    pub(crate) fn loss_view(&mut self, n: usize, actions: usize) -> (&[f32], &[f32], &mut [f32]) {
        let dq = &mut self.dq[..n * actions];
        dq.fill(0.0);
        (&self.q, &self.q_kept, dq)
    }

    /// Gradients of the loss over the first `n` rows of the last forward
    /// pass into `self.grads`, from the `dq` written through
    /// [`Workspace::loss_view`].
    pub(crate) fn backward(&mut self, w: &Weights, n: usize) -> crate::Result<()> {
        let (w4, _) = w.head().ok_or(crate::ModelError::Fused("a backward pass without a head"))?;
        let (actions, hid, t) = (w.shapes.actions, w.layers.out(), w.layers.trunk_len());
        let off = offsets(w.shapes, w.layers);
        let (g4, gb4) = self.grads[off[t]..off[t + 2]].split_at_mut(actions * hid);
        g4.fill(0.0);
        gb4.fill(0.0);
        // The Q head (a few outputs): by hand.
        let last = self.h.len() - 1;
        let (dq, h) = (&self.dq[..n * actions], &self.h[last][..n * hid]);
        let dh = &mut self.dh[last][..n * hid];
        for ((dq, h), dh) in
            dq.chunks_exact(actions).zip(h.chunks_exact(hid)).zip(dh.chunks_exact_mut(hid))
        {
            dh.fill(0.0);
            for (a, &d) in dq.iter().enumerate() {
                gb4[a] += d;
                if d != 0.0 {
                    for j in 0..hid {
                        g4[a * hid + j] += d * h[j];
                        dh[j] += d * w4[a * hid + j];
                    }
                }
            }
        }
        self.backward_trunk(w, n)
    }

    /// The last hidden layer's activations `[n, out]` of the last forward
    /// pass: what the recurrent network's GRU reads.
    pub(crate) fn trunk_out(&self, n: usize, layers: Layers) -> &[f32] {
        &self.h[self.h.len() - 1][..n * layers.out()]
    }

    /// The gradient with respect to the last hidden layer's activations of
    /// the first `n` rows, for the caller to write before
    /// [`Workspace::backward_trunk`].
    pub(crate) fn trunk_grad(&mut self, n: usize, layers: Layers) -> &mut [f32] {
        let last = self.dh.len() - 1;
        &mut self.dh[last][..n * layers.out()]
    }

    /// Gradients of the trunk (every parameter before the Q head, at its
    /// offset in `self.grads`) from the gradient with respect to the last
    /// hidden layer's activations written through
    /// [`Workspace::trunk_grad`] (or by [`Workspace::backward`]'s head).
    pub(crate) fn backward_trunk(&mut self, w: &Weights, n: usize) -> crate::Result<()> {
        let (shapes, layers) = (w.shapes, w.layers);
        let off = offsets(shapes, layers);
        let f = layers.features(shapes);
        // The hidden layers, last to first: each one's weights, bias and
        // the gradient of what it read.
        for k in (0..layers.hidden().len()).rev() {
            let (out, input) =
                (layers.hidden()[k], if k == 0 { f } else { layers.hidden()[k - 1] });
            let (gw, gb) = self.grads[off[6 + 2 * k]..off[8 + 2 * k]].split_at_mut(out * input);
            gb.fill(0.0);
            let (dbefore, drest) = self.dh.split_at_mut(k);
            let dh = &mut drest[0][..n * out];
            mask_and_sum(dh, &self.h[k][..n * out], gb);
            let (x, dx) = if k == 0 {
                (&self.feat[..n * f], &mut self.dfeat[..n * f])
            } else {
                (&self.h[k - 1][..n * input], &mut dbefore[k - 1][..n * input])
            };
            matmul(out, input, n, View::transposed(dh, out), View::rows(x, input), gw, false)?;
            matmul(
                n,
                input,
                out,
                View::rows(dh, out),
                View::rows(w.p[6 + 2 * k], input),
                dx,
                false,
            )?;
        }
        self.backward_convolutions(w, n, &off)
    }

    /// [`Workspace::backward_trunk`] below the hidden layers: from the
    /// features' gradient to the velocity branch and the convolutions.
    fn backward_convolutions(&mut self, w: &Weights, n: usize, off: &[usize]) -> crate::Result<()> {
        let (shapes, layers) = (w.shapes, w.layers);
        let [c1, c2] = layers.conv();
        let (vel, f, pooled) = (shapes.scalars, layers.features(shapes), layers.pooled(shapes));
        let geo = Geometry::of(shapes);
        let (hw1, hw2, p1, p2) = (geo.cells1(), geo.cells2(), p1(shapes), p2(c1));
        let g = &mut self.grads[..off[6]];
        let (g1, rest) = g.split_at_mut(off[1]);
        let (gb1, rest) = rest.split_at_mut(c1);
        let (g2, rest) = rest.split_at_mut(c2 * p2);
        let (gb2, rest) = rest.split_at_mut(c2);
        let units = vel_units(shapes);
        let (gv, gbv) = rest.split_at_mut(units * vel);
        // The products overwrite g1 and g2; the rest accumulates.
        for acc in [&mut *gb1, gb2, gv, gbv] {
            acc.fill(0.0);
        }
        let (feat, dfeat) = (&self.feat[..n * f], &mut self.dfeat[..n * f]);
        mask(dfeat, feat);
        // The velocity branch, from the inputs the forward pass kept.
        for s in 0..n {
            let d = &dfeat[s * f + pooled..(s + 1) * f];
            let v = &self.vel[s * vel..(s + 1) * vel];
            for j in 0..units {
                gbv[j] += d[j];
                for k in 0..vel {
                    gv[j * vel + k] += d[j] * v[k];
                }
            }
        }
        // Pooling (the ReLU's mask is in `feat > 0`).
        let da2 = &mut self.da2[..n * hw2 * c2];
        unpool(dfeat, &self.arg, (da2, gb2), n, f, geo);
        // conv2: dW = da2ᵀ·patches, dpatches = da2·W, then col2im.
        matmul(c2, p2, n * hw2, View::transposed(da2, c2), View::rows(&self.cols2, p2), g2, false)?;
        let dcols2 = &mut self.dcols2[..n * hw2 * p2];
        matmul(n * hw2, p2, c2, View::rows(da2, c2), View::rows(w.p[2], p2), dcols2, false)?;
        let da1 = &mut self.da1[..n * hw1 * c1];
        col2im2(dcols2, da1, n, c1, geo);
        mask_and_sum(da1, &self.a1[..n * hw1 * c1], gb1);
        // conv1: dW = da1ᵀ·patches (the image needs no gradient).
        matmul(c1, p1, n * hw1, View::transposed(da1, c1), View::rows(&self.cols1, p1), g1, false)?;
        Ok(())
    }
}
