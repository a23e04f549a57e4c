//! What can go wrong in a benchmark: a bad argument, a component that
//! failed, or a measurement that shows the system misbehaving (a damaged
//! batch, shared memory left behind). Each error says, through [`Doing`],
//! what the bench was doing; the binary adds its own context with `anyhow`.

use rotorhive_roles::error::RoleError;

/// An error of a benchmark.
#[derive(Debug, thiserror::Error)]
pub enum BenchError {
    /// A command-line argument or a bench config that is wrong; the text
    /// names it.
    #[error("{0}")]
    Usage(String),
    /// The bench saw the system misbehave, or a helper process fail.
    #[error("{0}")]
    Failed(String),
    /// A role or the run's config.
    #[error(transparent)]
    Role(#[from] RoleError),
    /// A run's records.
    #[error(transparent)]
    Records(#[from] rotorhive_records::RecordsError),
    /// iceoryx2.
    #[error(transparent)]
    Transport(#[from] rotorhive_transport::TransportError),
    /// The network.
    #[error(transparent)]
    Model(#[from] rotorhive_model::ModelError),
    /// Zenoh, through the link.
    #[error(transparent)]
    Link(#[from] rotorhive_link::LinkError),
    /// The simulator.
    #[error(transparent)]
    Lanes(#[from] rotorhive_sim::LanesError),
    /// The GPU renderer.
    #[error(transparent)]
    Render(#[from] rotorhive_sim::GpuError),
    /// An arena.
    #[error(transparent)]
    Arena(#[from] rotorhive_sim::ArenaError),
    /// A file, a socket or a process.
    #[error(transparent)]
    Io(#[from] std::io::Error),
    /// JSON from a helper process.
    #[error(transparent)]
    Json(#[from] serde_json::Error),
    /// msgpack, the baseline's serializer.
    #[error(transparent)]
    Msgpack(#[from] rmp_serde::decode::Error),
    /// msgpack, encoding.
    #[error(transparent)]
    MsgpackEncode(#[from] rmp_serde::encode::Error),
    /// Writing a report into a string.
    #[error(transparent)]
    Format(#[from] std::fmt::Error),
    /// A number a helper process printed.
    #[error(transparent)]
    Float(#[from] std::num::ParseFloatError),
    /// A port a helper process printed.
    #[error(transparent)]
    Int(#[from] std::num::ParseIntError),
    /// `err`, while the bench was doing `doing` (the cause is part of the
    /// text, not a separate source, so `{:#}` names it once).
    #[error("{doing}: {err}")]
    While {
        /// What the bench was doing.
        doing: String,
        /// What failed.
        err: Box<BenchError>,
    },
}

/// A config's error, as the roles take it (the same text).
impl From<rotorhive_config::ConfigError> for BenchError {
    fn from(e: rotorhive_config::ConfigError) -> Self {
        Self::Role(e.into())
    }
}

/// Result of this crate.
pub type Result<T> = std::result::Result<T, BenchError>;

/// Says what the bench was doing when an error happened (this crate's
/// `anyhow::Context`); on an `Option`, a `None` is the failure.
pub trait Doing<T> {
    /// The error, while doing `what`.
    fn doing(self, what: &str) -> Result<T>;
    /// The error, while doing what `what` says (built only on an error).
    fn doing_with(self, what: impl FnOnce() -> String) -> Result<T>;
}

impl<T, E: Into<BenchError>> Doing<T> for std::result::Result<T, E> {
    fn doing(self, what: &str) -> Result<T> {
        self.map_err(|e| BenchError::While { doing: what.to_string(), err: Box::new(e.into()) })
    }

    fn doing_with(self, what: impl FnOnce() -> String) -> Result<T> {
        self.map_err(|e| BenchError::While { doing: what(), err: Box::new(e.into()) })
    }
}

impl<T> Doing<T> for Option<T> {
    fn doing(self, what: &str) -> Result<T> {
        self.ok_or_else(|| BenchError::Failed(what.to_string()))
    }

    fn doing_with(self, what: impl FnOnce() -> String) -> Result<T> {
        self.ok_or_else(|| BenchError::Failed(what()))
    }
}

/// `Err(BenchError::Usage(format!(...)))`, returned.
macro_rules! usage {
    ($($t:tt)*) => { return Err($crate::error::BenchError::Usage(format!($($t)*))) };
}
/// `Err(BenchError::Failed(format!(...)))`, returned.
macro_rules! failed {
    ($($t:tt)*) => { return Err($crate::error::BenchError::Failed(format!($($t)*))) };
}
pub(crate) use {failed, usage};
