//! A telemetry sample's counters by name and unit, as its role means them
//! ([`Counters`]): `Telemetry` is one plain layout for every role (it
//! crosses processes and hosts as bytes), and its `work`, `work2`, `lost`
//! and `value_milli` mean something else in each role; this is the one
//! place that says what.

use crate::{Delivery, RoleKind, Telemetry};

/// What a role's telemetry sample counts, named, with its unit.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Counters {
    /// A sim.
    Sim {
        /// Agent-steps taken.
        agent_steps: u64,
        /// Episodes finished.
        episodes: u64,
        /// Messages found missing or re-sent steps that lost nothing.
        messages_lost: u64,
    },
    /// An actor.
    Actor {
        /// Transitions sent to the replay (or its host's link).
        transitions: u64,
        /// Episodes ended.
        episodes: u64,
        /// The largest epsilon of its agents.
        epsilon: f64,
        /// Messages it gave up or found missing.
        messages_lost: u64,
    },
    /// The replay.
    Replay {
        /// Transitions inserted.
        transitions: u64,
        /// Minibatches sent to the learner.
        minibatches: u64,
        /// Transitions held.
        size: u64,
        /// Transitions of this host's actors missing (sequence gaps, at the
        /// size of the batch after the gap) or corrupt.
        transitions_lost: u64,
    },
    /// The learner.
    Learner {
        /// Updates made.
        updates: u64,
        /// Weight versions published.
        weights_published: u64,
        /// Mean loss of the updates since the previous sample.
        loss: f64,
    },
    /// A host's link.
    Link {
        /// Transitions carried (the head: taken in; a worker: sent a first time).
        transitions: u64,
        /// Their bytes.
        bytes: u64,
        /// Transitions missing from another host's actors (the head's link).
        transitions_lost: u64,
        /// A worker's delivery to the head.
        delivery: Delivery,
    },
}

impl Telemetry {
    /// Its counters by name, for its role; `None` for a code of no role.
    pub fn counters(&self) -> Option<Counters> {
        let t = self;
        Some(match RoleKind::from_code(t.role)? {
            RoleKind::Sim => {
                Counters::Sim { agent_steps: t.work, episodes: t.work2, messages_lost: t.lost }
            }
            RoleKind::Actor => Counters::Actor {
                transitions: t.work,
                episodes: t.work2,
                epsilon: t.value_milli as f64 / 1e3,
                messages_lost: t.lost,
            },
            RoleKind::Replay => Counters::Replay {
                transitions: t.work,
                minibatches: t.work2,
                size: t.value_milli.max(0) as u64,
                transitions_lost: t.lost,
            },
            RoleKind::Learner => Counters::Learner {
                updates: t.work,
                weights_published: t.work2,
                loss: t.value_milli as f64 / 1e6,
            },
            RoleKind::Link => Counters::Link {
                transitions: t.work,
                bytes: t.work2,
                transitions_lost: t.lost,
                delivery: t.delivery,
            },
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn each_role_names_its_counters() {
        let t = |role: RoleKind| Telemetry {
            role: role as u32,
            work: 7,
            work2: 3,
            lost: 2,
            value_milli: 1500,
            ..Telemetry::default()
        };
        assert_eq!(
            t(RoleKind::Sim).counters(),
            Some(Counters::Sim { agent_steps: 7, episodes: 3, messages_lost: 2 })
        );
        assert_eq!(
            t(RoleKind::Actor).counters(),
            Some(Counters::Actor { transitions: 7, episodes: 3, epsilon: 1.5, messages_lost: 2 })
        );
        assert_eq!(
            t(RoleKind::Replay).counters(),
            Some(Counters::Replay {
                transitions: 7,
                minibatches: 3,
                size: 1500,
                transitions_lost: 2
            })
        );
        assert_eq!(
            t(RoleKind::Learner).counters(),
            Some(Counters::Learner { updates: 7, weights_published: 3, loss: 0.0015 })
        );
        let mut link = t(RoleKind::Link);
        link.delivery.acknowledged = 5;
        let Some(Counters::Link { transitions, delivery, .. }) = link.counters() else {
            panic!("a link's counters");
        };
        assert_eq!((transitions, delivery.acknowledged), (7, 5));
        assert_eq!(Telemetry { role: 99, ..t(RoleKind::Sim) }.counters(), None);
    }
}
