//! Fast role tests: every role as a thread of this test over iceoryx2's
//! `local` service (serial mode), with real simulation, real rendering and
//! a real network, for a few seconds each. Each case checks what crossed the
//! channels through the roles' own telemetry and episodes.

use std::collections::BTreeMap;
use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use rotorhive_msg::{EpisodeHeader, RoleKind, Telemetry};
use rotorhive_roles::{Config, episodes_channel, roles_of, spawn_serial};
use rotorhive_transport::{Channel, Hub, Local};

/// What a serial run of `cfg` reported after `seconds`: the newest telemetry
/// of every role, and the episodes the actors published.
struct Report {
    latest: BTreeMap<(u32, u32), Telemetry>,
    episodes: u64,
}

impl Report {
    fn work(&self, role: RoleKind) -> u64 {
        self.latest.values().filter(|t| t.role == role as u32).map(|t| t.work).sum()
    }

    fn get(&self, role: RoleKind, index: u32) -> Telemetry {
        *self
            .latest
            .get(&(role as u32, index))
            .unwrap_or_else(|| panic!("no telemetry of {role:?} {index}"))
    }
}

fn config(overrides: &[&str]) -> Config {
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../..");
    let mut sets: Vec<String> = vec![
        "sim.agents=4".into(),
        "sim.generated_lanes=0".into(),
        "replay.min_fill=200".into(),
        "replay.capacity=2000".into(),
        "eval.every_s=0".into(),
        format!("sim.arena=\"{}\"", root.join("configs/arenas/train.toml").display()),
    ];
    sets.extend(overrides.iter().map(|s| s.to_string()));
    Config::load(Some(&root.join("configs/default.toml")), &sets).unwrap()
}

