//! The metrics a daemon records, by name (`docs/operations.md` lists them). Times are histograms
//! in seconds, sizes in bytes; the binary adds the labels `role` and `daemon` to every series.

use lightfold_protocol::FrameStats;
use std::time::Duration;

pub const FRAMES_DONE: &str = "lightfold_frames_done_total";
pub const FRAMES_FAILED: &str = "lightfold_frames_failed_total";
pub const PHASE_SECONDS: &str = "lightfold_frame_phase_seconds";
pub const BYTES_IN: &str = "lightfold_bytes_in_total";
pub const BYTES_OUT: &str = "lightfold_bytes_out_total";
pub const LINK_BYTES_IN: &str = "lightfold_link_bytes_in_total";
pub const STALE_BANDS: &str = "lightfold_stale_bands_total";
pub const BUFFERED_BYTES: &str = "lightfold_buffered_bytes";
pub const PEAK_RSS_BYTES: &str = "lightfold_peak_rss_bytes";
pub const ADAPTER_INFO: &str = "lightfold_adapter_info";
pub const PLAN_EPOCH: &str = "lightfold_plan_epoch";
pub const PLAN_SESSION_START: &str = "lightfold_plan_session_start_seconds";
pub const READY: &str = "lightfold_ready";
pub const FRAMES_DELIVERED: &str = "lightfold_frames_delivered_total";
pub const FRAME_LATENCY: &str = "lightfold_frame_latency_seconds";
pub const DAEMON_FRAME_SECONDS: &str = "lightfold_daemon_frame_seconds";
pub const DAEMONS_LOST: &str = "lightfold_daemons_lost_total";
pub const DAEMONS_REJOINED: &str = "lightfold_daemons_rejoined_total";
pub const REPLANS: &str = "lightfold_replans_total";
pub const DAEMONS: &str = "lightfold_daemons";
pub const BUILD_INFO: &str = "lightfold_build_info";

/// Why a daemon gives up a frame (`frame_failed`'s reasons).
pub const FAILURE_REASONS: [&str; 3] = ["abandoned", "preempted", "refused"];

/// The counters a daemon of `role` (`node`, `compositor`, `coordinator`) may ever bump, at 0, so
/// a dashboard or an alert sees the series before the first event (a rate over a series that does
/// not exist yet is no rate at all). Call once, after the exporter is installed.
pub fn zero_counters(role: &str) {
    if role == "coordinator" {
        for name in [FRAMES_DELIVERED, DAEMONS_LOST, DAEMONS_REJOINED, REPLANS] {
            metrics::counter!(name).absolute(0);
        }
    } else {
        metrics::counter!(FRAMES_DONE).absolute(0);
        for reason in FAILURE_REASONS {
            metrics::counter!(FRAMES_FAILED, "reason" => reason).absolute(0);
        }
    }
}

/// `lightfold_build_info{version, protocol} 1`: what this binary is, for dashboards that tell a
/// rolling upgrade's old daemons from its new ones (a daemon of another protocol version cannot
/// join a cluster). Call once, after the exporter is installed.
pub fn build_info() {
    metrics::gauge!(
        BUILD_INFO,
        "version" => env!("CARGO_PKG_VERSION"),
        "protocol" => lightfold_protocol::PROTOCOL_VERSION.to_string()
    )
    .set(1.0);
}

