//! Per-frame and summary timing tables of a coordinator run: render time per node, composite time
//! per stage, bytes per link, end-to-end latency in frames, frame interval.

use crate::control::FrameResult;
use crate::plan::Plan;
use lightfold_protocol::FrameStats;
use std::fmt::Write;

/// What is kept of each frame for the report (images are written out, not kept).
#[derive(Debug, Clone)]
pub struct FrameRecord {
    pub frame: u64,
    pub latency_ms: f64,
    pub interval_ms: Option<f64>,
    pub latency_frames: u32,
    pub sink_bytes: u64,
    pub stats: Vec<FrameStats>,
}

/// Collects frame records as they arrive.
#[derive(Debug, Default)]
pub struct Report {
    pub frames: Vec<FrameRecord>,
    last_received: Option<std::time::Instant>,
}

impl Report {
    pub fn record(&mut self, r: &FrameResult) {
        let interval_ms = self
            .last_received
            .map(|t| r.received_at.saturating_duration_since(t).as_secs_f64() * 1e3);
        self.last_received = Some(r.received_at);
        let mut stats = r.stats.clone();
        stats.sort_by(|a, b| a.daemon_id.cmp(&b.daemon_id));
        self.frames.push(FrameRecord {
            frame: r.frame,
            latency_ms: r
                .received_at
                .saturating_duration_since(r.requested_at)
                .as_secs_f64()
                * 1e3,
            interval_ms,
            latency_frames: r.latency_frames,
            sink_bytes: r.sink_bytes,
            stats,
        });
    }

    /// The per-stage table: one row per daemon, means over frames.
    pub fn table(&self, plan: &Plan) -> String {
        let mut out = String::new();
        let n = self.frames.len().max(1) as f64;
        let mut ids: Vec<String> = plan.nodes.iter().map(|n| n.node.clone()).collect();
        ids.extend(plan.stages.iter().map(|s| s.compositor.clone()));
        let _ = writeln!(
            out,
            "{:<14} {:>6} {:>8} {:>8} {:>8} {:>8} {:>8} {:>9} {:>8} {:>10}",
            "daemon",
            "lights",
            "passes",
            "shadow",
            "eye",
            "readbk",
            "pack",
            "composite",
            "total",
            "bytes out"
        );
        for id in &ids {
            let rows: Vec<&FrameStats> = self
                .frames
                .iter()
                .flat_map(|f| f.stats.iter().filter(|s| &s.daemon_id == id))
                .collect();
            let mean =
                |f: &dyn Fn(&FrameStats) -> u64| rows.iter().map(|s| f(s) as f64).sum::<f64>() / n;
            let ms = |us: f64| format!("{:.1}", us / 1e3);
            let lights = plan
                .nodes
                .iter()
                .find(|p| &p.node == id)
                .map_or("-".to_string(), |p| p.lights.len().to_string());
            let _ = writeln!(
                out,
                "{:<14} {:>6} {:>8.1} {:>8} {:>8} {:>8} {:>8} {:>9} {:>8} {:>10.0}",
                id,
                lights,
                mean(&|s| s.shadow_passes as u64),
                ms(mean(&|s| s.shadow_us)),
                ms(mean(&|s| s.eye_us)),
                ms(mean(&|s| s.readback_us)),
                ms(mean(&|s| s.pack_us)),
                ms(mean(&|s| s.composite_us)),
                ms(mean(&|s| s.total_us)),
                mean(&|s| s.bytes_out),
            );
        }
        out
    }

    /// One line per frame: latency, interval, frames in flight.
    pub fn frame_lines(&self) -> String {
        let mut out = String::new();
        for f in &self.frames {
            let _ = writeln!(
                out,
                "frame {:>4}: latency {:>8.1} ms ({} frames)  interval {}  sink {} bytes",
                f.frame,
                f.latency_ms,
                f.latency_frames,
                f.interval_ms
                    .map_or("-".to_string(), |i| format!("{i:.1} ms")),
                f.sink_bytes
            );
        }
        out
    }

    /// Summary: mean latency, mean frame interval, node-seconds per frame.
    pub fn summary(&self, plan: &Plan) -> String {
        let n = self.frames.len().max(1) as f64;
        let latency = self.frames.iter().map(|f| f.latency_ms).sum::<f64>() / n;
        let intervals: Vec<f64> = self.frames.iter().filter_map(|f| f.interval_ms).collect();
        let node_ids: Vec<&str> = plan.nodes.iter().map(|p| p.node.as_str()).collect();
        let node_seconds = self
            .frames
            .iter()
            .flat_map(|f| {
                f.stats
                    .iter()
                    .filter(|s| node_ids.contains(&s.daemon_id.as_str()))
            })
            .map(|s| s.total_us as f64 / 1e6)
            .sum::<f64>()
            / n;
        let mut s = format!(
            "{} frame(s): mean latency {:.1} ms, node-seconds per frame {:.3}",
            self.frames.len(),
            latency,
            node_seconds
        );
        if !intervals.is_empty() {
            let mean = intervals.iter().sum::<f64>() / intervals.len() as f64;
            let _ = write!(
                s,
                ", mean frame interval {mean:.1} ms ({:.2} frames/s)",
                1e3 / mean
            );
        }
        s
    }
}
