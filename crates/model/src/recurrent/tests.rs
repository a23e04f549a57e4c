use super::update::sequence_priorities;
use super::*;
use crate::{Dqn, DqnConfig, QNet, Teaching};
use rotorhive_msg::NO_EXPERT;

const SHAPES: Shapes = Shapes::PAPER;

/// The sequence update's settings the tests start from.
fn base_config() -> SeqConfig {
    SeqConfig {
        lr: 1e-3,
        lr_final: 1e-3,
        lr_decay_updates: 0,
        max_grad_norm: 0.0,
        double: true,
        gamma: 0.9,
        n_step: 3,
        burn_in: 2,
        target_update: 10,
        huber_delta: 1.0,
        reward_scale: 1.0,
        margin: 0.8,
    }
}

fn random_obs(rng: &mut Pcg64Mcg, n: usize) -> Vec<f32> {
    (0..n * SHAPES.obs_len()).map(|_| rng.random_range(0.0..1.0)).collect()
}

#[test]
fn stepping_equals_unrolling_and_a_state_carries_exactly() {
    let dev = Device::Cpu;
    let net = RecurrentQNet::new(SHAPES, 8, 3, &dev).unwrap();
    let (t, b, len) = (6, 3, SHAPES.obs_len());
    let mut rng = Pcg64Mcg::seed_from_u64(9);
    let obs = random_obs(&mut rng, t * b);
    let h0: Vec<f32> = (0..b * 8).map(|_| rng.random_range(-1.0..1.0)).collect();
    let all = Tensor::from_slice(&obs, (t, b, len), &dev).unwrap();
    let ones = Tensor::ones((t, b), DType::F32, &dev).unwrap();
    let h0t = Tensor::from_slice(&h0, (b, 8), &dev).unwrap();
    let (q, h_end) = net.unroll(&all, &h0t, &ones).unwrap();
    let q = q.flatten_all().unwrap().to_vec1::<f32>().unwrap();
    // One step at a time, the state carried by the caller.
    let mut state = h0.clone();
    let mut stepped = Vec::new();
    for s in 0..t {
        stepped.extend(net.step(&obs[s * b * len..(s + 1) * b * len], &mut state).unwrap());
    }
    let close = |a: &[f32], b: &[f32]| a.iter().zip(b).all(|(x, y)| (x - y).abs() < 1e-5);
    assert!(close(&q, &stepped), "{q:?}\n{stepped:?}");
    assert!(close(&state, &h_end.flatten_all().unwrap().to_vec1::<f32>().unwrap()));
    // Three steps, then three more from the state reached: the same.
    let (_, h3) =
        net.unroll(&all.narrow(0, 0, 3).unwrap(), &h0t, &ones.narrow(0, 0, 3).unwrap()).unwrap();
    let (q_rest, _) =
        net.unroll(&all.narrow(0, 3, 3).unwrap(), &h3, &ones.narrow(0, 3, 3).unwrap()).unwrap();
    assert!(close(&q[3 * b * 2..], &q_rest.flatten_all().unwrap().to_vec1::<f32>().unwrap()));
    // The state matters: another start state gives other Q-values.
    let mut zero = vec![0.0; b * 8];
    assert!(!close(&net.step(&obs[..b * len], &mut zero).unwrap(), &q[..b * 2]));
}

#[test]
fn a_zeroed_state_starts_afresh() {
    let dev = Device::Cpu;
    let net = RecurrentQNet::new(SHAPES, 4, 5, &dev).unwrap();
    let mut rng = Pcg64Mcg::seed_from_u64(2);
    let obs = random_obs(&mut rng, 3);
    let all = Tensor::from_slice(&obs, (3, 1, SHAPES.obs_len()), &dev).unwrap();
    let keep = Tensor::from_slice(&[1.0f32, 1.0, 0.0], (3, 1), &dev).unwrap();
    let h0 = Tensor::ones((1, 4), DType::F32, &dev).unwrap();
    let (q, _) = net.unroll(&all, &h0, &keep).unwrap();
    let q = q.flatten_all().unwrap().to_vec1::<f32>().unwrap();
    let mut zero = vec![0.0; 4];
    let fresh = net.step(&obs[2 * SHAPES.obs_len()..], &mut zero).unwrap();
    assert!((q[4] - fresh[0]).abs() < 1e-6 && (q[5] - fresh[1]).abs() < 1e-6);
}