/// Registers the help text of every metric (call once, after the exporter is installed).
pub fn describe() {
    use metrics::{Unit, describe_counter, describe_gauge, describe_histogram};
    describe_gauge!(
        BUILD_INFO,
        "1, labelled with this binary's version and cluster protocol version"
    );
    describe_counter!(
        FRAMES_DONE,
        "frames this daemon finished (rendered and sent, or combined and sent)"
    );
    describe_counter!(
        FRAMES_FAILED,
        "frames this daemon refused or abandoned, by reason"
    );
    describe_histogram!(
        PHASE_SECONDS,
        Unit::Seconds,
        "time of each phase of a frame (setup, shadow, eye, readback, pack, send, composite, total)"
    );
    describe_counter!(
        BYTES_IN,
        Unit::Bytes,
        "bytes received, by kind (bands, scene, sink)"
    );
    describe_counter!(BYTES_OUT, Unit::Bytes, "bytes sent downstream (bands)");
    describe_counter!(
        LINK_BYTES_IN,
        Unit::Bytes,
        "band payload bytes received per input link, by the producer's daemon id"
    );
    describe_counter!(
        STALE_BANDS,
        "bands dropped as belonging to an older plan epoch or an abandoned frame"
    );
    describe_gauge!(
        BUFFERED_BYTES,
        Unit::Bytes,
        "packed band bytes a stage holds now"
    );
    describe_gauge!(
        PEAK_RSS_BYTES,
        Unit::Bytes,
        "peak resident set of the process (VmHWM)"
    );
    describe_gauge!(
        ADAPTER_INFO,
        "the graphics adapter this node renders on (1; software=\"true\" for a CPU rasteriser)"
    );
    describe_gauge!(
        PLAN_EPOCH,
        "the plan epoch applied last, numbered within its coordinator session (1, 2, ...)"
    );
    describe_gauge!(
        PLAN_SESSION_START,
        Unit::Seconds,
        "start (Unix time) of the coordinator session whose plan was applied last"
    );
    describe_gauge!(
        READY,
        "1 when /readyz answers ready (daemons: registered and configured; coordinator: serving)"
    );
    describe_counter!(
        FRAMES_DELIVERED,
        "frames the coordinator received complete from the sink"
    );
    describe_histogram!(
        FRAME_LATENCY,
        Unit::Seconds,
        "time from a frame's request to its last band at the coordinator"
    );
    describe_histogram!(
        DAEMON_FRAME_SECONDS,
        Unit::Seconds,
        "each daemon's own time per frame as it reported it, by daemon id and phase"
    );
    describe_counter!(
        DAEMONS_LOST,
        "daemons the coordinator lost (link ended, heartbeats unanswered, frame overdue)"
    );
    describe_counter!(
        DAEMONS_REJOINED,
        "lost daemons that came back and were folded in"
    );
    describe_counter!(
        REPLANS,
        "plans applied after the first (daemons lost or rejoined, colours changed)"
    );
    describe_gauge!(
        DAEMONS,
        "daemons registered with the coordinator, by role and whether they render in software"
    );
}

