//! What can be wrong with a config: a key, a file, an override, or what
//! the config makes (arenas, lanes, the device it names). The roles take
//! it into their own error with the same text.

use rotorhive_model::ModelError;
use rotorhive_sim::{ArenaError, LanesError};

/// An error of the config.
#[derive(Debug, thiserror::Error)]
pub enum ConfigError {
    /// A config file, key or override that is wrong; the text names it.
    #[error("{0}")]
    Invalid(String),
    /// An arena file that cannot be used.
    #[error(transparent)]
    Arena(#[from] ArenaError),
    /// The lanes a config makes could not be built.
    #[error(transparent)]
    Lanes(#[from] LanesError),
    /// The device a config names.
    #[error(transparent)]
    Model(#[from] ModelError),
    /// A config file that cannot be read.
    #[error(transparent)]
    Io(#[from] std::io::Error),
    /// `err`, while doing `doing` (the cause is part of the text, not a
    /// separate source, so `{:#}` names it once).
    #[error("{doing}: {err}")]
    While {
        /// What was being done: "key `learner.device`".
        doing: String,
        /// What failed.
        err: Box<ConfigError>,
    },
}

/// Result of this crate.
pub type Result<T> = std::result::Result<T, ConfigError>;

/// Says what was being done when an error happened.
pub trait Doing<T> {
    /// The error, while doing `what`.
    fn doing(self, what: &str) -> Result<T>;
    /// The error, while doing what `what` says (built only on an error).
    fn doing_with(self, what: impl FnOnce() -> String) -> Result<T>;
}

impl<T, E: Into<ConfigError>> Doing<T> for std::result::Result<T, E> {
    fn doing(self, what: &str) -> Result<T> {
        self.map_err(|e| ConfigError::While { doing: what.to_string(), err: Box::new(e.into()) })
    }

    fn doing_with(self, what: impl FnOnce() -> String) -> Result<T> {
        self.map_err(|e| ConfigError::While { doing: what(), err: Box::new(e.into()) })
    }
}

/// `Err(ConfigError::Invalid(format!(...)))`, returned.
macro_rules! config_err {
    ($($t:tt)*) => { return Err($crate::error::ConfigError::Invalid(format!($($t)*))) };
}
pub(crate) use config_err;
