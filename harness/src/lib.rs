//! lightfold's harness: clusters to test and measure with, and the one check of their frames.
//!
//! - [`in_process`]: render nodes and compositors as tasks of this process, killed and restarted
//!   on their addresses, and a coordinator session over them (tests).
//! - [`driver`]: the one fake coordinator (and producer and sink) over real links, for tests
//!   and benchmarks of one daemon or a chain.
//! - [`check`]: the single-device render a cluster frame must equal, and the comparison within
//!   the link formats' bound (tests, `lightfold soak`).
//! - [`sweep`]: accuracy sweeps rendered through an in-process cluster.
//! - [`local_cluster`]: a cluster all on this machine, as its nodes will report themselves, and
//!   the bound on its processes.
//! - [`launcher`]: local clusters of daemon processes (`lightfold demo`, `soak`, `bench`), and
//!   what launchers signal and measure them with.
//! - [`soak`]: `lightfold soak`, the failover soak: faults injected into a process cluster, every
//!   frame checked, detection and recovery measured.
//! - [`bench`]: `lightfold bench`, benchmarks that print figures; [`view_probe`]: `lightfold
//!   view-probe`, a live view measured as a viewer sees it.
//! - [`fixtures`]: the device or a loud failure, small scenes, test deadlines.
//!
//! The workspace's cluster tests (`tests/it`) and scaling examples live in this crate too. Every
//! wait has a deadline.

pub mod bench;
pub mod check;
pub mod driver;
pub mod fixtures;
pub mod in_process;
pub mod launcher;
pub mod local_cluster;
pub mod soak;
pub mod sweep;
pub mod view_probe;

pub use check::{
    Check, assert_close, assert_close_within, compare, radiance, single_device, single_device_aa,
    single_device_filtered, single_device_parts, single_device_peeled,
};
pub use fixtures::{
    gpu, latency_and_interval, ms, orbit_options, silhouettes, small, small_glass,
    small_glass_stack, small_helmet, test_control,
};
pub use in_process::{ClusterOptions, InProcessCluster, RUN_DEADLINE, RunOutput, render_on};
