//! What can go wrong in a role or its config. Each error says what failed
//! and, through [`Doing`], what the role was doing; the binary adds its own
//! context with `anyhow`.

use rotorhive_model::ModelError;
use rotorhive_replay::SnapshotError;
use rotorhive_sim::{ArenaError, GpuError, LanesError};
use rotorhive_transport::TransportError;

/// An error of a role or of the config.
#[derive(Debug, thiserror::Error)]
pub enum RoleError {
    /// A config file, key, override or role argument that is wrong; the
    /// text names it.
    #[error("{0}")]
    Config(String),
    /// A message or a schedule that breaks the run's rules (another
    /// environment's batch, weights that came too early, a loss a
    /// deterministic run cannot take).
    #[error("{0}")]
    Protocol(String),
    /// An arena file that cannot be used.
    #[error(transparent)]
    Arena(#[from] ArenaError),
    /// iceoryx2 failed.
    #[error(transparent)]
    Transport(#[from] TransportError),
    /// The network, its optimiser or a checkpoint failed.
    #[error(transparent)]
    Model(#[from] ModelError),
    /// The simulator could not be built.
    #[error(transparent)]
    Lanes(#[from] LanesError),
    /// The GPU renderer failed.
    #[error(transparent)]
    Render(#[from] GpuError),
    /// The replay's file.
    #[error(transparent)]
    Snapshot(#[from] SnapshotError),
    /// A file, a directory or a thread.
    #[error(transparent)]
    Io(#[from] std::io::Error),
    /// `err`, while the role was doing `doing` (the cause is part of the
    /// text, not a separate source, so `{:#}` names it once).
    #[error("{doing}: {err}")]
    While {
        /// What the role was doing: "waiting for observations", "role sim-0".
        doing: String,
        /// What failed.
        err: Box<RoleError>,
    },
}

/// Result of this crate.
pub type Result<T> = std::result::Result<T, RoleError>;

/// A config's error as the role's, with the same text.
impl From<rotorhive_config::ConfigError> for RoleError {
    fn from(e: rotorhive_config::ConfigError) -> Self {
        use rotorhive_config::ConfigError as C;
        match e {
            C::Invalid(s) => Self::Config(s),
            C::Arena(e) => Self::Arena(e),
            C::Lanes(e) => Self::Lanes(e),
            C::Model(e) => Self::Model(e),
            C::Io(e) => Self::Io(e),
            C::While { doing, err } => Self::While { doing, err: Box::new((*err).into()) },
        }
    }
}

/// Says what the role was doing when an error happened (this crate's
/// `anyhow::Context`).
pub trait Doing<T> {
    /// The error, while doing `what`.
    fn doing(self, what: &str) -> Result<T>;
    /// The error, while doing what `what` says (built only on an error).
    fn doing_with(self, what: impl FnOnce() -> String) -> Result<T>;
}

impl<T, E: Into<RoleError>> Doing<T> for std::result::Result<T, E> {
    fn doing(self, what: &str) -> Result<T> {
        self.map_err(|e| RoleError::While { doing: what.to_string(), err: Box::new(e.into()) })
    }

    fn doing_with(self, what: impl FnOnce() -> String) -> Result<T> {
        self.map_err(|e| RoleError::While { doing: what(), err: Box::new(e.into()) })
    }
}

/// `Err(RoleError::Config(format!(...)))`, returned.
macro_rules! config_err {
    ($($t:tt)*) => { return Err($crate::error::RoleError::Config(format!($($t)*))) };
}
/// `Err(RoleError::Protocol(format!(...)))`, returned.
macro_rules! protocol_err {
    ($($t:tt)*) => { return Err($crate::error::RoleError::Protocol(format!($($t)*))) };
}
pub(crate) use {config_err, protocol_err};

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_cause_is_named_once_with_what_the_role_was_doing() {
        let e: Result<()> = Err(std::io::Error::other("disk full"))
            .doing("writing a checkpoint")
            .doing_with(|| "role learner".into());
        let e = e.unwrap_err();
        assert_eq!(format!("{e}"), "role learner: writing a checkpoint: disk full");
        // anyhow's `{:#}` walks `source()`: the cause must not appear twice.
        assert_eq!(
            format!("{:#}", anyhow::Error::from(e)),
            "role learner: writing a checkpoint: disk full"
        );
    }
}
