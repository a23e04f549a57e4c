//! What the learner loop asks of an update, the feedforward one's or the
//! recurrent one's ([`Learning`]), and what it keeps of them: the teacher's
//! weight per minibatch and the telemetry's gauges.

use std::path::Path;

use rotorhive_model::{Teaching, UpdateStats, UpdateTiming};
use rotorhive_msg::MinibatchHeader;
use rotorhive_transport::Service;

use super::minibatch::Minibatch;
use crate::config::Config;
use crate::error::Result;

/// A learner's update as the loop drives it: unpack a minibatch, update on
/// it, publish and save the online network. The feedforward learner's
/// (`feedforward.rs`) and the recurrent one's (`recurrent.rs`).
pub trait Learning {
    /// Unpacks a minibatch message's `payload` of `rows` rows into this
    /// learner's buffers and `io.picks`; a message of another size is
    /// refused.
    fn unpack<S: Service>(
        &mut self,
        payload: &[u16],
        rows: usize,
        io: &mut Minibatch<S>,
    ) -> Result<()>;

    /// One update on the minibatch unpacked (`mb` its header: the teacher's
    /// weight now): importance-weighted, with its new priorities sent back,
    /// under prioritized replay (a send that fails counts in `lost`); the
    /// loss.
    fn update<S: Service>(
        &mut self,
        settings: &UpdateSettings,
        mb: &MinibatchHeader,
        io: &mut Minibatch<S>,
        lost: &mut u64,
    ) -> Result<f32>;

    /// Updates made (across restarts).
    fn updates(&self) -> u64;

    /// Where the last update's time went.
    fn timing(&self) -> UpdateTiming;

    /// Floats of the online network's flat weights.
    fn num_params(&self) -> usize;

    /// The online network's weights, flat, into `into`.
    fn write_flat(&self, into: &mut [f32]) -> Result<()>;

    /// Replaces the online network's weights (the run's average, at its end).
    fn load_flat(&mut self, flat: &[f32]) -> Result<()>;

    /// Writes the online network as a checkpoint at `path` with `tags`.
    fn save_weights(&self, path: &Path, tags: &[(&str, String)]) -> Result<()>;

    /// Writes the whole learner state (networks, Adam, counters) at `path`.
    fn save_state(&self, path: &Path) -> Result<()>;

    /// Adds the last update's learning diagnostics to the gauges.
    fn gauge(&self, gauges: &mut Gauges, reward_scale: f64, tel: &mut rotorhive_msg::Telemetry);
}

/// What an update reads of the run's config, resolved once at the
/// learner's start rather than looked up on every minibatch.
pub struct UpdateSettings {
    /// The teacher's section, where it teaches.
    teacher: Option<crate::config::TeacherSection>,
    /// `learner.td_weight`.
    td_weight: f32,
    /// Priorities go back in the run's lockstep (`deterministic`).
    pub deterministic: bool,
    /// `learner.reward_scale`, which the gauges undo.
    pub reward_scale: f64,
}

impl UpdateSettings {
    /// The settings of `cfg`.
    pub fn of(cfg: &Config) -> Self {
        Self {
            teacher: cfg.teacher.on().then(|| cfg.teacher.clone()),
            td_weight: cfg.learner.td_weight as f32,
            deterministic: cfg.deterministic,
            reward_scale: cfg.learner.reward_scale,
        }
    }

    /// How minibatch `mb` weighs the labels: the teacher's weight times the
    /// replay's fade (a fade that is not finite counts as 0), the TD loss
    /// at `learner.td_weight` beside imitation; none without a teacher.
    pub fn teaching(&self, mb: &MinibatchHeader) -> Option<Teaching> {
        self.teacher.as_ref().map(|t| {
            let fade = if mb.teacher.is_finite() { mb.teacher.clamp(0.0, 1.0) } else { 0.0 };
            t.teaching(fade, self.td_weight)
        })
    }
}

/// The learner's gauges in its telemetry, over the updates since the last
/// sample (one minibatch's loss is too noisy to show a trend): the mean loss
/// and the mean policy lag.
#[derive(Default)]
pub struct Gauges {
    loss: (f64, u32),
    lag: (f64, u32),
    /// Sums of the updates' max-Q, |TD| and terminals, and their rows.
    max_q: f64,
    td: f64,
    terminal: u64,
    rows: u64,
}

impl Gauges {
    /// Adds an update's loss and its minibatch's policy lag: the learner's
    /// weight version minus the mean version the transitions were acted
    /// with (those restored from a snapshot have none).
    pub fn add(
        &mut self,
        loss: f32,
        mb: &MinibatchHeader,
        version: u64,
        tel: &mut rotorhive_msg::Telemetry,
    ) {
        if loss.is_finite() {
            self.loss = (self.loss.0 + loss as f64, self.loss.1 + 1);
            tel.value_milli = (self.loss.0 / self.loss.1 as f64 * 1e6) as i64;
        }
        if mb.acted > 0 {
            self.lag = (
                self.lag.0 + version as f64 - mb.acted_version_sum as f64 / mb.acted as f64,
                self.lag.1 + 1,
            );
            tel.policy_lag_milli =
                (self.lag.0 / self.lag.1 as f64 * 1e3).clamp(0.0, u32::MAX as f64) as u32;
        }
    }
}

impl Gauges {
    /// Adds the last update's learning diagnostics `st` and the count of
    /// skipped updates (in reward units: the network's values divided by
    /// `reward_scale`).
    pub fn learn(
        &mut self,
        st: UpdateStats,
        skipped: u64,
        reward_scale: f64,
        tel: &mut rotorhive_msg::Telemetry,
    ) {
        tel.learning.skipped_updates = skipped.min(u32::MAX as u64) as u32;
        if !(st.max_q_sum.is_finite() && st.abs_td_sum.is_finite()) || st.rows == 0 {
            return;
        }
        (self.max_q, self.td) = (self.max_q + st.max_q_sum, self.td + st.abs_td_sum);
        (self.terminal, self.rows) =
            (self.terminal + st.terminal as u64, self.rows + st.rows as u64);
        let rows = self.rows as f64;
        tel.learning.mean_max_q = (self.max_q / rows / reward_scale) as f32;
        tel.learning.mean_abs_td = (self.td / rows / reward_scale) as f32;
        tel.learning.terminal_share = (self.terminal as f64 / rows) as f32;
    }
}
