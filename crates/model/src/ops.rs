//! The fast CPU path: candle custom ops with hand-written forward and backward
//! passes over raw `f32` slices and `gemm` matrix multiplies.
//!
//! - [`Gather`] / [`Scatter`]: a row-wise gather (im2col) and its gradient, a
//!   scatter-add (col2im).
//! - [`Linear`]: `act(x · wᵀ + b)` in one pass (one GEMM writing over the
//!   broadcast bias, ReLU in place); its backward masks the gradient once and
//!   computes `dW`, `db` and, only when `x` needs it, `dx`.
//! - [`MaxPool2`]: 2×2 max-pooling of a channels-last map, gradient routed to
//!   the first maximum of each window (exact, unlike candle-nn 0.11.1).
//! - [`TdHuber`]: picks `Q(s, a)`, subtracts the TD target and averages the
//!   Huber loss; its gradient lands only on the taken actions.
//! - [`AdamStep`]: the Adam update of one parameter, in place.
//!
//! Every op checks its input layout and fails with a candle error (never a
//! panic) on anything it was not written for.

use std::sync::{Arc, Mutex};

use candle_core::{CpuStorage, CustomOp1, CustomOp3, InplaceOp2, Layout, Shape, Storage, Tensor, bail};

/// A read-only strided matrix view for [`matmul`].
#[derive(Clone, Copy)]
pub(crate) struct View<'a> {
    data: &'a [f32],
    rs: usize,
    cs: usize,
}

impl<'a> View<'a> {
    /// A row-major matrix with `cols` columns.
    pub(crate) fn rows(data: &'a [f32], cols: usize) -> Self {
        Self { data, rs: cols, cs: 1 }
    }

    /// The transpose of a row-major matrix with `cols` columns.
    pub(crate) fn transposed(data: &'a [f32], cols: usize) -> Self {
        Self { data, rs: 1, cs: cols }
    }

    fn fits(&self, rows: usize, cols: usize) -> bool {
        rows == 0 || cols == 0 || (rows - 1) * self.rs + (cols - 1) * self.cs < self.data.len()
    }
}

thread_local! {
    /// Set while a data-parallel shard runs: its GEMMs stay on its thread.
    static SERIAL: std::cell::Cell<bool> = const { std::cell::Cell::new(false) };
}

/// Threads the CPU kernels may use (`RAYON_NUM_THREADS`, as candle reads it).
pub(crate) fn threads() -> usize {
    candle_core::utils::get_num_threads().max(1)
}

/// Runs `f` with every GEMM of this thread single-threaded.
pub(crate) fn serial<R>(f: impl FnOnce() -> R) -> R {
    let before = SERIAL.with(|s| s.replace(true));
    let r = f();
    SERIAL.with(|s| s.set(before));
    r
}

/// Runs `f(i)` for every shard `i < shards` in parallel (shard 0 on this
/// thread, the others on scoped threads), each with single-threaded GEMMs,
/// and returns the results in order. Candle's own elementwise pool must stay
/// single-threaded (`CANDLE_NUM_THREADS=1`): it serialises concurrent callers.
pub(crate) fn sharded<R: Send>(shards: usize, f: impl Fn(usize) -> R + Sync) -> Vec<R> {
    if shards <= 1 {
        return vec![serial(|| f(0))];
    }
    std::thread::scope(|sc| {
        let f = &f;
        let others: Vec<_> = (1..shards).map(|i| sc.spawn(move || serial(|| f(i)))).collect();
        let mut out = vec![serial(|| f(0))];
        out.extend(others.into_iter().map(|h| h.join().unwrap_or_else(|p| std::panic::resume_unwind(p))));
        out
    })
}

fn parallelism() -> gemm::Parallelism {
    if SERIAL.with(|s| s.get()) {
        return gemm::Parallelism::None;
    }
    match threads() {
        1 => gemm::Parallelism::None,
        n => gemm::Parallelism::Rayon(n),
    }
}

