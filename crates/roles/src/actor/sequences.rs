//! R2D2's sequences, assembled per agent from an actor's steps: each agent's
//! window holds the observations since its start, the steps' outcomes and
//! the recurrent state the actor had at every observation. A window of
//! `steps` transitions leaves packed ([`SeqLayout`]) with the state at its
//! first observation (the stored state), then slides on by `steps −
//! burn_in`: consecutive sequences overlap by the burn-in, so that their
//! trained steps tile the agent's stream. Sequences cross episode ends
//! (the done flag tells the learner to zero the state there).

use rotorhive_msg::{NO_EXPERT, SeqLayout, TAIL};

use super::Taken;

/// One agent's open window.
#[derive(Debug, Default, Clone)]
struct Window {
    /// Observations, flat.
    obs: Vec<f32>,
    /// The state before each observation was acted on, flat.
    states: Vec<f32>,
    /// Each step's action, reward, done, expert action, demonstration flag.
    tails: Vec<[f32; TAIL]>,
}

/// Per-agent windows of an actor, and the sequences the last step released.
pub struct Sequences {
    layout: SeqLayout,
    /// Steps a window slides by after it leaves.
    period: usize,
    windows: Vec<Window>,
    /// Sequences released by the last [`Sequences::push`], packed one after
    /// another.
    pub out: Vec<u16>,
    /// Their agents, in order.
    pub agents: Vec<usize>,
    /// Their trained steps (the last [`Sequences::period`] of each: they
    /// tile the stream) flown by the teacher, and the student's labelled.
    pub taught: (u64, u64),
}

impl Sequences {
    /// Windows for `agents` agents of sequences of `layout`, overlapping by
    /// `burn_in` steps (fewer than the sequence's steps).
    pub fn new(layout: SeqLayout, burn_in: usize, agents: usize) -> Self {
        assert!(burn_in < layout.steps, "the burn-in must leave a step to train");
        Self {
            layout,
            period: layout.steps - burn_in,
            windows: vec![Window::default(); agents],
            out: Vec::new(),
            agents: Vec::new(),
            taught: (0, 0),
        }
    }

    /// Trained steps per sequence: the steps a window slides by.
    pub fn period(&self) -> usize {
        self.period
    }

    /// Forgets every open window (the sim restarted).
    pub fn clear(&mut self) {
        for w in &mut self.windows {
            *w = Window::default();
        }
        self.out.clear();
        self.agents.clear();
    }

