//! What both ends of the link share: the key names, the bounds on a
//! message, the layout fingerprint, the link's telemetry, the check of an
//! actor's sequence.

use rotorhive_msg::{EPISODE_FIELDS, RoleKind, SeqTracker, Telemetry, TransitionHeader};
use rotorhive_transport::Service;
use rotorhive_transport::{Channel, Hub};
use zenoh::handlers::FifoChannelHandler;

use crate::check;
use crate::error::Result;

/// The largest message a host accepts: a full transition batch (1,024 ×
/// 8,228 bytes) with room to spare; Zenoh's default is 1 GiB.
pub const MAX_MESSAGE_BYTES: usize = 16 << 20;
/// The largest episodes message (4,096 records) and telemetry sample the
/// head accepts, by Zenoh's low-pass filter, so that its queues of them stay
/// bounded in bytes.
pub(crate) const MAX_EPISODES_BYTES: usize = check::MAX_EPISODES * EPISODE_FIELDS * 4 + 4096;
pub(crate) const MAX_TELEMETRY_BYTES: usize = 4096;

/// The layout this build sends: the message layout, the link's delivery
/// headers and the model's size, of the paper's task (a worker says it
/// before it has the run's config; the shapes then come with the config,
/// the same for every host of one build).
pub fn layout(num_params: usize) -> u64 {
    let delivery = std::mem::size_of::<crate::delivery::LinkHeader>()
        + std::mem::size_of::<crate::delivery::Ack>();
    rotorhive_msg::layout_fingerprint()
        ^ (num_params as u64).rotate_left(17)
        ^ (delivery as u64).rotate_left(41)
}

pub(crate) fn key(run: &str, what: &str) -> String {
    format!("rotorhive/{run}/{what}")
}

/// The key a worker in `slot` puts `what` on: the head knows the sender by
/// it and checks each message against that host ([`crate::check`]). Under
/// TLS the head's access control admits slot `i`'s keys from certificate
/// `worker-i` only; over plain `tcp/` anyone may put anywhere (each message
/// is still checked against the slot its key names).
pub(crate) fn host_key(run: &str, slot: u32, what: &str) -> String {
    format!("rotorhive/{run}/host/{slot}/{what}")
}

/// The key of the join queryable.
pub(crate) const JOIN: &str = "rotorhive/join";

/// Telemetry of a link: stages `receive`, `forward`, `weights`, `send_wait`
/// ([`LinkStage`]), published by the transport's periodic publisher.
pub(crate) type LinkTelemetry<S> = rotorhive_transport::Periodic<S, Telemetry>;

/// The link's telemetry in a run of `roles` roles.
pub(crate) fn link_telemetry<S: Service>(
    hub: &Hub<S>,
    roles: usize,
    index: usize,
) -> Result<LinkTelemetry<S>> {
    let sample = Telemetry {
        role: RoleKind::Link as u32,
        index: index as u32,
        pid: std::process::id(),
        ..Telemetry::default()
    };
    Ok(rotorhive_transport::Periodic::new(hub, &Channel::telemetry(roles), sample)?)
}

/// The batches of `h`'s actor missing just before it (`seen` tracks each
/// actor's sequence), warned about as missing at `link` (`where_`: where).
pub(crate) fn missing_before(
    seen: &mut SeqTracker,
    h: &TransitionHeader,
    link: &str,
    where_: &str,
) -> u64 {
    let gap = seen.observe(h.actor as usize, h.seq);
    if gap > 0 {
        let (a, from) = (h.actor, h.seq - gap);
        tracing::warn!("{link}: actor {a} batches {from}..{} missing{where_}", h.seq);
    }
    gap
}

pub(crate) type Fifo = zenoh::pubsub::Subscriber<FifoChannelHandler<zenoh::sample::Sample>>;
