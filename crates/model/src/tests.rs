//! Checks of the network against plain candle and against finite differences.

use super::*;
use candle_core::DType;
use rotorhive_msg::{DEPTH_PIXELS, DEPTH_SIDE as SIDE, NO_EXPERT, label_mask};

// The paper's task's shapes, as most checks here use them.
const OBS_LEN: usize = Shapes::PAPER.obs_len();
const TRANSITION_LEN: usize = Shapes::PAPER.transition_len();

fn random(n: usize, seed: u64, lo: f32, hi: f32) -> Vec<f32> {
    let mut rng = Pcg64Mcg::seed_from_u64(seed);
    (0..n).map(|_| rng.random_range(lo..hi)).collect()
}

fn generic(net: &QNet) -> QNet {
    let mut g = net.clone();
    g.set_fused(false).unwrap();
    g
}

/// A batch of transitions with valid actions, rewards and dones.
fn transitions(n: usize, seed: u64) -> Vec<f32> {
    transitions_of(Shapes::PAPER, n, seed)
}

/// [`transitions`] for a network of `shapes`: every action taken.
fn transitions_of(shapes: Shapes, n: usize, seed: u64) -> Vec<f32> {
    let (tl, ol) = (shapes.transition_len(), shapes.obs_len());
    let mut data = random(n * tl, seed, 0.0, 1.0);
    for i in 0..n {
        data[i * tl + 2 * ol] = (i % shapes.actions) as f32;
        data[i * tl + 2 * ol + 1] = if i % 3 == 0 { -100.0 } else { 3.0 };
        data[i * tl + 2 * ol + 2] = if i % 3 == 0 { 1.0 } else { 0.0 };
        data[i * tl + 2 * ol + 3] = NO_EXPERT;
        data[i * tl + 2 * ol + 4] = 0.0;
    }
    data
}

pub(crate) fn cfg(double: bool) -> DqnConfig {
    DqnConfig {
        lr: 1e-3,
        lr_final: 1e-3,
        lr_decay_updates: 0,
        gamma: 0.9,
        target_update: 1000,
        huber_delta: 10.0,
        double,
        reward_scale: 1.0,
        max_grad_norm: 0.0,
        margin: 0.8,
    }
}

/// Gradients through candle's autograd over stock ops (the reference), flat.
fn autograd(dqn: &Dqn, batch: &[f32]) -> Vec<f32> {
    let grads = dqn.loss(batch).unwrap().backward().unwrap();
    dqn.online
        .vars()
        .iter()
        .flat_map(|v| {
            grads.get(v.as_tensor()).unwrap().flatten_all().unwrap().to_vec1::<f32>().unwrap()
        })
        .collect()
}

/// The slice of parameter `i` in a flat vector of a network for `shapes`.
fn part(flat: &[f32], shapes: Shapes, i: usize) -> &[f32] {
    let off = kernels::offsets(shapes, Layers::DEFAULT);
    &flat[off[i]..off[i + 1]]
}

fn close(a: &[f32], b: &[f32], tol: f32, what: &str) {
    assert_eq!(a.len(), b.len(), "{what}");
    let scale = b.iter().fold(0f32, |m, x| m.max(x.abs())).max(1e-3);
    for (i, (x, y)) in a.iter().zip(b).enumerate() {
        assert!((x - y).abs() <= tol * scale, "{what}[{i}]: {x} vs {y} (scale {scale})");
    }
}

#[test]
fn forward_matches_stock_candle_convolutions() {
    let dev = Device::Cpu;
    for seed in [1, 2, 3] {
        let net = QNet::new(seed, &dev).unwrap();
        let obs =
            Tensor::from_vec(random(5 * OBS_LEN, seed + 10, 0.0, 1.0), (5, OBS_LEN), &dev).unwrap();
        assert!(net.fused());
        let a = net.forward(&obs).unwrap().flatten_all().unwrap().to_vec1::<f32>().unwrap();
        let b =
            generic(&net).forward(&obs).unwrap().flatten_all().unwrap().to_vec1::<f32>().unwrap();
        close(&a, &b, 1e-4, "q-values");
    }
}

