//! Deterministic runs (`deterministic = true`): two `hive train` runs of the
//! same config and seed, real role processes over real shared memory, write
//! the same episodes and the same final network, byte for byte.

mod common;

use common::{root, tmp};
use rotorhive_records::Summary;
use rotorhive_records::rows::{MetricsKind, MetricsRow};
use std::process::Command;

/// A short deterministic run of `sets`; returns its episode rows without
/// `wall_s`, its final network's bytes and its summary.
fn run(name: &str, sets: &[&str], serial: bool) -> (Vec<String>, Vec<u8>, Summary) {
    let dir = tmp(name);
    let mut c = Command::new(env!("CARGO_BIN_EXE_hive"));
    c.current_dir(root())
        .args(["train", "configs/default.toml", "--quiet", "--max-seconds", "120", "--run-dir"])
        .arg(&dir);
    if serial {
        c.arg("--serial");
    }
    let common = [
        "deterministic=true",
        "sim.generated_lanes=0",
        "replay.capacity=3000",
        "eval.every_s=0",
        "seed=5",
    ];
    for s in common.iter().chain(sets) {
        c.args(["--set", s]);
    }
    let out = c.output().unwrap();
    assert!(
        out.status.success(),
        "{name} failed: {}\n{}",
        String::from_utf8_lossy(&out.stderr),
        String::from_utf8_lossy(&out.stdout)
    );
    let rows = common::metrics(&dir)
        .into_iter()
        .filter(|r| r.kind == MetricsKind::Episode)
        // Compared as printed: an undefined rolling reward is NaN, which
        // equals nothing.
        .map(|r| format!("{:?}", MetricsRow { wall_s: 0.0, ..r }))
        .collect();
    let weights = std::fs::read(dir.join("final.safetensors")).unwrap();
    let summary = common::summary(&dir);
    let _ = std::fs::remove_dir_all(&dir);
    (rows, weights, summary)
}

/// Two runs of `sets`, the second as processes or (`serial`) as threads of
/// one process: the same records either way.
fn assert_reproducible(name: &str, sets: &[&str], updates: u64, serial: bool) -> Summary {
    let (rows_a, weights_a, summary) = run(&format!("{name}-a"), sets, false);
    let (rows_b, weights_b, _) = run(&format!("{name}-b"), sets, serial);
    assert!(rows_a.len() > 20, "{name}: only {} episodes", rows_a.len());
    assert_eq!(
        summary.learner_updates, updates,
        "{name}: the schedule's updates, all made: {summary:?}"
    );
    if let Some(i) = rows_a.iter().zip(&rows_b).position(|(a, b)| a != b) {
        panic!("{name}: episode row {i} differs:\n{}\n{}", rows_a[i], rows_b[i]);
    }
    assert_eq!(rows_a.len(), rows_b.len(), "{name}: episode counts");
    assert!(weights_a == weights_b, "{name}: the final networks differ");
    summary
}

/// One environment, batched observations, one-step returns: 3,000
/// agent-steps of 4 agents (750 rounds), 1 + (3,000 - 200) / 32 = 88 updates
/// at one sample per insert (pinned: the schedule's arithmetic follows it);
/// the second run in serial mode (every role a thread, iceoryx2 `local`).
#[test]
#[ignore = "slow multi-process test: scripts/test runs it (--include-ignored)"]
fn one_batched_environment_repeats_exactly_in_processes_and_in_serial_mode() {
    let _ = assert_reproducible(
        "det-one",
        &[
            "max_env_steps=3000",
            "sim.agents=4",
            "replay.min_fill=200",
            "replay.samples_per_insert=1.0",
        ],
        88,
        true,
    );
}

