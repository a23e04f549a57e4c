//! `hive learner`: updates on the minibatches the replay process queues,
//! weights published by version, checkpoints as safetensors; one loop
//! ([`run`]) for both networks: the feedforward learner's DQN update
//! (`learner/feedforward.rs`) or, with memory, the recurrent one's R2D2
//! update on stored sequences (`learner/recurrent.rs`), each a
//! [`learning::Learning`]. Also the learner benchmark's settings
//! ([`dqn_config`]), which measures the same update path.

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use rotorhive_msg::{LearnerStage, MinibatchHeader, RoleKind, Telemetry, WeightsHeader};
use rotorhive_transport::{Channel, Service};

use crate::ctx::{Ctx, POLL, STALL_TIMEOUT, roles_of};
use crate::error::{Doing, Result};

mod feedforward;
mod learning;
mod minibatch;
mod publish;
mod recurrent;

pub use feedforward::dqn_config;
pub use recurrent::seq_config;

use feedforward::Feedforward;
use learning::{Gauges, Learning, UpdateSettings};
use minibatch::Minibatch;
use publish::{Average, publish_flat};
use recurrent::Recurrent;

/// Runs the learner until the run stops: the recurrent one where the
/// network has memory, the feedforward one otherwise.
pub fn run<S: Service>(cx: Ctx<'_, S>) -> Result<()> {
    let run_dir = cx.run_dir.map_or_else(|| PathBuf::from("."), Path::to_path_buf);
    let ckpt = run_dir.join("checkpoints");
    std::fs::create_dir_all(&ckpt).doing_with(|| format!("cannot create {}", ckpt.display()))?;
    let paths = Paths {
        latest: ckpt.join("latest.safetensors"),
        state: ckpt.join("learner-state.safetensors"),
        last: run_dir.join("final.safetensors"),
    };
    match (cx.cfg.memory(), cx.cfg.seq_layout()) {
        (Some(width), Some(layout)) => {
            let learner = Recurrent::start(cx.cfg, (width, layout), &paths.latest, &paths.state)?;
            learn(cx, learner, &paths)
        }
        _ => {
            let learner = Feedforward::start(cx.cfg, &paths.state)?;
            learn(cx, learner, &paths)
        }
    }
}

/// Where a learner writes: its newest weights, its whole state, and the
/// run's final weights.
struct Paths {
    latest: PathBuf,
    state: PathBuf,
    last: PathBuf,
}

/// The learner loop: a minibatch in, an update, the weights out every
/// `learner.publish_every` updates, a checkpoint every
/// `learner.checkpoint_every_s`; at the end the state, the newest weights
/// and the run's final ones (its average, with `learner.average_updates`).
fn learn<S: Service, L: Learning>(cx: Ctx<'_, S>, mut learner: L, paths: &Paths) -> Result<()> {
    let (cfg, hub) = (cx.cfg, cx.hub);
    let mut rx =
        hub.receiver::<u16, MinibatchHeader>(&Channel::minibatches(cfg.replay.prefetch))?;
    let mut io = Minibatch::new(hub, cfg)?;
    let mut w_tx = hub.sender::<f32, WeightsHeader>(
        &Channel::weights(cfg.sim.envs),
        cfg.num_params(),
        STALL_TIMEOUT,
    )?;
    let mut tel = crate::ctx::counters(hub, RoleKind::Learner, 0, roles_of(cfg))?;
    let mut version = learner.updates(); // increasing across restarts
    let mut average = Average::new(cfg);
    publish(&mut w_tx, &learner, average.as_mut(), &mut version)?;
    let min_period = if cfg.learner.max_rate_hz > 0.0 {
        Duration::from_secs_f64(1.0 / cfg.learner.max_rate_hz)
    } else {
        Duration::ZERO
    };
    let (tags, settings) = (cfg.checkpoint_tags(), UpdateSettings::of(cfg));
    let (mut last_ckpt, mut last_update) = (Instant::now(), Instant::now());
    let mut saves = (0u32, Duration::ZERO);
    let mut gauges = Gauges::default();
    while !hub.shutdown_requested() {
        let t = Instant::now();
        let msg = rx.recv_timeout(POLL).doing("waiting for minibatches")?;
        tel.sample.time_stage(LearnerStage::TransportWait, t);
        if tel.tick(false, Telemetry::beat) {
            gauges = Gauges::default();
        }
        let Some(msg) = msg else { continue };
        // The learner's half of the rate limit.
        let since = last_update.elapsed();
        if since < min_period {
            std::thread::sleep(min_period - since);
        }
        last_update = Instant::now();
        let mb = *msg.user_header();
        learner.unpack(msg.payload(), mb.batch as usize, &mut io)?;
        drop(msg);
        let loss = learner.update(&settings, &mb, &mut io, &mut tel.sample.lost)?;
        add_timing(&mut tel.sample, learner.timing());
        tel.sample.work = learner.updates();
        gauges.add(loss, &mb, version, &mut tel.sample);
        learner.gauge(&mut gauges, settings.reward_scale, &mut tel.sample);
        if learner.updates().is_multiple_of(cfg.learner.publish_every) {
            publish(&mut w_tx, &learner, average.as_mut(), &mut version)?;
            tel.sample.weight_version = version;
            tel.sample.work2 = version;
        }
        if last_ckpt.elapsed().as_secs_f64() >= cfg.learner.checkpoint_every_s {
            checkpoint(&learner, paths, &tags, &mut saves)?;
            last_ckpt = Instant::now();
        }
    }
    log_saves(saves);
    learner.save_state(&paths.state)?;
    if let Some(avg) = &average {
        // Training is over: the online network becomes the run's average.
        learner.load_flat(avg.weights())?;
    }
    learner.save_weights(&paths.last, &tags)?;
    tel.tick(true, Telemetry::beat);
    Ok(())
}

/// Publishes the online network (or its running average, [`Average`]) as
/// the next weight version (see [`publish_flat`]).
fn publish<S: Service, L: Learning>(
    w_tx: &mut rotorhive_transport::Sender<S, f32, WeightsHeader>,
    learner: &L,
    average: Option<&mut Average>,
    version: &mut u64,
) -> Result<()> {
    let write = |p: &mut [f32]| learner.write_flat(p);
    publish_flat(w_tx, (learner.num_params(), learner.updates()), write, average, version)
}

/// Saves the newest weights and the whole learner state, counting the
/// saves and their time in `saves`.
fn checkpoint<L: Learning>(
    learner: &L,
    paths: &Paths,
    tags: &[(&str, String)],
    saves: &mut (u32, Duration),
) -> Result<()> {
    let t = Instant::now();
    learner.save_weights(&paths.latest, tags)?;
    learner.save_state(&paths.state)?;
    saves.0 += 1;
    saves.1 += t.elapsed();
    Ok(())
}

/// Logs what a checkpoint cost the learner (it saves every
/// `checkpoint_every_s`).
fn log_saves(saves: (u32, Duration)) {
    if saves.0 > 0 {
        tracing::info!(
            "learner: {} checkpoints, {:.2} ms each on average",
            saves.0,
            saves.1.as_secs_f64() * 1e3 / saves.0 as f64
        );
    }
}

/// An update's stages into the learner's telemetry sample.
fn add_timing(sample: &mut Telemetry, tm: rotorhive_model::UpdateTiming) {
    sample.add_stage(LearnerStage::Forward, tm.forward_ns);
    sample.add_stage(LearnerStage::Backward, tm.backward_ns);
    sample.add_stage(LearnerStage::Optimiser, tm.optimiser_ns);
}
