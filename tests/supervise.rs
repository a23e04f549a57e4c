//! Reliability: every role of a real run is SIGKILLed in turn; the
//! supervisor cleans up after it, restarts it (the learner from its saved
//! state), counts the restarts, training goes on, and nothing is left in
//! shared memory.

mod common;

use common::{root, tmp, wait_for};
use rotorhive_records::Member;
use rustix::process::Signal;
use std::path::Path;
use std::process::{Command, Stdio};
use std::time::Duration;

/// Newest pid and counter of a role from `telemetry.csv`.
fn role_state(dir: &Path, role: Member) -> Option<(i32, u64)> {
    common::telemetry_of(dir, role).pop().map(|r| (r.pid as i32, r.work))
}

#[test]
#[ignore = "slow multi-process test: scripts/test runs it (--include-ignored)"]
fn killed_roles_are_restarted_and_training_goes_on() {
    let dir = tmp("supervise");
    let child = Command::new(env!("CARGO_BIN_EXE_hive"))
        .current_dir(root())
        .args(["train", "configs/default.toml", "--quiet", "--max-seconds", "70", "--run-dir"])
        .arg(&dir)
        .args(common::SMALL_RUN)
        .args([
            "--set",
            "learner.checkpoint_every_s=2",
            "--set",
            "eval.every_s=0",
            "--set",
            "threshold=100000",
        ])
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    wait_for("the learner to update", Duration::from_secs(40), || {
        role_state(&dir, Member::Learner).is_some_and(|(_, u)| u > 20)
    });
    wait_for("a learner state file", Duration::from_secs(20), || {
        dir.join("checkpoints/learner-state.safetensors").exists()
    });
    // The run's data segments (every payload crosses through them) are the
    // user's alone (mode 0600). iceoryx2's own node-management segments
    // (`*_node.*`) are created by iceoryx2 with other modes and not checked.
    use std::os::unix::fs::PermissionsExt;
    let mut segments = 0;
    for e in std::fs::read_dir("/dev/shm").unwrap().flatten() {
        let name = e.file_name().to_string_lossy().to_string();
        if name.starts_with("iox2_") && name.ends_with(".data") {
            let mode = e.metadata().unwrap().permissions().mode();
            assert_eq!(mode & 0o077, 0, "{:?} is open to others: {mode:o}", e.path());
            segments += 1;
        }
    }
    assert!(segments > 0, "no shared-memory segments found");
    let mut killed = Vec::new();
    for role in [Member::Actor, Member::Sim, Member::Replay, Member::Learner] {
        let (pid, before) = role_state(&dir, role).unwrap();
        common::signal(pid, Signal::KILL);
        killed.push((role, pid));
        // A new process of the role reports, and the learner keeps updating.
        wait_for(&format!("{role} to come back"), Duration::from_secs(30), || {
            role_state(&dir, role).is_some_and(|(p, _)| p != pid)
        });
        let (_, learner_before) = role_state(&dir, Member::Learner).unwrap();
        wait_for(
            &format!("updates after killing {role} ({before})"),
            Duration::from_secs(30),
            || role_state(&dir, Member::Learner).is_some_and(|(_, u)| u > learner_before + 5),
        );
    }
    // The restored learner went on from its saved update count.
    let (_, updates) = role_state(&dir, Member::Learner).unwrap();
    assert!(updates > 20, "learner at {updates} updates after its restart");
    // SIGINT to our own child: stop the run as Ctrl-C would.
    common::signal(child.id() as i32, Signal::INT);
    let out = child.wait_with_output().unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "train failed: {stderr}");
    let summary = common::summary(&dir);
    assert!(summary.restarts >= 4, "{summary:?} ({killed:?})");
    assert!(summary.leftover_services.is_empty(), "{summary:?}");
    let _ = std::fs::remove_dir_all(&dir);
}

/// A role that keeps dying (here: the replay cannot read a corrupt snapshot
/// in the run directory) stops the run with a clear message instead of
/// restarting forever, and leaves no shared memory behind.
#[test]
#[ignore = "slow multi-process test: scripts/test runs it (--include-ignored)"]
fn a_role_that_keeps_dying_stops_the_run() {
    let dir = tmp("dying");
    std::fs::create_dir_all(&dir).unwrap();
    std::fs::write(dir.join("replay.bin"), b"not a snapshot").unwrap();
    let out = Command::new(env!("CARGO_BIN_EXE_hive"))
        .current_dir(root())
        .args(["train", "configs/default.toml", "--quiet", "--max-seconds", "60", "--run-dir"])
        .arg(&dir)
        .args(["--set", "sim.agents=4", "--set", "eval.every_s=0"])
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "the run went on with a replay that cannot start");
    assert!(stderr.contains("role replay died") && stderr.contains("giving up"), "{stderr}");
    assert!(!stderr.contains("panicked"), "{stderr}");
    let log = std::fs::read_to_string(dir.join("logs/replay.log")).unwrap();
    assert!(log.contains("replay.bin") && log.contains("not a rotorhive replay snapshot"), "{log}");
    let summary = common::summary(&dir);
    assert_eq!(summary.restarts, 3, "{summary:?}");
    assert!(summary.leftover_services.is_empty(), "{summary:?}");
    let _ = std::fs::remove_dir_all(&dir);
}
