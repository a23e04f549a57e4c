//! The Q-network and the DQN update, on candle.
//!
//! The network is the design's: conv 2→16 (6×6, stride 2) → conv 16→32 (3×3)
//! → max-pool 2 → 1152 features; velocity 3→16; concat → 64 → 2 Q-values.
//!
//! The convolutions are written as im2col + matrix multiply: a custom candle
//! op gathers the patches with precomputed indices and one GEMM
//! applies the kernel, with activations kept channels-last so no transpose is
//! ever needed. The gather's gradient is a scatter-add (col2im) op, the GEMM's
//! two GEMMs, which avoids candle's slow direct `conv_transpose2d` loop; the
//! first convolution's input (the image) gets no gradient at all. Max-pooling is a reshape and two `max` reductions, whose gradient is
//! exact (candle-nn 0.11.1's `max_pool2d` backward is 4× too small).
//!
//! Weights travel as one flat `f32` vector in a canonical order ([`PARAMS`]) and
//! are saved as safetensors.

use std::collections::HashMap;
use std::path::Path;
use std::time::Instant;

pub use candle_core::Device;
use candle_core::{D, DType, Tensor, Var};
use candle_nn::optim::{AdamW, Optimizer, ParamsAdamW};
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64Mcg;

/// Side of the depth images.
pub const SIDE: usize = 32;
/// Depth frames per observation.
pub const FRAMES: usize = 2;
/// Velocity components per observation.
pub const VEL: usize = 3;
/// Floats per observation.
pub const OBS_LEN: usize = FRAMES * SIDE * SIDE + VEL;
/// Q-values per observation.
pub const ACTIONS: usize = 2;
/// Floats per transition: `s | s' | action | reward | done`.
pub const TRANSITION_LEN: usize = 2 * OBS_LEN + 3;

const C1: usize = 16; // conv1 channels
const K1: usize = 6;
const S1: usize = 2;
const H1: usize = (SIDE - K1) / S1 + 1; // 14
const C2: usize = 32;
const K2: usize = 3;
const H2: usize = H1 - K2 + 1; // 12
const HP: usize = H2 / 2; // 6
const FEAT: usize = HP * HP * C2; // 1152
const VEL_H: usize = 16;
const HID: usize = 64;

/// Parameter names and shapes, in the canonical (flat) order.
pub const PARAMS: [(&str, &[usize]); 10] = [
    ("conv1.weight", &[C1, K1 * K1 * FRAMES]),
    ("conv1.bias", &[C1]),
    ("conv2.weight", &[C2, K2 * K2 * C1]),
    ("conv2.bias", &[C2]),
    ("vel.weight", &[VEL_H, VEL]),
    ("vel.bias", &[VEL_H]),
    ("fc1.weight", &[HID, FEAT + VEL_H]),
    ("fc1.bias", &[HID]),
    ("fc2.weight", &[ACTIONS, HID]),
    ("fc2.bias", &[ACTIONS]),
];

/// Number of floats in the flat weight vector.
pub fn num_params() -> usize {
    PARAMS.iter().map(|(_, s)| s.iter().product::<usize>()).sum()
}

/// Errors of the model layer.
#[derive(Debug, thiserror::Error)]
pub enum ModelError {
    /// A candle operation failed.
    #[error("tensor operation failed: {0}")]
    Candle(#[from] candle_core::Error),
    /// A checkpoint or weight vector does not fit the network.
    #[error("checkpoint {file}: {message}")]
    Checkpoint {
        /// The file (or `weights message`).
        file: String,
        /// What is wrong.
        message: String,
    },
    /// A batch has the wrong size.
    #[error("{what}: expected {expected} floats, got {got}")]
    Shape {
        /// What was passed.
        what: &'static str,
        /// Expected length.
        expected: usize,
        /// Actual length.
        got: usize,
    },
}

/// Result of this crate.
pub type Result<T> = std::result::Result<T, ModelError>;

/// A row-wise gather `out[b, j] = in[b, idx[j]]` as a candle custom op: the
/// im2col of a convolution. Its gradient is the matching scatter-add (col2im).
/// Candle's own `index_select` does the same but copies element by element
/// through a generic path, ten times slower at these sizes.
#[derive(Debug, Clone)]
struct Gather {
    idx: std::sync::Arc<Vec<u32>>,
    in_width: usize,
}

impl candle_core::CustomOp1 for Gather {
    fn name(&self) -> &'static str {
        "rotorhive-im2col"
    }

