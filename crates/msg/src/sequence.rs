//! A stored sequence, as a recurrent learner's transitions travel (actor →
//! replay → learner) and as the replay keeps them: R2D2's unit, `steps`
//! transitions of one agent with the `steps + 1` observations they join and
//! the recurrent state the agent's actor had at the first. Packed as a
//! transition is ([`Shapes::packed_len`]): depth as 16-bit fixed point, every
//! other value's `f32` bits as two words (low, high).

use crate::{Shapes, TAIL, dequantize_depth, f32_words, quantize_depth, word_f32};

/// The layout of one packed sequence.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct SeqLayout {
    /// The observation and action shapes.
    pub shapes: Shapes,
    /// Transitions in a sequence.
    pub steps: usize,
    /// Floats of the recurrent state stored with it.
    pub width: usize,
}

impl SeqLayout {
    /// Observations in a sequence: one more than its transitions.
    pub const fn observations(self) -> usize {
        self.steps + 1
    }

    /// Depth words: every observation's frames.
    const fn depth_words(self) -> usize {
        self.observations() * self.shapes.obs_depth()
    }

    /// `f32` values after the depth: the observations' scalars, each step's
    /// [`TAIL`] (action, reward, done, expert action, demonstration flag),
    /// then the state.
    pub const fn packed_values(self) -> usize {
        self.observations() * self.shapes.scalars + self.steps * TAIL + self.width
    }

    /// `u16` words in one packed sequence.
    pub const fn packed_len(self) -> usize {
        self.depth_words() + 2 * self.packed_values()
    }

    /// Packs one sequence: `obs` (`steps + 1` observations of
    /// [`Shapes::obs_len`] floats), `tails` (one per step: action, reward,
    /// done, expert action, demonstration flag) and `state` (`width`
    /// floats) into `out` ([`SeqLayout::packed_len`] words).
    pub fn pack(self, obs: &[f32], tails: &[[f32; TAIL]], state: &[f32], out: &mut [u16]) {
        let (len, fd) = (self.shapes.obs_len(), self.shapes.obs_depth());
        assert!(
            obs.len() == self.observations() * len
                && tails.len() == self.steps
                && state.len() == self.width
                && out.len() == self.packed_len(),
            "pack: wrong lengths"
        );
        let (depth, values) = out.split_at_mut(self.depth_words());
        for (o, d) in obs.chunks_exact(len).zip(depth.chunks_exact_mut(fd)) {
            for (q, v) in d.iter_mut().zip(&o[..fd]) {
                *q = quantize_depth(*v);
            }
        }
        let scalars = obs.chunks_exact(len).flat_map(|o| &o[fd..]).copied();
        let all = scalars.chain(tails.iter().flatten().copied()).chain(state.iter().copied());
        for (w, v) in values.chunks_exact_mut(2).zip(all) {
            f32_words(v, w);
        }
    }

    /// The `f32` values of a packed sequence (see
    /// [`SeqLayout::packed_values`]) into `out`.
    pub fn values(self, p: &[u16], out: &mut Vec<f32>) {
        out.clear();
        let words = &p[self.depth_words()..self.packed_len()];
        out.extend(words.chunks_exact(2).map(word_f32));
    }

    /// Unpacks one sequence into the learner's parts: `obs` (`steps + 1`
    /// observations), `actions`, `rewards`, `dones`, `experts` and `state`,
    /// each appended to.
    pub fn unpack_into(self, p: &[u16], out: &mut Unpacked) {
        assert!(p.len() == self.packed_len(), "unpack: wrong length");
        let (fd, k) = (self.shapes.obs_depth(), self.shapes.scalars);
        self.values(p, &mut out.scratch);
        let v = &out.scratch;
        for (i, d) in p[..self.depth_words()].chunks_exact(fd).enumerate() {
            out.obs.extend(d.iter().map(|q| dequantize_depth(*q)));
            out.obs.extend_from_slice(&v[i * k..(i + 1) * k]);
        }
        let tails = &v[self.observations() * k..self.observations() * k + self.steps * TAIL];
        for t in tails.chunks_exact(TAIL) {
            out.actions.push(t[0] as u8);
            out.rewards.push(t[1]);
            out.dones.push(t[2] != 0.0);
            out.experts.push(t[3]);
        }
        out.states.extend_from_slice(&v[v.len() - self.width..]);
    }