/// The cue task: an episode of four observations on a blank (noisy) depth
/// image; the first shows a cue (+1 or −1 in the first scalar), the last
/// says "decide" (the second scalar); the action there earns +1 if it
/// matches the cue (action 0 for +1), −1 if not; nothing else pays. At the
/// decision, the observation is the same for both cues: only memory can
/// tell them apart.
struct Cue {
    rng: Pcg64Mcg,
}

const EPISODE: usize = 4;
const UPDATES: u64 = 150;

impl Cue {
    /// One episode's observations (and a fifth, the next episode's start,
    /// for the bootstrap of the last transition) for `cue`.
    fn observations(&mut self, cue: f32) -> Vec<f32> {
        let (len, depth) = (SHAPES.obs_len(), SHAPES.obs_depth());
        let mut out = vec![0.0; (EPISODE + 1) * len];
        for (s, o) in out.chunks_exact_mut(len).enumerate() {
            for d in &mut o[..depth] {
                *d = self.rng.random_range(0.4..0.6);
            }
            o[depth] = if s == 0 || s == EPISODE { cue } else { 0.0 };
            o[depth + 1] = if s == EPISODE - 1 { 1.0 } else { 0.0 };
        }
        out
    }

    fn reward(cue: f32, step: usize, action: u8) -> f32 {
        match step {
            s if s < EPISODE - 1 => 0.0,
            _ if (action == 0) == (cue > 0.0) => 1.0,
            _ => -1.0,
        }
    }

    /// `n` episodes with uniformly random actions: cues, observations,
    /// actions, rewards.
    fn episodes(&mut self, n: usize) -> (Vec<f32>, Vec<f32>, Vec<u8>, Vec<f32>) {
        let (mut cues, mut obs, mut acts, mut rews) = (vec![], vec![], vec![], vec![]);
        for _ in 0..n {
            let cue = if self.rng.random::<bool>() { 1.0 } else { -1.0 };
            cues.push(cue);
            obs.extend(self.observations(cue));
            for s in 0..EPISODE {
                let a = self.rng.random_range(0..2u8);
                acts.push(a);
                rews.push(Self::reward(cue, s, a));
            }
        }
        (cues, obs, acts, rews)
    }
}

/// Of `n` episodes per cue, the share whose decision matched the cue.
fn success(mut decide: impl FnMut(&[f32]) -> u8, cue_task: &mut Cue, n: usize) -> f64 {
    let mut right = 0;
    for i in 0..2 * n {
        let cue = if i % 2 == 0 { 1.0 } else { -1.0 };
        let obs = cue_task.observations(cue);
        let a = decide(&obs);
        right += (Cue::reward(cue, EPISODE - 1, a) > 0.0) as usize;
    }
    right as f64 / (2 * n) as f64
}

