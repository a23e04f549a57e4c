//! Why a message from another host was dropped ([`Reject`], with what it
//! names) and the reason it is counted under ([`Reason`], `summary.json`'s
//! `rejected_by_reason`).

/// Why a message from another host was dropped.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Reject {
    /// Its key names no host of the run.
    UnknownSender,
    /// No header, or a header of the wrong size.
    Header,
    /// A payload whose length is not what the header's count needs.
    Length {
        /// Bytes received.
        got: usize,
        /// Bytes the header's count needs.
        want: usize,
    },
    /// A count of 0 or above the limit.
    Count(u32),
    /// An environment index outside the sender's own.
    Actor(u32),
    /// A role the sender does not run, or an instance it does not own.
    Role {
        /// Role code.
        role: u32,
        /// Instance index.
        index: u32,
    },
    /// Values an honest sender never writes (non-finite, out of range).
    Values(u64),
    /// A batch of another link epoch than the sender's current join.
    Epoch(u64),
}

/// The reason a refusal is counted under (`summary.json`'s
/// `rejected_by_reason`), one per kind of [`Reject`] and the join's refusal.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
pub enum Reason {
    /// A key that names no host of the run.
    Slot,
    /// No header, or one of the wrong size.
    Header,
    /// A payload of another length than its header's count needs.
    Length,
    /// A count of 0 or above the limit.
    Count,
    /// An environment that is not the sender's.
    Environment,
    /// A role or instance the sender does not run.
    Role,
    /// Non-finite or out-of-range values.
    Values,
    /// A batch of another epoch than its slot's current join (from an
    /// earlier process of that worker, or forged).
    Epoch,
    /// A join request the head refused.
    JoinRefused,
}

impl Reason {
    /// Every reason, in `summary.json`'s order (which is the order of the
    /// variants: a reason's index here is `reason as usize`).
    pub const ALL: [Reason; 9] = [
        Reason::Slot,
        Reason::Header,
        Reason::Length,
        Reason::Count,
        Reason::Environment,
        Reason::Role,
        Reason::Values,
        Reason::Epoch,
        Reason::JoinRefused,
    ];

    /// Its word in `summary.json`.
    pub fn name(self) -> &'static str {
        match self {
            Reason::Slot => "slot",
            Reason::Header => "header",
            Reason::Length => "length",
            Reason::Count => "count",
            Reason::Environment => "environment",
            Reason::Role => "role",
            Reason::Values => "values",
            Reason::Epoch => "epoch",
            Reason::JoinRefused => "join_refused",
        }
    }
}

impl Reject {
    /// The reason it is counted under.
    pub fn reason(&self) -> Reason {
        match self {
            Reject::UnknownSender => Reason::Slot,
            Reject::Header => Reason::Header,
            Reject::Length { .. } => Reason::Length,
            Reject::Count(_) => Reason::Count,
            Reject::Actor(_) => Reason::Environment,
            Reject::Role { .. } => Reason::Role,
            Reject::Values(_) => Reason::Values,
            Reject::Epoch(_) => Reason::Epoch,
        }
    }
}

impl std::fmt::Display for Reject {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Reject::UnknownSender => write!(f, "a key that names no host of the run"),
            Reject::Header => write!(f, "no header of the right size"),
            Reject::Length { got, want } => {
                write!(f, "{got} bytes where the header's count needs {want}")
            }
            Reject::Count(n) => write!(f, "a count of {n}"),
            Reject::Actor(a) => write!(f, "environment {a}, which is not the sender's"),
            Reject::Role { role, index } => {
                write!(f, "role code {role} index {index}, which the sender does not run")
            }
            Reject::Values(n) => write!(f, "{n} records with non-finite or out-of-range values"),
            Reject::Epoch(e) => write!(f, "link epoch {e}, not the one of the sender's join"),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_reason_sits_at_its_own_index_and_has_its_own_word() {
        for (i, r) in Reason::ALL.iter().enumerate() {
            assert_eq!(*r as usize, i, "{r:?}");
            assert_eq!(Reason::ALL.iter().filter(|x| x.name() == r.name()).count(), 1);
        }
    }
}
