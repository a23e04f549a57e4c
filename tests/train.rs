//! End-to-end: `hive train` starts real role processes that talk over real
//! iceoryx2 shared memory, trains a real network for a short while, and
//! leaves nothing behind. Bad input is refused with a clear message.

mod common;

use common::{root, tmp};
use rotorhive_records::rows::{EvalRow, MetricsKind};
use rotorhive_records::{Member, TelemetryRow};
use std::process::Command;

fn hive() -> Command {
    let mut c = Command::new(env!("CARGO_BIN_EXE_hive"));
    c.current_dir(root());
    c
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
        .args(common::SMALL_RUN)
        .args(["--set", "learner.checkpoint_every_s=5"])
        // A target network that never moves, so that the TD loss is a
        // regression on fixed targets and must fall if the learner learns
        // (with the default target update it rises as the Q-values grow),
        // and a learning rate that shows the fall within the run.
        .args(["--set", "learner.target_update=1000000000", "--set", "learner.lr=0.002"])
        // Sized for one core: one environment, one thread of each, as on two.
        .args(["--cores", "1"])
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(out.status.success(), "train failed: {stderr}\n{stdout}");
    let summary = common::summary(&dir);
    // The sizing printed at the start is the one given, and the summary's.
    let cores = std::thread::available_parallelism().unwrap().get();
    let line = format!(
        "sizing: 1 cores (of {cores}): 1 environment(s) of 8 agents, 1 render thread(s) each, \
         1 actor thread(s) each, 1 learner thread(s) (sized: sim.envs, sim.render_threads, \
         actor.threads, learner.threads)"
    );
    assert!(stdout.lines().any(|l| l == line), "{line}\n{stdout}");
    let sizing = summary.sizing.clone().unwrap();
    assert_eq!(
        (sizing["cores"].as_u64(), sizing["cores_available"].as_u64()),
        (Some(1), Some(cores as u64))
    );
    assert_eq!(sizing["sized"].as_array().map(Vec::len), Some(4), "{sizing}");
    // Real work crossed the processes.
    assert!(summary.env_steps > 300, "{summary:?}");
    assert!(summary.episodes > 0, "{summary:?}");
    assert!(summary.learner_updates > 20, "{summary:?}");
    assert!(summary.checkpoint.is_some() && summary.env_steps_per_s > 0.0, "{summary:?}");
    // Transitions arrived uncorrupted and in order: no sequence gaps, no bad values.
    assert_eq!(summary.lost_messages, 0, "{summary:?}");
    // Nothing left in shared memory.
    assert!(summary.leftover_services.is_empty(), "{summary:?}");
    // Weights reached the actor: it acted with a version newer than the first.
    let tel = common::telemetry(&dir);
    let of = |m: Member| tel.iter().filter(move |r| r.role == m);
    let actor_version = of(Member::Actor).map(|r| r.weight_version).max().unwrap();
    let learner_version = of(Member::Learner).map(|r| r.weight_version).max().unwrap();
    assert!(
        actor_version > 1 && learner_version > 1,
        "actor {actor_version}, learner {learner_version}"
    );
    // The learner's loss (its telemetry gauge: the mean over each second's
    // updates) falls: the last third of the samples against the first third.
    let learner_rows: Vec<&TelemetryRow> = of(Member::Learner).filter(|r| r.work != 0).collect();
    let losses: Vec<f64> = learner_rows.iter().filter_map(|r| r.value.parse().ok()).collect();
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
    let learner_cpu = of(Member::Learner).map(|r| r.cpu_pct).fold(0.0, f64::max);
    assert!(learner_cpu > 25.0, "learner CPU {learner_cpu} % of a core");
    // The supervisor's own process has its row (it monitors and evaluates),
    // and the profile shows it.
    let own: Vec<f64> = of(Member::Supervisor).map(|r| r.cpu_pct).collect();
    assert!(own.len() >= 10 && own.iter().all(|c| c.is_finite()), "supervisor rows: {own:?}");
    let profile = std::fs::read_to_string(dir.join("profile.md")).unwrap();
    assert!(profile.contains("| supervisor (monitor, evaluator, link) |"), "{profile}");
    // The learning diagnostics: the learner's rows carry mean max-Q, mean
    // |TD error| and the terminal share; the actor's its epsilon spread;
    // the profile shows them.
    let learning: Vec<_> = learner_rows.iter().filter_map(|r| r.learning).collect();
    assert_eq!(learning.len(), learner_rows.len(), "learner rows without diagnostics");
    assert!(learning.iter().any(|l| l.mean_abs_td > 0.0), "no TD error in the learner's rows");
    assert!(
        learning.iter().all(|l| l.mean_max_q.is_finite() && l.skipped_updates == 0),
        "learner diagnostics"
    );
    assert!(
        of(Member::Actor).all(|r| r.learning.is_some_and(|l| l.eps_min <= l.eps_max)),
        "actor epsilon spread"
    );
    assert!(
        profile.contains("mean max-Q") && profile.contains("Exploration at the end"),
        "{profile}"
    );
    assert_eq!(summary.skipped_updates, 0, "{summary:?}");
    assert!(summary.result_validation_success.is_some(), "{summary:?}");
    if !std::path::Path::new("/dev/nvidiactl").exists() {
        assert!(
            summary.gpu_util_mean_pct.is_none() && summary.gpu_power_mean_w.is_none(),
            "{summary:?}"
        );
        assert!(tel.iter().all(|r| r.gpu.is_none()), "GPU columns filled without a GPU");
    }
    // The checkpoint loads and evaluates.
    let ckpt = summary.checkpoint.clone().unwrap();
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
    // `hive profile` reads the finished run: each role's share and the
    // bottleneck.
    let out = hive().args(["profile", dir.to_str().unwrap()]).output().unwrap();
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    assert!(text.contains("# Profile of") && text.contains("learner"), "{text}");
    the_checkpoint_is_diagnosed_on_its_training_layouts(&dir, &ckpt);
    let _ = std::fs::remove_dir_all(&dir);
}