/// Gradients of the whole loss on the fused path (hand-written backward:
/// convolutions, pooling to its argmax, ReLU masks, the TD-Huber loss)
/// against candle's autograd over stock ops, plain and double DQN, one shard
/// and two, for the paper's shapes, a goal task's (six scalars, three
/// actions) and one of four depth frames, a task with the camera's map
/// (72 more scalars, a 64-unit branch for them), and for networks of other
/// widths (other channels, two and three hidden layers).
#[test]
fn fused_gradients_match_stock_candle() {
    let goal = Shapes::task(FRAMES, true, true);
    let map = Shapes::task(FRAMES, false, false).with_map(72);
    let goal_map = goal.with_map(256);
    let wide = Layers::new(&[8, 24], &[48, 20]).unwrap();
    let deep = Layers::new(&[20, 12], &[40, 24, 16]).unwrap();
    for (seed, double, threads, shapes, layers) in [
        (1, false, 1, Shapes::PAPER, Layers::DEFAULT),
        (2, true, 1, Shapes::PAPER, Layers::DEFAULT),
        (3, true, 2, Shapes::PAPER, Layers::DEFAULT),
        (4, true, 2, goal, Layers::DEFAULT),
        (5, true, 2, Shapes::task(4, false, false), Layers::DEFAULT),
        (6, true, 1, Shapes::PAPER, wide),
        (7, true, 2, goal, deep),
        (8, true, 2, map, Layers::DEFAULT),
        (9, false, 1, goal_map, wide),
        // The seen movers after the map: 5 tracks of 14 floats.
        (12, true, 2, map.with_tracks(70), Layers::DEFAULT),
        // Frames of other cameras: 48 × 40 (a 10 × 8 pooled map), and 13 ×
        // 27, whose odd conv2 map loses its last column to the pooling.
        (10, true, 2, Shapes::PAPER.with_depth([48, 40]), Layers::DEFAULT),
        (11, false, 1, goal.with_depth([13, 27]), wide),
    ] {
        let mut dqn = Dqn::with_layers(cfg(double), shapes, layers, seed, &Device::Cpu).unwrap();
        dqn.set_threads(threads);
        let n = num_params(shapes, layers);
        dqn.target.load_flat(&random(n, seed + 50, -0.1, 0.1)).unwrap();
        let batch = transitions_of(shapes, 17, seed + 20);
        let (l1, fused) = dqn.gradients(&batch).unwrap();
        let plain = autograd(&dqn, &batch);
        let l2 = dqn.loss(&batch).unwrap().to_scalar::<f32>().unwrap();
        assert!((l1 - l2).abs() <= 1e-4 * l2.abs().max(1.0), "loss {l1} vs {l2}");
        let off = kernels::offsets(shapes, layers);
        for (i, (name, _)) in params(shapes, layers).iter().enumerate() {
            let (a, b) = (&fused[off[i]..off[i + 1]], &plain[off[i]..off[i + 1]]);
            close(a, b, 1e-3, &format!("{name} of {}", layers.name()));
        }
        dqn.set_fused(false).unwrap();
        let (l3, generic) = dqn.gradients(&batch).unwrap();
        assert_eq!((l3, &generic), (l2, &plain), "the generic path's gradients are autograd's");
    }
}

/// [`transitions_of`] with every row labelled by an expert action (rows
/// `i % 4 == 0` unlabelled), the large-margin loss on.
fn labelled(shapes: Shapes, n: usize, seed: u64) -> Vec<f32> {
    let (tl, ol) = (shapes.transition_len(), shapes.obs_len());
    let mut data = transitions_of(shapes, n, seed);
    for (i, t) in data.chunks_exact_mut(tl).enumerate() {
        t[2 * ol + 3] = if i % 4 == 0 { NO_EXPERT } else { ((i / 2) % shapes.actions) as f32 };
        t[2 * ol + 4] = (i % 3 == 1 && i % 4 != 0) as u8 as f32;
    }
    data
}

/// DQfD's large-margin loss: its gradients on the fused path (its +1/−1 on
/// the Q-values of a* and a_E) against candle's autograd over stock ops
/// (max, gather), with the TD loss, one shard and two, two and three
/// actions; and without a weight the labels change nothing.
#[test]
fn the_margin_losss_gradients_match_stock_candle() {
    let goal = Shapes::task(FRAMES, true, true);
    for (seed, threads, shapes) in [(1, 1, Shapes::PAPER), (2, 2, Shapes::PAPER), (3, 2, goal)] {
        let mut dqn = Dqn::with_shapes(cfg(true), shapes, seed, &Device::Cpu).unwrap();
        dqn.set_threads(threads);
        dqn.target
            .load_flat(&random(num_params(shapes, Layers::DEFAULT), seed + 50, -0.1, 0.1))
            .unwrap();
        let batch = labelled(shapes, 19, seed + 20);
        let plain_batch = transitions_of(shapes, 19, seed + 20);
        let (l0, g0) = dqn.gradients(&plain_batch).unwrap();
        let (l_off, g_off) = dqn.gradients(&batch).unwrap();
        assert_eq!((l0, &g0), (l_off, &g_off), "labels without a margin weight change nothing");
        dqn.set_margin_weight(0.5);
        let (l1, fused) = dqn.gradients(&batch).unwrap();
        assert!(l1 > l0, "the margin adds to the loss: {l1} vs {l0}");
        let st = dqn.stats();
        assert_eq!(st.labelled, 14, "{st:?}");
        assert!(st.margin_sum > 0.0, "{st:?}");
        let plain = autograd(&dqn, &batch);
        let l2 = dqn.loss(&batch).unwrap().to_scalar::<f32>().unwrap();
        assert!((l1 - l2).abs() <= 1e-4 * l2.abs().max(1.0), "loss {l1} vs {l2}");
        for (i, (name, _)) in params(shapes, Layers::DEFAULT).iter().enumerate() {
            close(part(&fused, shapes, i), part(&plain, shapes, i), 1e-3, name);
        }
        assert!(fused.iter().zip(&g0).any(|(a, b)| a != b), "the margin moves the gradient");
    }
}

