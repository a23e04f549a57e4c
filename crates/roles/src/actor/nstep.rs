//! n-step returns (as in Ape-X): what an actor keeps of each agent's last
//! steps until their transitions leave.

/// One n-step transition ready to leave: the agent, the ring slot of its
/// first observation, the action taken there, the discounted return of up
/// to n rewards, whether the episode ended within them, and the teacher's
/// action there and whether it flew it.
#[derive(Debug, Clone, Copy)]
pub struct Ready {
    /// The agent.
    pub agent: usize,
    /// Ring slot of the transition's first observation ([`NStep::obs`]).
    pub slot: usize,
    /// The action taken there.
    pub action: u8,
    /// Discounted return of up to n rewards.
    pub ret: f32,
    /// Whether the episode ended within them.
    pub done: bool,
    /// The teacher's action at the first observation ([`NO_EXPERT`](rotorhive_msg::NO_EXPERT): none).
    pub expert: f32,
    /// Whether the teacher flew that step (a demonstration).
    pub demo: bool,
}

/// What every agent did at its last observation: the action taken, the
/// teacher's action there ([`NO_EXPERT`](rotorhive_msg::NO_EXPERT): none) and whether the teacher
/// flew it.
#[derive(Debug, Clone, Copy)]
pub struct Taken<'a> {
    /// The actions taken.
    pub actions: &'a [u8],
    /// The teacher's actions.
    pub experts: &'a [f32],
    /// Whether the teacher flew each agent.
    pub flown: &'a [bool],
}

/// A step waiting in [`NStep`]: its ring slot, action, reward, the
/// teacher's action and whether the teacher flew it.
#[derive(Debug, Clone, Copy)]
struct Pending {
    slot: usize,
    action: u8,
    reward: f32,
    expert: f32,
    demo: bool,
}

/// n-step returns (as in Ape-X): the last n observations of every agent in
/// a ring of n + 1 batches, and per agent the (slot, action, reward) of the
/// steps whose transitions have not left yet. The learner bootstraps with
/// gamma^n.
pub struct NStep {
    n: usize,
    gamma: f32,
    agents: usize,
    /// Floats per observation.
    len: usize,
    ring: Vec<f32>,
    /// Slot of the newest stored observation batch.
    slot: usize,
    queue: Vec<std::collections::VecDeque<Pending>>,
    /// The transitions the last [`NStep::push`] released.
    pub out: Vec<Ready>,
}

impl NStep {
    /// n-step returns with discount `gamma` for `agents` agents whose
    /// observations are `len` floats.
    pub fn new(n: usize, gamma: f32, agents: usize, len: usize) -> Self {
        Self {
            n,
            gamma,
            agents,
            len,
            ring: vec![0.0; (n + 1) * agents * len],
            slot: 0,
            queue: vec![Default::default(); agents],
            out: Vec::new(),
        }
    }

    /// Forgets every pending step (the sim restarted).
    pub fn clear(&mut self) {
        self.queue.iter_mut().for_each(|q| q.clear());
        self.out.clear();
    }

    /// The observation of `agent` stored in ring slot `slot`.
    pub fn obs(&self, slot: usize, agent: usize) -> &[f32] {
        let at = (slot * self.agents + agent) * self.len;
        &self.ring[at..at + self.len]
    }

    /// Stores the observations the next actions are taken on.
    pub fn store(&mut self, obs: &[f32]) {
        self.slot = (self.slot + 1) % (self.n + 1);
        let at = self.slot * self.agents * self.len;
        self.ring[at..at + self.agents * self.len].copy_from_slice(obs);
    }

    /// Records the outcome of the last actions and fills `out` with the
    /// transitions that can leave now.
    pub fn push(&mut self, taken: Taken<'_>, rewards: &[f32], dones: &[f32]) {
        self.out.clear();
        for i in 0..self.agents {
            let q = &mut self.queue[i];
            q.push_back(Pending {
                slot: self.slot,
                action: taken.actions[i],
                reward: rewards[i],
                expert: taken.experts[i],
                demo: taken.flown[i],
            });
            let ret = |q: &std::collections::VecDeque<Pending>, from: usize| {
                q.iter().skip(from).rev().fold(0.0f32, |acc, e| e.reward + self.gamma * acc)
            };
            let ready = |k: usize, done: bool| Ready {
                agent: i,
                slot: q[k].slot,
                action: q[k].action,
                ret: ret(q, k),
                done,
                expert: q[k].expert,
                demo: q[k].demo,
            };
            if dones[i] != 0.0 {
                for k in 0..q.len() {
                    self.out.push(ready(k, true));
                }
                q.clear();
            } else if q.len() == self.n {
                self.out.push(ready(0, false));
                q.pop_front();
            }
        }
    }
}
