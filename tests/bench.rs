//! Smoke test of every `hive bench` subcommand as a process, at its smallest
//! size: each must exit 0 and end its `--json` output with one object that
//! holds the fields the README and the design's contracts name. A benchmark
//! that breaks (as `bench render`'s completion check once did, waiting for a
//! payload value the teacher's labels had replaced) fails here.

mod common;

use common::{root, tmp};
use serde_json::Value;
use std::process::Command;

/// Runs `hive bench ARGS --json`; its last stdout line as JSON.
fn bench(args: &[&str]) -> Value {
    let out = Command::new(env!("CARGO_BIN_EXE_hive"))
        .current_dir(root())
        .arg("bench")
        .args(args)
        .arg("--json")
        .output()
        .unwrap();
    let (stdout, stderr) =
        (String::from_utf8_lossy(&out.stdout), String::from_utf8_lossy(&out.stderr));
    assert!(out.status.success(), "hive bench {args:?} failed:\n{stderr}\n{stdout}");
    let last = stdout.lines().last().unwrap_or_default();
    serde_json::from_str(last)
        .unwrap_or_else(|e| panic!("hive bench {args:?}: last line is not JSON ({e}): {last}"))
}

/// `v[key]` is a finite number above 0.
fn positive(v: &Value, key: &str) -> f64 {
    let x = v[key].as_f64().unwrap_or_else(|| panic!("no number {key} in {v}"));
    assert!(x.is_finite() && x > 0.0, "{key} = {x} in {v}");
    x
}

#[test]
#[ignore = "slow multi-process test: scripts/test runs it (--include-ignored)"]
fn every_benchmark_runs_at_its_smallest_size_and_prints_its_json() {
    let dir = tmp("bench-smoke");
    std::fs::create_dir_all(&dir).unwrap();

    let v = bench(&["sim", "--agents", "2", "--steps", "3"]);
    positive(&v, "agent_steps_per_s");
    assert_eq!(v["agents"].as_u64(), Some(2), "{v}");

    for renderer in ["cpu", "wgpu"] {
        let plot = dir.join(format!("render-{renderer}.png"));
        let v = bench(&[
            "render",
            "--agents",
            "1,3",
            "--steps",
            "2",
            "--renderer",
            renderer,
            "--plot",
            plot.to_str().unwrap(),
        ]);
        let rows = v["rows"].as_array().unwrap_or_else(|| panic!("no rows: {v}"));
        assert_eq!(rows.len(), 2, "{v}");
        for r in rows {
            for k in ["batched_ms", "non_batched_ms", "ratio"] {
                positive(r, k);
            }
        }
        assert!(std::fs::read(&plot).unwrap().starts_with(b"\x89PNG"));
    }

    // A level's lanes, fixed and renewed with fresh layouts, side by side.
    let v = bench(&[
        "sim",
        "--agents",
        "4",
        "--steps",
        "60",
        "--config",
        "configs/levels/dense.toml",
        "--fresh-layouts",
        "1",
    ]);
    let rows = v["rows"].as_array().expect("two rows");
    assert_eq!(rows.len(), 2, "{v}");
    assert_eq!(
        (rows[0]["lanes"].as_str(), rows[1]["lanes"].as_str()),
        (Some("fixed"), Some("fresh/1"))
    );
    positive(&rows[1], "agent_steps_per_s");

    // L4 reads the camera's map and the seen movers: its cost beside the
    // simulator without them; and with them turned off by `--set`, the
    // simulator alone (its teacher, which reads the map, flies in no
    // simulator bench).
    let level = ["sim", "--agents", "2", "--steps", "3", "--config", "configs/levels/moving.toml"];
    let v = bench(&level);
    let rows = v["rows"].as_array().expect("with and without the map");
    assert_eq!((rows[0]["map"].as_str(), rows[1]["map"].as_str()), (Some("rays+t5"), Some("none")));
    let off = ["--set", "sim.map.encoding=\"none\"", "--set", "sim.tracks.count=0"];
    let v = bench(&[&level[..], &off[..]].concat());
    assert_eq!(v["map"].as_str(), Some("none"), "{v}");

    for hidden in ["64", "96,32"] {
        let v = bench(&["learner", "--updates", "3", "--batch", "8", "--hidden", hidden]);
        for k in ["updates_per_s", "infer_b1_ms", "infer_b50_ms"] {
            positive(&v, k);
        }
        assert_eq!(v["batch"].as_u64(), Some(8), "{v}");
        assert_eq!(
            v["layers"].as_str(),
            Some(format!("conv:16,32 hidden:{hidden}").as_str()),
            "{v}"
        );
    }

    let v = bench(&["replay", "--producers", "1", "--seconds", "0.3"]);
    positive(&v, "inserts_per_s");
    positive(&v, "samples_per_s");
    assert!(v["rows"].as_array().is_some_and(|r| !r.is_empty()), "{v}");

    let v = bench(&["ipc", "--iters", "20"]);
    assert!(v["obs_batch"]["shm_p50_us"].as_f64().is_some(), "{v}");
    positive(&v["weights"], "ratio");

    let v = bench(&["link", "--seconds", "1", "--batch", "10"]);
    positive(&v, "transitions_per_s");
    positive(&v, "baseline_transitions_per_s");
    positive(&v, "ratio");
    assert_eq!(v["lost"].as_u64(), Some(0), "{v}");

    // One cell of one seed of the paper's table, a few seconds.
    let table = dir.join("table.toml");
    std::fs::write(
        &table,
        "config = \"configs/default.toml\"\nbudget_s = 6.0\nseeds = [1]\n\
         modes = [\"batched\"]\ncells = [[1, 4]]\n\
         set = [\"eval.every_s=0\", \"replay.min_fill=200\"]\n",
    )
    .unwrap();
    let out = dir.join("table");
    let v = bench(&["table", "--config", table.to_str().unwrap(), "--out", out.to_str().unwrap()]);
    let rows = v["rows"].as_array().unwrap_or_else(|| panic!("no rows: {v}"));
    assert_eq!(rows.len(), 1, "{v}");
    assert!(rows[0]["failure"].is_null(), "{v}");
    positive(&rows[0], "env_steps_per_s");
    assert!(out.join("agent-table.md").exists());

    // One seed of one arm, a few seconds, scored on a few test episodes.
    let out = dir.join("seeds");
    let v = bench(&[
        "seeds",
        "configs/default.toml",
        "--seeds",
        "1",
        "--budget-s",
        "6",
        "--test-episodes",
        "10",
        "--set",
        "replay.min_fill=200",
        "--out",
        out.to_str().unwrap(),
    ]);
    let arm = &v["arms"][0];
    for k in ["name", "runs", "converged", "median_time_s", "test_success", "test_success_min"] {
        assert!(arm.get(k).is_some(), "no {k} in {arm}");
    }
    assert_eq!(arm["runs"].as_u64(), Some(1), "{arm}");
    assert_eq!(arm["test_success"].as_array().map(Vec::len), Some(1), "{arm}");
    assert!(v["prob_improvement"].is_array(), "{v}");
    assert!(out.join("seeds.md").exists() && out.join("seeds.csv").exists());
    let _ = std::fs::remove_dir_all(&dir);
}