/// The phases of a frame a daemon reports, with their time in microseconds.
fn phases(s: &FrameStats) -> [(&'static str, u64); 8] {
    [
        ("setup", s.setup_us),
        ("shadow", s.shadow_us),
        ("eye", s.eye_us),
        ("readback", s.readback_us),
        ("pack", s.pack_us),
        ("send", s.send_us),
        ("composite", s.composite_us),
        ("total", s.total_us),
    ]
}

/// Seconds of a microsecond count.
fn secs(us: u64) -> f64 {
    us as f64 / 1e6
}

/// A frame this daemon finished, as it reports it to the coordinator. Phases the daemon does
/// not have (a stage renders no shadows) are left out rather than recorded as zero.
pub fn frame_done(s: &FrameStats) {
    metrics::counter!(FRAMES_DONE).increment(1);
    for (phase, us) in phases(s) {
        if us > 0 || phase == "total" {
            metrics::histogram!(PHASE_SECONDS, "phase" => phase).record(secs(us));
        }
    }
    metrics::counter!(BYTES_OUT).increment(s.bytes_out);
}

/// A frame this daemon refused or abandoned.
pub fn frame_failed(reason: &'static str) {
    metrics::counter!(FRAMES_FAILED, "reason" => reason).increment(1);
}

/// Bytes received: `kind` is `bands` (a stage's inputs), `scene` (a node's scene chunks) or
/// `sink` (the coordinator's final bands).
pub fn bytes_in(kind: &'static str, n: u64) {
    metrics::counter!(BYTES_IN, "kind" => kind).increment(n);
}

/// Band payload bytes received on the input link from `peer`.
pub fn link_bytes_in(peer: &str, n: u64) {
    metrics::counter!(LINK_BYTES_IN, "peer" => peer.to_string()).increment(n);
}

pub fn stale_band() {
    metrics::counter!(STALE_BANDS).increment(1);
}

pub fn buffered_bytes(n: u64) {
    metrics::gauge!(BUFFERED_BYTES).set(n as f64);
}

pub fn peak_rss_bytes(n: u64) {
    metrics::gauge!(PEAK_RSS_BYTES).set(n as f64);
}

/// The plan epoch applied last. Epochs are the session's start in ms × 2¹⁶ plus a count, beyond
/// what a float gauge holds exactly, so they are exported as the two parts.
pub fn plan_epoch(epoch: u64) {
    metrics::gauge!(PLAN_EPOCH).set((epoch & 0xffff) as f64);
    metrics::gauge!(PLAN_SESSION_START).set((epoch >> 16) as f64 / 1000.0);
}

/// The adapter a node renders on.
pub fn adapter(name: &str, backend: &str, software: bool) {
    metrics::gauge!(
        ADAPTER_INFO,
        "adapter" => name.to_string(),
        "backend" => backend.to_string(),
        "software" => if software { "true" } else { "false" },
    )
    .set(1.0);
}

pub fn ready(ready: bool) {
    metrics::gauge!(READY).set(if ready { 1.0 } else { 0.0 });
}

/// A frame the coordinator received, with the daemons' reports on it.
pub fn frame_delivered(latency: Duration, sink_bytes: u64, stats: &[FrameStats]) {
    metrics::counter!(FRAMES_DELIVERED).increment(1);
    metrics::histogram!(FRAME_LATENCY).record(latency.as_secs_f64());
    bytes_in("sink", sink_bytes);
    for s in stats {
        for (phase, us) in phases(s) {
            if us > 0 || phase == "total" {
                metrics::histogram!(
                    DAEMON_FRAME_SECONDS,
                    "peer" => s.daemon_id.clone(),
                    "phase" => phase,
                )
                .record(secs(us));
            }
        }
    }
}

pub fn daemon_lost() {
    metrics::counter!(DAEMONS_LOST).increment(1);
}

pub fn daemon_rejoined() {
    metrics::counter!(DAEMONS_REJOINED).increment(1);
}

pub fn replanned() {
    metrics::counter!(REPLANS).increment(1);
}

/// Daemons registered, by role (`node`, `compositor`) and software rendering.
pub fn daemons(role: &'static str, software: bool, n: usize) {
    metrics::gauge!(
        DAEMONS,
        "role" => role,
        "software" => if software { "true" } else { "false" },
    )
    .set(n as f64);
}

#[cfg(test)]
mod tests {
    use super::*;
    use metrics_exporter_prometheus::PrometheusBuilder;

    #[test]
    fn a_frame_shows_in_the_exposition() {
        let recorder = PrometheusBuilder::new().build_recorder();
        let handle = recorder.handle();
        metrics::with_local_recorder(&recorder, || {
            describe();
            let s = FrameStats {
                daemon_id: "node-0".into(),
                shadow_us: 12_000,
                eye_us: 30_000,
                total_us: 50_000,
                bytes_out: 4096,
                ..FrameStats::default()
            };
            frame_done(&s);
            frame_done(&s);
            link_bytes_in("node-3", 700);
            link_bytes_in("node-3", 300);
            frame_failed("timeout");
            plan_epoch((1_700_000_000_123 << 16) + 3);
            adapter("llvmpipe (LLVM 15.0.6, 256 bits)", "vulkan", true);
            frame_delivered(Duration::from_millis(80), 100, &[s]);
        });
        let text = handle.render();
        assert!(text.contains("lightfold_frames_done_total 2"), "{text}");
        assert!(text.contains("lightfold_bytes_out_total 8192"), "{text}");
        assert!(
            text.contains("lightfold_link_bytes_in_total{peer=\"node-3\"} 1000"),
            "{text}"
        );
        assert!(text.contains("lightfold_frames_failed_total{reason=\"timeout\"} 1"));
        assert!(text.contains("lightfold_plan_epoch 3"), "{text}");
        assert!(text.contains("lightfold_plan_session_start_seconds 1700000000.123"));
        assert!(text.contains("software=\"true\""));
        // No phase the frame did not have.
        assert!(!text.contains("phase=\"readback\""), "{text}");
        assert!(text.contains("phase=\"shadow\""));
        assert!(text.contains("# HELP lightfold_frames_done_total"));
        assert!(text.contains("peer=\"node-0\""));
    }

    #[test]
    fn counters_exist_at_zero_before_their_first_event() {
        for (role, present, absent) in [
            (
                "coordinator",
                vec![
                    "lightfold_replans_total 0",
                    "lightfold_daemons_lost_total 0",
                ],
                "lightfold_frames_failed_total",
            ),
            (
                "node",
                vec![
                    "lightfold_frames_done_total 0",
                    "lightfold_frames_failed_total{reason=\"refused\"} 0",
                ],
                "lightfold_replans_total",
            ),
        ] {
            let recorder = PrometheusBuilder::new().build_recorder();
            let handle = recorder.handle();
            metrics::with_local_recorder(&recorder, || {
                describe();
                zero_counters(role);
            });
            let text = handle.render();
            for p in present {
                assert!(text.contains(p), "{role}: {p} missing in\n{text}");
            }
            assert!(!text.contains(absent), "{role}: {absent} in\n{text}");
        }
    }
}
