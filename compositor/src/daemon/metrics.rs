//! Counters a running stage exposes: bytes it holds (input queues, bands being combined, the output
//! queue) with their peak, and frame outcomes. Tests read them to prove memory stays bounded under
//! backpressure; they are also recorded as the daemon's metrics (`lightfold_telemetry::record`).

use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};

/// Live counters of one stage. Cheap to clone the `Arc` and read from anywhere.
#[derive(Debug, Default)]
pub struct StageMetrics {
    buffered: AtomicU64,
    peak_buffered: AtomicU64,
    frames_done: AtomicU64,
    frames_failed: AtomicU64,
    stale_bands: AtomicU64,
    mismatches: AtomicU64,
}

impl StageMetrics {
    pub fn new() -> Arc<StageMetrics> {
        Arc::new(StageMetrics::default())
    }

    /// Packed bytes the stage holds right now (received and not yet combined, plus combined and
    /// not yet written to the downstream socket). Decoded f32 scratch of the one or two bands
    /// being combined is not included; it is bounded by the band size.
    pub fn buffered_bytes(&self) -> u64 {
        self.buffered.load(Ordering::Relaxed)
    }

    /// Highest `buffered_bytes` seen since start (or the last `reset_peak`).
    pub fn peak_buffered_bytes(&self) -> u64 {
        self.peak_buffered.load(Ordering::Relaxed)
    }

    pub fn reset_peak(&self) {
        self.peak_buffered
            .store(self.buffered_bytes(), Ordering::Relaxed);
    }

    /// Frames combined and fully written downstream.
    pub fn frames_done(&self) -> u64 {
        self.frames_done.load(Ordering::Relaxed)
    }

    /// Frames abandoned (mismatch, timeout, lost peer).
    pub fn frames_failed(&self) -> u64 {
        self.frames_failed.load(Ordering::Relaxed)
    }

    /// Bands dropped because they belonged to an older epoch or an abandoned frame.
    pub fn stale_bands(&self) -> u64 {
        self.stale_bands.load(Ordering::Relaxed)
    }

    /// Bands rejected as not matching the configured frame.
    pub fn mismatches(&self) -> u64 {
        self.mismatches.load(Ordering::Relaxed)
    }

    pub(crate) fn hold(self: &Arc<Self>, bytes: u64) -> Held {
        let now = self.buffered.fetch_add(bytes, Ordering::Relaxed) + bytes;
        self.peak_buffered.fetch_max(now, Ordering::Relaxed);
        lightfold_telemetry::record::buffered_bytes(now);
        Held {
            bytes,
            metrics: Arc::clone(self),
        }
    }

    pub(crate) fn frame_done(&self) {
        self.frames_done.fetch_add(1, Ordering::Relaxed);
    }

    pub(crate) fn frame_failed(&self) {
        self.frames_failed.fetch_add(1, Ordering::Relaxed);
        lightfold_telemetry::record::frame_failed("abandoned");
    }

    pub(crate) fn stale_band(&self) {
        self.stale_bands.fetch_add(1, Ordering::Relaxed);
        lightfold_telemetry::record::stale_band();
    }

    pub(crate) fn mismatch(&self) {
        self.mismatches.fetch_add(1, Ordering::Relaxed);
    }
}

/// Accounts `bytes` as buffered until dropped.
#[derive(Debug)]
pub(crate) struct Held {
    bytes: u64,
    metrics: Arc<StageMetrics>,
}

impl Drop for Held {
    fn drop(&mut self) {
        let before = self
            .metrics
            .buffered
            .fetch_sub(self.bytes, Ordering::Relaxed);
        lightfold_telemetry::record::buffered_bytes(before.saturating_sub(self.bytes));
    }
}