/// Makes the newest frame of transition `t` nearer on its left half
/// (`left`) or its right one, clearly either way.
fn nearer_half(t: &mut [f32], left: bool) {
    for y in 0..SIDE {
        for x in 0..SIDE {
            let v = &mut t[DEPTH_PIXELS + y * SIDE + x];
            *v = if (x < SIDE / 2) == left { *v * 0.3 } else { 0.7 + *v * 0.3 };
        }
    }
}

/// The imitation loss: one row by hand, then its fused gradients (the
/// softmax minus the softmax over the allowed actions) against candle's
/// autograd over stock ops (log-sum-exp), with the TD loss at half weight,
/// labels of one action and of sets, one shard and two, two and three
/// actions.
#[test]
fn the_imitation_losss_gradients_match_stock_candle() {
    let mut g = [0.0f32; 3];
    let l = teaching::imitation_row(&[0.5, 1.0, 0.0], 0b011, 0.5, 0.5, &mut g);
    let e = [1f32.exp(), 2f32.exp(), 1.0];
    let want = (e[0] + e[1] + e[2]).ln() - (e[0] + e[1]).ln();
    assert!((l - want).abs() < 1e-6, "{l} vs {want}");
    let sum = e.iter().sum::<f32>();
    // Scaled by k = 0.5 over tau = 0.5: once.
    let g_want = [e[0] / sum - e[0] / (e[0] + e[1]), e[1] / sum - e[1] / (e[0] + e[1]), e[2] / sum];
    g.iter().zip(g_want).for_each(|(a, b)| assert!((a - b).abs() < 1e-6, "{g:?}"));
    let goal = Shapes::task(FRAMES, true, true);
    for (seed, threads, shapes) in [(1, 1, Shapes::PAPER), (2, 2, Shapes::PAPER), (3, 2, goal)] {
        let mut dqn = Dqn::with_shapes(cfg(true), shapes, seed, &Device::Cpu).unwrap();
        dqn.set_threads(threads);
        dqn.target
            .load_flat(&random(num_params(shapes, Layers::DEFAULT), seed + 50, -0.1, 0.1))
            .unwrap();
        let mut batch = labelled(shapes, 19, seed + 20);
        let ol = shapes.obs_len();
        for (i, t) in batch.chunks_exact_mut(shapes.transition_len()).enumerate() {
            if shapes.actions == 3 && i % 3 == 0 {
                t[2 * ol + 3] = rotorhive_msg::label_of_mask(0b101);
            }
        }
        let (l0, g0) = dqn.gradients(&batch).unwrap();
        dqn.set_teaching(Teaching { td: 0.5, margin: 0.0, imitation: 0.7, temperature: 0.3 });
        let (l1, fused) = dqn.gradients(&batch).unwrap();
        assert_ne!(l1, l0);
        let st = dqn.stats();
        let tl = shapes.transition_len();
        let labelled = batch.chunks_exact(tl).filter(|t| t[2 * ol + 3] != NO_EXPERT).count();
        assert_eq!(st.labelled as usize, labelled, "{st:?}");
        assert!(labelled >= 14, "{labelled}");
        let plain = autograd(&dqn, &batch);
        let l2 = dqn.loss(&batch).unwrap().to_scalar::<f32>().unwrap();
        assert!((l1 - l2).abs() <= 1e-4 * l2.abs().max(1.0), "loss {l1} vs {l2}");
        for (i, (name, _)) in params(shapes, Layers::DEFAULT).iter().enumerate() {
            close(part(&fused, shapes, i), part(&plain, shapes, i), 1e-3, name);
        }
        assert!(fused.iter().zip(&g0).any(|(a, b)| a != b), "imitation moves the gradient");
    }
}

/// With the TD loss off (`learner.td_weight = 0`), imitation alone makes a
/// learner's greedy action one its labels allow on its training states.
#[test]
fn a_learner_fed_only_labels_by_imitation_agrees_with_them() {
    let shapes = Shapes::task(FRAMES, false, true);
    let (tl, ol) = (shapes.transition_len(), shapes.obs_len());
    let mut dqn =
        Dqn::with_shapes(DqnConfig { lr: 3e-3, ..cfg(true) }, shapes, 7, &Device::Cpu).unwrap();
    dqn.set_teaching(Teaching { td: 0.0, margin: 0.0, imitation: 1.0, temperature: 0.2 });
    // Left half nearer: "go right or hold" (a set); else "go left" alone.
    let mut batch = random(64 * tl, 3, 0.0, 1.0);
    for (i, t) in batch.chunks_exact_mut(tl).enumerate() {
        let left = i % 2 == 0;
        nearer_half(t, left);
        t[2 * ol..2 * ol + 5].copy_from_slice(&[(i % 3) as f32, -3.0, 0.0, 0.0, 0.0]);
        t[2 * ol + 3] = if left { rotorhive_msg::label_of_mask(0b110) } else { 0.0 };
    }
    let obs: Vec<f32> = batch.chunks_exact(tl).flat_map(|t| t[..ol].to_vec()).collect();
    let agree = |dqn: &Dqn| {
        let g = dqn.online.greedy(&obs).unwrap();
        let masks = batch.chunks_exact(tl).map(|t| label_mask(t[2 * ol + 3], 3).unwrap());
        g.iter().zip(masks).filter(|(a, m)| m >> **a & 1 == 1).count()
    };
    let before = agree(&dqn);
    for _ in 0..150 {
        dqn.update(&batch).unwrap();
    }
    let after = agree(&dqn);
    assert!(after >= 62, "greedy agrees with {after} of 64 labels (before: {before})");
}