    fn cpu_fwd(&self, storage: &candle_core::CpuStorage, layout: &candle_core::Layout) -> candle_core::Result<(candle_core::CpuStorage, candle_core::Shape)> {
        let Some((start, end)) = layout.contiguous_offsets() else { candle_core::bail!("im2col needs a contiguous input") };
        let src = &storage.as_slice::<f32>()?[start..end];
        let (rows, width) = layout.shape().dims2()?;
        if width != self.in_width {
            candle_core::bail!("im2col: input rows have {width} values, expected {}", self.in_width);
        }
        let n = self.idx.len();
        let mut out = vec![0f32; rows * n];
        for (o, row) in out.chunks_exact_mut(n).zip(src.chunks_exact(width)) {
            for (v, &i) in o.iter_mut().zip(self.idx.iter()) {
                *v = row[i as usize];
            }
        }
        Ok((candle_core::CpuStorage::F32(out), candle_core::Shape::from((rows, n))))
    }

    fn bwd(&self, _arg: &Tensor, _res: &Tensor, grad: &Tensor) -> candle_core::Result<Option<Tensor>> {
        Ok(Some(grad.contiguous()?.apply_op1_no_bwd(&Scatter { idx: self.idx.clone(), in_width: self.in_width })?))
    }
}

/// The gradient of [`Gather`]: `out[b, idx[j]] += g[b, j]` (col2im).
#[derive(Debug, Clone)]
struct Scatter {
    idx: std::sync::Arc<Vec<u32>>,
    in_width: usize,
}

impl candle_core::CustomOp1 for Scatter {
    fn name(&self) -> &'static str {
        "rotorhive-col2im"
    }

    fn cpu_fwd(&self, storage: &candle_core::CpuStorage, layout: &candle_core::Layout) -> candle_core::Result<(candle_core::CpuStorage, candle_core::Shape)> {
        let Some((start, end)) = layout.contiguous_offsets() else { candle_core::bail!("col2im needs a contiguous input") };
        let g = &storage.as_slice::<f32>()?[start..end];
        let (rows, n) = layout.shape().dims2()?;
        let mut out = vec![0f32; rows * self.in_width];
        for (o, row) in out.chunks_exact_mut(self.in_width).zip(g.chunks_exact(n)) {
            for (v, &i) in row.iter().zip(self.idx.iter()) {
                o[i as usize] += v;
            }
        }
        Ok((candle_core::CpuStorage::F32(out), candle_core::Shape::from((rows, self.in_width))))
    }
}

/// Gather indices for the two convolutions (im2col), shared by every network.
#[derive(Debug, Clone)]
struct Im2Col {
    conv1: Gather,
    conv2: Gather,
}

impl Im2Col {
    fn new() -> Self {
        // conv1 reads the observation row (channels-first frames); rows of the
        // patch matrix are output pixels (oy, ox), columns (ky, kx, c).
        let mut i1 = Vec::with_capacity(H1 * H1 * K1 * K1 * FRAMES);
        for oy in 0..H1 {
            for ox in 0..H1 {
                for ky in 0..K1 {
                    for kx in 0..K1 {
                        for c in 0..FRAMES {
                            i1.push((c * SIDE * SIDE + (oy * S1 + ky) * SIDE + ox * S1 + kx) as u32);
                        }
                    }
                }
            }
        }
        // conv2 reads conv1's channels-last output.
        let mut i2 = Vec::with_capacity(H2 * H2 * K2 * K2 * C1);
        for oy in 0..H2 {
            for ox in 0..H2 {
                for ky in 0..K2 {
                    for kx in 0..K2 {
                        for c in 0..C1 {
                            i2.push((((oy + ky) * H1 + ox + kx) * C1 + c) as u32);
                        }
                    }
                }
            }
        }
        Self {
            conv1: Gather { idx: std::sync::Arc::new(i1), in_width: OBS_LEN },
            conv2: Gather { idx: std::sync::Arc::new(i2), in_width: H1 * H1 * C1 },
        }
    }
}

