//! End-to-end: `hive train` starts real role processes that talk over real
//! iceoryx2 shared memory, trains a real network for a short while, and
//! leaves nothing behind. Bad input is refused with a clear message.

mod common;

use common::{root, tmp};
use std::path::PathBuf;
use std::process::Command;

fn hive() -> Command {
    let mut c = Command::new(env!("CARGO_BIN_EXE_hive"));
    c.current_dir(root());
    c
}

fn csv_rows(path: &PathBuf) -> Vec<Vec<String>> {
    std::fs::read_to_string(path)
        .unwrap()
        .lines()
        .skip(1)
        .map(|l| l.split(',').map(str::to_string).collect())
        .collect()
}

/// The training runs of this file take turns: on a 2-core machine two at once
/// would halve each learner's updates.
static TRAINING: std::sync::Mutex<()> = std::sync::Mutex::new(());

#[test]
#[ignore = "slow multi-process test: scripts/test runs it (--include-ignored)"]
fn short_multi_process_training_run() {
    let _turn = TRAINING.lock().unwrap_or_else(std::sync::PoisonError::into_inner);
    let dir = tmp("train");
    let out = hive()
        .args(["train", "configs/default.toml", "--quiet", "--max-seconds", "35", "--run-dir"])
        .arg(&dir)
        .args([
            "--set",
            "sim.agents=8",
            "--set",
            "replay.min_fill=300",
            "--set",
            "replay.capacity=2000",
            "--set",
            "learner.checkpoint_every_s=5",
        ])
        // A target network that never moves, so that the TD loss is a
        // regression on fixed targets and must fall if the learner learns
        // (with the default target update it rises as the Q-values grow),
        // and a learning rate that shows the fall within the run.
        .args(["--set", "learner.target_update=1000000000", "--set", "learner.lr=0.002"])
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        out.status.success(),
        "train failed: {stderr}\n{}",
        String::from_utf8_lossy(&out.stdout)
    );
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("summary.json")).unwrap()).unwrap();
    for key in [
        "converged",
        "threshold",
        "time_to_threshold_s",
        "wall_s",
        "env_steps",
        "episodes",
        "learner_updates",
        "envs",
        "agents_per_env",
        "agents_total",
        "observation_mode",
        "renderer",
        "env_steps_per_s",
        "updates_per_s",
        "cpu_util_mean_pct",
        "gpu_util_mean_pct",
        "gpu_power_mean_w",
        "peak_rss_mb",
        "restarts",
        "checkpoint",
    ] {
        assert!(summary.get(key).is_some(), "summary.json lacks {key}: {summary}");
    }
    // Real work crossed the processes.
    assert!(summary["env_steps"].as_u64().unwrap() > 300, "{summary}");
    assert!(summary["episodes"].as_u64().unwrap() > 0, "{summary}");
    assert!(summary["learner_updates"].as_u64().unwrap() > 20, "{summary}");
    // Transitions arrived uncorrupted and in order: no sequence gaps, no bad values.
    assert_eq!(summary["lost_messages"].as_u64(), Some(0), "{summary}");
    // Nothing left in shared memory.
    assert_eq!(summary["leftover_services"].as_array().map(Vec::len), Some(0), "{summary}");
    // Weights reached the actor: it acted with a version newer than the first.
    let tel = csv_rows(&dir.join("telemetry.csv"));
    let actor_version = tel
        .iter()
        .filter(|r| r[1] == "actor")
        .map(|r| r[10].parse::<u64>().unwrap())
        .max()
        .unwrap();
    let learner_version = tel
        .iter()
        .filter(|r| r[1] == "learner")
        .map(|r| r[10].parse::<u64>().unwrap())
        .max()
        .unwrap();
    assert!(
        actor_version > 1 && learner_version > 1,
        "actor {actor_version}, learner {learner_version}"
    );
    // The learner's loss (its telemetry gauge: the mean over each second's
    // updates) falls: the last third of the samples against the first third.
    let losses: Vec<f64> = tel
        .iter()
        .filter(|r| r[1] == "learner" && r[8] != "0")
        .filter_map(|r| r[19].parse().ok())
        .collect();
    assert!(losses.len() >= 9, "too few learner samples: {losses:?}");
    let third = losses.len() / 3;
    let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len() as f64;
    let (first, last) = (mean(&losses[..third]), mean(&losses[losses.len() - third..]));
    assert!(
        last.is_finite() && last < 0.9 * first,
        "the loss did not fall ({first:.3} → {last:.3}): {losses:?}"
    );
    // Telemetry: the learner, busy updating, shows a high CPU share; without
    // an NVIDIA GPU the GPU fields are empty and the summary's GPU keys null.
    let learner_cpu = tel
        .iter()
        .filter(|r| r[1] == "learner")
        .filter_map(|r| r[4].parse::<f64>().ok())
        .fold(0.0, f64::max);
    assert!(learner_cpu > 25.0, "learner CPU {learner_cpu} % of a core");
    // The supervisor's own process has its row (it monitors and evaluates),
    // and the profile shows it.
    let own: Vec<f64> = tel
        .iter()
        .filter(|r| r[1] == "supervisor")
        .filter_map(|r| r[4].parse::<f64>().ok())
        .collect();
    assert!(own.len() >= 10 && own.iter().all(|c| c.is_finite()), "supervisor rows: {own:?}");
    let profile = std::fs::read_to_string(dir.join("profile.md")).unwrap();
    assert!(profile.contains("| supervisor (monitor, evaluator, link) |"), "{profile}");
    // The learning diagnostics: the learner's rows carry mean max-Q, mean
    // |TD error| and the terminal share; the actor's its epsilon spread;
    // the profile shows them.
    let learner_rows: Vec<&Vec<String>> =
        tel.iter().filter(|r| r[1] == "learner" && r[8] != "0").collect();
    assert!(
        learner_rows.iter().any(|r| r[22].parse::<f64>().is_ok_and(|td| td > 0.0)),
        "no TD error in the learner's rows"
    );
    assert!(
        learner_rows.iter().all(|r| r[21].parse::<f64>().is_ok_and(f64::is_finite) && r[24] == "0"),
        "learner diagnostics"
    );
    assert!(
        tel.iter()
            .filter(|r| r[1] == "actor")
            .all(|r| r[25].parse::<f64>().is_ok() && r[26].parse::<f64>().is_ok()),
        "actor epsilon spread"
    );
    assert!(
        profile.contains("mean max-Q") && profile.contains("Exploration at the end"),
        "{profile}"
    );
    for key in [
        "time_to_target_success_s",
        "result_validation_success",
        "result_validation_episodes",
        "skipped_updates",
    ] {
        assert!(summary.get(key).is_some(), "summary.json lacks {key}: {summary}");
    }
    assert_eq!(summary["skipped_updates"].as_u64(), Some(0), "{summary}");
    if !std::path::Path::new("/dev/nvidiactl").exists() {
        assert!(
            summary["gpu_util_mean_pct"].is_null() && summary["gpu_power_mean_w"].is_null(),
            "{summary}"
        );
        assert!(
            tel.iter().all(|r| r[16].is_empty() && r[17].is_empty() && r[18].is_empty()),
            "GPU columns filled without a GPU"
        );
    }
    // The checkpoint loads and evaluates.
    let ckpt = summary["checkpoint"].as_str().unwrap().to_string();
    let out =
        hive().args(["eval", "--checkpoint", &ckpt, "--episodes", "5", "--json"]).output().unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let last = String::from_utf8_lossy(&out.stdout).lines().last().unwrap().to_string();
    let v: serde_json::Value = serde_json::from_str(&last).unwrap();
    assert_eq!(v["episodes"].as_u64(), Some(5));
    assert!(
        dir.join("reward.png").exists()
            && dir.join("config.toml").exists()
            && dir.join("metrics.csv").exists()
    );
    // It flies in a video: an animated GIF with a frame per action step, and
    // a still frame as a PNG.
    let (gif, still) = (dir.join("play.gif"), dir.join("play.png"));
    let out = hive()
        .args([
            "play",
            "--checkpoint",
            &ckpt,
            "--agents",
            "4",
            "--out",
            gif.to_str().unwrap(),
            "--still",
            still.to_str().unwrap(),
            "--json",
        ])
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let last = String::from_utf8_lossy(&out.stdout).lines().last().unwrap().to_string();
    let v: serde_json::Value = serde_json::from_str(&last).unwrap();
    let frames = v["frames"].as_u64().unwrap();
    assert!(frames >= 2, "{v}");
    assert_eq!(v["episodes"].as_u64(), Some(4));
    let mut decoder =
        gif::DecodeOptions::new().read_info(std::fs::File::open(&gif).unwrap()).unwrap();
    let (mut decoded, mut first) = (0u64, None::<Vec<u8>>);
    let mut changed = false;
    while let Some(f) = decoder.read_next_frame().unwrap() {
        assert_eq!((f.width, f.height), (640, 240));
        changed |= first.as_ref().is_some_and(|p| *p != f.buffer.to_vec());
        first.get_or_insert_with(|| f.buffer.to_vec());
        decoded += 1;
    }
    assert_eq!(decoded, frames);
    assert!(changed, "the frames show the flight going on");
    assert!(std::fs::read(&still).unwrap().starts_with(b"\x89PNG"));
    let _ = std::fs::remove_dir_all(&dir);
}

