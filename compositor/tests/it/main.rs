//! The integration tests of `compositor`, one binary (each file of this folder a module).

mod common;
mod support;

mod chain_tree;
mod daemon_backpressure;
mod daemon_claims;
mod daemon_mismatch;
mod daemon_relink;
mod daemon_retarget;
mod daemon_stage;
mod daemon_wiring;
mod depth_packed;
mod differential;
mod operators;
mod packed_out;
mod penumbra;
mod pipeline;
mod precision;
