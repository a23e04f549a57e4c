//! The run's scalars for TensorBoard (`RUN_DIR/tb/`), once a second, with
//! agent-steps as the step axis (as SB3 and CleanRL log against timesteps):
//! rollout (rolling reward, success, epsilon, episodes), training (loss,
//! mean max-Q, |TD|, policy lag, skipped updates, updates/s), speed
//! (agent-steps/s), the replay's size, every role's CPU, the machine's CPU
//! and GPU, and each greedy validation as it comes.

use std::path::Path;

use anyhow::{Context, Result};
use rotorhive_records::tensorboard::EventWriter;
use rotorhive_records::{Member, TelemetryRow};

use super::evaluator::EvalPoint;
use super::records::{Counts, Progress};

/// The event file and what the rates are taken against.
pub(super) struct Board {
    writer: EventWriter,
    /// Wall time, agent-steps and updates at the previous tick.
    last: Option<(f64, u64, u64)>,
    /// Validations already written.
    evals: usize,
}

impl Board {
    /// A new event file in `RUN_DIR/tb/`.
    pub(super) fn open(run_dir: &Path, host: &str) -> Result<Self> {
        let dir = run_dir.join("tb");
        let writer = EventWriter::create(&dir, host)
            .with_context(|| format!("cannot write TensorBoard logs in {}", dir.display()))?;
        Ok(Self { writer, last: None, evals: 0 })
    }

    /// One tick's scalars (and any new validation), flushed.
    pub(super) fn tick(
        &mut self,
        wall: f64,
        counts: Counts,
        progress: &Progress,
        rows: &[TelemetryRow],
        evals: &[EvalPoint],
    ) -> Result<()> {
        let (steps, updates, replay) = counts;
        let unix = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map_or(0.0, |d| d.as_secs_f64());
        let mut v: Vec<(String, f64)> = vec![
            ("rollout/rolling_reward".into(), progress.rolling()),
            ("rollout/epsilon".into(), progress.epsilon),
            ("rollout/success_rate".into(), progress.success_rate().unwrap_or(f64::NAN)),
            ("rollout/episodes".into(), progress.episodes as f64),
            ("train/updates".into(), updates as f64),
            ("replay/size".into(), replay as f64),
            ("time/wall_s".into(), wall),
        ];
        if let Some((w0, s0, u0)) = self.last {
            let dt = (wall - w0).max(1e-9);
            v.push(("time/agent_steps_per_s".into(), steps.saturating_sub(s0) as f64 / dt));
            v.push(("train/updates_per_s".into(), updates.saturating_sub(u0) as f64 / dt));
        }
        self.last = Some((wall, steps, updates));
        for r in rows {
            v.push((format!("cpu/{}", r.member_name()), r.cpu_pct));
            if r.role == Member::Learner {
                v.push(("train/loss".into(), r.value.parse().unwrap_or(f64::NAN)));
                v.push(("train/policy_lag".into(), r.policy_lag.unwrap_or(f64::NAN)));
                if let Some(l) = r.learning {
                    v.push(("train/mean_max_q".into(), l.mean_max_q as f64));
                    v.push(("train/mean_abs_td".into(), l.mean_abs_td as f64));
                    v.push(("train/skipped_updates".into(), l.skipped_updates as f64));
                }
            }
        }
        if let Some(r) = rows.first() {
            v.push(("cpu/machine".into(), r.machine_cpu_pct));
            if let Some([util, mem, power]) = r.gpu {
                v.extend([
                    ("gpu/util_pct".into(), util),
                    ("gpu/mem_mb".into(), mem),
                    ("gpu/power_w".into(), power),
                ]);
            }
        }
        for e in &evals[self.evals.min(evals.len())..] {
            v.push(("eval/validation_success".into(), e.success));
            v.push(("eval/validation_reward".into(), e.mean_reward));
            if let Some((s, _)) = e.confirmed {
                v.push(("eval/confirmed_success".into(), s));
            }
        }
        self.evals = evals.len();
        let named: Vec<(&str, f64)> = v.iter().map(|(k, x)| (k.as_str(), *x)).collect();
        let path = self.writer.path().display().to_string();
        self.writer
            .scalars(steps as i64, unix, &named)
            .and_then(|()| self.writer.flush())
            .with_context(|| format!("cannot write {path}"))
    }
}
