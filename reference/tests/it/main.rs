//! The integration tests of `reference`, one binary (each file of this folder a module).

mod common;

mod area;
mod convergence;
mod metrics;
mod peel;
mod point_sum;
mod ties;