/// Runs every role of `cfg` as threads until the learner has made `updates`
/// updates and every sim and actor has counted more than `per_env` (one
/// thread can start late on a loaded machine while the others feed the
/// learner); a watchdog fails the test after 60 s. Then stops them.
fn run_serial(name: &str, cfg: &Config, updates: u64, per_env: u64) -> Report {
    let dir = std::env::temp_dir().join(format!("rotorhive-serial-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let prefix = format!("serial-{name}");
    let hub = Hub::<Local>::new(&prefix, "test").unwrap();
    let mut tel = hub.receiver::<u8, Telemetry>(&Channel::telemetry(roles_of(cfg))).unwrap();
    let mut eps = hub.receiver::<f32, EpisodeHeader>(&episodes_channel(cfg.sim.envs)).unwrap();
    let stop = Arc::new(AtomicBool::new(false));
    let threads = spawn_serial(cfg, &prefix, &dir, &stop).unwrap();
    let mut report = Report { latest: BTreeMap::new(), episodes: 0 };
    let start = Instant::now();
    let envs = cfg.sim.envs as u32;
    let behind = |r: &Report| {
        let feeding = (0..envs).all(|e| {
            [RoleKind::Sim, RoleKind::Actor]
                .iter()
                .all(|&k| r.latest.get(&(k as u32, e)).is_some_and(|t| t.work > per_env))
        });
        r.work(RoleKind::Learner) < updates || !feeding
    };
    while behind(&report) {
        assert!(
            start.elapsed() < Duration::from_secs(60),
            "watchdog: {name} made too few updates or steps in 60 s"
        );
        if let Some((n, _)) = threads.iter().find(|(_, h)| h.is_finished()) {
            panic!("{name}: role {n} stopped early");
        }
        while let Some(m) = tel.try_recv().unwrap() {
            let t = *m.user_header();
            report.latest.insert((t.role, t.index), t);
        }
        while let Some(m) = eps.try_recv().unwrap() {
            report.episodes += m.user_header().count as u64;
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    stop.store(true, Ordering::SeqCst);
    for (n, h) in threads {
        h.join().unwrap().unwrap_or_else(|e| panic!("{name}: role {n}: {e:#}"));
    }
    // The last counters every role publishes as it stops.
    while let Some(m) = tel.try_recv().unwrap() {
        let t = *m.user_header();
        report.latest.insert((t.role, t.index), t);
    }
    assert!(
        dir.join("final.safetensors").exists() && dir.join("replay.bin").exists(),
        "{name}: the run directory lacks its files"
    );
    let _ = std::fs::remove_dir_all(&dir);
    report
}

#[test]
fn two_environments_non_batched_n_step_prioritized_with_the_rate_limit() {
    // Two sims and two actors, one message per agent (the actor's gather),
    // 3-step returns, and the rate limit on both sides: every transition is
    // sampled about once.
    // Prioritized replay too: the learner's TD errors come back as priorities.
    let cfg = config(&[
        "sim.envs=2",
        "sim.observation_mode=\"non-batched\"",
        "learner.n_step=3",
        "replay.samples_per_insert=1.0",
        "replay.prioritized=true",
    ]);
    let r = run_serial("two-envs", &cfg, 60, 50);
    for e in 0..2 {
        let (sim, actor) = (r.get(RoleKind::Sim, e), r.get(RoleKind::Actor, e));
        assert!(
            sim.work > 50 && actor.work > 50,
            "env {e}: sim steps {}, actor transitions {}",
            sim.work,
            actor.work
        );
        assert_eq!(actor.lost, 0, "actor {e} lost observation steps");
        assert!(actor.weight_version > 1, "actor {e} never took newer weights");
    }
    let replay = r.get(RoleKind::Replay, 0);
    assert_eq!(replay.lost, 0, "the replay saw sequence gaps or corrupt transitions");
    // Both actors' transitions reached the replay (n-step ones included):
    // no sequence gap (above), and all but the tail. The roles stop on one
    // flag, so an actor may go on sending for a few rounds after the
    // replay's last read (into the channel's buffer, then to no receiver):
    // that tail is not loss (seen: 229 of 5,479 on a loaded machine).
    let produced = r.get(RoleKind::Actor, 0).work + r.get(RoleKind::Actor, 1).work;
    assert!(
        replay.work * 10 >= produced * 9 && replay.work <= produced,
        "replay inserted {}, actors produced {produced}",
        replay.work
    );
    // The sample side of the limit: minibatches × batch stay within the
    // transitions inserted since sampling began, plus its buffer.
    let buffer =
        2 * (cfg.replay.prefetch as u64 + cfg.learner.publish_every + 2) * cfg.replay.batch as u64;
    let sampled = replay.work2 * cfg.replay.batch as u64;
    assert!(
        sampled <= replay.work - cfg.replay.min_fill as u64 + buffer,
        "sampled {sampled} of {} inserted",
        replay.work
    );
    assert!(r.episodes > 0, "no episodes reached the supervisor's channel");
    // The priorities of (nearly) every minibatch row came back and were
    // applied; the few stale ones are rows overwritten since.
    let (applied, stale) =
        (replay.learning.priority_updates as u64, replay.learning.stale_priorities as u64);
    assert!(
        applied + stale > 0 && applied >= (applied + stale) / 2,
        "priorities applied {applied}, stale {stale}"
    );
    assert!(
        applied + stale <= replay.work2 * cfg.replay.batch as u64,
        "more priorities than rows sampled"
    );
}

#[test]
fn one_environment_batched_without_the_rate_limit_with_ape_x_exploration() {
    // Also Ape-X's per-agent epsilons, a reward scale and gradient clipping:
    // the actor's telemetry shows the spread of its agents' rates, and the
    // learner's its diagnostics.
    let ape_x = [
        "actor.exploration=\"per-actor\"",
        "learner.reward_scale=0.01",
        "learner.max_grad_norm=10",
        "learner.n_step=3",
    ];
    let cfg = config(&[&["replay.samples_per_insert=0.0"][..], &ape_x].concat());
    let r = run_serial("batched", &cfg, 100, 4 * 50);
    let (sim, actor, replay) =
        (r.get(RoleKind::Sim, 0), r.get(RoleKind::Actor, 0), r.get(RoleKind::Replay, 0));
    assert!(sim.work >= 4 * 50, "sim agent-steps {}", sim.work);
    assert_eq!(actor.lost + replay.lost, 0);
    assert!(r.work(RoleKind::Learner) >= 100);
    assert!(
        replay.work2 >= 100 && r.episodes > 0,
        "minibatches {}, episodes {}",
        replay.work2,
        r.episodes
    );
    // Four agents: 0.4, 0.4^(1+7/3), 0.4^(1+14/3), 0.4^8.
    let l = actor.learning;
    assert!((l.eps_max - 0.4).abs() < 1e-6 && (l.eps_min - 0.4f32.powi(8)).abs() < 1e-6, "{l:?}");
    let d = r.get(RoleKind::Learner, 0).learning;
    assert!(d.mean_abs_td > 0.0 && d.mean_abs_td.is_finite() && d.mean_max_q.is_finite(), "{d:?}");
    assert!((0.0..=1.0).contains(&d.terminal_share) && d.skipped_updates == 0, "{d:?}");
}

#[test]
fn memory_sends_sequences_and_the_learner_unrolls_them() {
    // A GRU of 16: sequences of 6 steps (2 of burn-in) from one actor's 4
    // agents reach the replay whole, and the learner trains on them.
    let cfg = config(&[
        "learner.memory=\"gru:16\"",
        "learner.sequence_steps=6",
        "learner.burn_in=2",
        "replay.batch=4",
    ]);
    let r = run_serial("memory", &cfg, 30, 60);
    memory_run_checks(&r);
}

#[test]
fn memory_with_prioritized_replay_sends_each_sequences_priority_back() {
    let cfg = config(&[
        "learner.memory=\"gru:16\"",
        "learner.sequence_steps=6",
        "learner.burn_in=2",
        "replay.batch=4",
        "replay.prioritized=true",
    ]);
    let r = run_serial("memory-prio", &cfg, 30, 60);
    memory_run_checks(&r);
    let l = r.get(RoleKind::Replay, 0).learning;
    // Every sequence of (nearly) every minibatch comes back with its
    // priority; a few may find their row overwritten since.
    let (applied, stale) = (l.priority_updates as u64, l.stale_priorities as u64);
    assert!(applied >= 4 * 20, "{applied} priorities applied, {stale} stale");
    assert!(stale * 10 <= applied, "{applied} priorities applied, {stale} stale");
}

/// What a serial run with memory (sequences of 6 steps, 2 of burn-in) must
/// show: no sequence lost, what the actor sent reached the replay, the
/// learner trained and the actor took newer weights.
fn memory_run_checks(r: &Report) {
    let (actor, replay) = (r.get(RoleKind::Actor, 0), r.get(RoleKind::Replay, 0));
    assert_eq!(actor.lost + replay.lost, 0, "lost or corrupt sequences");
    // Each sequence counts its 4 trained steps as the actor's transitions;
    // all but the tail sent as the run stopped reached the replay.
    assert!(replay.work > 0, "no sequence reached the replay");
    assert!(
        replay.work * 4 <= actor.work && replay.work * 4 * 10 >= actor.work * 9,
        "replay inserted {} sequences, the actor sent {} trained steps",
        replay.work,
        actor.work
    );
    assert!(r.work(RoleKind::Learner) >= 30 && replay.work2 >= 30);
    assert!(actor.weight_version > 1, "the actor never took newer weights");
    assert!(r.episodes > 0);
}

#[test]
fn memory_with_a_teacher_keeps_its_demonstration_sequences_and_labels() {
    // The planner flies the first of the 4 agents and labels half of the
    // others' steps: the sequences carry both, the flown agent's go to the
    // demonstrations' reservoir, and the learner trains with the margin.
    let cfg = config(&[
        "learner.memory=\"gru:16\"",
        "learner.sequence_steps=6",
        "learner.burn_in=2",
        "replay.batch=4",
        "teacher.policy=\"planner\"",
        "teacher.demo_agents=1",
        "teacher.label_share=0.5",
        "teacher.demo_batch_share=0.5",
    ]);
    let r = run_serial("memory-teacher", &cfg, 30, 60);
    let (actor, replay) = (r.get(RoleKind::Actor, 0), r.get(RoleKind::Replay, 0));
    assert_eq!(actor.lost + replay.lost, 0, "lost or corrupt sequences");
    let (sent, t) = (actor.work, actor.teacher);
    // A quarter of the trained steps flown (the flown agent's sequences
    // are whole demonstrations), some of the rest labelled.
    assert!(
        t.demo_transitions * 5 >= sent && t.demo_transitions * 3 <= sent,
        "{} demonstrated of {sent} trained steps",
        t.demo_transitions
    );
    assert!(t.labelled_transitions > 0, "no step labelled: {t:?}");
    let held = replay.teacher.demo_transitions;
    assert!(held > 0 && held % 4 == 0, "the reservoir holds {held} steps (whole sequences)");
    assert!(held <= t.demo_transitions, "{held} held of {} sent", t.demo_transitions);
    assert!(r.work(RoleKind::Learner) >= 30);
}
