//! `hive bench learner`: updates per second on random minibatches through
//! the learner's update path, and actor inference latency at batch 1 and 50.

use std::time::Instant;

use crate::error::{Result, usage};
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64Mcg;
use rotorhive_model::{Device, Dqn, DqnConfig, Layers};
use rotorhive_msg::Shapes;
use rotorhive_roles::Config;
use rotorhive_roles::learner::dqn_config;

/// One path's figures in `hive bench learner`.
struct PathFigures {
    updates_per_s: f64,
    forward_ms: f64,
    backward_ms: f64,
    optimiser_ms: f64,
    infer_b1_ms: f64,
    infer_b50_ms: f64,
}

impl PathFigures {
    fn json(&self) -> serde_json::Value {
        serde_json::json!({ "updates_per_s": self.updates_per_s, "forward_ms": self.forward_ms, "backward_ms": self.backward_ms, "optimiser_ms": self.optimiser_ms, "infer_b1_ms": self.infer_b1_ms, "infer_b50_ms": self.infer_b50_ms })
    }
}

/// Measures updates and inference on one path (fused or generic) on
/// `device` (the fused path: the CPU only).
fn measure(
    (fused, device): (bool, &Device),
    (shapes, layers): (Shapes, Layers),
    (threads, batch, updates): (usize, usize, usize),
) -> Result<PathFigures> {
    let cfg = Config::default();
    let dqn_cfg = DqnConfig { double: false, ..dqn_config(&cfg) };
    let mut dqn = Dqn::with_layers(dqn_cfg, shapes, layers, 1, device)?;
    let (obs_len, transition_len) = (shapes.obs_len(), shapes.transition_len());
    dqn.set_fused(fused)?;
    dqn.set_threads(threads);
    let mut rng = Pcg64Mcg::seed_from_u64(3);
    let mut data: Vec<f32> = (0..batch * transition_len).map(|_| rng.random::<f32>()).collect();
    for i in 0..batch {
        data[i * transition_len + 2 * obs_len] = (i % 2) as f32;
        data[i * transition_len + 2 * obs_len + 3] = rotorhive_msg::NO_EXPERT;
    }
    // The update as the default config trains: with prioritized replay,
    // each row's loss weighted and its TD error kept for the feedback.
    let weights: Vec<f32> = (0..batch).map(|i| 0.5 + (i % 4) as f32 * 0.125).collect();
    let weighted = cfg.replay.prioritized.then_some(weights.as_slice());
    for _ in 0..5 {
        dqn.update_weighted(&data, weighted)?;
    }
    let (mut f, mut b, mut o) = (0u64, 0u64, 0u64);
    let start = Instant::now();
    for _ in 0..updates {
        dqn.update_weighted(&data, weighted)?;
        let t = dqn.timing();
        f += t.forward_ns;
        b += t.backward_ns;
        o += t.optimiser_ns;
    }
    let wall = start.elapsed().as_secs_f64();
    let ms = |ns: u64| ns as f64 / 1e6 / updates as f64;
    let infer = |n: usize| -> Result<f64> {
        let obs: Vec<f32> = (0..n * obs_len).map(|i| (i % 97) as f32 / 97.0).collect();
        dqn.online.greedy(&obs)?;
        let reps = 50;
        let t = Instant::now();
        for _ in 0..reps {
            dqn.online.greedy(&obs)?;
        }
        Ok(t.elapsed().as_secs_f64() * 1e3 / reps as f64)
    };
    Ok(PathFigures {
        updates_per_s: updates as f64 / wall,
        forward_ms: ms(f),
        backward_ms: ms(b),
        optimiser_ms: ms(o),
        infer_b1_ms: infer(1)?,
        infer_b50_ms: infer(50)?,
    })
}

/// `hive bench learner`: updates per second on random minibatches through the
/// same update path of a network for `shapes` of widths `layers`, and actor
/// inference latency at batch 1 and 50; with `compare`, the generic path of
/// stock candle ops measured in the same run.
pub fn bench(
    (threads, batch, updates): (usize, usize, usize),
    (shapes, layers): (Shapes, Layers),
    (compare, cuda): (bool, bool),
    json: bool,
) -> Result<()> {
    if threads == 0 || batch == 0 || updates == 0 {
        usage!("--threads, --batch and --updates must be positive");
    }
    if cuda {
        return bench_cuda(batch, updates, (shapes, layers), json);
    }
    // The pools' threads were set by `main` (`BenchCmd::thread_env`).
    let sizes = (threads, batch, updates);
    let net = (shapes, layers);
    let fused = measure((true, &Device::Cpu), net, sizes)?;
    let generic = if compare { Some(measure((false, &Device::Cpu), net, sizes)?) } else { None };
    let params = rotorhive_model::num_params(shapes, layers);
    let depth = format!("{}x{}", shapes.depth[0], shapes.depth[1]);
    println!(
        "network {} on {} frames of {depth}: {params} parameters, {} bytes a stored transition",
        layers.name(),
        shapes.frames,
        2 * shapes.packed_len()
    );
    for (name, p) in
        std::iter::once(("fused", &fused)).chain(generic.as_ref().map(|g| ("generic", g)))
    {
        println!(
            "{name:>8}: threads {threads}, batch {batch}: {:.1} updates/s (forward {:.2} ms, backward {:.2} ms, optimiser {:.2} ms); inference batch 1: {:.3} ms, batch 50: {:.3} ms",
            p.updates_per_s,
            p.forward_ms,
            p.backward_ms,
            p.optimiser_ms,
            p.infer_b1_ms,
            p.infer_b50_ms
        );
    }
    if let Some(g) = &generic {
        println!(
            "speed-up of the fused path: {:.1}× updates/s, {:.1}× batch-50 inference",
            fused.updates_per_s / g.updates_per_s,
            g.infer_b50_ms / fused.infer_b50_ms
        );
    }
    if json {
        let mut v = fused.json();
        v["device"] = "cpu".into();
        v["layers"] = layers.name().into();
        v["params"] = params.into();
        v["depth"] = depth.into();
        v["transition_bytes"] = (2 * shapes.packed_len()).into();
        v["threads"] = threads.into();
        v["batch"] = batch.into();
        if let Some(g) = &generic {
            v["generic"] = g.json();
            v["speedup"] = (fused.updates_per_s / g.updates_per_s).into();
        }
        println!("{v}");
    }
    Ok(())
}

/// `hive bench learner --device cuda`: the generic path (stock candle ops)
/// on GPU 0, the minibatch copied there once per update as in a run.
fn bench_cuda(batch: usize, updates: usize, net: (Shapes, Layers), json: bool) -> Result<()> {
    let layers = net.1;
    let device = rotorhive_model::device(rotorhive_model::DeviceKind::Cuda)?;
    let p = measure((false, &device), net, (1, batch, updates))?;
    println!(
        "    cuda: batch {batch}: {:.1} updates/s (forward {:.2} ms, backward {:.2} ms, optimiser {:.2} ms); inference batch 1: {:.3} ms, batch 50: {:.3} ms",
        p.updates_per_s, p.forward_ms, p.backward_ms, p.optimiser_ms, p.infer_b1_ms, p.infer_b50_ms
    );
    if json {
        let mut v = p.json();
        v["device"] = "cuda".into();
        v["layers"] = layers.name().into();
        v["batch"] = batch.into();
        v["samples_per_s"] = (p.updates_per_s * batch as f64).into();
        println!("{v}");
    }
    Ok(())
}