    /// Records one step of every agent: the outcome of the last actions
    /// (`last`: what was taken, the rewards and the dones; none at a
    /// stream's first step), then the observations `obs` the next actions
    /// are taken on, with each agent's state before acting on them
    /// (`states`). Fills `out` with the sequences complete now.
    pub fn push(&mut self, last: Option<(Taken<'_>, &[f32], &[f32])>, obs: &[f32], states: &[f32]) {
        self.out.clear();
        self.agents.clear();
        self.taught = (0, 0);
        let (len, width) = (self.layout.shapes.obs_len(), self.layout.width);
        let (steps, period) = (self.layout.steps, self.period);
        for (i, w) in self.windows.iter_mut().enumerate() {
            if let (Some((taken, rewards, dones)), false) = (last, w.obs.is_empty()) {
                let demo = if taken.flown[i] { 1.0 } else { 0.0 };
                let done = if dones[i] != 0.0 { 1.0 } else { 0.0 };
                w.tails.push([taken.actions[i] as f32, rewards[i], done, taken.experts[i], demo]);
            }
            w.obs.extend_from_slice(&obs[i * len..(i + 1) * len]);
            w.states.extend_from_slice(&states[i * width..(i + 1) * width]);
            if w.tails.len() < steps {
                continue;
            }
            let at = self.out.len();
            self.out.resize(at + self.layout.packed_len(), 0);
            self.layout.pack(&w.obs, &w.tails, &w.states[..width], &mut self.out[at..]);
            self.agents.push(i);
            for t in &w.tails[steps - period..] {
                let demo = t[4] == 1.0;
                self.taught.0 += demo as u64;
                self.taught.1 += (!demo && t[3] != NO_EXPERT) as u64;
            }
            w.obs.drain(..period * len);
            w.states.drain(..period * width);
            w.tails.drain(..period);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rotorhive_msg::{Shapes, Unpacked};

    #[test]
    fn sequences_carry_their_start_state_and_their_trained_steps_tile() {
        let layout = SeqLayout { shapes: Shapes::PAPER, steps: 5, width: 2 };
        let (agents, len, burn) = (2, Shapes::PAPER.obs_len(), 2);
        let mut seqs = Sequences::new(layout, burn, agents);
        let mut released: Vec<Vec<Unpacked>> = vec![Vec::new(); agents];
        let experts = [NO_EXPERT; 2];
        let flown = [false; 2];
        for step in 0..20u32 {
            // The first scalar says the step and the agent; the state, the
            // step; agent 1's episode ends every 7 steps.
            let mut obs = vec![0.5; agents * len];
            let mut states = vec![0.0; agents * 2];
            for a in 0..agents {
                obs[a * len + Shapes::PAPER.obs_depth()] = (100 * a as u32 + step) as f32;
                states[a * 2] = step as f32;
                states[a * 2 + 1] = -(a as f32);
            }
            let actions = [(step % 2) as u8, ((step + 1) % 2) as u8];
            let rewards = [step as f32, 10.0 * step as f32];
            let dones = [0.0, if step % 7 == 6 { 1.0 } else { 0.0 }];
            let taken = Taken { actions: &actions, experts: &experts, flown: &flown };
            // The outcome of the actions taken at step − 1: those actions
            // are step − 1's (recorded here as this step's parity flipped).
            let prev = [((step + 1) % 2) as u8, (step % 2) as u8];
            let last = Taken { actions: &prev, ..taken };
            seqs.push((step > 0).then_some((last, &rewards[..], &dones[..])), &obs, &states);
            for (k, &a) in seqs.agents.iter().enumerate() {
                let mut u = Unpacked::default();
                layout.unpack_into(
                    &seqs.out[k * layout.packed_len()..][..layout.packed_len()],
                    &mut u,
                );
                released[a].push(u);
            }
        }
        // Windows of 5 steps sliding by 3: starts at 0, 3, 6, 9, 12 (the
        // last needs step 17's observation).
        for (a, seqs) in released.iter().enumerate() {
            assert_eq!(seqs.len(), 5, "agent {a}");
            for (k, u) in seqs.iter().enumerate() {
                let start = 3 * k as u32;
                assert_eq!(u.states, [start as f32, -(a as f32)], "agent {a} sequence {k}");
                let firsts: Vec<f32> =
                    u.obs.chunks_exact(len).map(|o| o[Shapes::PAPER.obs_depth()]).collect();
                let want: Vec<f32> =
                    (start..=start + 5).map(|s| (100 * a as u32 + s) as f32).collect();
                assert_eq!(firsts, want);
                // Step s's outcome: action taken at s, reward paid at s + 1.
                for (j, s) in (start..start + 5).enumerate() {
                    let act = if a == 0 { s % 2 } else { (s + 1) % 2 } as u8;
                    assert_eq!(u.actions[j], act);
                    let r = (s + 1) as f32 * if a == 0 { 1.0 } else { 10.0 };
                    assert_eq!(u.rewards[j], r);
                    assert_eq!(u.dones[j], a == 1 && (s + 1) % 7 == 6);
                }
            }
        }
        // A restart forgets the open windows.
        seqs.clear();
        let obs = vec![0.5; agents * len];
        seqs.push(None, &obs, &[0.0; 4]);
        assert!(seqs.out.is_empty() && seqs.agents.is_empty());
    }
}
