//! The link's errors, each naming the endpoint or the peer.

use std::path::PathBuf;

use rotorhive_transport::TransportError;

/// Errors of the link, naming the endpoint or the peer. A cause is part of
/// the text and not also `source()`, so `{:#}` names it once.
#[derive(Debug, thiserror::Error)]
pub enum LinkError {
    /// An endpoint that is not `tcp/`, `tls/` or `quic/HOST:PORT`.
    #[error(
        "endpoint {0:?}: expected tcp/HOST:PORT, tls/HOST:PORT or quic/HOST:PORT (for example quic/192.168.1.10:7447)"
    )]
    BadEndpoint(String),
    /// A `tls/` endpoint without certificates, or certificates that are not there.
    #[error("{0}")]
    Tls(String),
    /// A Zenoh configuration file that cannot be read.
    #[error("zenoh config {path}: {message}")]
    ZenohConfig {
        /// The file.
        path: PathBuf,
        /// What is wrong.
        message: String,
    },
    /// Zenoh refused to open the session or a declaration.
    #[error("zenoh ({what}): {cause}")]
    Zenoh {
        /// What was attempted.
        what: String,
        /// Zenoh's error, as it came (in the text; not `source()`).
        cause: zenoh::Error,
    },
    /// The link's thread could not start, or panicked.
    #[error("the link thread {0}")]
    Thread(&'static str),
    /// No head answered a worker in time.
    #[error(
        "no head answered at {endpoint} within {secs:.0} s (is `hive train --listen {endpoint}` running there, and the port open?)"
    )]
    NoHead {
        /// The endpoint tried.
        endpoint: String,
        /// Seconds waited.
        secs: f64,
    },
    /// The head refused the worker.
    #[error("the head at {endpoint} refused this worker: {why}")]
    Refused {
        /// The head's endpoint.
        endpoint: String,
        /// Its reason.
        why: String,
    },
    /// Too few workers joined before the timeout.
    #[error(
        "only {joined} of {wanted} worker hosts joined within {secs:.0} s (`cluster.join_timeout_s`)"
    )]
    TooFewWorkers {
        /// Joined.
        joined: usize,
        /// Wanted.
        wanted: usize,
        /// Seconds waited.
        secs: f64,
    },
    /// The head went away without ending the run.
    #[error("lost the head: its session ended without the run's end")]
    LostHead,
    /// Shared memory on this host.
    #[error(transparent)]
    Transport(#[from] TransportError),
    /// Stopped by a signal while waiting.
    #[error("stopped while waiting for {0}")]
    Stopped(&'static str),
}

/// Result of this crate.
pub type Result<T> = std::result::Result<T, LinkError>;

pub(crate) fn zerr(what: impl Into<String>) -> impl FnOnce(zenoh::Error) -> LinkError {
    let what = what.into();
    move |cause| LinkError::Zenoh { what, cause }
}
