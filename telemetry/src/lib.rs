//! What operators see of a running daemon: the metrics every daemon records (through the
//! `metrics` facade — the `lightfold` binary installs the Prometheus exporter and serves
//! `/metrics`; with nothing installed a record is a no-op), whether the daemon is live and ready
//! (`/healthz`, `/readyz`), which graphics adapters are software rasterisers, and the process's log
//! lines (`logging`: text for people, JSON for collectors, each naming its daemon).
//!
//! Pure bookkeeping: must not depend on tokio, wgpu, HTTP or any daemon crate, so every daemon
//! crate can record into it. Metric names and their meaning are listed in `docs/operations.md`.

pub mod adapter;
pub mod health;
pub mod logging;
pub mod out;
pub mod process;
pub mod record;

pub use adapter::is_software_rasteriser;