fn fails_with(args: &[&str], needles: &[&str]) {
    let out = hive().args(args).output().unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "{args:?} succeeded");
    assert!(!stderr.contains("panicked"), "{args:?} panicked: {stderr}");
    for n in needles {
        assert!(stderr.contains(n), "{args:?}: message lacks {n:?}: {stderr}");
    }
}

#[test]
fn bad_input_is_refused_clearly() {
    let dir = tmp("bad");
    std::fs::create_dir_all(&dir).unwrap();
    let bad_toml = dir.join("bad.toml");
    std::fs::write(&bad_toml, "seed = [\n").unwrap();
    fails_with(&["train", bad_toml.to_str().unwrap()], &["bad.toml"]);
    fails_with(&["train", "--set", "sim.agnets=3"], &["agnets"]);
    fails_with(&["train", "--set", "replay.batch=0"], &["replay.batch"]);
    fails_with(&["train", "--set", "replay.batch=999999"], &["replay.batch", "capacity"]);
    fails_with(&["train", "--set", "sim.agents=\"many\""], &["agents"]);
    fails_with(&["train", "--set", "sim.arena=\"/nonexistent/a.toml\""], &["/nonexistent/a.toml"]);
    let bad_arena = dir.join("arena.toml");
    std::fs::write(
        &bad_arena,
        std::fs::read_to_string(
            PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../configs/arenas/test.toml"),
        )
        .unwrap()
        .replacen("radius = ", "radius = -", 1),
    )
    .unwrap();
    fails_with(
        &["train", "--set", &format!("sim.arena=\"{}\"", bad_arena.display())],
        &["arena.toml", "obstacle", "radius"],
    );
    let trunc = dir.join("w.safetensors");
    std::fs::write(&trunc, b"\x10\x00\x00\x00\x00\x00\x00\x00{\"a\":").unwrap();
    fails_with(&["eval", "--checkpoint", trunc.to_str().unwrap()], &["w.safetensors"]);
    fails_with(
        &["play", "--checkpoint", trunc.to_str().unwrap(), "--out", "x.gif"],
        &["w.safetensors"],
    );
    fails_with(&["play", "--checkpoint", "c.safetensors", "--out", "x.mp4"], &["x.mp4", ".gif"]);
    fails_with(
        &["export", "--checkpoint", trunc.to_str().unwrap(), "--out", "x.onnx"],
        &["w.safetensors"],
    );
    fails_with(&["export", "--checkpoint", "c.safetensors", "--out", "x.txt"], &["x.txt", ".onnx"]);
    fails_with(&["train", "--resume", dir.to_str().unwrap()], &["--resume", "learner state"]);
    fails_with(&["train", "--set", "sim.renderer=\"vulkan\""], &["sim.renderer"]);
    fails_with(&["train", "--set", "eval.target_success=2"], &["eval.target_success"]);
    fails_with(&["train", "--set", "actor.exploration=\"greedy\""], &["actor.exploration"]);
    fails_with(&["train", "--set", "actor.per_actor_base=1.5"], &["actor.per_actor_base"]);
    fails_with(&["train", "--set", "learner.reward_scale=0"], &["learner.reward_scale"]);
    fails_with(&["train", "--set", "learner.max_grad_norm=-1"], &["learner.max_grad_norm"]);
    fails_with(&["bench", "seeds", "--seeds", "5-1"], &["--seeds"]);
    fails_with(&["bench", "seeds", "--arm", "a:nonsense"], &["key=value"]);
    fails_with(&["bench", "seeds", "--arm", "a:sim.agnets=3"], &["arm a", "agnets"]);
    fails_with(&["train", "--set", "sim.generated_lanes=-1"], &["generated_lanes"]);
    fails_with(&["profile", dir.to_str().unwrap()], &["telemetry.csv"]);
    let out = hive().args(["fly-to-the-moon"]).output().unwrap();
    assert_eq!(out.status.code(), Some(2));
    let out = hive().args(["train", "--no-such-flag"]).output().unwrap();
    assert_eq!(out.status.code(), Some(2));
    let _ = std::fs::remove_dir_all(&dir);
}