/// Two environments of non-batched observations (the actor's gather),
/// 3-step returns, Ape-X's per-agent epsilons and prioritized replay: the
/// replay inserts rounds environment by environment and applies the
/// learner's priorities in minibatch order, each before the minibatch
/// `prefetch` later is sampled.
#[test]
#[ignore = "slow multi-process test: scripts/test runs it (--include-ignored)"]
fn two_non_batched_environments_with_n_step_and_prioritized_replay_repeat_exactly() {
    let sets = [
        "max_env_steps=4800",
        "sim.envs=2",
        "sim.agents=4",
        "sim.observation_mode=\"non-batched\"",
        "learner.n_step=3",
        "replay.min_fill=320",
        "replay.samples_per_insert=1.0",
        "replay.prioritized=true",
        "actor.exploration=\"per-actor\"",
        "learner.reward_scale=0.01",
    ];
    let summary = assert_reproducible("det-two", &sets, 1 + (4800 - 320) / 32, false);
    // Two simulator processes, one actor each, both stepped; the rest sized
    // for two cores on any machine (a deterministic run without `cores`).
    let s = summary.sizing.unwrap();
    assert_eq!((s["cores"].as_u64(), s["envs"].as_u64()), (Some(2), Some(2)), "{s}");
    assert_eq!(
        s["sized"],
        serde_json::json!(["sim.render_threads", "actor.threads", "learner.threads"])
    );
    assert_eq!((summary.envs, summary.agents_total), (2, 8));
}

/// With memory (`learner.memory`), two environments of non-batched
/// observations: the actors send every round (sequences leave only every
/// few steps), the schedule counts a sequence's trained steps (4 here:
/// 1 + (3,000 - 200) / (4 × 4) = 176 updates), and the recurrent learner's
/// updates, its states and the sequences' stored states repeat exactly, in
/// processes and in serial mode; prioritized, so that its priorities come
/// back in order.
#[test]
#[ignore = "slow multi-process test: scripts/test runs it (--include-ignored)"]
fn memory_repeats_exactly_in_processes_and_in_serial_mode() {
    let sets = [
        "max_env_steps=3000",
        "sim.envs=2",
        "sim.agents=4",
        "sim.observation_mode=\"non-batched\"",
        "replay.min_fill=200",
        "replay.samples_per_insert=1.0",
        "replay.batch=4",
        "replay.prioritized=true",
        "learner.memory=\"gru:8\"",
        "learner.sequence_steps=6",
        "learner.burn_in=2",
    ];
    let _ = assert_reproducible("det-memory", &sets, 1 + (3000 - 200) / 16, true);
}