/// `dst[m×n] (+)= a[m×k] · b[k×n]`, `dst` row-major and contiguous.
pub(crate) fn matmul(m: usize, n: usize, k: usize, a: View, b: View, dst: &mut [f32], accumulate: bool) -> candle_core::Result<()> {
    if !a.fits(m, k) || !b.fits(k, n) || dst.len() < m * n {
        bail!("matmul {m}×{k} · {k}×{n}: an operand is too small");
    }
    if m == 0 || n == 0 {
        return Ok(());
    }
    // SAFETY: the bounds of all three operands were checked above; `dst` does
    // not alias the inputs (it is a unique borrow).
    unsafe {
        gemm::gemm(
            m,
            n,
            k,
            dst.as_mut_ptr(),
            1,
            n as isize,
            accumulate,
            a.data.as_ptr(),
            a.cs as isize,
            a.rs as isize,
            b.data.as_ptr(),
            b.cs as isize,
            b.rs as isize,
            if accumulate { 1.0 } else { 0.0 },
            1.0,
            false,
            false,
            false,
            parallelism(),
        );
    }
    Ok(())
}

/// The contiguous `f32` slice of a storage.
fn slice<'a>(storage: &'a CpuStorage, layout: &Layout, op: &str) -> candle_core::Result<&'a [f32]> {
    let Some((start, end)) = layout.contiguous_offsets() else { bail!("{op} needs a contiguous input") };
    Ok(&storage.as_slice::<f32>()?[start..end])
}

/// Runs `f` on the contiguous `f32` data of a CPU tensor.
fn with_slice<R>(t: &Tensor, op: &str, f: impl FnOnce(&[f32]) -> candle_core::Result<R>) -> candle_core::Result<R> {
    let t = t.contiguous()?;
    let (storage, layout) = t.storage_and_layout();
    match &*storage {
        Storage::Cpu(cpu) => f(slice(cpu, layout, op)?),
        _ => bail!("{op}: the fused path runs on the CPU only"),
    }
}

fn tensor(data: Vec<f32>, shape: impl Into<Shape>, like: &Tensor) -> candle_core::Result<Tensor> {
    Tensor::from_vec(data, shape, like.device())
}

/// A row-wise gather of runs: output row `b` is the concatenation of
/// `in[b, start .. start + run]` for every `start` in `starts`: the im2col of a
/// convolution, as contiguous copies. Its gradient is the matching
/// scatter-add (col2im). Candle's own `index_select` copies element by element
/// through a generic path, many times slower here.
#[derive(Debug, Clone)]
pub(crate) struct Gather {
    starts: Arc<Vec<u32>>,
    run: usize,
    in_width: usize,
}

impl Gather {
    pub(crate) fn new(starts: Vec<u32>, run: usize, in_width: usize) -> Self {
        assert!(starts.iter().all(|&s| s as usize + run <= in_width), "im2col runs must lie inside the input row");
        Self { starts: Arc::new(starts), run, in_width }
    }

    fn out_width(&self) -> usize {
        self.starts.len() * self.run
    }
}

impl CustomOp1 for Gather {
    fn name(&self) -> &'static str {
        "rotorhive-im2col"
    }

    fn cpu_fwd(&self, storage: &CpuStorage, layout: &Layout) -> candle_core::Result<(CpuStorage, Shape)> {
        let src = slice(storage, layout, self.name())?;
        let (rows, width) = layout.shape().dims2()?;
        if width != self.in_width {
            bail!("im2col: input rows have {width} values, expected {}", self.in_width);
        }
        let n = self.out_width();
        let mut out = Vec::with_capacity(rows * n);
        for row in src.chunks_exact(width) {
            for &s in self.starts.iter() {
                out.extend_from_slice(&row[s as usize..s as usize + self.run]);
            }
        }
        Ok((CpuStorage::F32(out), Shape::from((rows, n))))
    }

    fn bwd(&self, _arg: &Tensor, _res: &Tensor, grad: &Tensor) -> candle_core::Result<Option<Tensor>> {
        Ok(Some(grad.contiguous()?.apply_op1_no_bwd(&Scatter(self.clone()))?))
    }
}