    /// True when a packed sequence's values are not what an actor writes:
    /// a step's action not one of the run's, a done or demonstration flag
    /// other than 0 or 1, a label none of [`crate::label_mask`]'s, or a
    /// value that is not finite.
    pub fn values_corrupt(self, values: &[f32]) -> bool {
        if values.len() != self.packed_values() {
            return true;
        }
        let start = self.observations() * self.shapes.scalars;
        let one_of = |a: f32| a >= 0.0 && a < self.shapes.actions as f32 && a.fract() == 0.0;
        let flag = |f: f32| f == 0.0 || f == 1.0;
        values[start..start + self.steps * TAIL].chunks_exact(TAIL).any(|t| {
            !one_of(t[0])
                || !flag(t[2])
                || crate::label_mask(t[3], self.shapes.actions).is_none()
                || !flag(t[4])
        }) || values.iter().any(|v| !v.is_finite())
    }
}

/// What one replay row holds: a packed transition, or (with memory) a
/// packed sequence.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RowLayout {
    /// A transition of [`Shapes::packed_len`] words.
    Transition(Shapes),
    /// A sequence of [`SeqLayout::packed_len`] words.
    Sequence(SeqLayout),
}

impl RowLayout {
    /// `u16` words of one row.
    pub const fn packed_len(self) -> usize {
        match self {
            RowLayout::Transition(s) => s.packed_len(),
            RowLayout::Sequence(l) => l.packed_len(),
        }
    }

    /// The observation and action shapes of its steps.
    pub const fn shapes(self) -> Shapes {
        match self {
            RowLayout::Transition(s) => s,
            RowLayout::Sequence(l) => l.shapes,
        }
    }

    /// Where a packed row's `f32` values start (its depth words before
    /// them) and how many there are: the part a row's check reads.
    pub const fn value_span(self) -> (usize, usize) {
        match self {
            RowLayout::Transition(s) => (s.packed_depth(), s.packed_scalars()),
            RowLayout::Sequence(l) => (l.depth_words(), l.packed_values()),
        }
    }

    /// True when a row's values ([`RowLayout::value_span`]) are not what an
    /// actor writes ([`Shapes::scalars_corrupt`], [`SeqLayout::values_corrupt`]).
    pub fn values_corrupt(self, values: &[f32]) -> bool {
        match self {
            RowLayout::Transition(s) => s.scalars_corrupt(values),
            RowLayout::Sequence(l) => l.values_corrupt(values),
        }
    }

    /// Whether a packed row is the teacher's demonstration: a transition
    /// flagged so, or a sequence whose last step is (the teacher flies an
    /// agent from an episode's start, so a sequence it flew to the end is
    /// its own from the episode's first step on).
    pub fn is_demo(self, row: &[u16]) -> bool {
        match self {
            RowLayout::Transition(s) => s.packed_scalar(row, 2 * s.scalars + 4) == 1.0,
            RowLayout::Sequence(l) => {
                let at = l.depth_words()
                    + 2 * (l.observations() * l.shapes.scalars + l.steps * TAIL - 1);
                word_f32(&row[at..]) == 1.0
            }
        }
    }

    /// Rows of `batch` (whole rows of this layout) whose values are not
    /// what an actor writes.
    pub fn corrupt_rows(self, batch: &[u16]) -> u64 {
        match self {
            RowLayout::Transition(s) => s.corrupt_transitions(batch),
            RowLayout::Sequence(l) => {
                let mut values = Vec::with_capacity(l.packed_values());
                batch
                    .chunks_exact(l.packed_len())
                    .filter(|row| {
                        l.values(row, &mut values);
                        l.values_corrupt(&values)
                    })
                    .count() as u64
            }
        }
    }
}

/// Sequences unpacked for the learner (appended to by
/// [`SeqLayout::unpack_into`]; [`Unpacked::clear`] between minibatches).
#[derive(Debug, Default, Clone)]
pub struct Unpacked {
    /// Observations, `[sequences][steps + 1][obs_len]`.
    pub obs: Vec<f32>,
    /// Actions, `[sequences][steps]`.
    pub actions: Vec<u8>,
    /// Rewards, `[sequences][steps]`.
    pub rewards: Vec<f32>,
    /// Episode ends, `[sequences][steps]`.
    pub dones: Vec<bool>,
    /// The teacher's action at each step ([`NO_EXPERT`](crate::NO_EXPERT): none),
    /// `[sequences][steps]`.
    pub experts: Vec<f32>,
    /// Start states, `[sequences][width]`.
    pub states: Vec<f32>,
    scratch: Vec<f32>,
}

