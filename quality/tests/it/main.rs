//! The integration tests of `quality`, one binary (each file of this folder a module).

mod accuracy_sweep;
mod calibration;
mod cell_filter;
mod gloss_rule;
mod hard_cases;
mod ties;
