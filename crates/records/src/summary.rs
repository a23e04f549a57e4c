//! `summary.json`: the result of a run, written by `hive train` and read
//! back by `hive bench table` and by scripts (design.md's contract names
//! its keys; every field here is one of them).

use std::collections::BTreeMap;
use std::path::Path;

use crate::{HostRole, ObservationMode, RecordsError, Renderer, Result};
use serde::{Deserialize, Serialize};

/// One host of a run (`summary.json`'s `hosts`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct HostSummary {
    /// The machine's name.
    pub name: String,
    /// `head`, `worker`, or `unknown` (keys that name no host).
    pub role: HostRole,
    /// Environments it ran.
    pub envs: u32,
    /// Agents per environment.
    pub agents: u32,
    /// Agent-steps its sims reported.
    pub env_steps: u64,
    /// Transitions lost on the way from it (sequence gaps of its actors,
    /// and what it sent that the head never took), across restarts.
    pub lost_transitions: u64,
    /// Transitions its link sent a first time (a worker; 0 on the head).
    #[serde(default)]
    pub transitions_sent: u64,
    /// Transitions the head's replay took from it and acknowledged.
    #[serde(default)]
    pub transitions_acknowledged: u64,
    /// Transitions its link sent again (asked for again, or after its
    /// session came back).
    #[serde(default)]
    pub transitions_resent: u64,
    /// Transitions that reached the head again after it had taken them:
    /// dropped.
    #[serde(default)]
    pub duplicates_dropped: u64,
    /// Messages from it that failed the head's checks and were dropped (a
    /// host named `unknown`: messages on keys that name no host of the run,
    /// and refused join requests).
    #[serde(default)]
    pub rejected_messages: u64,
    /// The same by reason (`slot`, `header`, `length`, `count`,
    /// `environment`, `role`, `values`, `join_refused`), the reasons that
    /// counted any.
    #[serde(default)]
    pub rejected_by_reason: BTreeMap<String, u64>,
}

