//! lightfold's coordinator: the pure planner (`plan(scene, cluster, options) -> Plan`) and the
//! control loop that dials daemons, applies plans, drives frames and receives the final image.
//!
//! Must not depend on wgpu or the node crate.

pub mod cluster;
pub mod console;
pub mod control;
pub mod frames_out;
pub mod operator;
pub mod plan;
pub mod report;
pub mod run;
pub mod tiles;