/// `hive eval --training-layouts --failures --agree` on a short run's
/// checkpoint: the layouts it trained on, the failure map and the audit.
fn the_checkpoint_is_diagnosed_on_its_training_layouts(dir: &std::path::Path, ckpt: &str) {
    let map = dir.join("failures");
    let run = dir.to_str().unwrap();
    let v = eval_json(&[
        "--checkpoint",
        ckpt,
        "--training-layouts",
        run,
        "--episodes",
        "24",
        "--failures",
        map.to_str().unwrap(),
        "--agree",
        "view",
    ]);
    assert_eq!(v["episodes"].as_u64(), Some(24), "{v}");
    let layouts = v["layouts"].as_array().unwrap();
    assert!(layouts.len() > 1, "{v}");
    assert!(layouts.iter().all(|l| l["name"].as_str().unwrap().starts_with("env-0-")), "{v}");
    let q = v["layout_quartiles"].as_array().unwrap();
    assert_eq!(q.len(), 3);
    assert!(q[0].as_f64() <= q[1].as_f64() && q[1].as_f64() <= q[2].as_f64(), "{v}");
    assert!(v["layouts_under_half"].as_u64().is_some(), "{v}");
    // Every failed episode is a row of the map; the pictures and the last
    // observations are there.
    let failures = v["failures"].as_u64().unwrap();
    let flown = (v["success_rate"].as_f64().unwrap() * 24.0).round() as u64;
    assert_eq!(failures, 24 - flown, "{v}");
    let csv = std::fs::read_to_string(map.join("failures.csv")).unwrap();
    assert_eq!(csv.lines().count() as u64, failures + 1, "{csv}");
    let npy = std::fs::read(map.join("last-observations.npy")).unwrap();
    assert!(npy.starts_with(b"\x93NUMPY"));
    let pictures = std::fs::read_dir(&map)
        .unwrap()
        .filter(|e| e.as_ref().unwrap().path().extension().is_some_and(|x| x == "png"))
        .count();
    assert!(failures == 0 || pictures > 0, "{failures} failures, {pictures} pictures");
    let share = v["trap_share"].as_f64().unwrap();
    assert!((0.0..=1.0).contains(&share) && v["traps"].as_u64().is_some(), "{v}");
    // The audit judged the steps flown.
    let g = &v["agreement"];
    assert_eq!(g["sight"], "view");
    assert!(g["all_steps"].as_u64().unwrap() > 24, "{g}");
    for k in ["all", "decisive", "before_crash"] {
        assert!(g[k].is_null() || (0.0..=1.0).contains(&g[k].as_f64().unwrap()), "{g}");
    }
    // The decisive steps by the nearest mover: every one in a class; with
    // no movers in these layouts, all in `none`.
    let near = g["decisive_by_nearest_mover"].as_object().unwrap();
    let steps = |k: &str| near[k]["steps"].as_u64().unwrap();
    let total: u64 =
        ["none", "unseen", "glimpsed", "moving", "turned"].iter().map(|k| steps(k)).sum();
    assert_eq!(total, g["decisive_steps"].as_u64().unwrap(), "{g}");
    assert_eq!(steps("none"), total, "{g}");
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

/// `hive eval --json`'s last line.
fn eval_json(args: &[&str]) -> serde_json::Value {
    let out = hive().arg("eval").args(args).arg("--json").output().unwrap();
    assert!(out.status.success(), "{args:?}: {}", String::from_utf8_lossy(&out.stderr));
    let last = String::from_utf8_lossy(&out.stdout).lines().last().unwrap().to_string();
    serde_json::from_str(&last).unwrap()
}

#[test]
fn the_scripted_pilots_fly_a_levels_test_layouts() {
    // L4's held-out layouts: the planner, which knows where every moving
    // obstacle will be, flies most of their episodes; the reactive rule,
    // which sees only the depth images, hardly any.
    let args = ["--level", "moving", "--episodes", "100"];
    let planner = eval_json(&[&args[..], &["--policy", "planner"]].concat());
    let reactive = eval_json(&[&args[..], &["--policy", "reactive"]].concat());
    assert_eq!(planner["policy"], "planner");
    assert_eq!(planner["sight"], "all");
    assert_eq!(planner["episodes"].as_u64(), Some(100));
    assert_eq!(planner["layouts"].as_array().map(Vec::len), Some(50));
    let (p, r) =
        (planner["success_rate"].as_f64().unwrap(), reactive["success_rate"].as_f64().unwrap());
    assert!(p >= 0.7 && p > r + 0.5, "planner {p}, reactive rule {r}");
    // Episodes it found no way through from the spawn are among those it
    // did not fly; the other pilots report none.
    let hopeless = planner["hopeless"].as_f64().unwrap();
    assert!(hopeless <= 100.0 * (1.0 - p) + 1e-9, "{hopeless} hopeless at {p}");
    assert!(reactive["hopeless"].is_null());
    // An evaluation flies no teacher: L4's, which reads the camera's map,
    // does not refuse the map turned off, and the reactive rule (which
    // reads the frames alone) flies the same episodes without it.
    let off = ["--set", "sim.map.encoding=\"none\"", "--set", "sim.tracks.count=0"];
    let blind = eval_json(&[&args[..], &["--policy", "reactive"], &off[..]].concat());
    assert_eq!(blind["success_rate"], reactive["success_rate"], "{blind}");
    // Told only what the pixels show, the planner still flies L1's
    // still layouts; the quartiles of its layouts are in order.
    let args = ["--level", "dense", "--episodes", "20", "--policy", "planner"];
    let pixels = eval_json(&[&args[..], &["--sight", "pixels"]].concat());
    assert_eq!(pixels["sight"], "pixels");
    let p = pixels["success_rate"].as_f64().unwrap();
    assert!(p >= 0.6, "the planner of the pixels flew {p} of L1");
    let q: Vec<f64> = pixels["layout_quartiles"]
        .as_array()
        .unwrap()
        .iter()
        .map(|x| x.as_f64().unwrap())
        .collect();
    assert!(q[0] <= q[1] && q[1] <= q[2], "{q:?}");
    // `--validation-layouts`: the level's validation layouts, where a
    // setting is chosen before the test layouts judge it.
    let args = ["--level", "dense", "--episodes", "20", "--policy", "reactive"];
    let v = eval_json(&[&args[..], &["--validation-layouts"]].concat());
    let names: Vec<&str> =
        v["layouts"].as_array().unwrap().iter().map(|l| l["name"].as_str().unwrap()).collect();
    assert_eq!(names.len(), 20, "{names:?}");
    assert!(names.iter().all(|n| n.starts_with("validation-")), "{names:?}");
    assert_eq!(v["validation_layouts"], true);
}

/// A checkpoint flown on a level sees as it was trained to: four frames
/// three action periods apart come from its header, not the level's two
/// consecutive ones; a `--set` that contradicts it is refused by name.
#[test]
fn a_checkpoint_flies_a_level_with_its_own_frames() {
    use rotorhive_model::{Device, Layers, PolicyNet, Shapes};
    let dir = tmp("strided");
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("strided.safetensors");
    let shapes = Shapes::task(4, false, false).with_stride(3);
    let net = |layers, memory| PolicyNet::new(shapes, layers, memory, 5, &Device::Cpu).unwrap();
    net(Layers::DEFAULT, None).save(&path, &[]).unwrap();
    let ckpt = path.to_str().unwrap();
    let v = eval_json(&["--checkpoint", ckpt, "--level", "moving", "--episodes", "5"]);
    assert_eq!((v["frames"].as_u64(), v["frame_stride"].as_u64()), (Some(4), Some(3)));
    assert_eq!(v["episodes"].as_u64(), Some(5));
    assert_eq!(v["memory"], "none");
    // A recurrent checkpoint flies as one, its header naming its memory.
    let gru = dir.join("gru.safetensors");
    net(Layers::DEFAULT, Some(8)).save(&gru, &[]).unwrap();
    let v =
        eval_json(&["--checkpoint", gru.to_str().unwrap(), "--level", "moving", "--episodes", "5"]);
    assert_eq!((v["memory"].as_str(), v["episodes"].as_u64()), (Some("gru:8"), Some(5)));
    // A network of other widths flies as it was built, its header naming them.
    let wide = dir.join("wide.safetensors");
    net(Layers::new(&[8, 24], &[96, 32]).unwrap(), None).save(&wide, &[]).unwrap();
    let v = eval_json(&[
        "--checkpoint",
        wide.to_str().unwrap(),
        "--level",
        "moving",
        "--episodes",
        "5",
    ]);
    assert_eq!(
        (v["layers"].as_str(), v["episodes"].as_u64()),
        (Some("conv:8,24 hidden:96,32"), Some(5))
    );
    // And plays, its state carried per drone.
    let gif = dir.join("gru.gif");
    let args = ["--agents", "2", "--out", gif.to_str().unwrap(), "--json"];
    let out = hive().args(["play", "--checkpoint", gru.to_str().unwrap()]).args(args).output();
    let out = out.unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let last = String::from_utf8_lossy(&out.stdout).lines().last().unwrap().to_string();
    let v: serde_json::Value = serde_json::from_str(&last).unwrap();
    assert_eq!(v["episodes"].as_u64(), Some(2));
    let reactive = eval_json(&["--policy", "reactive", "--level", "moving", "--episodes", "5"]);
    assert_eq!(
        (reactive["frames"].as_u64(), reactive["frame_stride"].as_u64()),
        (Some(2), Some(1))
    );
    fails_with(
        &["eval", "--checkpoint", ckpt, "--level", "moving", "--set", "sim.frame_stride=1"],
        &["strided.safetensors", "frame_stride 3 (this network: 1)"],
    );
    let _ = std::fs::remove_dir_all(&dir);
}

/// A checkpoint whose network reads the camera's map and the seen movers
/// takes their settings from its run's `config.toml`: without one beside
/// it, or with one naming other sizes, it is refused by name.
#[test]
fn a_checkpoint_with_a_memory_needs_its_runs_settings() {
    use rotorhive_model::{Device, Layers, PolicyNet, Shapes};
    let dir = tmp("memory-settings");
    std::fs::create_dir_all(dir.join("checkpoints")).unwrap();
    let path = dir.join("checkpoints/memory.safetensors");
    // The map's 36 rays (two distances each) and five movers of 14 floats.
    let shapes = Shapes::task(2, false, false).with_map(72).with_tracks(70);
    let net = PolicyNet::new(shapes, Layers::DEFAULT, None, 5, &Device::Cpu).unwrap();
    net.save(&path, &[]).unwrap();
    let c = path.to_str().unwrap();
    let flies = ["eval", "--checkpoint", c, "--episodes", "2"];
    fails_with(
        &flies,
        &["memory.safetensors", "72 floats of the camera's map", "config.toml, not found"],
    );
    let config = dir.join("config.toml");
    let write = |count: usize| {
        let text = format!("[sim.map]\nencoding = \"rays\"\n[sim.tracks]\ncount = {count}\n");
        std::fs::write(&config, text).unwrap();
    };
    write(5);
    let v = eval_json(&flies[1..]);
    assert_eq!(v["episodes"].as_u64(), Some(2));
    // Another count of movers: the evaluation flies the run's config and
    // refuses the network; `hive play` reads the checkpoint's memory first.
    write(3);
    fails_with(&flies, &["memory.safetensors", "tracks 70 (this network: 42)"]);
    let gif = dir.join("memory.gif");
    fails_with(
        &["play", "--checkpoint", c, "--agents", "1", "--out", gif.to_str().unwrap()],
        &["memory.safetensors", "70 floats of the seen movers", "names 42"],
    );
    let _ = std::fs::remove_dir_all(&dir);
}

/// A run of another camera (64 × 64) trains, and its checkpoint flies,
/// plays and exports with that camera wherever it goes (its run's config
/// beside it, a level's, or none: the header names it); a camera that
/// contradicts it is refused by name.
#[test]
#[ignore = "slow multi-process test: scripts/test runs it (--include-ignored)"]
fn a_run_of_another_camera_trains_flies_plays_and_exports() {
    let _turn = TRAINING.lock().unwrap_or_else(std::sync::PoisonError::into_inner);
    let dir = tmp("camera64");
    let camera = ["--set", "sim.camera.width=64", "--set", "sim.camera.height=64"];
    let out = hive()
        .args(["train", "configs/default.toml", "--quiet", "--max-seconds", "12", "--run-dir"])
        .arg(&dir)
        .args(common::SMALL_RUN)
        .args(camera)
        .output()
        .unwrap();
    assert!(out.status.success(), "train failed: {}", String::from_utf8_lossy(&out.stderr));
    let summary = common::summary(&dir);
    assert!(summary.env_steps > 100 && summary.learner_updates > 0, "{summary:?}");
    let ckpt = dir.join("final.safetensors");
    let c = ckpt.to_str().unwrap();
    let named = "64x64 hfov 90 range 20 pool 1";
    let v = eval_json(&["--checkpoint", c, "--episodes", "4"]);
    assert_eq!((v["camera"].as_str(), v["episodes"].as_u64()), (Some(named), Some(4)));
    // Alone, or on a level of the paper's camera: the header's camera.
    let lone = dir.join("lone.safetensors");
    std::fs::copy(&ckpt, &lone).unwrap();
    let l = lone.to_str().unwrap();
    for args in [&["--checkpoint", l][..], &["--checkpoint", l, "--level", "dense"]] {
        let v = eval_json(&[args, &["--episodes", "4"]].concat());
        assert_eq!(v["camera"].as_str(), Some(named), "{args:?}");
    }
    fails_with(
        &["eval", "--checkpoint", c, "--set", "sim.camera.hfov_deg=100"],
        &["final.safetensors", "trained with the camera 64x64 hfov 90", "gives 64x64 hfov 100"],
    );
    fails_with(
        &["eval", "--checkpoint", l, "--set", "sim.camera.width=32"],
        &["lone.safetensors", "trained with the camera 64x64", "gives 32x64"],
    );
    let onnx = dir.join("c64.onnx");
    let out = hive().args(["export", "--checkpoint", l, "--out"]).arg(&onnx).output().unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    assert!(String::from_utf8_lossy(&out.stdout).contains("depth (B, 2, 64, 64)"));
    let gif = dir.join("c64.gif");
    let out = hive()
        .args(["play", "--checkpoint", l, "--agents", "2", "--out", gif.to_str().unwrap()])
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    assert!(std::fs::metadata(&gif).unwrap().len() > 1000);
    let _ = std::fs::remove_dir_all(&dir);
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
            std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR"))
                .join("../../configs/arenas/test.toml"),
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
    // Weights that cannot compute a Q-value: every command refuses them by
    // the tensor's name.
    let nan = dir.join("nan.safetensors");
    let net = rotorhive_model::QNet::new(0, &rotorhive_model::Device::Cpu).unwrap();
    net.load_flat(&vec![f32::NAN; net.num_params()]).unwrap();
    net.save(&nan).unwrap();
    let nan = nan.to_str().unwrap();
    let why = ["nan.safetensors", "tensor `conv1.weight`", "not finite"];
    fails_with(&["eval", "--checkpoint", nan, "--episodes", "1"], &why);
    fails_with(&["play", "--checkpoint", nan, "--out", "x.gif"], &why);
    fails_with(&["export", "--checkpoint", nan, "--out", "x.onnx"], &why);
    fails_with(&["play", "--checkpoint", "c.safetensors", "--out", "x.mp4"], &["x.mp4", ".gif"]);
    fails_with(
        &["export", "--checkpoint", trunc.to_str().unwrap(), "--out", "x.onnx"],
        &["w.safetensors"],
    );
    fails_with(&["export", "--checkpoint", "c.safetensors", "--out", "x.txt"], &["x.txt", ".onnx"]);
    fails_with(
        &["eval", "--policy", "planner", "--checkpoint", "c.safetensors"],
        &["--policy planner", "--checkpoint"],
    );
    fails_with(
        &["eval", "--policy", "planner", "--sight", "view", "--memory-s", "9"],
        &["--memory-s", "view-memory"],
    );
    fails_with(
        &["eval", "--policy", "planner", "--sight", "view", "--rays", "64"],
        &["--rays", "pixels-memory"],
    );
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
    // Cameras the renderers or the network cannot take, and two names of
    // one range.
    fails_with(
        &["train", "--set", "sim.camera.width=100", "--set", "sim.camera.pool=3"],
        &["sim.camera.width", "99 or 102"],
    );
    let huge = ["--set", "replay.capacity=4000000", "--set", "sim.camera.width=256"];
    fails_with(
        &[&["train", "--set", "sim.camera.height=256"][..], &huge].concat(),
        &["replay.capacity", "GB; this machine has"],
    );
    fails_with(&["train", "--set", "sim.camera.height=8"], &["sim.camera.height", "12 to 256"]);
    fails_with(&["train", "--set", "sim.camera.preset=\"kinect\""], &["sim.camera.preset"]);
    fails_with(
        &["train", "--set", "sim.depth_range=30", "--set", "sim.camera.range=25"],
        &["sim.depth_range", "sim.camera.range"],
    );
    let teacher =
        |k: &str| ["train", "--set", "teacher.policy=\"planner\"", "--set", k].map(String::from);
    for (set, needle) in [
        ("teacher.label_share=1.5", "teacher.label_share"),
        ("teacher.margin=-1", "teacher.margin"),
        ("teacher.memory_s=9", "view-memory"),
        ("replay.prioritized=true", "replay.prioritized"),
        ("teacher.sight=\"psychic\"", "teacher.sight"),
    ] {
        let args = teacher(set);
        fails_with(&args.each_ref().map(String::as_str), &[needle]);
    }
    fails_with(&["train", "--set", "teacher.policy=\"oracle\""], &["teacher.policy"]);
    let pretrain =
        ["teacher.policy=\"planner\"", "teacher.demo_agents=0", "teacher.pretrain_updates=9"];
    let args: Vec<&str> = pretrain.iter().flat_map(|k| ["--set", k]).collect();
    fails_with(&[&["train"][..], &args].concat(), &["teacher.pretrain_updates", "demo_agents"]);
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
    // A threshold no run reaches: on a fast CPU the default config
    // converges in under 9 s, before its third evaluation.
    let small = [
        "--set",
        "threshold=100000",
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
        .args(common::SMALL_RUN)
        .args(small)
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let updates = common::summary(&dir).learner_updates;
    assert!(updates > 20, "{updates} updates");
    assert!(dir.join("checkpoints/learner-state.safetensors").exists());
    assert!(dir.join("replay.bin").exists(), "no replay snapshot at the end of the run");
    let evals_before = common::evals(&dir);
    assert!(evals_before.len() >= 3, "{evals_before:?}");
    let out = hive()
        .args(["train", "--quiet", "--max-seconds", "10", "--resume"])
        .arg(&dir)
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let second = common::summary(&dir);
    assert!(second.resumed);
    // The learner's update counter went on from where it stopped.
    assert!(second.learner_updates > updates, "{second:?} after {updates}");
    let log = std::fs::read_to_string(dir.join("logs/replay.log")).unwrap();
    assert!(log.contains("restored"), "replay did not restore its memory: {log}");
    assert!(second.leftover_services.is_empty());
    let metrics = common::metrics(&dir);
    assert!(
        metrics.iter().any(|r| r.kind == MetricsKind::Resume),
        "metrics.csv was not appended to"
    );
    // evals.csv keeps the first run's rows and adds the new ones, and a row
    // is marked best (its weights written to best.safetensors) only when
    // its confirmed score beats every earlier one, the first run's included.
    let evals = common::evals(&dir);
    assert_eq!(evals[..evals_before.len()], evals_before[..]);
    assert!(evals.len() > evals_before.len(), "the resumed run evaluated nothing: {evals:?}");
    let score = |r: &EvalRow| r.confirmed_success_rate.zip(r.confirmed_mean_reward);
    let mut best: Option<(f64, f64)> = None;
    for r in &evals {
        // (Compared as printed: ties at the printed precision may go either way.)
        let (marked, s) = (r.best == 1, score(r));
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
