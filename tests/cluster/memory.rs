//! A worker with memory: its actors' sequences over the link.

use crate::common::{self, tmp};
use crate::{TURN, assert_delivered, free_port, small_head, small_worker, text};
use rotorhive_records::Member;

/// With memory a worker's actors send sequences (each with its stored
/// state): they cross the link whole, checked as sequences, the head's
/// replay takes every one and its learner trains on them.
#[test]
#[ignore = "slow multi-process test: scripts/test runs it (--include-ignored)"]
fn a_worker_with_memory_sends_its_sequences_to_the_head_without_loss() {
    let _turn = TURN.lock().unwrap_or_else(|e| e.into_inner());
    let dir = tmp("memory-head");
    let ep = format!("tcp/127.0.0.1:{}", free_port());
    let memory = [
        "--set",
        "learner.memory=\"gru:16\"",
        "--set",
        "learner.sequence_steps=6",
        "--set",
        "learner.burn_in=2",
        "--set",
        "replay.batch=4",
    ];
    let head = small_head("cluster-head", &ep, "20", &dir, &memory);
    let worker = small_worker(&ep, &tmp("memory-worker"));
    let h = head.wait_with_output().unwrap();
    let w = worker.wait_with_output().unwrap();
    assert!(h.status.success(), "head: {}", text(&h));
    assert!(w.status.success(), "worker: {}", text(&w));
    let s = common::summary(&dir);
    assert_eq!(s.hosts.len(), 2, "{s:?}");
    for host in &s.hosts {
        assert_delivered(host, &s, &h, &w);
        assert_eq!(host.rejected_messages, 0, "{s:?}");
    }
    assert_eq!(s.lost_messages, 0, "{s:?}");
    assert!(s.learner_updates > 20, "{s:?}");
    // The worker's actor (environment 1) sent sequences: its count is
    // their trained steps (4 each), and its batches were all delivered.
    let tel = common::telemetry(&dir);
    let actor = tel.iter().rfind(|r| r.role == Member::Actor && r.index == 1).unwrap();
    assert!(actor.work > 400, "{actor:?}");
    // It acted with the head's learner's weights (a recurrent network's:
    // not refused for the feedforward network's size).
    let wout = String::from_utf8_lossy(&w.stdout);
    assert!(wout.contains(" 0 rejected)"), "{wout}");
    assert!(actor.weight_version > 2, "{actor:?}");
    let _ = std::fs::remove_dir_all(&dir);
}