/// The result of one `hive train`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Summary {
    /// Whether the rolling reward reached the threshold.
    pub converged: bool,
    /// The rolling-reward threshold.
    pub threshold: f64,
    /// Wall seconds to the threshold.
    pub time_to_threshold_s: Option<f64>,
    /// Wall seconds of the run.
    pub wall_s: f64,
    /// Agent-steps of every host.
    pub env_steps: u64,
    /// Episodes finished.
    pub episodes: u64,
    /// Rolling mean episode reward at the end.
    pub rolling_reward: Option<f64>,
    /// Share of the rolling window's episodes that reached the goal.
    pub rolling_success_rate: Option<f64>,
    /// Learner updates.
    pub learner_updates: u64,
    /// Environments of this host.
    pub envs: usize,
    /// Agents per environment.
    pub agents_per_env: usize,
    /// Agents of every host.
    pub agents_total: usize,
    /// Every host of the run, this one first.
    pub hosts: Vec<HostSummary>,
    /// `batched` or `non-batched`.
    pub observation_mode: ObservationMode,
    /// `cpu` or `wgpu`.
    pub renderer: Renderer,
    /// Agent-steps per wall second.
    pub env_steps_per_s: f64,
    /// Learner updates per wall second.
    pub updates_per_s: f64,
    /// Mean whole-machine CPU %.
    pub cpu_util_mean_pct: Option<f64>,
    /// Mean GPU utilisation (null without a GPU).
    pub gpu_util_mean_pct: Option<f64>,
    /// Mean GPU power (null without a GPU).
    pub gpu_power_mean_w: Option<f64>,
    /// Peak GPU memory (null without a GPU).
    pub gpu_mem_peak_mb: Option<f64>,
    /// Peak of the summed resident memory of the run's processes.
    pub peak_rss_mb: f64,
    /// Mean policy lag of the learner's minibatches: its weight version at
    /// the update minus the version each transition was acted with.
    pub policy_lag_mean: Option<f64>,
    /// Roles restarted after dying.
    pub restarts: u64,
    /// Lost, every role, across restarts: messages an actor gave up or
    /// found missing, plus transitions the replay and the head's link found
    /// missing (sequence gaps) or corrupt.
    pub lost_messages: u64,
    /// Messages and joins refused from other hosts by reason, summed over
    /// `hosts`.
    #[serde(default)]
    pub rejected_by_reason: BTreeMap<String, u64>,
    /// The run's result: the best greedy checkpoint, else the last weights.
    pub checkpoint: Option<String>,
    /// The last weights the learner saved.
    pub last_checkpoint: Option<String>,
    /// Greedy evaluations made.
    pub evaluations: usize,
    /// The best evaluation's success rate.
    pub best_eval_success_rate: Option<f64>,
    /// Its mean reward.
    pub best_eval_mean_reward: Option<f64>,
    /// When it was made (wall s).
    pub best_eval_at_s: Option<f64>,
    /// At which learner update.
    pub best_eval_updates: Option<u64>,
    /// When a greedy validation (screening) first reached
    /// `eval.target_success` (wall s); null if never.
    #[serde(default)]
    pub time_to_target_success_s: Option<f64>,
    /// Agent-steps (every host's) when the rolling reward reached the
    /// threshold; null if never.
    #[serde(default)]
    pub env_steps_at_threshold: Option<u64>,
    /// Learner updates then.
    #[serde(default)]
    pub updates_at_threshold: Option<u64>,
    /// The actors' exploration rate then.
    #[serde(default)]
    pub epsilon_at_threshold: Option<f64>,
    /// Agent-steps until a greedy validation first reached
    /// `eval.target_success`: the learning metric; null if never.
    #[serde(default)]
    pub env_steps_to_target: Option<u64>,
    /// The result's validation success: its confirmation on fresh spawns
    /// (`eval.confirm_episodes`), or its screening when confirmation is off.
    #[serde(default)]
    pub result_validation_success: Option<f64>,
    /// Episodes behind `result_validation_success`.
    #[serde(default)]
    pub result_validation_episodes: Option<usize>,
    /// The last validation's (screening) success, to compare with the best.
    #[serde(default)]
    pub final_validation_success: Option<f64>,
    /// Updates skipped for a non-finite loss or gradient.
    #[serde(default)]
    pub skipped_updates: u64,
    /// What the teacher did (its keys at the top level of the JSON).
    #[serde(flatten)]
    pub teaching: Teaching,
    /// The cores the run was sized for and what it ran with: `cores`,
    /// `cores_available`, `envs`, `render_threads`, `actor_threads`,
    /// `learner_threads`, and `sized`, the keys the sizing filled.
    #[serde(default)]
    pub sizing: Option<serde_json::Value>,
    /// The run's camera map (`[sim.map]`) as it ran, with `floats` (the
    /// observation's share); null without a map.
    #[serde(default)]
    pub map: Option<serde_json::Value>,
    /// The run's seen movers (`[sim.tracks]`) as it ran, with `floats`;
    /// null without tracks.
    #[serde(default)]
    pub tracks: Option<serde_json::Value>,
    /// Stopped by a signal.
    pub interrupted: bool,
    /// Continued from an earlier run (`--resume`).
    pub resumed: bool,
    /// Why the run failed, if it did.
    pub failure: Option<String>,
    /// iceoryx2 services of the run still there after it (should be none).
    pub leftover_services: Vec<String>,
}

/// What a run's teacher (`[teacher]`) did, in `summary.json`.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct Teaching {
    /// The run's `[teacher]` section as it ran (null without a teacher).
    pub teacher: Option<serde_json::Value>,
    /// Transitions the teacher flew (demonstrations), as the actors sent them.
    pub demo_transitions: u64,
    /// The student's transitions sent with the teacher's action.
    pub labelled_transitions: u64,
    /// Milliseconds of the planner per label of a student's step (null
    /// without labels).
    pub teacher_ms_per_label: Option<f64>,
    /// Milliseconds of the planner per step of an agent it flies (null
    /// without demonstrations).
    pub teacher_ms_per_demo_step: Option<f64>,
    /// Seconds of the planner in all the sims together (its labels and the
    /// steps it flew), outside the sims' stages.
    pub teacher_s: f64,
}

impl Summary {
    /// Writes `RUN_DIR/summary.json` atomically (`rotorhive_msg::durable`),
    /// so a crash or a full disk leaves no half-written summary.
    pub fn write(&self, run_dir: &Path) -> Result<()> {
        let path = run_dir.join("summary.json");
        let text = serde_json::to_string_pretty(self).map_err(RecordsError::Encode)? + "\n";
        rotorhive_msg::durable::atomic_write(&path, |tmp| std::fs::write(tmp, &text), |e| e)
            .map_err(RecordsError::io("write", &path))
    }

