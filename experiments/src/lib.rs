//! Experiments and probes beside the product, one example each
//! (`experiments/examples/`): questions asked of the trainer's parts
//! before the trainer takes an answer in. Nothing of the trainer uses
//! them; they keep none of its contracts (config, checkpoints, link).
//!
//! - `drqn_probe`: does memory (a GRU carried per agent, R2D2's stored
//!   states and burn-in) let a Q-learner fly the moving obstacles of L4
//!   within five minutes? Results: `docs/results/memory.md`.