#[test]
fn a_cue_needed_later_is_learned_with_memory_and_not_without() {
    let dev = Device::Cpu;
    let len = SHAPES.obs_len();
    let cfg = SeqConfig { lr: 3e-3, n_step: 1, burn_in: 0, target_update: 25, ..base_config() };
    let mut seq = SeqDqn::new(cfg, SHAPES, 16, 1, &dev).unwrap();
    let dqn_cfg = DqnConfig {
        lr: 1e-3,
        lr_final: 1e-3,
        lr_decay_updates: 0,
        gamma: 0.9,
        target_update: 25,
        huber_delta: 1.0,
        double: true,
        reward_scale: 1.0,
        max_grad_norm: 0.0,
        margin: 0.8,
    };
    let mut ff = Dqn::with_shapes(dqn_cfg, SHAPES, 1, &dev).unwrap();
    let mut task = Cue { rng: Pcg64Mcg::seed_from_u64(7) };
    let sequences = 8;
    let dones: Vec<bool> = (0..sequences * EPISODE).map(|i| i % EPISODE == EPISODE - 1).collect();
    let states = vec![0.0; sequences * 16];
    for _ in 0..UPDATES {
        let (_, obs, actions, rewards) = task.episodes(sequences);
        let batch = SeqBatch {
            sequences,
            steps: EPISODE,
            obs: &obs,
            actions: &actions,
            rewards: &rewards,
            dones: &dones,
            states: &states,
            experts: &[],
            weights: &[],
        };
        let loss = seq.update(&batch).unwrap();
        assert!(loss.is_finite());
        // The same transitions for the feedforward network.
        let mut rows = Vec::with_capacity(sequences * EPISODE * SHAPES.transition_len());
        for i in 0..sequences {
            let o = &obs[i * (EPISODE + 1) * len..(i + 1) * (EPISODE + 1) * len];
            for s in 0..EPISODE {
                let k = i * EPISODE + s;
                rows.extend_from_slice(&o[s * len..(s + 1) * len]);
                rows.extend_from_slice(&o[(s + 1) * len..(s + 2) * len]);
                let done = if dones[k] { 1.0 } else { 0.0 };
                rows.extend([actions[k] as f32, rewards[k], done, NO_EXPERT, 0.0]);
            }
        }
        ff.update(&rows).unwrap();
    }
    assert_eq!(seq.updates(), UPDATES);
    let net = &seq.online;
    let with_memory = success(
        |obs| {
            let mut h = vec![0.0; 16];
            let mut a = 0;
            for s in 0..EPISODE {
                a = net.greedy(&obs[s * len..(s + 1) * len], &mut h).unwrap()[0];
            }
            a
        },
        &mut task,
        50,
    );
    // The same network with its state zeroed at every step: no memory.
    let zeroed = success(
        |obs| {
            let at = (EPISODE - 1) * len;
            net.greedy(&obs[at..at + len], &mut [0.0; 16]).unwrap()[0]
        },
        &mut task,
        50,
    );
    let online: &QNet = &ff.online;
    let feedforward = success(
        |obs| online.greedy(&obs[(EPISODE - 1) * len..EPISODE * len]).unwrap()[0],
        &mut task,
        50,
    );
    assert!(with_memory >= 0.95, "with memory: {with_memory}");
    assert!(zeroed <= 0.6 && feedforward <= 0.6, "zeroed: {zeroed}, feedforward: {feedforward}");
}

#[test]
fn a_bad_sequence_batch_is_refused_by_name() {
    let dev = Device::Cpu;
    let cfg = base_config();
    let mut seq = SeqDqn::new(cfg, SHAPES, 4, 1, &dev).unwrap();
    let mut rng = Pcg64Mcg::seed_from_u64(1);
    let obs = random_obs(&mut rng, 6);
    let (acts, rews, dones, states) = (vec![0u8; 5], vec![0.5; 5], vec![false; 5], vec![0.0; 4]);
    let good = SeqBatch {
        sequences: 1,
        steps: 5,
        obs: &obs,
        actions: &acts,
        rewards: &rews,
        dones: &dones,
        states: &states,
        experts: &[],
        weights: &[],
    };
    assert!(seq.update(&good).unwrap().is_finite());
    let bad_action = [0u8, 0, 7, 0, 0];
    let e = seq.update(&SeqBatch { actions: &bad_action, ..good }).unwrap_err().to_string();
    assert!(e.contains("sequence action"), "{e}");
    let e = seq.update(&SeqBatch { states: &states[..3], ..good }).unwrap_err().to_string();
    assert!(e.contains("sequence states"), "{e}");
    let short = SeqBatch { steps: 2, obs: &obs[..3 * SHAPES.obs_len()], ..good };
    let e = seq
        .update(&SeqBatch { actions: &acts[..2], rewards: &rews[..2], dones: &dones[..2], ..short })
        .unwrap_err()
        .to_string();
    assert!(e.contains("burn-in"), "{e}");
    let nan = [0.5, f32::NAN, 0.5, 0.5, 0.5];
    let e = seq.update(&SeqBatch { rewards: &nan, ..good }).unwrap_err().to_string();
    assert!(e.contains("finite"), "{e}");
    assert!(RecurrentQNet::new(SHAPES, 0, 1, &dev).is_err());
}

