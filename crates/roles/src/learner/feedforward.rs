//! The feedforward learner: DQN updates ([`Dqn`]) on minibatches of
//! transitions, on the fused CPU path or the generic one.

use std::path::Path;

use rotorhive_model::{Dqn, DqnConfig, UpdateTiming};
use rotorhive_msg::{MinibatchHeader, PICK_WORDS, Pick, Shapes};
use rotorhive_transport::Service;

use super::learning::{Gauges, Learning, UpdateSettings};
use super::minibatch::Minibatch;
use crate::config::Config;
use crate::error::{Doing, Result, protocol_err};

/// The DQN settings of a config's `[learner]`.
pub fn dqn_config(cfg: &Config) -> DqnConfig {
    let l = &cfg.learner;
    DqnConfig {
        lr: l.lr,
        lr_final: l.lr_final,
        lr_decay_updates: l.lr_decay_updates,
        gamma: (l.gamma as f32).powi(l.n_step as i32),
        target_update: l.target_update,
        huber_delta: l.huber_delta as f32,
        double: l.double_dqn,
        reward_scale: l.reward_scale as f32,
        max_grad_norm: l.max_grad_norm as f32,
        margin: cfg.teacher.margin as f32,
    }
}

/// The feedforward update and its minibatch in the network's layout.
pub struct Feedforward {
    dqn: Dqn,
    shapes: Shapes,
    /// Transitions as floats (they arrive packed, with 16-bit depth).
    batch: Vec<f32>,
}

impl Feedforward {
    /// A learner with the config's network and optimiser; a restarted (or
    /// resumed) one goes on from its last saved state at `state`: weights,
    /// target, Adam moments and counters.
    pub fn start(cfg: &Config, state: &Path) -> Result<Self> {
        let mut dqn = Dqn::with_layers(
            dqn_config(cfg),
            cfg.shapes(),
            cfg.layers(),
            crate::streams::network(cfg.seed),
            &rotorhive_model::device(cfg.learner.device.kind())?,
        )?;
        dqn.set_threads(cfg.learner.threads);
        if state.exists() {
            dqn.load_state(state)
                .doing_with(|| format!("restoring the learner from {}", state.display()))?;
            tracing::info!("learner restored from {} at update {}", state.display(), dqn.updates());
        }
        Ok(Self { dqn, shapes: cfg.shapes(), batch: Vec::new() })
    }
}

impl Learning for Feedforward {
    fn unpack<S: Service>(
        &mut self,
        payload: &[u16],
        rows: usize,
        io: &mut Minibatch<S>,
    ) -> Result<()> {
        unpack_batch(self.shapes, payload, rows, &mut self.batch, &mut io.picks)
    }

    fn update<S: Service>(
        &mut self,
        settings: &UpdateSettings,
        mb: &MinibatchHeader,
        io: &mut Minibatch<S>,
        lost: &mut u64,
    ) -> Result<f32> {
        if let Some(t) = settings.teaching(mb) {
            self.dqn.set_teaching(t);
        }
        io.load_weights();
        if io.weights.is_empty() {
            return self.dqn.update(&self.batch).doing("learner update");
        }
        let loss =
            self.dqn.update_weighted(&self.batch, Some(&io.weights)).doing("learner update")?;
        io.send_back(self.dqn.td_abs(), mb.seq, settings.deterministic, lost)?;
        Ok(loss)
    }

    fn updates(&self) -> u64 {
        self.dqn.updates()
    }

    fn timing(&self) -> UpdateTiming {
        self.dqn.timing()
    }

    fn num_params(&self) -> usize {
        self.dqn.online.num_params()
    }

    fn write_flat(&self, into: &mut [f32]) -> Result<()> {
        Ok(self.dqn.online.write_flat(into)?)
    }

    fn load_flat(&mut self, flat: &[f32]) -> Result<()> {
        Ok(self.dqn.online.load_flat(flat)?)
    }

    fn save_weights(&self, path: &Path, tags: &[(&str, String)]) -> Result<()> {
        // Atomically: `QNet::save_with` goes through `rotorhive_msg::durable`.
        self.dqn
            .online
            .save_with(path, tags)
            .doing_with(|| format!("cannot write checkpoint {}", path.display()))
    }

    fn save_state(&self, path: &Path) -> Result<()> {
        self.dqn
            .save_state(path)
            .doing_with(|| format!("cannot write learner state {}", path.display()))
    }

    fn gauge(&self, gauges: &mut Gauges, reward_scale: f64, tel: &mut rotorhive_msg::Telemetry) {
        gauges.learn(self.dqn.stats(), self.dqn.skipped(), reward_scale, tel);
    }
}

/// Unpacks a minibatch of `rows` packed transitions and their picks into
/// `out`, the learner's float layout (`transition_len` per transition),
/// and `picks` (each row's place and importance weight).
fn unpack_batch(
    shapes: Shapes,
    packed: &[u16],
    rows: usize,
    out: &mut Vec<f32>,
    picks: &mut Vec<Pick>,
) -> Result<()> {
    let (pl, tl) = (shapes.packed_len(), shapes.transition_len());
    if rows == 0 || packed.len() != rows * (pl + PICK_WORDS) {
        protocol_err!(
            "a minibatch of {} words is not {rows} packed transitions and their picks ({} words each)",
            packed.len(),
            pl + PICK_WORDS
        );
    }
    let (data, tail) = packed.split_at(rows * pl);
    out.resize(rows * tl, 0.0);
    for (p, o) in data.chunks_exact(pl).zip(out.chunks_exact_mut(tl)) {
        shapes.unpack(p, o);
    }
    picks.clear();
    picks.extend(tail.chunks_exact(PICK_WORDS).map(Pick::unpack));
    Ok(())
}
