//! The learner of a run with memory (`learner.memory = "gru:WIDTH"`): R2D2's
//! update ([`SeqDqn`]) on minibatches of stored sequences, weights published
//! by version and checkpoints as the feedforward learner's, in deterministic
//! runs too (the replay's schedule counts a sequence's trained steps). Its
//! update's stages (forward, backward, optimiser) reach telemetry and `hive
//! profile` as the feedforward learner's. A restarted
//! one goes on from `checkpoints/learner-state.safetensors` (both networks,
//! Adam's moments and step), as the feedforward learner does. Under
//! prioritized replay each sequence's priority goes back as R2D2's (η = 0.9
//! of its largest |TD error| and the rest of their mean), its importance
//! weight scaling its loss. With a teacher, DQfD's
//! margin loss on the labelled steps, weighted and faded as the
//! feedforward learner's.

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use rotorhive_model::{SeqBatch, SeqConfig, SeqDqn};
use rotorhive_msg::{
    LearnerStage, MinibatchHeader, PICK_WORDS, Pick, RoleKind, SeqLayout, Telemetry, Unpacked,
    WeightsHeader,
};
use rotorhive_transport::{Channel, Service};

use super::Gauges;
use crate::config::Config;
use crate::ctx::{Ctx, POLL, STALL_TIMEOUT, roles_of};
use crate::error::{Doing, Result, protocol_err};

/// The sequence update's settings of a config's `[learner]`.
pub fn seq_config(cfg: &Config) -> SeqConfig {
    let l = &cfg.learner;
    SeqConfig {
        lr: l.lr as f32,
        gamma: l.gamma as f32,
        n_step: l.n_step,
        burn_in: l.burn_in,
        target_update: l.target_update,
        huber_delta: l.huber_delta as f32,
        reward_scale: l.reward_scale as f32,
        margin: cfg.teacher.margin as f32,
    }
}

/// Runs the recurrent learner until the run stops.
pub fn run<S: Service>(cx: Ctx<'_, S>, width: usize, layout: SeqLayout) -> Result<()> {
    let (cfg, hub) = (cx.cfg, cx.hub);
    let run_dir = cx.run_dir.map_or_else(|| PathBuf::from("."), Path::to_path_buf);
    let ckpt_dir = run_dir.join("checkpoints");
    std::fs::create_dir_all(&ckpt_dir)
        .doing_with(|| format!("cannot create {}", ckpt_dir.display()))?;
    let latest = ckpt_dir.join("latest.safetensors");
    let state = ckpt_dir.join("learner-state.safetensors");
    let mut dqn = start(cfg, width, &latest, &state)?;
    let mut rx =
        hub.receiver::<u16, MinibatchHeader>(&Channel::minibatches(cfg.replay.prefetch))?;
    let mut w_tx = hub.sender::<f32, WeightsHeader>(
        &Channel::weights(cfg.sim.envs),
        cfg.num_params(),
        STALL_TIMEOUT,
    )?;
    let mut tel = crate::ctx::counters(hub, RoleKind::Learner, 0, roles_of(cfg))?;
    let mut version = 0;
    let mut average = super::Average::new(cfg);
    publish(&mut w_tx, &dqn, average.as_mut(), &mut version)?;
    let mut last_ckpt = Instant::now();
    let mut gauges = Gauges::default();
    let mut batch = Unpacked::default();
    // Its picks and, under prioritized replay, the priorities' channel
    // (its float batch stays empty: the sequences unpack into `batch`).
    let mut prio = super::Minibatch::new(hub, cfg)?;
    let tags = cfg.checkpoint_tags();
    while !hub.shutdown_requested() {
        let t = Instant::now();
        let msg = rx.recv_timeout(POLL).doing("waiting for minibatches")?;
        tel.sample.time_stage(LearnerStage::TransportWait, t);
        if tel.tick(false, Telemetry::beat) {
            gauges = Gauges::default();
        }
        let Some(msg) = msg else { continue };
        let mb = *msg.user_header();
        unpack(layout, msg.payload(), mb.batch as usize, &mut batch, &mut prio.picks)?;
        drop(msg);
        let loss = learn(cfg, &mut dqn, (layout, &mb), &batch, &mut prio, &mut tel.sample.lost)?;
        super::add_timing(&mut tel.sample, dqn.timing());
        tel.sample.work = dqn.updates();
        gauges.add(loss, &mb, version, &mut tel.sample);
        if dqn.updates() % cfg.learner.publish_every == 0 {
            publish(&mut w_tx, &dqn, average.as_mut(), &mut version)?;
            tel.sample.weight_version = version;
            tel.sample.work2 = version;
        }
        if last_ckpt.elapsed() >= Duration::from_secs_f64(cfg.learner.checkpoint_every_s) {
            save(&dqn, (&latest, &state), &tags)?;
            last_ckpt = Instant::now();
        }
    }
    save(&dqn, (&latest, &state), &tags)?;
    if let Some(avg) = &average {
        // Training is over: the online network becomes the run's average.
        dqn.online.load_flat(avg.weights())?;
    }
    let fin = run_dir.join("final.safetensors");
    dqn.online
        .save(&fin, &tags)
        .doing_with(|| format!("cannot write checkpoint {}", fin.display()))?;
    tel.tick(true, Telemetry::beat);
    Ok(())
}