/// The gradient of [`Gather`]: every run of the gradient row is added back
/// where it was read from (col2im).
#[derive(Debug, Clone)]
pub(crate) struct Scatter(Gather);

impl CustomOp1 for Scatter {
    fn name(&self) -> &'static str {
        "rotorhive-col2im"
    }

    fn cpu_fwd(&self, storage: &CpuStorage, layout: &Layout) -> candle_core::Result<(CpuStorage, Shape)> {
        let Gather { starts, run, in_width } = &self.0;
        let g = slice(storage, layout, self.name())?;
        let (rows, n) = layout.shape().dims2()?;
        if n != self.0.out_width() {
            bail!("col2im: gradient rows have {n} values, expected {}", self.0.out_width());
        }
        let mut out = vec![0f32; rows * in_width];
        for (o, row) in out.chunks_exact_mut(*in_width).zip(g.chunks_exact(n)) {
            for (&s, part) in starts.iter().zip(row.chunks_exact(*run)) {
                o[s as usize..s as usize + run].iter_mut().zip(part).for_each(|(o, v)| *o += v);
            }
        }
        Ok((CpuStorage::F32(out), Shape::from((rows, *in_width))))
    }
}

/// `act(x · wᵀ + b)` for `x: [R, K]`, `w: [N, K]`, `b: [N]`; `act` is ReLU or
/// the identity.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Linear {
    pub(crate) relu: bool,
}

impl CustomOp3 for Linear {
    fn name(&self) -> &'static str {
        "rotorhive-linear"
    }

    fn cpu_fwd(&self, xs: &CpuStorage, xl: &Layout, ws: &CpuStorage, wl: &Layout, bs: &CpuStorage, bl: &Layout) -> candle_core::Result<(CpuStorage, Shape)> {
        let (x, w, b) = (slice(xs, xl, "linear x")?, slice(ws, wl, "linear w")?, slice(bs, bl, "linear b")?);
        let (r, k) = xl.shape().dims2()?;
        let (n, k2) = wl.shape().dims2()?;
        if k != k2 || b.len() != n {
            bail!("linear: x is {r}×{k}, w is {n}×{k2}, b has {}", b.len());
        }
        let mut out = Vec::with_capacity(r * n);
        for _ in 0..r {
            out.extend_from_slice(b);
        }
        matmul(r, n, k, View::rows(x, k), View::transposed(w, k), &mut out, true)?;
        if self.relu {
            out.iter_mut().for_each(|v| *v = v.max(0.0));
        }
        Ok((CpuStorage::F32(out), Shape::from((r, n))))
    }

    fn bwd(&self, x: &Tensor, w: &Tensor, _b: &Tensor, res: &Tensor, grad: &Tensor) -> candle_core::Result<(Option<Tensor>, Option<Tensor>, Option<Tensor>)> {
        let (r, k) = x.dims2()?;
        let (n, _) = w.dims2()?;
        // The gradient through the activation.
        let mut g = with_slice(grad, "linear grad", |g| Ok(g.to_vec()))?;
        if self.relu {
            with_slice(res, "linear res", |y| {
                g.iter_mut().zip(y).filter(|(_, y)| **y <= 0.0).for_each(|(g, _)| *g = 0.0);
                Ok(())
            })?;
        }
        let mut db = vec![0f32; n];
        for row in g.chunks_exact(n) {
            db.iter_mut().zip(row).for_each(|(d, v)| *d += v);
        }
        let mut dw = vec![0f32; n * k];
        with_slice(x, "linear x", |xv| matmul(n, k, r, View::transposed(&g, n), View::rows(xv, k), &mut dw, false))?;
        let dx = if x.track_op() {
            let mut dx = vec![0f32; r * k];
            with_slice(w, "linear w", |wv| matmul(r, k, n, View::rows(&g, n), View::rows(wv, k), &mut dx, false))?;
            Some(tensor(dx, (r, k), x)?)
        } else {
            None
        };
        Ok((dx, Some(tensor(dw, (n, k), w)?), Some(tensor(db, n, w)?)))
    }
}

