//! The worker's end of the link: the join, and the running bridge between
//! its shared memory and the head.

use std::time::{Duration, Instant};

use zenoh::Wait;

use crate::error::{LinkError, Result, zerr};
use crate::options::{LinkOptions, open};
use crate::shared::JOIN;
use crate::wire::{self, Earlier, Hello, Welcome};

/// How a worker's link ended.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum WorkerEnd {
    /// The head ended the run.
    RunEnded,
    /// This process was asked to stop.
    Stopped,
}

/// Counters of a worker's link.
#[derive(Debug, Default, Clone, Copy)]
pub struct WorkerStats {
    /// Transitions sent (a first time).
    pub transitions: u64,
    /// Transitions the head acknowledged.
    pub acknowledged: u64,
    /// Transitions sent again (asked for again, or a session came back).
    pub resent: u64,
    /// Weight versions received.
    pub weights: u64,
    /// Newest weight version received.
    pub weight_version: u64,
    /// Episode or telemetry messages dropped.
    pub dropped: u64,
    /// Weights from the head that failed their check and were dropped.
    pub rejected: u64,
}

impl WorkerStats {
    /// Transitions sent and not (yet) acknowledged: at the link's end,
    /// those lost.
    pub fn unacknowledged(&self) -> u64 {
        self.transitions.saturating_sub(self.acknowledged)
    }
}

/// A worker's end of the link.
pub struct Worker {
    pub(crate) session: zenoh::Session,
    /// The head's answer.
    pub slot: u32,
    /// Index of this host's first environment in the run.
    pub env_offset: u32,
    /// The link epoch of this join: every batch carries it.
    pub epoch: u64,
    /// The run's name.
    pub run: String,
    /// The head's resolved config (TOML).
    pub config: String,
    /// The training arena (TOML).
    pub arena: String,
    /// How long the link waits for a head that went away to come back
    /// (`cluster.reconnect_s`; 60 s until set), its window kept, before it
    /// gives up.
    pub reconnect: Duration,
    /// Where the link keeps what this process has sent ([`SentLog`]);
    /// none until set.
    pub sent_log: Option<std::path::PathBuf>,
}

impl Worker {
    /// Connects to the head at `endpoint` and joins its run, asking again
    /// until `timeout` (the head may start later than the worker).
    pub fn join(
        endpoint: &str,
        hello: &Hello,
        timeout: Duration,
        opts: &LinkOptions,
        stop: impl Fn() -> bool,
    ) -> Result<Self> {
        let session = open(None, Some(endpoint), opts)?;
        // A worker whose certificate holds a slot asks for it (the head's
        // access control admits that one only).
        let join = opts.slot.map_or(JOIN.to_string(), |s| format!("{JOIN}/{s}"));
        let start = Instant::now();
        while start.elapsed() < timeout {
            if stop() {
                return Err(LinkError::Stopped("the head"));
            }
            let left = timeout.saturating_sub(start.elapsed()).max(Duration::from_millis(100));
            let replies = session
                .get(&join)
                .payload(hello.encode())
                .timeout(left.min(Duration::from_secs(5)))
                .wait()
                .map_err(zerr("ask to join"))?;
            // Every answer ends the wait; none means nobody is there yet.
            if let Ok(r) = replies.recv() {
                let bytes = match r.result() {
                    Ok(s) => s.payload().to_bytes().into_owned(),
                    Err(e) => {
                        return Err(LinkError::Refused {
                            endpoint: endpoint.into(),
                            why: String::from_utf8_lossy(&e.payload().to_bytes()).into_owned(),
                        });
                    }
                };
                match Welcome::decode(&bytes) {
                    Some(Welcome::Joined { slot, env_offset, epoch, run, config, arena }) => {
                        let reconnect = Duration::from_secs(60);
                        return Ok(Self {
                            session,
                            slot,
                            env_offset,
                            epoch,
                            run,
                            config,
                            arena,
                            reconnect,
                            sent_log: None,
                        });
                    }
                    Some(Welcome::Refused(why)) => {
                        return Err(LinkError::Refused { endpoint: endpoint.into(), why });
                    }
                    None => {
                        return Err(LinkError::Refused {
                            endpoint: endpoint.into(),
                            why: "an answer that is not a rotorhive welcome".into(),
                        });
                    }
                }
            }
            // The session keeps trying to connect meanwhile.
            std::thread::sleep(Duration::from_millis(200));
        }
        Err(LinkError::NoHead { endpoint: endpoint.into(), secs: timeout.as_secs_f64() })
    }
}

/// What a worker process has sent under its epoch, in a file of its run
/// directory (16 bytes: the epoch and the transitions sent, little-endian),
/// written before each batch goes: a process killed outright leaves it
/// behind, and the next one in that directory tells the head at its join
/// ([`crate::wire::Hello::earlier`]), so the head counts exactly what the
/// killed one sent and the head never took (not only what its last
/// once-a-second report said).
pub struct SentLog {
    file: std::fs::File,
}

impl SentLog {
    /// The log at `path`, created (or emptied) for this process.
    pub fn create(path: &std::path::Path) -> std::io::Result<Self> {
        Ok(Self { file: std::fs::File::create(path)? })
    }

    /// What the earlier process's log at `path` says (nothing known, or a
    /// file of another size: 0, 0).
    pub fn read(path: &std::path::Path) -> Earlier {
        std::fs::read(path).ok().and_then(|b| wire::header_from(&b)).unwrap_or_default()
    }

    /// Records `e` (a failed write only makes the count less exact).
    pub(crate) fn record(&self, e: Earlier) {
        use std::os::unix::fs::FileExt;
        let _ = self.file.write_all_at(wire::header_bytes(&e), 0);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_sent_log_reads_back_and_a_damaged_one_reads_as_nothing() {
        let dir = std::env::temp_dir().join(format!("rotorhive-sentlog-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("link-sent");
        assert_eq!(SentLog::read(&path), Earlier::default(), "no file");
        let log = SentLog::create(&path).unwrap();
        log.record(Earlier { epoch: 7, sent: 100 });
        log.record(Earlier { epoch: 7, sent: 150 });
        assert_eq!(SentLog::read(&path), Earlier { epoch: 7, sent: 150 });
        std::fs::write(&path, b"short").unwrap();
        assert_eq!(SentLog::read(&path), Earlier::default(), "a file of another size");
        let _ = std::fs::remove_dir_all(&dir);
    }
}
