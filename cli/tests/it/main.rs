//! The integration tests of `cli`, one binary (each file of this folder a module).

mod accuracy_cli;
mod antialiasing;
mod compositor_chain;
mod demo;
mod demo_output;
mod limits;
mod live_view;
mod multihost;
mod newcomer_args;
mod ops;
mod partitions;
mod soak;
