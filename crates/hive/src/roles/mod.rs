//! The four roles of a run, each a process of its own.

pub mod actor;
pub mod learner;
pub mod replay;
pub mod sim;
