//! A worker host of the run as the head sees it, and the slot a worker's
//! key names.

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
