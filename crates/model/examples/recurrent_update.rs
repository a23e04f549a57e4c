//! Times the recurrent learner's update (`SeqDqn`) on the fused trunk and
//! on the generic path: 16 sequences of 22 transitions (8 of burn-in, 3-step
//! targets), a GRU of 64, the paper's shapes, one thread.
//!
//! ```text
//! RAYON_NUM_THREADS=1 cargo run --release -p rotorhive-model --example recurrent_update
//! ```

use rotorhive_model::{Device, SeqBatch, SeqConfig, SeqDqn, Shapes};
use std::time::Instant;
fn main() {
    let s = Shapes::PAPER;
    let cfg = SeqConfig {
        lr: 1e-4,
        lr_final: 1e-4,
        lr_decay_updates: 0,
        max_grad_norm: 0.0,
        double: true,
        gamma: 0.99,
        n_step: 3,
        burn_in: 8,
        target_update: 100,
        huber_delta: 1.0,
        reward_scale: 0.01,
        margin: 0.8,
    };
    let (n, t, w) = (16usize, 22usize, 64usize);
    let obs: Vec<f32> =
        (0..n * (t + 1) * s.obs_len()).map(|i| ((i * 7919) % 1000) as f32 / 1000.0).collect();
    let actions = vec![1u8; n * t];
    let rewards = vec![1.0f32; n * t];
    let dones: Vec<bool> = (0..n * t).map(|i| i % 17 == 16).collect();
    let states = vec![0.1f32; n * w];
    let b = SeqBatch {
        sequences: n,
        steps: t,
        obs: &obs,
        actions: &actions,
        rewards: &rewards,
        dones: &dones,
        states: &states,
        experts: &[],
        weights: &[],
    };
    for fused in [true, false] {
        let mut d = SeqDqn::new(cfg, s, w, 1, &Device::Cpu).unwrap();
        d.set_fused(fused).unwrap();
        d.update(&b).unwrap();
        let k = if fused { 20 } else { 5 };
        let t0 = Instant::now();
        for _ in 0..k {
            d.update(&b).unwrap();
        }
        let per = t0.elapsed().as_secs_f64() / k as f64;
        println!(
            "fused {fused}: {:.1} ms per update of {n} sequences of {t} steps ({:.0} trained steps/s)",
            per * 1e3,
            (n * (t - 8)) as f64 / per
        );
    }
}
