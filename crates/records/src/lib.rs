//! The records of a run directory: what `hive train` writes and what
//! `hive profile`, `hive bench table` and scripts read back.
//!
//! - [`summary::Summary`]: `summary.json`, the run's result;
//! - [`telemetry::TelemetryRow`]: a row of `telemetry.csv`;
//! - [`profile`]: where a run's time went, from its telemetry;
//! - [`plot`]: the run's curves as PNG files;
//! - [`rolling::Rolling`]: the convergence clock (rolling mean of episodes);
//! - [`tensorboard::EventWriter`]: the run's scalars for TensorBoard.

pub mod plot;
pub mod profile;
pub mod rolling;
pub mod summary;
pub mod telemetry;
pub mod tensorboard;

pub use rolling::Rolling;
pub use summary::{HostSummary, Summary};
pub use telemetry::TelemetryRow;