/// A new learner of `width`, or one restarted from its state (`state`: both
/// networks and Adam) or, failing that, from its latest weights.
fn start(cfg: &Config, width: usize, latest: &Path, state: &Path) -> Result<SeqDqn> {
    let device = rotorhive_model::device(cfg.learner.device.kind())?;
    let seed = crate::streams::network(cfg.seed);
    let mut dqn =
        SeqDqn::with_layers(seq_config(cfg), cfg.shapes(), cfg.layers(), width, seed, &device)?;
    if state.exists() {
        dqn.load_state(state)
            .doing_with(|| format!("restoring the learner from {}", state.display()))?;
        tracing::info!(
            "learner restored its state from {} ({} updates)",
            state.display(),
            dqn.updates()
        );
    } else if latest.exists() {
        dqn.restore(latest)
            .doing_with(|| format!("restoring the learner from {}", latest.display()))?;
        tracing::info!("learner restored its weights from {}", latest.display());
    }
    Ok(dqn)
}

/// One update on the sequences unpacked into `batch` (minibatch `mb` of
/// `layout`): the teacher's margin weight as the replay's fade says, each
/// sequence's importance weight and, under prioritized replay, its new
/// priority sent back (a send that fails counts in `lost`); the loss.
fn learn<S: Service>(
    cfg: &Config,
    dqn: &mut SeqDqn,
    (layout, mb): (SeqLayout, &MinibatchHeader),
    batch: &Unpacked,
    prio: &mut super::Minibatch<S>,
    lost: &mut u64,
) -> Result<f32> {
    prio.load_weights();
    if let Some(t) = super::teaching(cfg, mb) {
        dqn.set_teaching(t);
    }
    let loss = dqn.update(&SeqBatch {
        sequences: mb.batch as usize,
        steps: layout.steps,
        obs: &batch.obs,
        actions: &batch.actions,
        rewards: &batch.rewards,
        dones: &batch.dones,
        states: &batch.states,
        experts: &batch.experts,
        weights: &prio.weights,
    })?;
    if let Some(tx) = &mut prio.prio_tx {
        let (picks, det) = (&mut prio.picks, cfg.deterministic);
        super::send_priorities(tx, picks, dqn.priorities(), mb.seq, det, lost)?;
    }
    Ok(loss)
}

/// A minibatch of `rows` packed sequences into `out` and their picks into
/// `picks`; a message of another size is refused.
fn unpack(
    layout: SeqLayout,
    packed: &[u16],
    rows: usize,
    out: &mut Unpacked,
    picks: &mut Vec<Pick>,
) -> Result<()> {
    let pl = layout.packed_len();
    if rows == 0 || packed.len() != rows * (pl + PICK_WORDS) {
        protocol_err!(
            "a minibatch of {} words is not {rows} packed sequences and their picks ({} words each)",
            packed.len(),
            pl + PICK_WORDS
        );
    }
    out.clear();
    let (data, tail) = packed.split_at(rows * pl);
    for row in data.chunks_exact(pl) {
        layout.unpack_into(row, out);
    }
    picks.clear();
    picks.extend(tail.chunks_exact(PICK_WORDS).map(Pick::unpack));
    Ok(())
}

/// Writes the latest checkpoint (its header naming the memory) and the
/// learner's whole state (networks, Adam's moments and step), each
/// atomically.
fn save(dqn: &SeqDqn, (latest, state): (&Path, &Path), tags: &[(&str, String)]) -> Result<()> {
    dqn.online
        .save(latest, tags)
        .doing_with(|| format!("cannot write checkpoint {}", latest.display()))?;
    dqn.save_state(state).doing_with(|| format!("cannot write learner state {}", state.display()))
}

/// Publishes the online network (or its average) as the next weight
/// version, as the feedforward learner does.
fn publish<S: Service>(
    w_tx: &mut rotorhive_transport::Sender<S, f32, WeightsHeader>,
    dqn: &SeqDqn,
    average: Option<&mut super::Average>,
    version: &mut u64,
) -> Result<()> {
    let net = &dqn.online;
    let write = |p: &mut [f32]| Ok(net.write_flat(p)?);
    super::publish_flat(w_tx, (net.num_params(), dqn.updates()), write, average, version)
}
