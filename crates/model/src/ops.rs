//! The CPU path's building blocks: strided `gemm` products, data-parallel
//! shards, and Adam applied in place to a candle variable ([`AdamStep`], a
//! candle in-place op that fails with a candle error, never a panic, on a
//! layout it was not written for).

use std::sync::Mutex;

use candle_core::{CpuStorage, InplaceOp1, Layout, bail};

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

/// Runs `f(i)` for every shard `i < shards` in parallel on rayon's pool
/// (threads started once, not per call), each with single-threaded GEMMs,
/// and returns the results in order. Candle's own elementwise pool must stay
/// single-threaded (`CANDLE_NUM_THREADS=1`): it serialises concurrent callers.
pub(crate) fn sharded<R: Send>(shards: usize, f: impl Fn(usize) -> R + Sync) -> Vec<R> {
    if shards <= 1 {
        return vec![serial(|| f(0))];
    }
    use rayon::prelude::*;
    (0..shards).into_par_iter().map(|i| serial(|| f(i))).collect()
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
pub(crate) fn matmul(
    m: usize,
    n: usize,
    k: usize,
    a: View,
    b: View,
    dst: &mut [f32],
    accumulate: bool,
) -> candle_core::Result<()> {
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

/// The `f32` slice of a contiguous CPU parameter, for the in-place ops.
fn param_slice<'a>(
    ps: &'a mut CpuStorage,
    pl: &Layout,
    op: &str,
) -> candle_core::Result<&'a mut [f32]> {
    let Some((start, end)) = pl.contiguous_offsets() else {
        bail!("{op} needs a contiguous parameter")
    };
    let CpuStorage::F32(p) = ps else { bail!("{op} needs f32 parameters") };
    Ok(&mut p[start..end])
}

/// Overwrites a parameter in place with `src` (one copy, where `Var::set`
/// of a new tensor makes two).
pub(crate) struct CopyIn<'a>(pub(crate) &'a [f32]);

impl InplaceOp1 for CopyIn<'_> {
    fn name(&self) -> &'static str {
        "rotorhive-copy-in"
    }

    fn cpu_fwd(&self, ps: &mut CpuStorage, pl: &Layout) -> candle_core::Result<()> {
        let p = param_slice(ps, pl, "copy-in")?;
        if p.len() != self.0.len() {
            bail!("copy-in: parameter {}, source {}", p.len(), self.0.len());
        }
        p.copy_from_slice(self.0);
        Ok(())
    }
}

/// [`adam`] on a candle variable in place (CPU), with the gradient and the
/// moments kept by the caller.
pub(crate) struct AdamStep<'a> {
    pub(crate) grad: &'a [f32],
    pub(crate) moments: Mutex<(&'a mut [f32], &'a mut [f32])>,
    pub(crate) hyper: AdamHyper,
}

impl InplaceOp1 for AdamStep<'_> {
    fn name(&self) -> &'static str {
        "rotorhive-adam"
    }

    fn cpu_fwd(&self, ps: &mut CpuStorage, pl: &Layout) -> candle_core::Result<()> {
        let p = param_slice(ps, pl, "adam")?;
        let mut guard = self
            .moments
            .lock()
            .map_err(|_| candle_core::Error::Msg("adam moments poisoned".into()))?;
        let (m, v) = &mut *guard;
        if self.grad.len() != p.len() || m.len() != p.len() || v.len() != p.len() {
            bail!("adam: parameter {}, gradient {}, moments {}", p.len(), self.grad.len(), m.len());
        }
        adam(p, self.grad, m, v, self.hyper);
        Ok(())
    }
}