/// The teacher (`[teacher]`): `policy = "none"` with every other teacher
/// key set trains exactly as a run without the section; the planner as
/// teacher (one agent of four flown, half the others' steps labelled, the
/// demonstrations in their reservoir, the large-margin loss on, 20
/// updates of pre-training on demonstrations alone) repeats exactly too,
/// and changes what is learned.
#[test]
#[ignore = "slow multi-process test: scripts/test runs it (--include-ignored)"]
fn the_teacher_repeats_exactly_and_none_trains_as_without_it() {
    let base = [
        "max_env_steps=3000",
        "sim.agents=4",
        "replay.min_fill=200",
        "replay.samples_per_insert=1.0",
        "learner.n_step=3",
    ];
    let plain = run("det-teacher-plain", &base, false);
    let none_keys = [
        "teacher.policy=\"none\"",
        "teacher.demo_agents=2",
        "teacher.label_share=1.0",
        "teacher.weight=5.0",
        "teacher.demo_batch_share=0.5",
    ];
    let none = run("det-teacher-none", &[&base[..], &none_keys].concat(), false);
    assert_eq!(plain.0, none.0, "policy none: the same episodes as without the section");
    // The same tensors, bit for bit (the header's config checksum differs:
    // the configs do).
    assert!(
        tensors(&plain.1) == tensors(&none.1),
        "policy none: the same final network as without the section"
    );
    assert!(none.2.teaching.teacher.is_none() && none.2.teaching.demo_transitions == 0);
    let planner_keys = [
        "teacher.policy=\"planner\"",
        "teacher.demo_agents=1",
        "teacher.label_share=0.5",
        "teacher.demo_batch_share=0.25",
        "teacher.demo_capacity=1000",
        "teacher.pretrain_updates=20",
    ];
    let sets = [&base[..], &planner_keys].concat();
    let (rows_a, weights_a, summary) = run("det-teacher-a", &sets, false);
    // The schedule's 88 updates, and 20 on demonstrations alone first.
    assert_eq!(summary.learner_updates, 88 + 20, "{summary:?}");
    let (rows_b, weights_b, _) = run("det-teacher-b", &sets, true);
    assert_eq!(rows_a, rows_b, "the teacher's runs differ");
    assert!(weights_a == weights_b, "the teacher's final networks differ");
    assert!(weights_a != plain.1, "the teacher changed nothing");
    // The student alone is saved: the same tensors and header as without a
    // teacher (a different config's checksum aside), so `hive eval`, `hive
    // play`, the ONNX export and Python fly it from its observation.
    let names = |w: &[u8]| tensors(w).into_iter().map(|(k, s, _)| (k, s)).collect::<Vec<_>>();
    assert_eq!(names(&weights_a), names(&plain.1));
    // One agent in four flown by the planner; its labels (half of the
    // other three's steps and all of its own, asked) name an action only
    // where one alone keeps a way clear; its episodes are not the
    // student's.
    let t = &summary.teaching;
    let (demo, labelled) = (t.demo_transitions, t.labelled_transitions);
    // Counted to the end (the roles' last telemetry, read after they
    // stopped): about a quarter of the 3,000 agent-steps, not what the
    // last periodic sample had seen (450 on a slow CI machine).
    assert!((700..=750).contains(&demo), "{summary:?}");
    assert!((1..=1125).contains(&labelled), "{summary:?}");
    assert!(t.teacher.is_some() && t.teacher_ms_per_label.is_some(), "{summary:?}");
    assert!(t.teacher_s > 0.0, "the planner's time, counted: {summary:?}");
    assert!(rows_a.len() > 10, "{} student episodes", rows_a.len());
}

/// Polyak averaging (`learner.average_updates`): the actors fly, and
/// `final.safetensors` keeps, a running average of the online weights, so
/// the episodes and the final network are not those of the plain run;
/// the run repeats exactly, in processes and in serial mode, with the same
/// updates.
#[test]
#[ignore = "slow multi-process test: scripts/test runs it (--include-ignored)"]
fn weight_averaging_repeats_exactly_and_changes_what_the_actors_fly() {
    let base = [
        "max_env_steps=3000",
        "sim.agents=4",
        "replay.min_fill=200",
        "replay.samples_per_insert=1.0",
    ];
    let plain = run("det-avg-plain", &base, false);
    let sets = [&base[..], &["learner.average_updates=30"]].concat();
    let (rows_a, weights_a, summary) = run("det-avg-a", &sets, false);
    let (rows_b, weights_b, _) = run("det-avg-b", &sets, true);
    assert_eq!(rows_a, rows_b, "the averaged runs differ");
    assert!(weights_a == weights_b, "the averaged runs' final networks differ");
    assert_eq!((summary.learner_updates, plain.2.learner_updates), (88, 88), "the schedule's");
    assert!(rows_a != plain.0, "the actors flew the online weights");
    assert!(tensors(&weights_a) != tensors(&plain.1), "final.safetensors is not the average");
}

/// A safetensors file's tensors: name, shape and bytes, in name order.
fn tensors(file: &[u8]) -> Vec<(String, Vec<usize>, Vec<u8>)> {
    let st = safetensors::SafeTensors::deserialize(file).unwrap();
    let mut t: Vec<_> =
        st.tensors().into_iter().map(|(k, v)| (k, v.shape().to_vec(), v.data().to_vec())).collect();
    t.sort();
    t
}