#[test]
fn n_step_targets_stop_at_an_episode_end_and_at_the_sequence_end() {
    let cfg = SeqConfig { gamma: 0.5, n_step: 2, burn_in: 1, ..base_config() };
    let seq = SeqDqn::new(cfg, SHAPES, 4, 1, &Device::Cpu).unwrap();
    let (rewards, dones) = ([1.0, 2.0, 3.0, 4.0], [false, false, true, false]);
    let b = SeqBatch {
        sequences: 1,
        steps: 4,
        obs: &[],
        actions: &[0; 4],
        rewards: &rewards,
        dones: &dones,
        states: &[],
        experts: &[],
        weights: &[],
    };
    // Online Q-values from the burn-in's end (observations 1..=4), target
    // ones from the start (0..=4); the online network picks action 1 at
    // observation 4, the target values it at 10.
    let q: Vec<Vec<Vec<f32>>> = (1..=4).map(|s| vec![vec![0.0, s as f32]]).collect();
    let qt: Vec<Vec<Vec<f32>>> =
        (0..=4).map(|s| vec![vec![100.0, 10.0 * s as f32 / 4.0]]).collect();
    let y = seq.targets(&b, &q, &qt);
    // Step 1: 2 + 0.5·3, and the episode ends at step 2: no bootstrap.
    // Step 2: 3, the end. Step 3: 4, then the sequence ends: 0.5·Q'(s4, 1).
    assert_eq!(y, vec![3.5, 3.0, 4.0 + 0.5 * 10.0]);
}

