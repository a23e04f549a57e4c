//! The non-batched mode's per-agent observation messages gathered into
//! one batch.

use rotorhive_msg::ObsHeader;

/// Assembles one step's observation batch (the layout of a batched message)
/// from per-agent messages, as the non-batched mode sends them.
pub struct Gather {
    n: usize,
    /// Floats per observation.
    len: usize,
    buf: Vec<f32>,
    step: u64,
    have: usize,
}

impl Gather {
    /// A gatherer of `n` agents' observations of `len` floats.
    pub fn new(n: usize, len: usize) -> Self {
        Self { n, len, buf: vec![0.0; n * (len + 4)], step: u64::MAX, have: 0 }
    }

    /// Copies in the agents of one message; true once all agents of its
    /// step are in (a message of a newer step starts the batch afresh).
    pub fn add(&mut self, h: &ObsHeader, src: &[f32]) -> bool {
        let n = self.n;
        if h.step != self.step || self.have == 0 {
            self.step = h.step;
            self.have = 0;
        }
        let (a, k) = (h.first as usize, h.agents as usize);
        let (g, l) = (&mut self.buf, self.len);
        g[a * l..(a + k) * l].copy_from_slice(&src[..k * l]);
        // Then the rewards, the dones, the teacher's actions and its labels.
        for c in 0..4 {
            let (to, from) = (n * l + c * n + a, k * l + c * k);
            g[to..to + k].copy_from_slice(&src[from..from + k]);
        }
        self.have += k;
        if self.have < n {
            return false;
        }
        self.have = 0;
        true
    }

    /// The gathered batch: observations, rewards, dones, the teacher's
    /// actions and labels.
    pub fn batch(&self) -> &[f32] {
        &self.buf
    }
}
