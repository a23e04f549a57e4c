//! Helpers shared by the integration tests of `hive` (each test file uses
//! some of them).
#![allow(dead_code)]

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use rotorhive_records::rows::{EvalRow, MetricsRow};
use rotorhive_records::{Member, Summary, TelemetryRow};

/// The `--set` arguments of a small run on one host: 8 agents, a replay of
/// 2,000 that samples from 300 (each test adds its own).
pub const SMALL_RUN: [&str; 6] =
    ["--set", "sim.agents=8", "--set", "replay.min_fill=300", "--set", "replay.capacity=2000"];

/// The repository root (configs and arenas are read relative to it).
pub fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../..")
}

/// A fresh scratch directory for test `name` of this test process.
pub fn tmp(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("rotorhive-test-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    d
}

/// Polls `f` until it holds; fails the test naming `what` after `timeout`.
pub fn wait_for(what: &str, timeout: Duration, mut f: impl FnMut() -> bool) {
    let t = Instant::now();
    while !f() {
        assert!(t.elapsed() < timeout, "timed out waiting for {what}");
        std::thread::sleep(Duration::from_millis(100));
    }
}

/// A finished run's `summary.json`, through the records crate's type.
pub fn summary(run_dir: &Path) -> Summary {
    Summary::read(run_dir).unwrap_or_else(|e| panic!("{e:#}"))
}

/// A run's `telemetry.csv`, through the records crate's type (by column
/// name); empty while the file is missing or its last row half written, so
/// that a live run can be polled.
pub fn telemetry(run_dir: &Path) -> Vec<TelemetryRow> {
    rotorhive_records::telemetry::read(run_dir).unwrap_or_default()
}

/// The rows of `telemetry.csv` of one member (`Member::Learner`, ...).
pub fn telemetry_of(run_dir: &Path, member: Member) -> Vec<TelemetryRow> {
    telemetry(run_dir).into_iter().filter(|r| r.role == member).collect()
}

/// A run's `metrics.csv`, through the records crate's type.
pub fn metrics(run_dir: &Path) -> Vec<MetricsRow> {
    rotorhive_records::rows::read(&run_dir.join("metrics.csv")).unwrap_or_else(|e| panic!("{e:#}"))
}

/// A run's `evals.csv`, through the records crate's type.
pub fn evals(run_dir: &Path) -> Vec<EvalRow> {
    rotorhive_records::rows::read(&run_dir.join("evals.csv")).unwrap_or_else(|e| panic!("{e:#}"))
}

/// Sends `sig` to process `pid` of this test's run; fails the test if the
/// process is not there.
pub fn signal(pid: i32, sig: rustix::process::Signal) {
    let p = rustix::process::Pid::from_raw(pid).unwrap_or_else(|| panic!("pid {pid}"));
    rustix::process::kill_process(p, sig).unwrap_or_else(|e| panic!("kill({pid}, {sig:?}): {e}"));
}

/// The child processes of `pid`, with their command lines.
pub fn children_of(pid: u32) -> Vec<(i32, String)> {
    let mut out = Vec::new();
    for e in std::fs::read_dir("/proc").unwrap().flatten() {
        let Ok(p) = e.file_name().to_string_lossy().parse::<i32>() else {
            continue;
        };
        let Ok(stat) = std::fs::read_to_string(format!("/proc/{p}/stat")) else {
            continue;
        };
        // The parent's pid is the second field after the command's ")".
        let ppid = stat
            .rsplit_once(')')
            .and_then(|(_, rest)| rest.split_whitespace().nth(1))
            .and_then(|v| v.parse::<u32>().ok());
        if ppid == Some(pid) {
            let cmd = std::fs::read(format!("/proc/{p}/cmdline")).unwrap_or_default();
            out.push((p, String::from_utf8_lossy(&cmd).replace('\0', " ")));
        }
    }
    out
}

/// Whether process `pid` still runs (a zombie does not).
pub fn alive(pid: i32) -> bool {
    std::fs::read_to_string(format!("/proc/{pid}/stat")).is_ok_and(|s| {
        s.rsplit_once(')').and_then(|(_, r)| r.split_whitespace().next()) != Some("Z")
    })
}