#[test]
fn the_fused_trunk_gives_the_generic_gradients() {
    let dev = Device::Cpu;
    let cfg = SeqConfig { reward_scale: 0.5, ..base_config() };
    let (n, t, width) = (3, 7, 8);
    let mut rng = Pcg64Mcg::seed_from_u64(4);
    let obs = random_obs(&mut rng, n * (t + 1));
    let actions: Vec<u8> = (0..n * t).map(|_| rng.random_range(0..2)).collect();
    let rewards: Vec<f32> = (0..n * t).map(|_| rng.random_range(-1.0..1.0)).collect();
    let dones: Vec<bool> = (0..n * t).map(|i| i % 5 == 3).collect();
    let states: Vec<f32> = (0..n * width).map(|_| rng.random_range(-1.0..1.0)).collect();
    let batch = SeqBatch {
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
    let mut fused = SeqDqn::new(cfg, SHAPES, width, 6, &dev).unwrap();
    let mut generic = SeqDqn::new(cfg, SHAPES, width, 6, &dev).unwrap();
    generic.set_fused(false).unwrap();
    assert!(fused.online.fused() && !generic.online.fused());
    let (lf, gf) = fused.gradients(&batch).unwrap();
    let (lg, gg) = generic.gradients(&batch).unwrap();
    assert!((lf - lg).abs() < 1e-5 * lg.abs().max(1.0), "loss {lf} against {lg}");
    assert_eq!(gf.len(), fused.online.num_params());
    same_gradients(&gf, &gg, width);
    // DQfD's margin on the steps the teacher labelled (two in three, the
    // burn-in's too, which must not count): the same on both paths, and it
    // moves the loss and the gradient.
    let experts: Vec<f32> =
        (0..n * t).map(|i| if i % 3 == 2 { NO_EXPERT } else { (i % 2) as f32 }).collect();
    let labelled = SeqBatch { experts: &experts, ..batch };
    let (l0, g0) = fused.gradients(&labelled).unwrap();
    assert_eq!((l0, &g0), (lf, &gf), "labels without a margin weight change nothing");
    fused.set_margin_weight(0.5);
    generic.set_margin_weight(0.5);
    let burn_only: Vec<f32> =
        (0..n * t).map(|i| if i % t < cfg.burn_in { 1.0 } else { NO_EXPERT }).collect();
    let burn_labelled = SeqBatch { experts: &burn_only, ..batch };
    assert_eq!(fused.gradients(&burn_labelled).unwrap().0, lf, "the burn-in is not trained");
    let (lm, gm) = fused.gradients(&labelled).unwrap();
    let (lmg, gmg) = generic.gradients(&labelled).unwrap();
    assert!(lm > lf, "the margin adds to the loss: {lm} against {lf}");
    assert!((lm - lmg).abs() < 1e-5 * lmg.abs().max(1.0), "loss {lm} against {lmg}");
    same_gradients(&gm, &gmg, width);
    assert!(gm.iter().zip(&gf).any(|(a, b)| a != b), "the margin moves the gradient");
    assert_eq!(fused.gradients(&batch).unwrap().0, lf, "no label, no margin");
    // Prioritized replay's importance weights: ones change nothing, a
    // scale scales the TD loss, and both paths agree on uneven ones.
    fused.set_margin_weight(0.0);
    generic.set_margin_weight(0.0);
    let ones = SeqBatch { weights: &[1.0; 3], ..batch };
    assert!((fused.gradients(&ones).unwrap().0 - lf).abs() <= 1e-6 * lf.abs().max(1.0));
    let twice = SeqBatch { weights: &[2.0; 3], ..batch };
    let l2 = fused.gradients(&twice).unwrap().0;
    assert!((l2 - 2.0 * lf).abs() <= 1e-5 * lf.abs().max(1.0), "{l2} against 2 x {lf}");
    let uneven = SeqBatch { weights: &[0.5, 1.5, 0.0], ..batch };
    let (lw, gw) = fused.gradients(&uneven).unwrap();
    let (lwg, gwg) = generic.gradients(&uneven).unwrap();
    assert!((lw - lwg).abs() < 1e-5 * lwg.abs().max(1.0), "loss {lw} against {lwg}");
    same_gradients(&gw, &gwg, width);
    // Each sequence's priority: R2D2's mix of its largest and mean |TD|.
    let p = fused.priorities().to_vec();
    assert_eq!(p.len(), n);
    assert!(p.iter().all(|x| x.is_finite() && *x > 0.0), "{p:?}");
    let close = p.iter().zip(generic.priorities()).all(|(a, b)| (a - b).abs() < 1e-4);
    assert!(close, "{p:?} against {:?}", generic.priorities());
    let bad = SeqBatch { weights: &[1.0, f32::NAN, 1.0], ..batch };
    assert!(fused.gradients(&bad).unwrap_err().to_string().contains("finite"));
    let short = SeqBatch { weights: &[1.0], ..batch };
    assert!(fused.gradients(&short).unwrap_err().to_string().contains("importance weights"));
    // And a step of each keeps them together.
    fused.update(&batch).unwrap();
    generic.update(&batch).unwrap();
    let mut state = (vec![0.0; width], vec![0.0; width]);
    let len = SHAPES.obs_len();
    let qf = fused.online.step(&obs[..len], &mut state.0).unwrap();
    let qg = generic.online.step(&obs[..len], &mut state.1).unwrap();
    assert!(qf.iter().zip(&qg).all(|(a, b)| (a - b).abs() < 1e-4), "{qf:?} {qg:?}");
}

/// Per parameter of a network of `width`: the fused gradient `gf` within
/// 1e-3 of the generic one `gg` (the difference's norm against the
/// gradient's).
fn same_gradients(gf: &[f32], gg: &[f32], width: usize) {
    same_gradients_of(gf, gg, Layers::DEFAULT, width);
}

/// [`same_gradients`] for a trunk of widths `layers`.
fn same_gradients_of(gf: &[f32], gg: &[f32], layers: Layers, width: usize) {
    let mut off = 0;
    for (name, shape) in recurrent_params(SHAPES, layers, width) {
        let k: usize = shape.iter().product();
        let (a, b) = (&gf[off..off + k], &gg[off..off + k]);
        let diff = a.iter().zip(b).map(|(x, y)| (x - y) * (x - y)).sum::<f32>().sqrt();
        let norm = b.iter().map(|y| y * y).sum::<f32>().sqrt();
        assert!(norm > 0.0, "{name}: no gradient");
        assert!(diff <= 1e-3 * norm, "{name}: |fused - generic| {diff} against |generic| {norm}");
        off += k;
    }
}

/// A trunk of other widths (two hidden layers): the fused trunk's
/// gradients are the generic path's, and a step of each keeps them together.
#[test]
fn a_trunk_of_other_widths_gives_the_generic_gradients() {
    let dev = Device::Cpu;
    let layers = Layers::new(&[12, 20], &[40, 24]).unwrap();
    let (n, t, width) = (2, 6, 8);
    let mut rng = Pcg64Mcg::seed_from_u64(9);
    let obs = random_obs(&mut rng, n * (t + 1));
    let actions: Vec<u8> = (0..n * t).map(|_| rng.random_range(0..2)).collect();
    let rewards: Vec<f32> = (0..n * t).map(|_| rng.random_range(-1.0..1.0)).collect();
    let dones: Vec<bool> = (0..n * t).map(|i| i % 4 == 3).collect();
    let states: Vec<f32> = (0..n * width).map(|_| rng.random_range(-1.0..1.0)).collect();
    let batch = SeqBatch {
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
    let cfg = base_config();
    let mut fused = SeqDqn::with_layers(cfg, SHAPES, layers, width, 6, &dev).unwrap();
    let mut generic = SeqDqn::with_layers(cfg, SHAPES, layers, width, 6, &dev).unwrap();
    generic.set_fused(false).unwrap();
    let (lf, gf) = fused.gradients(&batch).unwrap();
    let (lg, gg) = generic.gradients(&batch).unwrap();
    assert!((lf - lg).abs() < 1e-5 * lg.abs().max(1.0), "loss {lf} against {lg}");
    assert_eq!(gf.len(), fused.online.num_params());
    same_gradients_of(&gf, &gg, layers, width);
    fused.update(&batch).unwrap();
    generic.update(&batch).unwrap();
    let mut state = (vec![0.0; width], vec![0.0; width]);
    let len = SHAPES.obs_len();
    let qf = fused.online.step(&obs[..len], &mut state.0).unwrap();
    let qg = generic.online.step(&obs[..len], &mut state.1).unwrap();
    assert!(qf.iter().zip(&qg).all(|(a, b)| (a - b).abs() < 1e-4), "{qf:?} {qg:?}");
}

#[test]
fn a_sequences_priority_mixes_its_largest_and_mean_td_error() {
    // Two sequences of three trained steps, step major.
    let abs = vec![vec![1.0, 0.0], vec![4.0, 0.0], vec![1.0, 2.0]];
    let p = sequence_priorities(&abs, 2);
    assert!((p[0] - (0.9 * 4.0 + 0.1 * 2.0)).abs() < 1e-6, "{p:?}");
    assert!((p[1] - (0.9 * 2.0 + 0.1 * 2.0 / 3.0)).abs() < 1e-6, "{p:?}");
}

#[test]
fn a_learner_fed_only_labelled_sequences_follows_the_labels() {
    // By DQfD's margin beside the TD loss, and by imitation alone (the TD
    // loss at weight 0).
    let imitation = Teaching { td: 0.0, margin: 0.0, imitation: 1.0, temperature: 0.2 };
    for teaching in [Teaching::margin(1.0), imitation] {
        let share = follows_the_labels(teaching);
        assert!(share >= 0.9, "{teaching:?}: the greedy action agrees on {share} of the steps");
    }
}

/// The share of fresh steps on which a learner taught by `teaching` on
/// labelled sequences alone agrees with the labels.
fn follows_the_labels(teaching: Teaching) -> f64 {
    // No reward anywhere: only the teacher's loss can order the actions.
    // The label depends on what the observation shows (its first velocity
    // input's sign), so the network must read it to agree.
    let dev = Device::Cpu;
    let cfg = SeqConfig { lr: 3e-3, target_update: 20, ..base_config() };
    let (n, t, width, len) = (8, 8, 8, SHAPES.obs_len());
    let vel = SHAPES.obs_depth();
    let mut seq = SeqDqn::new(cfg, SHAPES, width, 2, &dev).unwrap();
    seq.set_teaching(teaching);
    let mut rng = Pcg64Mcg::seed_from_u64(5);
    let label_of = |o: &[f32]| if o[vel] > 0.0 { 1.0 } else { 0.0 };
    let draw = |rng: &mut Pcg64Mcg| {
        let mut obs = random_obs(rng, n * (t + 1));
        for o in obs.chunks_exact_mut(len) {
            o[vel] = rng.random_range(-1.0..1.0);
        }
        let experts: Vec<f32> = (0..n * t)
            .map(|k| label_of(&obs[((k / t) * (t + 1) + k % t) * len..][..len]))
            .collect();
        (obs, experts)
    };
    let actions: Vec<u8> = (0..n * t).map(|_| rng.random_range(0..2)).collect();
    let (rewards, dones, states) = (vec![0.0; n * t], vec![false; n * t], vec![0.0; n * width]);
    for _ in 0..150 {
        let (obs, experts) = draw(&mut rng);
        let b = SeqBatch {
            sequences: n,
            steps: t,
            obs: &obs,
            actions: &actions,
            rewards: &rewards,
            dones: &dones,
            states: &states,
            experts: &experts,
            weights: &[],
        };
        assert!(seq.update(&b).unwrap().is_finite());
    }
    // Fresh sequences, flown step by step from a zeroed state.
    let (obs, _) = draw(&mut rng);
    let (mut agree, mut total) = (0, 0);
    for s in obs.chunks_exact((t + 1) * len) {
        let mut h = vec![0.0; width];
        for o in s.chunks_exact(len) {
            let a = seq.online.greedy(o, &mut h).unwrap()[0];
            agree += (a as f32 == label_of(o)) as usize;
            total += 1;
        }
    }
    agree as f64 / total as f64
}

#[test]
fn a_bad_label_is_refused_by_name() {
    let cfg = SeqConfig { n_step: 1, burn_in: 0, ..base_config() };
    let mut seq = SeqDqn::new(cfg, SHAPES, 4, 1, &Device::Cpu).unwrap();
    let obs = random_obs(&mut Pcg64Mcg::seed_from_u64(1), 3);
    let b = SeqBatch {
        sequences: 1,
        steps: 2,
        obs: &obs,
        actions: &[0, 1],
        rewards: &[0.0, 1.0],
        dones: &[false, true],
        states: &[0.0; 4],
        experts: &[NO_EXPERT, 1.0],
        weights: &[],
    };
    assert!(seq.update(&b).unwrap().is_finite());
    let e = seq.update(&SeqBatch { experts: &[0.5, 1.0], ..b }).unwrap_err().to_string();
    assert!(e.contains("sequence label"), "{e}");
    // A set of actions beyond the task's two is no label either.
    let e = seq.update(&SeqBatch { experts: &[12.0, 1.0], ..b }).unwrap_err().to_string();
    assert!(e.contains("sequence label"), "{e}");
    let three = seq.update(&SeqBatch { experts: &[11.0, 1.0], ..b }).unwrap();
    assert!(three.is_finite(), "both actions (8 + 0b11) are a set of the two");
    let e = seq.update(&SeqBatch { experts: &[1.0], ..b }).unwrap_err().to_string();
    assert!(e.contains("sequence expert actions"), "{e}");
}

#[test]
fn a_learner_restarted_from_its_state_goes_on_as_if_it_had_not_stopped() {
    let dev = Device::Cpu;
    let cfg = SeqConfig { n_step: 2, burn_in: 1, target_update: 2, ..base_config() };
    let (n, t, width) = (2, 4, 8);
    let mut rng = Pcg64Mcg::seed_from_u64(3);
    let obs = random_obs(&mut rng, n * (t + 1));
    let actions: Vec<u8> = (0..n * t).map(|_| rng.random_range(0..2)).collect();
    let rewards: Vec<f32> = (0..n * t).map(|_| rng.random_range(-1.0..1.0)).collect();
    let (dones, states) = (vec![false; n * t], vec![0.1; n * width]);
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
    let dir = std::env::temp_dir().join(format!("rotorhive-seqstate-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("learner-state.safetensors");
    let mut a = SeqDqn::new(cfg, SHAPES, width, 1, &dev).unwrap();
    for _ in 0..3 {
        a.update(&b).unwrap();
    }
    a.save_state(&path).unwrap();
    // Another seed: everything it has comes from the file.
    let mut back = SeqDqn::new(cfg, SHAPES, width, 9, &dev).unwrap();
    back.load_state(&path).unwrap();
    assert_eq!(back.updates(), 3);
    // The next update (the target copied at 4) gives the same weights, bit
    // for bit: Adam's moments and step came back too.
    assert_eq!(a.update(&b).unwrap(), back.update(&b).unwrap());
    let flat = |d: &SeqDqn| {
        let mut w = vec![0.0; d.online.num_params()];
        d.online.write_flat(&mut w).unwrap();
        w
    };
    assert!(flat(&a) == flat(&back), "the restarted learner went another way");
    // Another width's state is refused, naming the tensor.
    let e = SeqDqn::new(cfg, SHAPES, 4, 1, &dev).unwrap().load_state(&path).unwrap_err();
    assert!(e.to_string().contains("gru.weight_ih"), "{e}");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn a_checkpoint_names_its_memory_and_a_network_of_another_is_refused() {
    let dev = Device::Cpu;
    let dir = std::env::temp_dir().join(format!("rotorhive-recurrent-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let (gru, plain) = (dir.join("gru.safetensors"), dir.join("plain.safetensors"));
    let net = RecurrentQNet::new(SHAPES, 8, 3, &dev).unwrap();
    net.save(&gru, &[("config_crc32c", "1234".into())]).unwrap();
    assert_eq!(crate::checkpoint_memory(&gru).unwrap(), Some(8));
    // Loaded back: the same function.
    let back = RecurrentQNet::new(SHAPES, 8, 99, &dev).unwrap();
    back.load(&gru).unwrap();
    let obs = random_obs(&mut Pcg64Mcg::seed_from_u64(1), 2);
    let (mut h1, mut h2) = (vec![0.5; 16], vec![0.5; 16]);
    assert_eq!(net.step(&obs, &mut h1).unwrap(), back.step(&obs, &mut h2).unwrap());
    // A memoryless network refuses it by name, and the other way round.
    let e = QNet::with_shapes(SHAPES, 0, &dev).unwrap().load(&gru).unwrap_err().to_string();
    assert!(e.contains("memory gru:8 (this network: none)"), "{e}");
    QNet::with_shapes(SHAPES, 0, &dev).unwrap().save(&plain).unwrap();
    assert_eq!(crate::checkpoint_memory(&plain).unwrap(), None);
    let e = back.load(&plain).unwrap_err().to_string();
    assert!(e.contains("memory none (this network: gru:8)"), "{e}");
    // Another width too.
    let e = RecurrentQNet::new(SHAPES, 16, 0, &dev).unwrap().load(&gru).unwrap_err().to_string();
    assert!(e.contains("memory gru:8 (this network: gru:16)"), "{e}");
    let _ = std::fs::remove_dir_all(&dir);
}

/// The recurrent update follows the feedforward one's policy: a
/// non-finite loss is skipped and counted (the weights untouched, the
/// learner alive), the gauges are filled, double DQN is a choice.
#[test]
fn the_sequence_update_skips_a_broken_loss_and_keeps_its_gauges() {
    let dev = Device::Cpu;
    let cfg = SeqConfig { n_step: 2, burn_in: 1, target_update: 2, ..base_config() };
    let (n, t, width) = (2, 4, 8);
    let mut rng = Pcg64Mcg::seed_from_u64(5);
    let obs = random_obs(&mut rng, n * (t + 1));
    let actions: Vec<u8> = (0..n * t).map(|_| rng.random_range(0..2)).collect();
    let rewards: Vec<f32> = (0..n * t).map(|_| rng.random_range(-1.0..1.0)).collect();
    let mut dones = vec![false; n * t];
    dones[t + 2] = true;
    let states = vec![0.1; n * width];
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
    {
        let mut seq = SeqDqn::new(cfg, SHAPES, width, 1, &dev).unwrap();
        seq.update(&b).unwrap();
        let st = seq.stats();
        assert_eq!((st.rows, st.terminal), (((t - 1) * n) as u32, 1));
        assert!(st.max_q_sum.is_finite() && st.abs_td_sum > 0.0 && st.grad_norm > 0.0);
        let mut w = vec![0.0; seq.online.num_params()];
        seq.online.write_flat(&mut w).unwrap();
        let before = w.clone();
        // Finite rewards (non-finite ones are refused by the batch's
        // check) whose loss overflows.
        let broken = vec![f32::MAX; rewards.len()];
        let loss = seq.update(&SeqBatch { rewards: &broken, ..b }).unwrap();
        assert!(!loss.is_finite(), "{loss}");
        assert_eq!((seq.updates(), seq.skipped()), (2, 1));
        seq.online.write_flat(&mut w).unwrap();
        assert!(w == before, "a skipped update changed the weights");
        assert!(seq.update(&b).unwrap().is_finite());
        assert_eq!((seq.updates(), seq.skipped()), (3, 1));
    }
    // Double DQN or not: other targets.
    let q = vec![vec![vec![1.0, 0.0]; n]; t + 1 - 1];
    let qt = vec![vec![vec![0.0, 2.0]; n]; t + 1];
    let no_end = vec![false; n * t];
    let b = SeqBatch { dones: &no_end, ..b };
    let seq = |double| SeqDqn::new(SeqConfig { double, ..cfg }, SHAPES, width, 1, &dev).unwrap();
    let (y_double, y_max) = (seq(true).targets(&b, &q, &qt), seq(false).targets(&b, &q, &qt));
    let last = (t - 1 - 1) * n; // the last trained step bootstraps from qt[t]
    assert!(
        (y_max[last] - y_double[last] - cfg.gamma * 2.0).abs() < 1e-5,
        "{y_max:?} {y_double:?}"
    );
}
