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
//! feedforward learner's. The update's policy (the learning rate's decay,
//! clipping, double DQN, a non-finite loss skipped and counted) and its
//! gauges are the feedforward learner's.

use std::path::Path;

use rotorhive_model::{SeqBatch, SeqConfig, SeqDqn, UpdateTiming};
use rotorhive_msg::{MinibatchHeader, PICK_WORDS, Pick, SeqLayout, Unpacked};
use rotorhive_transport::Service;

use super::learning::{Gauges, Learning, UpdateSettings};
use super::minibatch::Minibatch;
use crate::config::Config;
use crate::error::{Doing, Result, protocol_err};

/// The sequence update's settings of a config's `[learner]`.
pub fn seq_config(cfg: &Config) -> SeqConfig {
    let l = &cfg.learner;
    SeqConfig {
        lr: l.lr as f32,
        lr_final: l.lr_final as f32,
        lr_decay_updates: l.lr_decay_updates,
        max_grad_norm: l.max_grad_norm as f32,
        double: l.double_dqn,
        gamma: l.gamma as f32,
        n_step: l.n_step,
        burn_in: l.burn_in,
        target_update: l.target_update,
        huber_delta: l.huber_delta as f32,
        reward_scale: l.reward_scale as f32,
        margin: cfg.teacher.margin as f32,
    }
}

/// The recurrent update and its minibatch of sequences, unpacked.
pub struct Recurrent {
    dqn: SeqDqn,
    layout: SeqLayout,
    batch: Unpacked,
}

impl Recurrent {
    /// A new learner of `width`, or one restarted from its state (`state`:
    /// both networks and Adam) or, failing that, from its latest weights.
    pub fn start(
        cfg: &Config,
        (width, layout): (usize, SeqLayout),
        latest: &Path,
        state: &Path,
    ) -> Result<Self> {
        let device = rotorhive_model::device(cfg.learner.device.kind())?;
        let seed = crate::streams::network(cfg.seed);
        let (shapes, layers) = (cfg.shapes(), cfg.layers());
        let mut dqn = SeqDqn::with_layers(seq_config(cfg), shapes, layers, width, seed, &device)?;
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
        Ok(Self { dqn, layout, batch: Unpacked::default() })
    }
}

impl Learning for Recurrent {
    fn unpack<S: Service>(
        &mut self,
        payload: &[u16],
        rows: usize,
        io: &mut Minibatch<S>,
    ) -> Result<()> {
        unpack(self.layout, payload, rows, &mut self.batch, &mut io.picks)
    }

    fn update<S: Service>(
        &mut self,
        settings: &UpdateSettings,
        mb: &MinibatchHeader,
        io: &mut Minibatch<S>,
        lost: &mut u64,
    ) -> Result<f32> {
        io.load_weights();
        if let Some(t) = settings.teaching(mb) {
            self.dqn.set_teaching(t);
        }
        let b = &self.batch;
        let loss = self.dqn.update(&SeqBatch {
            sequences: mb.batch as usize,
            steps: self.layout.steps,
            obs: &b.obs,
            actions: &b.actions,
            rewards: &b.rewards,
            dones: &b.dones,
            states: &b.states,
            experts: &b.experts,
            weights: &io.weights,
        })?;
        io.send_back(self.dqn.priorities(), mb.seq, settings.deterministic, lost)?;
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
        // The header names the memory.
        self.dqn
            .online
            .save(path, tags)
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
