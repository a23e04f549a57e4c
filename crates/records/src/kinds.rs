//! The records' vocabulary: what a row or a summary names, as enums that
//! serialise to the words the files have always held (`head`, `batched`,
//! `cpu`, `learner`, …), so that no reader compares strings.

use rotorhive_msg::RoleKind;
use serde::{Deserialize, Serialize};

/// Who a row of `telemetry.csv` is about: a role, or the supervisor
/// (`hive train` itself).
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Member {
    /// A simulator.
    Sim,
    /// An actor.
    Actor,
    /// The replay.
    Replay,
    /// The learner.
    Learner,
    /// A host's link.
    Link,
    /// The supervisor.
    Supervisor,
}

impl Member {
    /// The word in the files.
    pub fn name(self) -> &'static str {
        match self.role() {
            Some(r) => r.name(),
            None => "supervisor",
        }
    }

    /// The role, for every member but the supervisor.
    pub fn role(self) -> Option<RoleKind> {
        match self {
            Member::Sim => Some(RoleKind::Sim),
            Member::Actor => Some(RoleKind::Actor),
            Member::Replay => Some(RoleKind::Replay),
            Member::Learner => Some(RoleKind::Learner),
            Member::Link => Some(RoleKind::Link),
            Member::Supervisor => None,
        }
    }

    /// Every member.
    pub const ALL: [Member; 6] = [
        Member::Sim,
        Member::Actor,
        Member::Replay,
        Member::Learner,
        Member::Link,
        Member::Supervisor,
    ];

    /// Reads the word in the files.
    pub fn parse(s: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|m| m.name() == s)
    }
}

impl From<RoleKind> for Member {
    fn from(r: RoleKind) -> Self {
        match r {
            RoleKind::Sim => Member::Sim,
            RoleKind::Actor => Member::Actor,
            RoleKind::Replay => Member::Replay,
            RoleKind::Learner => Member::Learner,
            RoleKind::Link => Member::Link,
        }
    }
}

impl std::fmt::Display for Member {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

/// A host's part in a run (`summary.json`'s `hosts[].role`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum HostRole {
    /// The host of `hive train`.
    Head,
    /// A host of `hive worker`.
    Worker,
    /// Messages on keys that name no host of the run.
    Unknown,
}

/// How observations travelled (`summary.json`'s `observation_mode`; the
/// config's `sim.observation_mode`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum ObservationMode {
    /// One message per step with every agent's observation.
    Batched,
    /// One message per agent.
    NonBatched,
}

/// What drew the depth images (`summary.json`'s `renderer`; the config's
/// `sim.renderer`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Renderer {
    /// Ray casting on the CPU.
    Cpu,
    /// wgpu.
    Wgpu,
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn members_read_back_what_they_write() {
        for m in Member::ALL {
            assert_eq!(Member::parse(m.name()), Some(m));
            assert_eq!(serde_json::to_value(m).unwrap(), m.name());
        }
        assert_eq!(Member::parse("head"), None);
        assert_eq!(serde_json::to_value(ObservationMode::NonBatched).unwrap(), "non-batched");
        assert_eq!(serde_json::to_value(HostRole::Unknown).unwrap(), "unknown");
    }
}