/// A stopped run goes on with `--resume`: the learner from its saved state,
/// the replay from its snapshot.
#[test]
#[ignore = "slow multi-process test: scripts/test runs it (--include-ignored)"]
fn a_stopped_run_resumes() {
    let _turn = TRAINING.lock().unwrap_or_else(std::sync::PoisonError::into_inner);
    let dir = tmp("resume");
    let small = [
        "--set",
        "sim.agents=8",
        "--set",
        "replay.min_fill=300",
        "--set",
        "replay.capacity=2000",
        "--set",
        "learner.checkpoint_every_s=3",
        "--set",
        "eval.every_s=3",
        "--set",
        "eval.episodes=10",
        "--set",
        "eval.confirm_episodes=10",
        "--set",
        "eval.validation_arenas=1",
    ];
    let out = hive()
        .args(["train", "configs/default.toml", "--quiet", "--max-seconds", "20", "--run-dir"])
        .arg(&dir)
        .args(small)
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let first: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("summary.json")).unwrap()).unwrap();
    let updates = first["learner_updates"].as_u64().unwrap();
    assert!(updates > 20, "{first}");
    assert!(dir.join("checkpoints/learner-state.safetensors").exists());
    assert!(dir.join("replay.bin").exists(), "no replay snapshot at the end of the run");
    let evals_before = csv_rows(&dir.join("evals.csv"));
    assert!(evals_before.len() >= 3, "{evals_before:?}");
    let out = hive()
        .args(["train", "--quiet", "--max-seconds", "10", "--resume"])
        .arg(&dir)
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let second: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("summary.json")).unwrap()).unwrap();
    assert_eq!(second["resumed"], true);
    // The learner's update counter went on from where it stopped.
    assert!(second["learner_updates"].as_u64().unwrap() > updates, "{second} after {updates}");
    let log = std::fs::read_to_string(dir.join("logs/replay.log")).unwrap();
    assert!(log.contains("restored"), "replay did not restore its memory: {log}");
    assert_eq!(second["leftover_services"].as_array().map(Vec::len), Some(0));
    let metrics = std::fs::read_to_string(dir.join("metrics.csv")).unwrap();
    assert!(metrics.contains("\nresume,"), "metrics.csv was not appended to");
    // evals.csv keeps the first run's rows and adds the new ones, and a row
    // is marked best (its weights written to best.safetensors) only when
    // its confirmed score beats every earlier one, the first run's included.
    let evals = csv_rows(&dir.join("evals.csv"));
    assert_eq!(evals[..evals_before.len()], evals_before[..]);
    assert!(evals.len() > evals_before.len(), "the resumed run evaluated nothing: {evals:?}");
    let score =
        |r: &Vec<String>| r[8].parse::<f64>().ok().map(|s| (s, r[9].parse::<f64>().unwrap()));
    let mut best: Option<(f64, f64)> = None;
    for r in &evals {
        // (Compared as printed: ties at the printed precision may go either way.)
        let (marked, s) = (r[6] == "1", score(r));
        if marked {
            assert!(
                s.is_some_and(|s| best.is_none_or(|b| s >= b)),
                "row {r:?} marked best below the best {best:?}"
            );
            best = s;
        } else {
            assert!(
                s.is_none_or(|s| best.is_some_and(|b| s <= b)),
                "row {r:?} beats the best {best:?} unmarked"
            );
        }
    }
    let _ = std::fs::remove_dir_all(&dir);
}
