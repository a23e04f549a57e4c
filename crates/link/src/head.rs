//! The head's side: admitting workers ([`admit`]), each slot's stream of
//! batches ([`inflow`], [`flows`]), a worker host as the head sees it
//! ([`host`]) and the thread that bridges them to the run ([`bridge`]).

pub mod admit;
pub mod bridge;
pub mod flows;
pub mod host;
pub mod inflow;