/// 2×2 max-pooling of a channels-last map stored as `[B·H·W, C]` rows,
/// giving `[B, (H/2)·(W/2)·C]`.
#[derive(Debug, Clone, Copy)]
pub(crate) struct MaxPool2 {
    pub(crate) h: usize,
    pub(crate) w: usize,
}

impl MaxPool2 {
    /// Calls `f(out_index, [the four input indices])` for every output value.
    fn windows(&self, batch: usize, c: usize, mut f: impl FnMut(usize, [usize; 4])) {
        let (h, w) = (self.h, self.w);
        let mut o = 0;
        for b in 0..batch {
            for py in 0..h / 2 {
                for px in 0..w / 2 {
                    let r = b * h * w + 2 * py * w + 2 * px;
                    let base = [r * c, (r + 1) * c, (r + w) * c, (r + w + 1) * c];
                    for ch in 0..c {
                        f(o, base.map(|i| i + ch));
                        o += 1;
                    }
                }
            }
        }
    }
}

impl CustomOp1 for MaxPool2 {
    fn name(&self) -> &'static str {
        "rotorhive-maxpool2"
    }

    fn cpu_fwd(&self, storage: &CpuStorage, layout: &Layout) -> candle_core::Result<(CpuStorage, Shape)> {
        let x = slice(storage, layout, self.name())?;
        let (rows, c) = layout.shape().dims2()?;
        if rows % (self.h * self.w) != 0 || !self.h.is_multiple_of(2) || !self.w.is_multiple_of(2) {
            bail!("maxpool: {rows} rows do not make {}×{} maps", self.h, self.w);
        }
        let batch = rows / (self.h * self.w);
        let per = self.h / 2 * (self.w / 2) * c;
        let mut out = vec![0f32; batch * per];
        self.windows(batch, c, |o, [a, b, cc, d]| out[o] = x[a].max(x[b]).max(x[cc]).max(x[d]));
        Ok((CpuStorage::F32(out), Shape::from((batch, per))))
    }

    fn bwd(&self, arg: &Tensor, res: &Tensor, grad: &Tensor) -> candle_core::Result<Option<Tensor>> {
        let (rows, c) = arg.dims2()?;
        let batch = rows / (self.h * self.w);
        let mut dx = vec![0f32; rows * c];
        with_slice(arg, "maxpool x", |x| {
            with_slice(res, "maxpool res", |y| {
                with_slice(grad, "maxpool grad", |g| {
                    self.windows(batch, c, |o, idx| {
                        // The first window entry holding the maximum takes the gradient.
                        let at = idx.into_iter().find(|&i| x[i] == y[o]).unwrap_or(idx[0]);
                        dx[at] += g[o];
                    });
                    Ok(())
                })
            })
        })?;
        Ok(Some(tensor(dx, (rows, c), arg)?))
    }
}

/// The Huber loss of `Q(s, a) − y` summed over a batch and divided by
/// `denom` (the whole minibatch, of which this may be a shard): `q: [B, A]`
/// in, scalar out.
#[derive(Debug, Clone)]
pub(crate) struct TdHuber {
    pub(crate) actions: Arc<Vec<u32>>,
    pub(crate) targets: Arc<Vec<f32>>,
    pub(crate) delta: f32,
    pub(crate) denom: usize,
}

impl TdHuber {
    fn errors<'a>(&'a self, q: &'a [f32], a: usize) -> impl Iterator<Item = (usize, f32)> + 'a {
        self.actions.iter().zip(self.targets.iter()).enumerate().map(move |(b, (&act, &y))| {
            let i = b * a + act as usize;
            (i, q[i] - y)
        })
    }
}

