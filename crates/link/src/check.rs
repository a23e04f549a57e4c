//! Every message from another host is checked here before any of its bytes
//! reach shared memory, the replay or the run's records: the header's exact
//! size, the payload's exact length for the count the header gives, the
//! sender's own environments (the slot in the key a worker publishes on,
//! not merely an index in range), and the values themselves. A message that
//! fails is dropped and counted against its host; nothing here panics,
//! whatever the bytes (property-tested below).

use rotorhive_msg::{
    EPISODE_FIELDS, EpisodeHeader, RoleKind, RowLayout, Telemetry, TransitionHeader, WeightsHeader,
    episode_corrupt,
};

use crate::delivery::LinkHeader;
use crate::head::host::Host;
use crate::wire;

pub use crate::wire::{MAX_BATCH, MAX_EPISODES};

pub use crate::reject::{Reason, Reject};

/// A payload in the fragments Zenoh received it in, read at increasing
/// offsets without gathering it into one buffer.
struct Fragments<'a> {
    frags: &'a [&'a [u8]],
    /// Fragment the cursor is in and that fragment's first byte's offset.
    at: usize,
    start: usize,
}

impl<'a> Fragments<'a> {
    fn new(frags: &'a [&'a [u8]]) -> Self {
        Self { frags, at: 0, start: 0 }
    }
    /// Copies `out.len()` bytes from `offset` (never below an earlier one).
    fn read(&mut self, mut offset: usize, out: &mut [u8]) -> bool {
        let mut done = 0;
        while done < out.len() {
            let Some(f) = self.frags.get(self.at) else {
                return false;
            };
            if offset >= self.start + f.len() {
                self.start += f.len();
                self.at += 1;
                continue;
            }
            let from = offset - self.start;
            let n = (f.len() - from).min(out.len() - done);
            out[done..done + n].copy_from_slice(&f[from..from + n]);
            done += n;
            offset += n;
        }
        true
    }
}

/// Checks a transition batch from `host`: headers (the batch's, then its
/// place in the link's stream), exact length, the sender's environment, and
/// every row's values for the run's `rows` (transitions, or with memory
/// sequences; the depth words have no invalid value). The payload stays in
/// its fragments.
pub fn transitions(
    host: &Host,
    rows: RowLayout,
    attachment: Option<&[u8]>,
    frags: &[&[u8]],
) -> Result<(TransitionHeader, LinkHeader), Reject> {
    let (h, link) = attachment.and_then(wire::transition_headers).ok_or(Reject::Header)?;
    // With memory an actor sends at most one sequence of each agent a step.
    let most = match rows {
        RowLayout::Transition(_) => MAX_BATCH,
        RowLayout::Sequence(_) => (host.agents as usize).min(MAX_BATCH),
    };
    if h.count == 0 || h.count as usize > most {
        return Err(Reject::Count(h.count));
    }
    let got: usize = frags.iter().map(|f| f.len()).sum();
    let packed = rows.packed_len();
    let want = h.count as usize * packed * 2;
    if got != want {
        return Err(Reject::Length { got, want });
    }
    if !host.owns(h.actor) {
        return Err(Reject::Actor(h.actor));
    }
    let mut cur = Fragments::new(frags);
    let (depth, values) = rows.value_span();
    let mut raw = vec![0u8; values * 4];
    let mut s = vec![0f32; values];
    let mut bad = 0;
    for i in 0..h.count as usize {
        if !cur.read((i * packed + depth) * 2, &mut raw) {
            return Err(Reject::Length { got, want });
        }
        for (v, b) in s.iter_mut().zip(raw.chunks_exact(4)) {
            *v = f32::from_le_bytes([b[0], b[1], b[2], b[3]]);
        }
        bad += rows.values_corrupt(&s) as u64;
    }
    if bad > 0 {
        return Err(Reject::Values(bad));
    }
    Ok((h, link))
}

/// The little-endian `f32`s of `bytes` (the payload's own byte order),
/// read where they lie.
fn floats(bytes: &[u8]) -> impl Iterator<Item = f32> + '_ {
    bytes.chunks_exact(4).map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
}

/// Checks an episodes message from `host`; its header. The payload's bytes
/// are the records to pass on as they are.
pub fn episodes(
    host: &Host,
    attachment: Option<&[u8]>,
    payload: &[u8],
) -> Result<EpisodeHeader, Reject> {
    let h: EpisodeHeader = attachment.and_then(wire::header_from).ok_or(Reject::Header)?;
    if h.count == 0 || h.count as usize > MAX_EPISODES {
        return Err(Reject::Count(h.count));
    }
    let want = h.count as usize * EPISODE_FIELDS * 4;
    if payload.len() != want {
        return Err(Reject::Length { got: payload.len(), want });
    }
    if !host.owns(h.actor) {
        return Err(Reject::Actor(h.actor));
    }
    let bad = payload
        .chunks_exact(EPISODE_FIELDS * 4)
        .filter(|r| {
            let mut rec = [0f32; EPISODE_FIELDS];
            rec.iter_mut().zip(floats(r)).for_each(|(o, v)| *o = v);
            episode_corrupt(&rec)
        })
        .count() as u64;
    if bad > 0 || h.epsilon_micro > 1_000_000 {
        return Err(Reject::Values(bad.max(1)));
    }
    Ok(h)
}

/// Checks a telemetry sample from `host`: only its sims and actors (by
/// environment) and its link (by slot), with finite diagnostics.
pub fn telemetry(
    host: &Host,
    attachment: Option<&[u8]>,
    payload_len: usize,
) -> Result<Telemetry, Reject> {
    let t: Telemetry = attachment.and_then(wire::header_from).ok_or(Reject::Header)?;
    if payload_len != 0 {
        return Err(Reject::Length { got: payload_len, want: 0 });
    }
    let mine = match RoleKind::from_code(t.role) {
        Some(RoleKind::Sim | RoleKind::Actor) => host.owns(t.index),
        Some(RoleKind::Link) => t.index == host.slot,
        _ => false,
    };
    if !mine {
        return Err(Reject::Role { role: t.role, index: t.index });
    }
    let l = &t.learning;
    if ![l.mean_max_q, l.mean_abs_td, l.terminal_share, l.eps_min, l.eps_max]
        .iter()
        .all(|v| v.is_finite())
    {
        return Err(Reject::Values(1));
    }
    Ok(t)
}

/// Checks weights from the head: the size this build's model has and finite
/// values (a head never publishes others); its header. The payload's bytes
/// are the weights to pass on as they are.
pub fn weights(
    num_params: usize,
    attachment: Option<&[u8]>,
    payload: &[u8],
) -> Result<WeightsHeader, Reject> {
    let h: WeightsHeader = attachment.and_then(wire::header_from).ok_or(Reject::Header)?;
    let want = num_params * 4;
    if h.len != num_params as u64 || payload.len() != want {
        return Err(Reject::Length { got: payload.len(), want });
    }
    let bad = floats(payload).filter(|v| !v.is_finite()).count() as u64;
    if bad > 0 {
        return Err(Reject::Values(bad));
    }
    Ok(h)
}

#[cfg(test)]
mod tests;