impl Unpacked {
    /// Empties every part (keeping the allocations).
    pub fn clear(&mut self) {
        self.obs.clear();
        self.actions.clear();
        self.rewards.clear();
        self.dones.clear();
        self.experts.clear();
        self.states.clear();
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::NO_EXPERT;

    const LAYOUT: SeqLayout = SeqLayout { shapes: Shapes::PAPER, steps: 3, width: 4 };

    fn sequence() -> (Vec<f32>, Vec<[f32; TAIL]>, Vec<f32>) {
        let len = Shapes::PAPER.obs_len();
        let obs: Vec<f32> = (0..4 * len).map(|i| (i % 997) as f32 / 997.0).collect();
        let tails = vec![
            [1.0, 0.5, 0.0, NO_EXPERT, 0.0],
            [0.0, -2.0, 1.0, 1.0, 1.0],
            [1.0, 0.0, 0.0, 0.0, 0.0],
        ];
        (obs, tails, vec![0.25, -0.5, 0.75, -1.0])
    }

    #[test]
    fn a_sequence_round_trips_with_its_state_exact() {
        let (obs, tails, state) = sequence();
        let mut packed = vec![0; LAYOUT.packed_len()];
        LAYOUT.pack(&obs, &tails, &state, &mut packed);
        let mut u = Unpacked::default();
        LAYOUT.unpack_into(&packed, &mut u);
        LAYOUT.unpack_into(&packed, &mut u);
        assert_eq!(u.states, [state.clone(), state.clone()].concat());
        assert_eq!(u.actions, [1, 0, 1, 1, 0, 1]);
        assert_eq!(u.rewards[..3], [0.5, -2.0, 0.0]);
        assert_eq!(u.dones[..3], [false, true, false]);
        assert_eq!(u.experts[..3], [NO_EXPERT, 1.0, 0.0]);
        assert_eq!(u.experts.len(), 6);
        // The last step is the student's: not a demonstration; flagged, it is.
        let rows = RowLayout::Sequence(LAYOUT);
        assert!(!rows.is_demo(&packed));
        let mut demo = tails.clone();
        demo[2][4] = 1.0;
        LAYOUT.pack(&obs, &demo, &state, &mut packed);
        assert!(rows.is_demo(&packed));
        let len = Shapes::PAPER.obs_len();
        assert_eq!(u.obs.len(), 2 * 4 * len);
        for (a, b) in u.obs.iter().zip(&obs) {
            assert!((a - b).abs() <= 1.0 / 65_535.0, "{a} {b}");
        }
        // The scalars are exact.
        assert_eq!(u.obs[len - 3..len], obs[len - 3..len]);
        let mut values = Vec::new();
        LAYOUT.values(&packed, &mut values);
        assert!(!LAYOUT.values_corrupt(&values));
    }

    #[test]
    fn a_corrupt_sequence_shows() {
        let (obs, mut tails, state) = sequence();
        let mut packed = vec![0; LAYOUT.packed_len()];
        let mut values = Vec::new();
        for (step, field, bad) in
            [(0, 0, 2.0), (1, 2, 0.5), (2, 3, 5.0), (2, 4, -1.0), (0, 1, f32::NAN)]
        {
            let keep = tails[step][field];
            tails[step][field] = bad;
            LAYOUT.pack(&obs, &tails, &state, &mut packed);
            LAYOUT.values(&packed, &mut values);
            assert!(LAYOUT.values_corrupt(&values), "step {step} field {field} = {bad}");
            tails[step][field] = keep;
        }
        let nan_state = [0.0, f32::INFINITY, 0.0, 0.0];
        LAYOUT.pack(&obs, &tails, &nan_state, &mut packed);
        LAYOUT.values(&packed, &mut values);
        assert!(LAYOUT.values_corrupt(&values));
        assert!(LAYOUT.values_corrupt(&values[1..]));
    }
}
