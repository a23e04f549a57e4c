//! The records of a run directory: what `hive train` writes and what
//! `hive profile`, `hive bench table` and scripts read back.
//!
//! - [`summary::Summary`]: `summary.json`, the run's result;
//! - [`telemetry::TelemetryRow`]: a row of `telemetry.csv`;
//! - [`profile`]: where a run's time went, from its telemetry;
//! - [`plot`]: the run's curves as PNG files;
//! - [`rolling::Rolling`]: the convergence clock (rolling mean of episodes);
//! - [`tensorboard::EventWriter`]: the run's scalars for TensorBoard.

pub mod kinds;
pub mod plot;
pub mod profile;
pub mod rolling;
pub mod rows;
pub mod summary;
pub mod telemetry;
pub mod tensorboard;

pub use rolling::Rolling;

/// What can go wrong reading or writing a run's records; each names the
/// file.
#[derive(Debug, thiserror::Error)]
pub enum RecordsError {
    /// A file could not be read or written.
    #[error("cannot {action} {file}: {err}")]
    Io {
        /// "read" or "write".
        action: &'static str,
        /// The file.
        file: String,
        /// Why (part of the text, so that `{:#}` names it once).
        err: std::io::Error,
    },
    /// `summary.json` is not a summary of this build.
    #[error("{file} is not a summary of this build: {err}")]
    Summary {
        /// The file.
        file: String,
        /// Where it differs.
        err: serde_json::Error,
    },
    /// A run directory without telemetry.
    #[error("{0}: no telemetry rows")]
    NoTelemetry(String),
    /// A row of a CSV table that does not parse.
    #[error("{file}: {message}")]
    Table {
        /// The file.
        file: String,
        /// Where and what (csv names the line and the column).
        message: String,
    },
    /// A row could not be written as CSV.
    #[error("cannot write a CSV row: {0}")]
    Csv(String),
    /// Plotters failed to draw.
    #[error("drawing failed: {0}")]
    Plot(String),
    /// A summary could not be encoded as JSON.
    #[error("cannot encode the summary: {0}")]
    Encode(serde_json::Error),
    /// Writing a report into a string failed.
    #[error("cannot format the report")]
    Format(#[from] std::fmt::Error),
}

/// Result of this crate.
pub type Result<T> = std::result::Result<T, RecordsError>;

impl RecordsError {
    /// An I/O error of `action` ("read", "write") on `file`.
    pub fn io<'a>(
        action: &'static str,
        file: &'a std::path::Path,
    ) -> impl FnOnce(std::io::Error) -> Self + 'a {
        move |err| RecordsError::Io { action, file: file.display().to_string(), err }
    }
}
pub use kinds::{HostRole, Member, ObservationMode, Renderer};
pub use summary::{HostSummary, Summary, Teaching};
pub use telemetry::TelemetryRow;