/// A learner fed only labelled transitions (no reward to tell the actions
/// apart) makes its greedy action agree with the labels.
#[test]
fn a_learner_fed_only_labels_makes_its_argmax_agree_with_them() {
    let shapes = Shapes::PAPER;
    let (tl, ol) = (shapes.transition_len(), shapes.obs_len());
    let mut dqn = Dqn::new(DqnConfig { lr: 3e-3, ..cfg(true) }, 7, &Device::Cpu).unwrap();
    dqn.set_margin_weight(1.0);
    // The label is a function of the observation: action 1 where the
    // left half of the newest frame is nearer than the right.
    let mut batch = random(64 * tl, 3, 0.0, 1.0);
    let label = |t: &[f32]| {
        let frame = &t[DEPTH_PIXELS..2 * DEPTH_PIXELS];
        let half = |r: std::ops::Range<usize>| -> f32 {
            (0..SIDE).flat_map(|y| r.clone().map(move |x| y * SIDE + x)).map(|i| frame[i]).sum()
        };
        (half(0..SIDE / 2) < half(SIDE / 2..SIDE)) as u8 as f32
    };
    for (i, t) in batch.chunks_exact_mut(tl).enumerate() {
        // A bias that makes the halves differ clearly, either way.
        let left = i % 2 == 0;
        nearer_half(t, left);
        let e = label(t);
        t[2 * ol] = (i / 2 % 2) as f32;
        t[2 * ol + 1] = 3.0;
        t[2 * ol + 2] = 0.0;
        t[2 * ol + 3] = e;
        t[2 * ol + 4] = 1.0;
    }
    let agree = |dqn: &Dqn| {
        let obs: Vec<f32> = batch.chunks_exact(tl).flat_map(|t| t[..ol].to_vec()).collect();
        let g = dqn.online.greedy(&obs).unwrap();
        g.iter().zip(batch.chunks_exact(tl)).filter(|(a, t)| **a as f32 == t[2 * ol + 3]).count()
    };
    let before = agree(&dqn);
    for _ in 0..150 {
        dqn.update(&batch).unwrap();
    }
    let after = agree(&dqn);
    assert!(after >= 62, "greedy agrees with {after} of 64 labels (before: {before})");
    assert!(dqn.stats().agree >= 62, "{:?}", dqn.stats());
}

/// The in-place Adam follows candle-nn's AdamW (weight decay 0) step for step.
#[test]
fn adam_matches_candle_nn() {
    use candle_nn::optim::{AdamW, Optimizer, ParamsAdamW};
    let mut dqn = Dqn::new(cfg(false), 5, &Device::Cpu).unwrap();
    let reference = Dqn::new(cfg(false), 5, &Device::Cpu).unwrap();
    let mut opt = AdamW::new(
        reference.online.vars().to_vec(),
        ParamsAdamW { lr: 1e-3, beta1: 0.9, beta2: 0.999, eps: 1e-8, weight_decay: 0.0 },
    )
    .unwrap();
    for step in 0..5 {
        let batch = transitions(4, 30 + step);
        opt.step(&reference.loss(&batch).unwrap().backward().unwrap()).unwrap();
        let grads = autograd(&dqn, &batch);
        dqn.opt_step(&grads).unwrap();
        close(
            &dqn.online.to_flat().unwrap(),
            &reference.online.to_flat().unwrap(),
            1e-4,
            "weights after adam",
        );
    }
}

/// Data-parallel shards give the update of the whole minibatch.
#[test]
fn sharded_updates_match_one_shard() {
    let mut a = Dqn::new(cfg(true), 3, &Device::Cpu).unwrap();
    let mut b = Dqn::new(cfg(true), 3, &Device::Cpu).unwrap();
    a.set_threads(1);
    b.set_threads(2);
    for i in 0..3 {
        let batch = transitions(32, 60 + i);
        let (la, lb) = (a.update(&batch).unwrap(), b.update(&batch).unwrap());
        assert!((la - lb).abs() <= 1e-4 * la.abs().max(1.0), "loss {la} vs {lb}");
    }
    close(&b.online.to_flat().unwrap(), &a.online.to_flat().unwrap(), 1e-4, "weights");
    // The same network's Q-values in one batch and in shards.
    let obs = random(40 * OBS_LEN, 61, 0.0, 1.0);
    let whole = a.online.q_values_sharded(&obs, 1).unwrap();
    let split = a.online.q_values_sharded(&obs, 3).unwrap();
    close(&split, &whole, 1e-5, "sharded q-values");
}