/// The Q-network's parameters, as trainable variables.
#[derive(Debug, Clone)]
pub struct QNet {
    params: Vec<Var>,
    im2col: Im2Col,
    device: Device,
}

impl QNet {
    /// A freshly initialised network (PyTorch's default uniform ±1/√fan_in),
    /// deterministic for a seed.
    pub fn new(seed: u64, device: &Device) -> Result<Self> {
        let mut rng = Pcg64Mcg::seed_from_u64(seed);
        let mut params = Vec::with_capacity(PARAMS.len());
        for (i, (_, shape)) in PARAMS.iter().enumerate() {
            // A bias shares the fan-in of the weight before it.
            let fan_in = if i % 2 == 0 { shape[1] } else { PARAMS[i - 1].1[1] };
            let bound = 1.0 / (fan_in as f32).sqrt();
            let n: usize = shape.iter().product();
            let data: Vec<f32> = (0..n).map(|_| rng.random_range(-bound..bound)).collect();
            params.push(Var::from_tensor(&Tensor::from_vec(data, *shape, device)?)?);
        }
        Ok(Self { params, im2col: Im2Col::new(), device: device.clone() })
    }

    /// The device the network lives on.
    pub fn device(&self) -> &Device {
        &self.device
    }

    /// Trainable variables, in canonical order.
    pub fn vars(&self) -> &[Var] {
        &self.params
    }

    fn p(&self, i: usize) -> &Tensor {
        self.params[i].as_tensor()
    }

    /// Q-values `[B, 2]` of observations `[B, OBS_LEN]`.
    pub fn forward(&self, obs: &Tensor) -> Result<Tensor> {
        let b = obs.dim(0)?;
        // conv1: gather patches, one GEMM, bias, ReLU → [B·196, 16] channels-last.
        let x = obs.contiguous()?.apply_op1(self.im2col.conv1.clone())?.reshape((b * H1 * H1, K1 * K1 * FRAMES))?;
        let x = x.matmul(&self.p(0).t()?)?.broadcast_add(self.p(1))?.relu()?;
        // conv2 on the channels-last map.
        let x = x.reshape((b, H1 * H1 * C1))?.apply_op1(self.im2col.conv2.clone())?.reshape((b * H2 * H2, K2 * K2 * C1))?;
        let x = x.matmul(&self.p(2).t()?)?.broadcast_add(self.p(3))?.relu()?;
        // 2×2 max-pool as two reductions over a split view.
        let x = x.reshape((b, HP, 2, HP, 2, C2))?.max(4)?.max(2)?.reshape((b, FEAT))?;
        let v = obs.narrow(1, FRAMES * SIDE * SIDE, VEL)?;
        let v = v.matmul(&self.p(4).t()?)?.broadcast_add(self.p(5))?.relu()?;
        let h = Tensor::cat(&[&x, &v], 1)?;
        let h = h.matmul(&self.p(6).t()?)?.broadcast_add(self.p(7))?.relu()?;
        Ok(h.matmul(&self.p(8).t()?)?.broadcast_add(self.p(9))?)
    }

    /// Q-values of a flat batch of observations (`n × OBS_LEN` floats).
    pub fn q_values(&self, obs: &[f32]) -> Result<Vec<f32>> {
        if obs.len() % OBS_LEN != 0 || obs.is_empty() {
            return Err(ModelError::Shape { what: "observation batch", expected: OBS_LEN, got: obs.len() });
        }
        let t = Tensor::from_slice(obs, (obs.len() / OBS_LEN, OBS_LEN), &self.device)?;
        Ok(self.forward(&t)?.flatten_all()?.to_vec1::<f32>()?)
    }

    /// Greedy actions of a flat batch of observations.
    pub fn greedy(&self, obs: &[f32]) -> Result<Vec<u8>> {
        let q = self.q_values(obs)?;
        Ok(q.chunks(ACTIONS).map(|c| argmax(c) as u8).collect())
    }

