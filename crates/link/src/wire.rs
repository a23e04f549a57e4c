//! What crosses between hosts, byte for byte: message headers and payloads
//! as they lie in shared memory (little-endian, same build, checked by the
//! layout fingerprint), and the two control messages of a join. Nothing here
//! goes through a general-purpose serializer.

use bytemuck::Pod;
use rotorhive_msg::TransitionHeader;

pub use crate::delivery::{Ack, LinkHeader};

/// The bytes of a header (a `bytemuck::Pod` type: `#[repr(C)]`, no padding,
/// every bit pattern valid; the message headers derive it).
pub fn header_bytes<H: Pod>(h: &H) -> &[u8] {
    bytemuck::bytes_of(h)
}

/// A header from its bytes, if they are exactly its size (any alignment).
pub fn header_from<H: Pod>(b: &[u8]) -> Option<H> {
    bytemuck::try_pod_read_unaligned(b).ok()
}

/// A payload as bytes.
pub fn payload_bytes<T: Pod>(p: &[T]) -> &[u8] {
    bytemuck::cast_slice(p)
}

/// A payload as bytes to write.
pub fn payload_bytes_mut<T: Pod>(p: &mut [T]) -> &mut [u8] {
    bytemuck::cast_slice_mut(p)
}

/// A transition batch's attachment: its header, then its place in the
/// link's stream.
pub fn transition_attachment(h: &TransitionHeader, link: &LinkHeader) -> Vec<u8> {
    let mut out = header_bytes(h).to_vec();
    out.extend_from_slice(header_bytes(link));
    out
}

/// A transition batch's two headers from its attachment, if it is exactly
/// their size.
pub fn transition_headers(b: &[u8]) -> Option<(TransitionHeader, LinkHeader)> {
    let n = std::mem::size_of::<TransitionHeader>();
    if b.len() != n + std::mem::size_of::<LinkHeader>() {
        return None;
    }
    Some((header_from(&b[..n])?, header_from(&b[n..])?))
}

const HELLO: [u8; 4] = *b"RHJ3";
const WELCOME: [u8; 4] = *b"RHW2";

/// A worker's request to join a run.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Hello {
    /// The worker's message layout ([`rotorhive_msg::layout_fingerprint`] and the model's size).
    pub layout: u64,
    /// Environments (sims) it runs.
    pub envs: u32,
    /// Agents per environment.
    pub agents: u32,
    /// Its host name (a worker that comes back under the same name gets its old place).
    pub host: String,
    /// The worker's secret for this name, kept in its run directory: a
    /// host that comes back under a name of the run must present the
    /// token it first joined with ([`MAX_TOKEN`] bytes at most).
    pub token: String,
    /// What the worker process before it in its run directory had sent
    /// when it stopped (its [`crate::worker::send::SentLog`]).
    pub earlier: Earlier,
}

/// A worker process's epoch and the transitions it had sent under it (all
/// 0: none known); its bytes go as they are, in the join and in the log.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, bytemuck::Pod, bytemuck::Zeroable)]
#[repr(C)]
pub struct Earlier {
    /// The epoch its join had.
    pub epoch: u64,
    /// Transitions it sent.
    pub sent: u64,
}

/// The most transitions one batch may carry (an actor sends one batch per
/// observation step of at most 1,024 agents).
pub const MAX_BATCH: usize = 1024;
/// The most episode records in one message.
pub const MAX_EPISODES: usize = 4096;

/// The longest join token a head accepts.
pub const MAX_TOKEN: usize = 128;

/// The head's answer.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Welcome {
    /// Joined.
    Joined {
        /// The worker's place among the run's hosts (1 = first worker).
        slot: u32,
        /// Index of its first environment in the run (its actors' indexes start here).
        env_offset: u32,
        /// The link epoch of this join: the worker's batches carry it.
        epoch: u64,
        /// The run's name: the key prefix of its data.
        run: String,
        /// The head's resolved config (TOML, as in the head's `config.toml`).
        config: String,
        /// The training arena (TOML), so the worker needs no shared filesystem.
        arena: String,
    },
    /// Refused, with why.
    Refused(String),
}

fn put_str(out: &mut Vec<u8>, s: &str) {
    out.extend_from_slice(&(s.len() as u32).to_le_bytes());
    out.extend_from_slice(s.as_bytes());
}

/// Reads little-endian fields off a message, failing on a short one.
struct Reader<'a>(&'a [u8]);

impl Reader<'_> {
    fn take(&mut self, n: usize) -> Option<&[u8]> {
        if self.0.len() < n {
            return None;
        }
        let (a, b) = self.0.split_at(n);
        self.0 = b;
        Some(a)
    }
    fn u32(&mut self) -> Option<u32> {
        Some(u32::from_le_bytes(self.take(4)?.try_into().ok()?))
    }
    fn u64(&mut self) -> Option<u64> {
        Some(u64::from_le_bytes(self.take(8)?.try_into().ok()?))
    }
    fn str(&mut self) -> Option<String> {
        let n = self.u32()? as usize;
        String::from_utf8(self.take(n)?.to_vec()).ok()
    }
}