impl CustomOp1 for TdHuber {
    fn name(&self) -> &'static str {
        "rotorhive-td-huber"
    }

    fn cpu_fwd(&self, storage: &CpuStorage, layout: &Layout) -> candle_core::Result<(CpuStorage, Shape)> {
        let q = slice(storage, layout, self.name())?;
        let (b, a) = layout.shape().dims2()?;
        if b != self.actions.len() || b != self.targets.len() || self.actions.iter().any(|&x| x as usize >= a) {
            bail!("td loss: {b}×{a} Q-values for {} actions and {} targets", self.actions.len(), self.targets.len());
        }
        let d = self.delta;
        let sum: f32 = self.errors(q, a).map(|(_, e)| if e.abs() <= d { 0.5 * e * e } else { d * (e.abs() - 0.5 * d) }).sum();
        Ok((CpuStorage::F32(vec![sum / self.denom as f32]), Shape::from(())))
    }

    fn bwd(&self, arg: &Tensor, _res: &Tensor, grad: &Tensor) -> candle_core::Result<Option<Tensor>> {
        let (b, a) = arg.dims2()?;
        let g = grad.to_scalar::<f32>()? / self.denom as f32;
        let mut dq = vec![0f32; b * a];
        with_slice(arg, "td loss q", |q| {
            for (i, e) in self.errors(q, a) {
                dq[i] = g * e.clamp(-self.delta, self.delta);
            }
            Ok(())
        })?;
        Ok(Some(tensor(dq, (b, a), arg)?))
    }
}

/// Adam's constants for one step.
#[derive(Debug, Clone, Copy)]
pub(crate) struct AdamHyper {
    pub(crate) lr: f32,
    pub(crate) beta1: f32,
    pub(crate) beta2: f32,
    pub(crate) eps: f32,
    /// The step number, from 1.
    pub(crate) t: u64,
}

/// One Adam step over flat slices (bias-corrected, no weight decay).
pub(crate) fn adam(p: &mut [f32], g: &[f32], m: &mut [f32], v: &mut [f32], h: AdamHyper) {
    let c1 = 1.0 - h.beta1.powi(h.t as i32);
    let c2 = 1.0 - h.beta2.powi(h.t as i32);
    let step = h.lr / c1;
    let sc2 = c2.sqrt();
    for (((p, g), m), v) in p.iter_mut().zip(g).zip(m.iter_mut()).zip(v.iter_mut()) {
        *m = h.beta1 * *m + (1.0 - h.beta1) * g;
        *v = h.beta2 * *v + (1.0 - h.beta2) * g * g;
        *p -= step * *m / ((*v).sqrt() / sc2 + h.eps);
    }
}

/// [`adam`] on a candle variable in place (CPU), with the moments kept by
/// the caller.
pub(crate) struct AdamStep<'a> {
    pub(crate) moments: Mutex<(&'a mut [f32], &'a mut [f32])>,
    pub(crate) hyper: AdamHyper,
}

impl InplaceOp2 for AdamStep<'_> {
    fn name(&self) -> &'static str {
        "rotorhive-adam"
    }

    fn cpu_fwd(&self, ps: &mut CpuStorage, pl: &Layout, gs: &CpuStorage, gl: &Layout) -> candle_core::Result<()> {
        let g = slice(gs, gl, "adam grad")?;
        let Some((start, end)) = pl.contiguous_offsets() else { bail!("adam needs a contiguous parameter") };
        let CpuStorage::F32(p) = ps else { bail!("adam needs f32 parameters") };
        let p = &mut p[start..end];
        let mut guard = self.moments.lock().map_err(|_| candle_core::Error::Msg("adam moments poisoned".into()))?;
        let (m, v) = &mut *guard;
        if g.len() != p.len() || m.len() != p.len() || v.len() != p.len() {
            bail!("adam: parameter {}, gradient {}, moments {}", p.len(), g.len(), m.len());
        }
        adam(p, g, m, v, self.hyper);
        Ok(())
    }
}
