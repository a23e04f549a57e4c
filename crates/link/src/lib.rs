//! The link between hosts: the only crate that imports zenoh.
//!
//! iceoryx2 stays the transport inside each host; the link of a host is one
//! more member of its run that carries, over one Zenoh session on TCP (peer
//! mode, explicit endpoints, no multicast, no router):
//! - transition batches worker → head: zenoh's `CongestionControl::Block`,
//!   a bounded FIFO on the head, then the head's bounded iceoryx2 send
//!   retried while the replay is full (or restarting), so back-pressure
//!   reaches the worker's actors end to end; every batch acknowledged once
//!   the replay took it, and sent again from the worker's window when it
//!   went missing or the session dropped and came back ([`delivery`]);
//! - weights head → worker, newest only (a ring of one; `Drop`: a slow
//!   worker never holds the head), republished on the worker's shared
//!   memory once per host;
//! - telemetry and episodes worker → head (they may drop under load; drops
//!   are counted).
//!
//! Observations, actions and minibatches never leave their host. Headers and
//! payloads cross as raw bytes ([`wire`]); both ends check the layout
//! fingerprint at the join and refuse a mismatch.

pub mod certs;
pub mod check;
pub mod delivery;
mod error;
mod head;
mod options;
mod reject;
mod shared;
pub mod wire;
mod worker;

pub use error::{LinkError, Result};
pub use head::admit::{ConfigFor, Flow, Head, HeadStats};
pub use head::bridge::HeadLink;
pub use head::host::{Host, JoinLimits, MAX_HOST_NAME};
pub use head::inflow;
pub use options::{LinkOptions, check_endpoint, check_options, is_loopback, is_tls, tls_files};
pub use shared::{MAX_MESSAGE_BYTES, layout};
pub use wire::{Earlier, Hello, Welcome};
pub use worker::join::{SentLog, Worker, WorkerEnd, WorkerStats};