impl Hello {
    /// Its bytes.
    pub fn encode(&self) -> Vec<u8> {
        let mut out = HELLO.to_vec();
        out.extend_from_slice(&self.layout.to_le_bytes());
        out.extend_from_slice(&self.envs.to_le_bytes());
        out.extend_from_slice(&self.agents.to_le_bytes());
        put_str(&mut out, &self.host);
        put_str(&mut out, &self.token);
        out.extend_from_slice(header_bytes(&self.earlier));
        out
    }

    /// Reads one, or `None` for bytes that are not a hello.
    pub fn decode(b: &[u8]) -> Option<Self> {
        let mut r = Reader(b);
        if r.take(4)? != HELLO {
            return None;
        }
        Some(Self {
            layout: r.u64()?,
            envs: r.u32()?,
            agents: r.u32()?,
            host: r.str()?,
            token: r.str()?,
            earlier: header_from(r.take(std::mem::size_of::<Earlier>())?)?,
        })
    }
}

impl Welcome {
    /// Its bytes.
    pub fn encode(&self) -> Vec<u8> {
        let mut out = WELCOME.to_vec();
        match self {
            Welcome::Joined { slot, env_offset, epoch, run, config, arena } => {
                out.extend_from_slice(&0u32.to_le_bytes());
                out.extend_from_slice(&slot.to_le_bytes());
                out.extend_from_slice(&env_offset.to_le_bytes());
                out.extend_from_slice(&epoch.to_le_bytes());
                put_str(&mut out, run);
                put_str(&mut out, config);
                put_str(&mut out, arena);
            }
            Welcome::Refused(why) => {
                out.extend_from_slice(&1u32.to_le_bytes());
                put_str(&mut out, why);
            }
        }
        out
    }

    /// Reads one, or `None` for bytes that are not a welcome.
    pub fn decode(b: &[u8]) -> Option<Self> {
        let mut r = Reader(b);
        if r.take(4)? != WELCOME {
            return None;
        }
        match r.u32()? {
            0 => Some(Welcome::Joined {
                slot: r.u32()?,
                env_offset: r.u32()?,
                epoch: r.u64()?,
                run: r.str()?,
                config: r.str()?,
                arena: r.str()?,
            }),
            1 => Some(Welcome::Refused(r.str()?)),
            _ => None,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rotorhive_msg::{EpisodeHeader, Telemetry, TransitionHeader, WeightsHeader};

    #[test]
    fn headers_have_no_hidden_padding() {
        // Field sizes add up to the type's size: no implicit padding bytes.
        assert_eq!(std::mem::size_of::<TransitionHeader>(), 4 + 4 + 8 + 8);
        assert_eq!(std::mem::size_of::<EpisodeHeader>(), 4 + 4 + 8 + 8);
        assert_eq!(std::mem::size_of::<WeightsHeader>(), 8 + 8 + 8);
        assert_eq!(std::mem::size_of::<Telemetry>(), 4 * 4 + 6 * 8 + 4 * 8 + 8 * 4 + 4 * 8 + 6 * 8);
    }

    #[test]
    fn headers_and_control_messages_round_trip() {
        let h = TransitionHeader { actor: 3, count: 50, seq: 77, weight_version: 9 };
        let back: TransitionHeader = header_from(header_bytes(&h)).unwrap();
        assert_eq!((back.actor, back.count, back.seq, back.weight_version), (3, 50, 77, 9));
        assert!(header_from::<TransitionHeader>(&header_bytes(&h)[1..]).is_none());
        let link = LinkHeader { epoch: 4, seq: 8 };
        let att = transition_attachment(&h, &link);
        assert_eq!(att.len(), 40);
        let (back, l) = transition_headers(&att).unwrap();
        assert_eq!((back.seq, l), (77, link));
        assert!(transition_headers(&att[..39]).is_none());
        assert!(transition_headers(header_bytes(&h)).is_none());
        let earlier = Earlier { epoch: 3, sent: 9 };
        let hello =
            Hello { layout: 42, envs: 2, agents: 37, host: "b".into(), token: "t".into(), earlier };
        assert_eq!(Hello::decode(&hello.encode()), Some(hello.clone()));
        assert!(Hello::decode(&hello.encode()[..10]).is_none());
        let w = Welcome::Joined {
            slot: 1,
            env_offset: 1,
            epoch: 5,
            run: "r".into(),
            config: "seed = 1".into(),
            arena: "x".into(),
        };
        assert_eq!(Welcome::decode(&w.encode()), Some(w));
        assert!(Welcome::decode(&hello.encode()).is_none());
        let p = [1.5f32, -2.0];
        let mut q = [0f32; 2];
        payload_bytes_mut(&mut q).copy_from_slice(payload_bytes(&p));
        assert_eq!(p, q);
    }
}