    /// The weights as one flat vector in canonical order.
    pub fn to_flat(&self) -> Result<Vec<f32>> {
        let mut out = Vec::with_capacity(num_params());
        for v in &self.params {
            out.extend(v.as_tensor().flatten_all()?.to_vec1::<f32>()?);
        }
        Ok(out)
    }

    /// Writes the flat weights into the variables.
    pub fn write_flat(&self, into: &mut [f32]) -> Result<()> {
        let flat = self.to_flat()?;
        if into.len() != flat.len() {
            return Err(ModelError::Shape { what: "weights buffer", expected: flat.len(), got: into.len() });
        }
        into.copy_from_slice(&flat);
        Ok(())
    }

    /// Replaces the weights with a flat vector in canonical order.
    pub fn load_flat(&self, flat: &[f32]) -> Result<()> {
        if flat.len() != num_params() {
            return Err(ModelError::Shape { what: "weights", expected: num_params(), got: flat.len() });
        }
        let mut off = 0;
        for (v, (_, shape)) in self.params.iter().zip(PARAMS) {
            let n: usize = shape.iter().product();
            v.set(&Tensor::from_slice(&flat[off..off + n], shape, &self.device)?)?;
            off += n;
        }
        Ok(())
    }

    /// Copies another network's weights into this one.
    pub fn copy_from(&self, other: &QNet) -> Result<()> {
        for (a, b) in self.params.iter().zip(&other.params) {
            a.set(&b.as_tensor().copy()?)?;
        }
        Ok(())
    }

    /// The weights by name.
    pub fn named(&self) -> HashMap<String, Tensor> {
        PARAMS.iter().zip(&self.params).map(|((n, _), v)| (n.to_string(), v.as_tensor().clone())).collect()
    }

    /// Loads weights by name, checking every name and shape.
    pub fn load_named(&self, tensors: &HashMap<String, Tensor>, file: &str) -> Result<()> {
        for ((name, shape), v) in PARAMS.iter().zip(&self.params) {
            let t = tensors.get(*name).ok_or_else(|| ModelError::Checkpoint { file: file.into(), message: format!("tensor `{name}` is missing") })?;
            if t.dims() != *shape {
                return Err(ModelError::Checkpoint { file: file.into(), message: format!("tensor `{name}` has shape {:?}, the network needs {:?}", t.dims(), shape) });
            }
            v.set(&t.to_dtype(DType::F32)?.to_device(&self.device)?)?;
        }
        Ok(())
    }

    /// Saves the weights as safetensors.
    pub fn save(&self, path: &Path) -> Result<()> {
        candle_core::safetensors::save(&self.named(), path)?;
        Ok(())
    }

    /// Loads weights saved by [`QNet::save`], with a clear error for a missing,
    /// truncated or mismatched file.
    pub fn load(&self, path: &Path) -> Result<()> {
        let file = path.display().to_string();
        let bytes = std::fs::read(path).map_err(|e| ModelError::Checkpoint { file: file.clone(), message: format!("cannot read: {e}") })?;
        let tensors = candle_core::safetensors::load_buffer(&bytes, &self.device)
            .map_err(|e| ModelError::Checkpoint { file: file.clone(), message: format!("not a valid safetensors file: {e}") })?;
        self.load_named(&tensors, &file)
    }
}

fn argmax(v: &[f32]) -> usize {
    let mut best = 0;
    for (i, x) in v.iter().enumerate() {
        if *x > v[best] {
            best = i;
        }
    }
    best
}

/// Hyper-parameters of the DQN update.
#[derive(Debug, Clone, Copy)]
pub struct DqnConfig {
    /// Adam learning rate.
    pub lr: f64,
    /// Discount.
    pub gamma: f32,
    /// Updates between target-network copies.
    pub target_update: u64,
    /// Huber loss threshold.
    pub huber_delta: f32,
}

