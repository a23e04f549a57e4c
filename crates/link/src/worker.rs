//! The worker's side: joining a head ([`join`]), the loop that bridges the
//! host's run to it ([`bridge`]) and its transitions out through the
//! window ([`send`]).

pub mod bridge;
pub mod join;
pub mod send;
