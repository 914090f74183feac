//! The integration tests of `coordinator`, one binary (each file of this folder a module).

mod plan_scenes;

mod plan_budget;
mod plan_formats;
mod plan_props;
mod plan_rules;
mod replan;
