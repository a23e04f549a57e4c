//! The transport: one place that names, opens and drives every iceoryx2
//! service of a rotorhive run.
//!
//! Each logical channel is a publish-subscribe service with a `#[repr(C)]`
//! user header and a slice payload, paired with an event service of the same
//! name so receivers sleep on a listener instead of spinning. Every service
//! name starts with the run's prefix, so two runs on one machine never meet.
//! Channels that must not lose data refuse to overflow and apply bounded
//! back-pressure: a sender retries for at most its stall timeout, then gives
//! up on that message with an error it can report, so no process ever blocks
//! forever on a dead peer.
//!
//! Generic over the iceoryx2 service variant: `ipc::Service` between
//! processes, `local::Service` between threads of one process (tests).

mod channel;
mod node;
mod signal;

use std::fmt::Debug;
use std::time::Duration;

use iceoryx2::prelude::*;

pub use channel::{Channel, DEFAULT_SPIN_US, Msg, Receiver, Sender, spin};
pub use iceoryx2::service::ipc::Service as Ipc;
pub use iceoryx2::service::local::Service as Local;
pub use node::{
    DOMAIN_ENV, Hub, Periodic, check_domain, cleanup_dead_nodes, domain_config, fresh_id,
    node_alive, services_of_run, supervisor_node_name, unique_prefix,
};
pub use signal::{dies_with_this_process, handle_hangup, request_stop, stop_requested};

/// The iceoryx2 service kinds a run uses: `Ipc` (processes, the default)
/// and `Local` (threads of one process: `--serial` and tests), with what
/// each promises about a loan's bytes.
pub trait Service: iceoryx2::service::Service + sealed::Sealed {
    /// Whether a fresh loan's payload is initialised memory before it is
    /// written: true for `Ipc`, whose payload lies in a shared-memory
    /// segment mapped from a file descriptor (zero-filled by the OS when
    /// created, later holding earlier samples); false for `Local`, whose
    /// segments come from the heap.
    const LOANS_ARE_INITIALISED: bool;
}

impl Service for Ipc {
    const LOANS_ARE_INITIALISED: bool = true;
}

impl Service for Local {
    const LOANS_ARE_INITIALISED: bool = false;
}

mod sealed {
    /// Only this crate's two service kinds are [`super::Service`]s: the
    /// loan's soundness rests on what each one's memory is.
    pub trait Sealed {}
    impl Sealed for super::Ipc {}
    impl Sealed for super::Local {}
}

/// An iceoryx2 error as it came: the error value itself, boxed (callers may
/// downcast it), shown in its error's text.
pub type Cause = Box<dyn std::error::Error + Send + Sync + 'static>;

/// Errors of the transport, naming the channel and the operation. A cause
/// is part of the text and not also `source()`, so `{:#}` names it once.
#[derive(Debug, thiserror::Error)]
pub enum TransportError {
    /// Creating the node failed.
    #[error("cannot create iceoryx2 node `{node}`: {cause}")]
    Node {
        /// The node name.
        node: String,
        /// iceoryx2's error (kept as it came, in the text; not `source()`).
        cause: Cause,
    },
    /// Opening or creating a service or port failed.
    #[error("channel `{channel}`: cannot {op}: {cause}")]
    Open {
        /// The channel.
        channel: String,
        /// What was attempted.
        op: &'static str,
        /// iceoryx2's error (kept as it came, in the text; not `source()`).
        cause: Cause,
    },
    /// Sending or receiving failed.
    #[error("channel `{channel}`: {op} failed: {cause}")]
    Io {
        /// The channel.
        channel: String,
        /// What was attempted.
        op: &'static str,
        /// iceoryx2's error (kept as it came, in the text; not `source()`).
        cause: Cause,
    },
    /// A message could not be delivered within the stall timeout.
    #[error("channel `{channel}`: receiver did not take the message within {timeout:?}")]
    Stalled {
        /// The channel.
        channel: String,
        /// The timeout.
        timeout: Duration,
    },
}

/// Result of this crate.
pub type Result<T> = std::result::Result<T, TransportError>;

/// Plain data that may travel as a payload element: `bytemuck::Pod` (no
/// padding, every bit pattern a valid value), so a loan can be handed out
/// before it is written. Every such type is one.
pub trait Plain: bytemuck::Pod + Debug + ZeroCopySend + Default {}
impl<T: bytemuck::Pod + Debug + ZeroCopySend + Default> Plain for T {}

#[cfg(test)]
mod tests;