    /// Reads `RUN_DIR/summary.json`; the error names the file.
    pub fn read(run_dir: &Path) -> Result<Self> {
        let path = run_dir.join("summary.json");
        let text = std::fs::read_to_string(&path).map_err(RecordsError::io("read", &path))?;
        serde_json::from_str(&text)
            .map_err(|err| RecordsError::Summary { file: path.display().to_string(), err })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_summary_round_trips_through_its_file_with_the_contract_keys() {
        let s = Summary {
            converged: true,
            threshold: 300.0,
            time_to_threshold_s: Some(52.5),
            wall_s: 60.0,
            env_steps: 400_000,
            episodes: 900,
            rolling_reward: Some(310.0),
            rolling_success_rate: Some(0.9),
            learner_updates: 12_000,
            envs: 2,
            agents_per_env: 25,
            agents_total: 50,
            hosts: vec![HostSummary {
                name: "here".into(),
                role: HostRole::Head,
                envs: 2,
                agents: 25,
                env_steps: 400_000,
                lost_transitions: 0,
                transitions_sent: 0,
                transitions_acknowledged: 0,
                transitions_resent: 0,
                duplicates_dropped: 0,
                rejected_messages: 3,
                rejected_by_reason: [("length".to_string(), 2), ("values".to_string(), 1)].into(),
            }],
            observation_mode: ObservationMode::Batched,
            renderer: Renderer::Cpu,
            env_steps_per_s: 6_666.7,
            updates_per_s: 200.0,
            cpu_util_mean_pct: Some(97.0),
            gpu_util_mean_pct: None,
            gpu_power_mean_w: None,
            gpu_mem_peak_mb: None,
            peak_rss_mb: 900.0,
            policy_lag_mean: Some(4.5),
            restarts: 0,
            lost_messages: 0,
            rejected_by_reason: [("length".to_string(), 2), ("values".to_string(), 1)].into(),
            checkpoint: Some("runs/x/checkpoints/best.safetensors".into()),
            last_checkpoint: None,
            evaluations: 3,
            best_eval_success_rate: Some(0.9),
            best_eval_mean_reward: Some(250.0),
            best_eval_at_s: Some(55.0),
            best_eval_updates: Some(11_000),
            time_to_target_success_s: Some(55.0),
            env_steps_at_threshold: Some(350_000),
            updates_at_threshold: Some(10_500),
            epsilon_at_threshold: Some(0.31),
            env_steps_to_target: Some(380_000),
            result_validation_success: Some(0.93),
            result_validation_episodes: Some(300),
            final_validation_success: Some(0.85),
            skipped_updates: 0,
            teaching: Teaching::default(),
            sizing: Some(serde_json::json!({ "cores": 2, "envs": 1 })),
            map: None,
            tracks: None,
            interrupted: false,
            resumed: false,
            failure: None,
            leftover_services: vec![],
        };
        let dir = std::env::temp_dir().join(format!("rotorhive-summary-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        s.write(&dir).unwrap();
        assert_eq!(Summary::read(&dir).unwrap(), s);
        let v: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(dir.join("summary.json")).unwrap())
                .unwrap();
        for key in [
            "converged",
            "time_to_threshold_s",
            "agents_total",
            "gpu_util_mean_pct",
            "checkpoint",
            "policy_lag_mean",
            "hosts",
            "time_to_target_success_s",
            "result_validation_success",
            "result_validation_episodes",
            "skipped_updates",
            "env_steps_at_threshold",
            "updates_at_threshold",
            "epsilon_at_threshold",
            "env_steps_to_target",
            "rejected_by_reason",
            "teacher",
            "demo_transitions",
            "labelled_transitions",
            "sizing",
            "map",
        ] {
            assert!(v.get(key).is_some(), "no key {key}");
        }
        assert!(v["gpu_util_mean_pct"].is_null());
        // Reasons are an object, reason → count (design.md's contract).
        assert_eq!(v["hosts"][0]["rejected_by_reason"]["length"], 2);
        assert_eq!(v["rejected_by_reason"]["values"], 1);
        std::fs::write(dir.join("summary.json"), "{\"converged\": 1}").unwrap();
        assert!(Summary::read(&dir).unwrap_err().to_string().contains("summary.json"));
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
