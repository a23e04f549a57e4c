//! A worker host of the run as the head sees it, what the head believes of
//! a join, and the slot a worker's key names.

use crate::wire::Hello;

/// A worker host of the run, as the head sees it.
#[derive(Debug, Clone)]
pub struct Host {
    /// Host name.
    pub name: String,
    /// Its place (1 = first worker).
    pub slot: u32,
    /// Environments.
    pub envs: u32,
    /// Agents per environment.
    pub agents: u32,
    /// Its first environment's index in the run.
    pub env_offset: u32,
    /// The link epoch of its first join (a join again gets a new one).
    pub epoch: u64,
    /// The join token it first joined with: it comes back only with it.
    pub(crate) token: String,
}

/// Whether a join token matches the one a host first joined with (in time
/// that does not depend on where they differ).
pub(crate) fn same_token(a: &str, b: &str) -> bool {
    a.len() == b.len() && a.bytes().zip(b.bytes()).fold(0u8, |d, (x, y)| d | (x ^ y)) == 0
}

impl Host {
    /// Whether environment `env` (its index in the run) is this host's.
    pub(crate) fn owns(&self, env: u32) -> bool {
        env >= self.env_offset && (env - self.env_offset) < self.envs
    }
}

/// The longest host name a head accepts (a DNS name's length).
pub const MAX_HOST_NAME: usize = 253;

/// What a head believes of a joining worker: no more than its own config
/// could hold. Environments and agents within the config's caps
/// ([`rotorhive_msg::MAX_ENVS_PER_HOST`], [`rotorhive_msg::MAX_AGENTS_PER_ENV`]),
/// and no more agents than one batch of the run's n-step returns can carry
/// (an episode's end releases up to `n_step` transitions of every agent,
/// and the head refuses a batch of more than [`crate::wire::MAX_BATCH`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct JoinLimits {
    /// Agents per environment of a worker that asks for 0 (the head's own).
    pub default_agents: u32,
    /// The run's n-step return length (`learner.n_step`).
    pub n_step: u32,
}

impl JoinLimits {
    /// The most agents per environment a worker may run.
    pub fn max_agents(&self) -> u32 {
        let per_batch = crate::wire::MAX_BATCH as u32 / self.n_step.max(1);
        per_batch.min(rotorhive_msg::MAX_AGENTS_PER_ENV as u32)
    }

    /// Checks a join's numbers and name (a worker that asks for 0 agents
    /// gets the default); the refusal says why.
    pub(crate) fn check(&self, h: &mut Hello) -> Result<(), String> {
        if h.agents == 0 {
            h.agents = self.default_agents;
        }
        let (max_envs, max_agents) = (rotorhive_msg::MAX_ENVS_PER_HOST as u32, self.max_agents());
        if !(1..=max_envs).contains(&h.envs) || !(1..=max_agents).contains(&h.agents) {
            return Err(format!(
                "a worker runs 1 to {max_envs} environments of 1 to {max_agents} agents here \
                 (n-step {}: one batch carries at most {} transitions), got {} × {}",
                self.n_step,
                crate::wire::MAX_BATCH,
                h.envs,
                h.agents
            ));
        }
        if h.host.is_empty()
            || h.host.len() > MAX_HOST_NAME
            || h.host.chars().any(|c| c.is_control() || c.is_whitespace())
        {
            return Err(format!(
                "a host name of 1 to {MAX_HOST_NAME} bytes without spaces or control \
                 characters is needed, got {} bytes",
                h.host.len()
            ));
        }
        Ok(())
    }
}

/// The first environment of each of `envs` hosts placed one after another
/// after the head's `head_envs`, or `None` where the run would pass
/// `u32::MAX` environments.
pub(crate) fn place(head_envs: u32, envs: impl IntoIterator<Item = u32>) -> Option<Vec<u32>> {
    let mut next = head_envs;
    envs.into_iter()
        .map(|e| {
            let at = next;
            next = next.checked_add(e)?;
            Some(at)
        })
        .collect()
}

/// The slot a worker's key names: `rotorhive/RUN/host/SLOT/WHAT`.
pub fn slot_of(key: &str, run: &str, what: &str) -> Option<u32> {
    let rest = key.strip_prefix("rotorhive/")?.strip_prefix(run)?.strip_prefix("/host/")?;
    let (slot, tail) = rest.split_once('/')?;
    if tail != what || slot.is_empty() || !slot.bytes().all(|b| b.is_ascii_digit()) {
        return None;
    }
    slot.parse().ok()
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn hello(envs: u32, agents: u32, host: &str) -> Hello {
        let earlier = Default::default();
        Hello { layout: 1, envs, agents, host: host.into(), token: "t".into(), earlier }
    }

    #[test]
    fn a_join_is_believed_only_within_the_configs_caps() {
        let limits = JoinLimits { default_agents: 8, n_step: 3 };
        assert_eq!(limits.max_agents(), 341);
        let mut h = hello(2, 0, "w1");
        assert_eq!(limits.check(&mut h), Ok(()));
        assert_eq!(h.agents, 8, "0 agents asks for the head's");
        for (envs, agents, host) in [
            (0, 8, "w"),
            (65, 8, "w"),
            (u32::MAX, 8, "w"),
            (1, 342, "w"),
            (1, u32::MAX, "w"),
            (1, 8, ""),
            (1, 8, "a b"),
            (1, 8, "bell\u{7}"),
        ] {
            let e = limits.check(&mut hello(envs, agents, host));
            assert!(e.is_err(), "{envs} × {agents} {host:?} was believed");
        }
        assert!(limits.check(&mut hello(1, 8, &"h".repeat(MAX_HOST_NAME + 1))).is_err());
        assert_eq!(place(1, [2, 3]), Some(vec![1, 3]));
        assert_eq!(place(u32::MAX - 1, [1, 1]), None);
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(2000))]
        /// Joins with any numbers: a believed one fits one batch and the
        /// config's caps, and placing any hosts never wraps.
        #[test]
        fn joins_with_extreme_numbers_are_refused_or_fit(envs in any::<u32>(), agents in any::<u32>(), n_step in 1u32..=16, host in ".{0,300}", head in any::<u32>(), more in proptest::collection::vec(any::<u32>(), 0..8)) {
            let limits = JoinLimits { default_agents: 4, n_step };
            let mut h = hello(envs, agents, &host);
            if limits.check(&mut h).is_ok() {
                prop_assert!(h.envs >= 1 && h.envs as usize <= rotorhive_msg::MAX_ENVS_PER_HOST);
                prop_assert!(h.agents >= 1 && (h.agents * n_step) as usize <= crate::wire::MAX_BATCH);
            }
            if let Some(at) = place(head, more.iter().copied()) {
                prop_assert!(at.windows(2).all(|w| w[0] <= w[1]));
                prop_assert!(at.iter().all(|a| *a >= head));
            }
        }
    }

    #[test]
    fn only_a_hosts_own_key_names_its_slot() {
        assert_eq!(slot_of("rotorhive/run-1/host/2/transitions", "run-1", "transitions"), Some(2));
        for k in [
            "rotorhive/run-1/host/2/episodes",
            "rotorhive/run-2/host/2/transitions",
            "rotorhive/run-1/host/+2/transitions",
            "rotorhive/run-1/host//transitions",
        ] {
            assert_eq!(slot_of(k, "run-1", "transitions"), None, "{k}");
        }
    }
}