/// Time spent in each part of the last update (ns).
#[derive(Debug, Clone, Copy, Default)]
pub struct UpdateTiming {
    /// Target and online forward passes and the loss.
    pub forward_ns: u64,
    /// Backward pass.
    pub backward_ns: u64,
    /// Adam step (and target copy).
    pub optimiser_ns: u64,
}

/// A DQN learner: online network, target network and Adam.
pub struct Dqn {
    /// The online network.
    pub online: QNet,
    target: QNet,
    opt: AdamW,
    cfg: DqnConfig,
    updates: u64,
    timing: UpdateTiming,
}

impl Dqn {
    /// A learner with freshly initialised networks.
    pub fn new(cfg: DqnConfig, seed: u64, device: &Device) -> Result<Self> {
        let online = QNet::new(seed, device)?;
        let target = QNet::new(seed, device)?;
        let opt = AdamW::new(online.vars().to_vec(), ParamsAdamW { lr: cfg.lr, beta1: 0.9, beta2: 0.999, eps: 1e-8, weight_decay: 0.0 })?;
        Ok(Self { online, target, opt, cfg, updates: 0, timing: UpdateTiming::default() })
    }

    /// Updates done so far.
    pub fn updates(&self) -> u64 {
        self.updates
    }

    /// Sets the update counter (when resuming).
    pub fn set_updates(&mut self, n: u64) {
        self.updates = n;
    }

    /// Timing of the last update.
    pub fn timing(&self) -> UpdateTiming {
        self.timing
    }

    /// Copies the online weights into the target network.
    pub fn sync_target(&self) -> Result<()> {
        self.target.copy_from(&self.online)
    }

    /// The Huber TD loss of a minibatch (flat transitions), differentiable
    /// with respect to the online network.
    pub fn loss(&self, batch: &Tensor) -> Result<Tensor> {
        let b = batch.dim(0)?;
        let s = batch.narrow(1, 0, OBS_LEN)?;
        let s2 = batch.narrow(1, OBS_LEN, OBS_LEN)?;
        let a = batch.narrow(1, 2 * OBS_LEN, 1)?.to_dtype(DType::U32)?;
        let r = batch.narrow(1, 2 * OBS_LEN + 1, 1)?;
        let done = batch.narrow(1, 2 * OBS_LEN + 2, 1)?;
        let next = self.target.forward(&s2.contiguous()?)?.detach().max_keepdim(D::Minus1)?;
        let y = (r + ((1.0 - done)? * next)?.affine(self.cfg.gamma as f64, 0.0)?)?;
        let q = self.online.forward(&s.contiguous()?)?.gather(&a, 1)?;
        let diff = (q - y.detach())?;
        let abs = diff.abs()?;
        let d = self.cfg.huber_delta as f64;
        let c = abs.clamp(0.0, d)?;
        let loss = ((c.sqr()? * 0.5)? + ((abs - &c)? * d)?)?;
        Ok(loss.sum_all()?.affine(1.0 / b as f64, 0.0)?)
    }

    /// One update on a minibatch of `n × TRANSITION_LEN` floats; returns the loss.
    pub fn update(&mut self, batch: &[f32]) -> Result<f32> {
        if batch.is_empty() || batch.len() % TRANSITION_LEN != 0 {
            return Err(ModelError::Shape { what: "minibatch", expected: TRANSITION_LEN, got: batch.len() });
        }
        let n = batch.len() / TRANSITION_LEN;
        let t0 = Instant::now();
        let batch = Tensor::from_slice(batch, (n, TRANSITION_LEN), self.online.device())?;
        let loss = self.loss(&batch)?;
        let loss_v = loss.to_scalar::<f32>()?;
        let t1 = Instant::now();
        let grads = loss.backward()?;
        let t2 = Instant::now();
        self.opt.step(&grads)?;
        self.updates += 1;
        if self.updates % self.cfg.target_update == 0 {
            self.sync_target()?;
        }
        let t3 = Instant::now();
        self.timing = UpdateTiming { forward_ns: (t1 - t0).as_nanos() as u64, backward_ns: (t2 - t1).as_nanos() as u64, optimiser_ns: (t3 - t2).as_nanos() as u64 };
        Ok(loss_v)
    }
}

#[cfg(test)]
mod tests;