#[test]
fn learner_state_round_trips() {
    let dev = Device::Cpu;
    let mut a = Dqn::new(cfg(true), 1, &dev).unwrap();
    for i in 0..3 {
        a.update(&transitions(8, 40 + i)).unwrap();
    }
    let dir = std::env::temp_dir().join(format!("rotorhive-state-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("learner.safetensors");
    a.save_state(&path).unwrap();
    let mut b = Dqn::new(cfg(true), 2, &dev).unwrap();
    b.load_state(&path).unwrap();
    assert_eq!(b.updates(), 3);
    // The same next update from the same state: weights, moments and step match.
    let batch = transitions(8, 99);
    let la = a.update(&batch).unwrap();
    let lb = b.update(&batch).unwrap();
    assert_eq!(la, lb);
    assert_eq!(a.online.to_flat().unwrap(), b.online.to_flat().unwrap());
    // A truncated state is refused with the file's name.
    let bytes = std::fs::read(&path).unwrap();
    std::fs::write(&path, &bytes[..bytes.len() / 3]).unwrap();
    let e = b.load_state(&path).err().unwrap().to_string();
    assert!(e.contains("learner.safetensors"), "{e}");
    std::fs::remove_dir_all(&dir).unwrap();
}

/// The fused path's gradients of the DQN loss against central finite
/// differences of its loss, in every parameter tensor (convolutions and
/// pooling included).
#[test]
fn gradients_match_finite_differences() {
    let dev = Device::Cpu;
    let mut dqn = Dqn::new(cfg(false), 4, &dev).unwrap();
    // Push the target net away from the online one so the TD error is not zero.
    dqn.target
        .load_flat(&random(num_params(Shapes::PAPER, Layers::DEFAULT), 99, -0.1, 0.1))
        .unwrap();
    let n = 6;
    let mut data = random(n * TRANSITION_LEN, 5, 0.0, 1.0);
    for i in 0..n {
        data[i * TRANSITION_LEN + 2 * OBS_LEN] = (i % 2) as f32;
        data[i * TRANSITION_LEN + 2 * OBS_LEN + 1] = 3.0;
        data[i * TRANSITION_LEN + 2 * OBS_LEN + 2] = if i == 3 { 1.0 } else { 0.0 };
        data[i * TRANSITION_LEN + 2 * OBS_LEN + 3] = NO_EXPERT;
    }
    let batch = data;
    let (_, grads) = dqn.gradients(&batch).unwrap();
    let flat = dqn.online.to_flat().unwrap();
    let mut rng = Pcg64Mcg::seed_from_u64(7);
    let mut off = 0;
    let mut checked = 0;
    for (pi, (name, shape)) in params(Shapes::PAPER, Layers::DEFAULT).iter().enumerate() {
        let len: usize = shape.iter().product();
        assert_eq!(
            len,
            kernels::offsets(Shapes::PAPER, Layers::DEFAULT)[pi + 1]
                - kernels::offsets(Shapes::PAPER, Layers::DEFAULT)[pi],
            "{name}"
        );
        let g = part(&grads, Shapes::PAPER, pi).to_vec();
        // The largest-gradient entry and a few random ones.
        let mut idx: Vec<usize> = (0..4).map(|_| rng.random_range(0..len)).collect();
        idx.push((0..len).max_by(|a, b| g[*a].abs().total_cmp(&g[*b].abs())).unwrap());
        for i in idx {
            // A ReLU or pooling switch within ±eps bends one difference
            // quotient; a smaller step steps over the kink, so one of three
            // steps must agree (a wrong gradient agrees with none).
            let fds: Vec<f32> = [1e-2f32, 3e-3, 1e-3]
                .iter()
                .map(|&eps| {
                    let mut plus = flat.clone();
                    plus[off + i] += eps;
                    dqn.online.load_flat(&plus).unwrap();
                    let lp = dqn.gradients(&batch).unwrap().0;
                    let mut minus = flat.clone();
                    minus[off + i] -= eps;
                    dqn.online.load_flat(&minus).unwrap();
                    let lm = dqn.gradients(&batch).unwrap().0;
                    (lp - lm) / (2.0 * eps)
                })
                .collect();
            dqn.online.load_flat(&flat).unwrap();
            let ok =
                fds.iter().any(|fd| (fd - g[i]).abs() <= 2e-3 + 0.05 * fd.abs().max(g[i].abs()));
            assert!(ok, "{name}[{i}]: backward {} vs finite differences {fds:?}", g[i]);
            checked += 1;
        }
        off += len;
    }
    assert_eq!(checked, 50);
}

#[test]
fn flat_weights_and_checkpoints_round_trip() {
    let dev = Device::Cpu;
    let a = QNet::new(1, &dev).unwrap();
    let b = QNet::new(2, &dev).unwrap();
    assert_ne!(a.to_flat().unwrap(), b.to_flat().unwrap());
    b.load_flat(&a.to_flat().unwrap()).unwrap();
    assert_eq!(a.to_flat().unwrap(), b.to_flat().unwrap());
    assert_eq!(a.to_flat().unwrap().len(), num_params(Shapes::PAPER, Layers::DEFAULT));
    // Written straight into a buffer (as into a loaned message): the same
    // floats; a buffer of the wrong size is refused.
    let mut buf = vec![f32::NAN; num_params(Shapes::PAPER, Layers::DEFAULT)];
    b.write_flat(&mut buf).unwrap();
    assert_eq!(buf, a.to_flat().unwrap());
    assert!(b.write_flat(&mut buf[1..]).unwrap_err().to_string().contains("weights buffer"));
    assert!(b.load_flat(&buf[1..]).is_err());
    // Loaded in place, the network computes with the new weights.
    let obs = random(3 * OBS_LEN, 4, 0.0, 1.0);
    assert_eq!(a.q_values(&obs).unwrap(), b.q_values(&obs).unwrap());

    let dir = std::env::temp_dir().join(format!("rotorhive-model-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("w.safetensors");
    a.save(&path).unwrap();
    let c = QNet::new(3, &dev).unwrap();
    c.load(&path).unwrap();
    assert_eq!(a.to_flat().unwrap(), c.to_flat().unwrap());

    // A truncated file and a foreign file are refused with the file's name.
    let bytes = std::fs::read(&path).unwrap();
    std::fs::write(&path, &bytes[..bytes.len() / 2]).unwrap();
    let e = c.load(&path).unwrap_err().to_string();
    assert!(e.contains("w.safetensors") && e.contains("valid"), "{e}");
    let other = HashMap::from([(
        "conv1.weight".to_string(),
        Tensor::zeros((3, 3), DType::F32, &dev).unwrap(),
    )]);
    candle_core::safetensors::save(&other, &path).unwrap();
    let e = c.load(&path).unwrap_err().to_string();
    assert!(e.contains("shape") || e.contains("missing"), "{e}");

    // The header describes the network; one written for another is refused
    // with the difference named.
    a.save_with(&path, &[("config_crc32c", "1234abcd".into())]).unwrap();
    let bytes = std::fs::read(&path).unwrap();
    let (_, header) = safetensors::SafeTensors::read_metadata(&bytes).unwrap();
    let meta = header.metadata().clone().unwrap();
    assert_eq!(meta["layout"], CHECKPOINT_LAYOUT);
    assert_eq!(meta["obs_len"], OBS_LEN.to_string());
    assert_eq!(meta["config_crc32c"], "1234abcd");
    // The same weights, the same bytes (the header's maps are written sorted).
    for _ in 0..5 {
        a.save_with(&path, &[("config_crc32c", "1234abcd".into())]).unwrap();
        assert_eq!(std::fs::read(&path).unwrap(), bytes);
    }
    let mut foreign = checkpoint_metadata(Shapes::PAPER);
    foreign.insert("layout".into(), "rotorhive-qnet/0".into());
    foreign.insert("actions".into(), "3".into());
    let tensors: Vec<(String, Tensor)> = a.named().into_iter().collect();
    safetensors::serialize_to_file(tensors, Some(foreign), &path).unwrap();
    let e = c.load(&path).unwrap_err().to_string();
    assert!(
        e.contains("layout rotorhive-qnet/0") && e.contains("actions 3 (this network: 2)"),
        "{e}"
    );
    // A goal task's network with four frames three actions apart: its
    // header says its shapes, a network of the paper's refuses it by name,
    // and one of its shapes loads it.
    let goal = Shapes::task(4, true, true).with_stride(3);
    let g = QNet::with_shapes(goal, 9, &dev).unwrap();
    g.save(&path).unwrap();
    assert_eq!(checkpoint_shapes(&path).unwrap(), goal);
    let e = c.load(&path).unwrap_err().to_string();
    assert!(
        e.contains("obs_len 4102 (this network: 2051)")
            && e.contains("frames 4 (this network: 2)")
            && e.contains("frame_stride 3 (this network: 1)")
            && e.contains("scalars 6 (this network: 3)")
            && e.contains("actions 3 (this network: 2)"),
        "{e}"
    );
    let h = QNet::with_shapes(checkpoint_shapes(&path).unwrap(), 0, &dev).unwrap();
    h.load(&path).unwrap();
    let obs = random(2 * goal.obs_len(), 5, 0.0, 1.0);
    assert_eq!(h.q_values(&obs).unwrap(), g.q_values(&obs).unwrap());
    assert_eq!(h.q_values(&obs).unwrap().len(), 2 * 3);
    // The same network trained on consecutive frames reads them otherwise.
    let e = QNet::with_shapes(Shapes::task(4, true, true), 0, &dev)
        .unwrap()
        .load(&path)
        .unwrap_err()
        .to_string();
    assert!(e.contains("frame_stride 3 (this network: 1)") && !e.contains("obs_len"), "{e}");
    // A network reading the camera's map names it, and one without a map
    // (or with another) refuses it by name.
    let mapped = Shapes::PAPER.with_map(72);
    let m = QNet::with_shapes(mapped, 3, &dev).unwrap();
    m.save(&path).unwrap();
    assert_eq!(checkpoint_shapes(&path).unwrap(), mapped);
    let e = c.load(&path).unwrap_err().to_string();
    assert!(
        e.contains("map 72 (this network: 0)") && e.contains("scalars 75 (this network: 3)"),
        "{e}"
    );
    let e = QNet::with_shapes(Shapes::PAPER.with_map(256), 0, &dev)
        .unwrap()
        .load(&path)
        .unwrap_err()
        .to_string();
    assert!(e.contains("map 72 (this network: 256)"), "{e}");
    QNet::with_shapes(mapped, 0, &dev).unwrap().load(&path).unwrap();
    // So does one reading the seen movers, after the map.
    let tracked = mapped.with_tracks(5 * rotorhive_msg::TRACK_FLOATS);
    QNet::with_shapes(tracked, 3, &dev).unwrap().save(&path).unwrap();
    assert_eq!(checkpoint_shapes(&path).unwrap(), tracked);
    let e = QNet::with_shapes(mapped, 0, &dev).unwrap().load(&path).unwrap_err().to_string();
    assert!(e.contains("tracks 70 (this network: 0)"), "{e}");
    QNet::with_shapes(tracked, 0, &dev).unwrap().load(&path).unwrap();
    // A header that claims shapes no task has is refused by name.
    for (key, value, claim) in [
        ("scalars", "7", "header claims 7 observation scalars"),
        ("frames", "9", "header claims 9 depth frames (1 to 8)"),
        ("frame_stride", "0", "header claims a frame stride of 0 action periods (1 to 8)"),
    ] {
        let mut odd = checkpoint_metadata(goal);
        odd.insert(key.into(), value.into());
        let tensors: Vec<(String, Tensor)> = g.named().into_iter().collect();
        safetensors::serialize_to_file(tensors, Some(odd), &path).unwrap();
        let e = checkpoint_shapes(&path).unwrap_err().to_string();
        assert!(e.contains(claim), "{e}");
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

/// A network of other widths: its header names them, a network of the
/// design's widths refuses it by name (and it the design's), `PolicyNet`
/// and `checkpoint_layers` load it as it is, with or without memory.
#[test]
fn a_network_of_other_widths_round_trips_and_is_refused_by_name() {
    let dev = Device::Cpu;
    let dir = std::env::temp_dir().join(format!("rotorhive-layers-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("w.safetensors");
    let layers = Layers::new(&[24, 40], &[96, 32]).unwrap();
    let obs = random(3 * OBS_LEN, 4, 0.0, 1.0);
    for memory in [None, Some(8)] {
        let a = PolicyNet::new(Shapes::PAPER, layers, memory, 3, &dev).unwrap();
        a.save(&path, &[]).unwrap();
        assert_eq!(checkpoint_layers(&path).unwrap(), layers);
        assert_eq!(checkpoint_memory(&path).unwrap(), memory);
        let b = PolicyNet::load(&path).unwrap();
        assert_eq!((b.layers(), b.memory()), (layers, memory));
        let (mut sa, mut sb) = (Vec::new(), Vec::new());
        assert_eq!(a.q_values(&obs, &mut sa).unwrap(), b.q_values(&obs, &mut sb).unwrap());
        let plain = PolicyNet::new(Shapes::PAPER, Layers::DEFAULT, memory, 0, &dev).unwrap();
        let e = plain.load_checkpoint(&path).unwrap_err().to_string();
        assert!(
            e.contains("layers conv:24,40 hidden:96,32 (this network: conv:16,32 hidden:64)"),
            "{e}"
        );
        plain.save(&path, &[]).unwrap();
        let e = a.load_checkpoint(&path).unwrap_err().to_string();
        assert!(e.contains("layers conv:16,32 hidden:64 (this network: conv:24,40"), "{e}");
    }
    // The design's network names no widths: its header is an earlier
    // build's.
    QNet::new(1, &dev).unwrap().save(&path).unwrap();
    let bytes = std::fs::read(&path).unwrap();
    let (_, header) = safetensors::SafeTensors::read_metadata(&bytes).unwrap();
    assert!(!header.metadata().clone().unwrap().contains_key("layers"));
    assert_eq!(checkpoint_layers(&path).unwrap(), Layers::DEFAULT);
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn updates_reduce_the_loss_on_a_fixed_batch() {
    let dev = Device::Cpu;
    let mut dqn = Dqn::new(
        DqnConfig {
            lr: 1e-3,
            lr_final: 1e-3,
            lr_decay_updates: 0,
            gamma: 0.0,
            target_update: 10_000,
            huber_delta: 1.0,
            double: false,
            reward_scale: 1.0,
            max_grad_norm: 0.0,
            margin: 0.8,
        },
        1,
        &dev,
    )
    .unwrap();
    let n = 32;
    let mut data = random(n * TRANSITION_LEN, 11, 0.0, 1.0);
    for i in 0..n {
        data[i * TRANSITION_LEN + 2 * OBS_LEN] = (i % 2) as f32;
        data[i * TRANSITION_LEN + 2 * OBS_LEN + 1] = if i % 2 == 0 { 3.0 } else { -1.0 };
        data[i * TRANSITION_LEN + 2 * OBS_LEN + 3] = NO_EXPERT;
    }
    let first = dqn.update(&data).unwrap();
    let mut last = first;
    for _ in 0..60 {
        last = dqn.update(&data).unwrap();
    }
    assert!(last < first * 0.2, "loss went from {first} to {last}");
    assert_eq!(dqn.updates(), 61);
}

#[test]
fn a_non_finite_loss_skips_the_update_and_changes_nothing() {
    let dev = Device::Cpu;
    let mut dqn = Dqn::new(cfg(true), 3, &dev).unwrap();
    let good = transitions(32, 5);
    dqn.update(&good).unwrap();
    let before = dqn.online.to_flat().unwrap();
    let mut bad = good.clone();
    bad[7 * TRANSITION_LEN + 2 * OBS_LEN + 1] = f32::NAN;
    let loss = dqn.update(&bad).unwrap();
    assert!(!loss.is_finite());
    assert_eq!((dqn.skipped(), dqn.updates()), (1, 2));
    assert_eq!(dqn.online.to_flat().unwrap(), before, "a skipped update must not move the weights");
    // An infinite observation gives non-finite gradients too.
    bad = good.clone();
    bad[3] = f32::INFINITY;
    dqn.update(&bad).unwrap();
    assert_eq!(dqn.skipped(), 2);
    assert_eq!(dqn.online.to_flat().unwrap(), before);
    // Training goes on afterwards.
    assert!(dqn.update(&good).unwrap().is_finite());
    assert_ne!(dqn.online.to_flat().unwrap(), before);
    assert!(dqn.online.to_flat().unwrap().iter().all(|v| v.is_finite()));
}

#[test]
fn the_reward_scale_scales_the_td_target() {
    // gamma 0: the target is the scaled reward alone, so the loss's
    // gradient on Q(s, a) is Q − scale·r and the stats see it.
    let dev = Device::Cpu;
    let batch = transitions(16, 9);
    let stats_with = |scale: f32| {
        let mut d = Dqn::new(
            DqnConfig { gamma: 0.0, huber_delta: 1e6, reward_scale: scale, ..cfg(false) },
            4,
            &dev,
        )
        .unwrap();
        d.update(&batch).unwrap();
        d.stats()
    };
    let (one, small) = (stats_with(1.0), stats_with(0.01));
    // The rewards are +3 and −100: |Q − r| is about the reward's size at
    // scale 1 and a hundred times smaller at 0.01.
    assert!(one.abs_td_sum / 16.0 > 20.0, "{one:?}");
    assert!(small.abs_td_sum / 16.0 < 1.0, "{small:?}");
    assert_eq!((one.rows, one.terminal), (16, 6));
    assert_eq!(one.max_q_sum, small.max_q_sum, "the same network sees the same Q-values");
}

#[test]
fn clipping_bounds_the_step_by_the_gradient_norm() {
    // With Adam the first step's size does not depend on the gradient's
    // scale, so compare what clipping feeds Adam: the moments. Two learners
    // on the same batch, one clipped to a tiny norm: the clipped one's
    // first moment is the unclipped one's times max/norm.
    let dev = Device::Cpu;
    let batch = transitions(32, 12);
    let mut free = Dqn::new(cfg(true), 6, &dev).unwrap();
    let mut clipped = Dqn::new(DqnConfig { max_grad_norm: 1e-3, ..cfg(true) }, 6, &dev).unwrap();
    free.update(&batch).unwrap();
    clipped.update(&batch).unwrap();
    let norm = free.stats().grad_norm;
    assert!(norm > 1e-3, "{norm}");
    assert_eq!(clipped.stats().grad_norm, norm, "the norm is reported before clipping");
    let k = (1e-3 / norm) as f32;
    let (mf, mc) = (free.first_moments(), clipped.first_moments());
    for (a, b) in mf.iter().zip(&mc) {
        assert!((a * k - b).abs() <= 1e-6 * a.abs().max(1e-3), "{a}·{k} vs {b}");
    }
}

#[test]
fn importance_weights_scale_each_rows_gradient_on_both_paths() {
    // Weights of 1 are the plain update; other weights give the gradient of
    // the weighted mean loss, the same on the fused and the generic path;
    // the per-row TD errors agree too.
    let dev = Device::Cpu;
    let batch = transitions(16, 21);
    let w: Vec<f32> = (0..16).map(|i| 0.25 + (i % 4) as f32 * 0.25).collect();
    let mut fused = Dqn::new(cfg(true), 8, &dev).unwrap();
    let mut plain = Dqn::new(cfg(true), 8, &dev).unwrap();
    let mut generic = Dqn::new(cfg(true), 8, &dev).unwrap();
    generic.set_fused(false).unwrap();
    fused.set_threads(2);
    plain.set_threads(2);
    let ones = vec![1.0; 16];
    fused.update_weighted(&batch, Some(&ones)).unwrap();
    plain.update(&batch).unwrap();
    assert!(
        fused.online.to_flat().unwrap() == plain.online.to_flat().unwrap(),
        "weights of 1 must change nothing"
    );
    assert_eq!(fused.td_abs().len(), 16);
    let (mut a, mut b) = (Dqn::new(cfg(true), 8, &dev).unwrap(), generic);
    a.set_threads(2);
    let la = a.update_weighted(&batch, Some(&w)).unwrap();
    let lb = b.update_weighted(&batch, Some(&w)).unwrap();
    assert!((la - lb).abs() <= 1e-4 * lb.abs().max(1.0), "{la} vs {lb}");
    close(a.td_abs(), b.td_abs(), 1e-4, "td");
    close(&a.first_moments(), &b.first_moments(), 1e-3, "weighted gradients");
    assert!(
        a.update_weighted(&batch, Some(&w[..3]))
            .unwrap_err()
            .to_string()
            .contains("importance weights")
    );
}

// Networks of other cameras' frames.
mod frames;
