//! Per-frame lines and summary tables of a coordinator run: render time per node, composite time
//! per stage, bytes per link, end-to-end latency and frame interval — every figure with its unit,
//! p50/p95 beside the means where there are frames enough, daemons in natural order (`comp-2`
//! before `comp-10`).

use crate::control::FrameResult;
use crate::plan::Plan;
use comfy_table::{CellAlignment, Table, presets};
use lightfold_protocol::FrameStats;
use lightfold_protocol::stats::{self, percentile_nearest_rank};
use std::cmp::Ordering;
use std::fmt::Write;

/// What is kept of each frame for the report (images are written out, not kept).
#[derive(Debug, Clone)]
pub struct FrameRecord {
    pub frame: u64,
    pub latency_ms: f64,
    pub interval_ms: Option<f64>,
    /// Frames requested after this one that were in flight when it arrived.
    pub latency_frames: u32,
    pub sink_bytes: u64,
    pub stats: Vec<FrameStats>,
}

impl FrameRecord {
    /// One line for the frame: `frame 3/200: latency 322.6 ms · interval 174.7 ms · …`, with
    /// `of` the frames the run asks for, when it knows.
    pub fn line(&self, of: Option<u32>) -> String {
        let mut s = match of {
            Some(n) => format!("frame {}/{n}: ", self.frame),
            None => format!("frame {}: ", self.frame),
        };
        let _ = write!(s, "latency {:.1} ms", self.latency_ms);
        match self.latency_frames {
            0 => {}
            1 => s.push_str(" (1 later frame in flight)"),
            n => {
                let _ = write!(s, " ({n} later frames in flight)");
            }
        }
        if let Some(i) = self.interval_ms {
            let _ = write!(s, " · interval {i:.1} ms");
        }
        let _ = write!(s, " · image {}", bytes(self.sink_bytes as f64));
        s
    }
}

/// Collects frame records as they arrive.
#[derive(Debug, Default)]
pub struct Report {
    pub frames: Vec<FrameRecord>,
    last_received: Option<std::time::Instant>,
}

/// Compares daemon ids (or any names) as people count: `comp-2` before `comp-10`, digits compared
/// by value.
pub fn natural_cmp(a: &str, b: &str) -> Ordering {
    let (mut a, mut b) = (a, b);
    loop {
        match (a.chars().next(), b.chars().next()) {
            (None, None) => return Ordering::Equal,
            (None, Some(_)) => return Ordering::Less,
            (Some(_), None) => return Ordering::Greater,
            (Some(x), Some(y)) if x.is_ascii_digit() && y.is_ascii_digit() => {
                let na = a.len() - a.trim_start_matches(|c: char| c.is_ascii_digit()).len();
                let nb = b.len() - b.trim_start_matches(|c: char| c.is_ascii_digit()).len();
                let (da, db) = (&a[..na], &b[..nb]);
                let (ta, tb) = (da.trim_start_matches('0'), db.trim_start_matches('0'));
                let by_value = ta.len().cmp(&tb.len()).then_with(|| ta.cmp(tb));
                // Equal values: fewer leading zeros first, so the order stays total.
                match by_value.then_with(|| na.cmp(&nb)) {
                    Ordering::Equal => {}
                    o => return o,
                }
                a = &a[na..];
                b = &b[nb..];
            }
            (Some(x), Some(y)) => {
                match x.cmp(&y) {
                    Ordering::Equal => {}
                    o => return o,
                }
                a = &a[x.len_utf8()..];
                b = &b[y.len_utf8()..];
            }
        }
    }
}

/// The mean of `v`, 0 when empty (a row's figures read "-" before they get here).
fn mean(v: &[f64]) -> f64 {
    stats::mean(v).unwrap_or(0.0)
}

/// A byte count with its unit (decimal, as the plan's MB): `512 B`, `36.9 kB`, `1.16 MB`.
pub fn bytes(b: f64) -> String {
    if b < 1e3 {
        format!("{b:.0} B")
    } else if b < 1e6 {
        format!("{:.1} kB", b / 1e3)
    } else if b < 1e9 {
        format!("{:.2} MB", b / 1e6)
    } else {
        format!("{:.2} GB", b / 1e9)
    }
}

/// Milliseconds as the table prints them: to 0.1 below 100, whole from 100.
fn ms_text(ms: f64) -> String {
    if ms >= 99.95 {
        format!("{ms:.0}")
    } else {
        format!("{ms:.1}")
    }
}

/// `mean ms, p50 ms, p95 ms` of `v` (the percentiles only with at least two values).
fn spread(v: &[f64]) -> String {
    let m = mean(v);
    match (
        percentile_nearest_rank(v, 0.5),
        percentile_nearest_rank(v, 0.95),
    ) {
        (Some(p50), Some(p95)) if v.len() >= 2 => {
            format!("mean {m:.1} ms, p50 {p50:.1} ms, p95 {p95:.1} ms")
        }
        _ => format!("{m:.1} ms"),
    }
}

impl Report {
    /// Keeps `r` (its timings, not its image) and returns what was kept.
    pub fn record(&mut self, r: &FrameResult) -> &FrameRecord {
        let interval_ms = self
            .last_received
            .map(|t| r.received_at.saturating_duration_since(t).as_secs_f64() * 1e3);
        self.last_received = Some(r.received_at);
        let mut stats = r.stats.clone();
        stats.sort_by(|a, b| natural_cmp(&a.daemon_id, &b.daemon_id));
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
        &self.frames[self.frames.len() - 1]
    }

    /// The per-daemon table (milliseconds to 0.1 below 100 ms, whole above, so that the
    /// columns stay narrow): render nodes then compositors, each in natural order, with means
    /// per frame over the frames the daemon reported (p50/p95 of its total with two frames or
    /// more) and its peak resident memory. Daemons lost on the way keep their rows.
    pub fn table(&self, plan: &Plan) -> String {
        let mut nodes: Vec<&str> = plan.nodes.iter().map(|n| n.node.as_str()).collect();
        let mut stages: Vec<&str> = plan.stages.iter().map(|s| s.compositor.as_str()).collect();
        let mut others: Vec<&str> = Vec::new();
        for s in self.frames.iter().flat_map(|f| &f.stats) {
            let id = s.daemon_id.as_str();
            if !nodes.contains(&id) && !stages.contains(&id) && !others.contains(&id) {
                others.push(id);
            }
        }
        for v in [&mut nodes, &mut stages, &mut others] {
            v.sort_by(|a, b| natural_cmp(a, b));
        }
        let spread = self.frames.len() >= 2;
        // Units under each name, so the columns stay narrow.
        let mut header = vec![
            "daemon",
            "lights",
            "shadow\npasses",
            "setup\nms",
            "shadow\nms",
            "eye\nms",
            "readback\nms",
            "pack\nms",
            "composite\nms",
            "total\nms",
        ];
        if spread {
            header.push("total\np50 / p95");
        }
        header.extend(["sent\nper frame", "peak\nRSS"]);
        let mut table = Table::new();
        table
            .load_style(presets::ASCII_MARKDOWN)
            .set_header(&header);
        let rows = nodes
            .iter()
            .map(|id| (id, Some(true)))
            .chain(stages.iter().map(|id| (id, Some(false))))
            .chain(others.iter().map(|id| (id, None)));
        for (id, is_node) in rows {
            let stats: Vec<&FrameStats> = self
                .frames
                .iter()
                .flat_map(|f| f.stats.iter().filter(|s| s.daemon_id == **id))
                .collect();
            let values = |f: &dyn Fn(&FrameStats) -> f64| -> Vec<f64> {
                stats.iter().map(|s| f(s)).collect()
            };
            let ms = |f: &dyn Fn(&FrameStats) -> u64| -> String {
                if stats.is_empty() {
                    "-".into()
                } else {
                    ms_text(mean(&values(&|s| f(s) as f64)) / 1e3)
                }
            };
            // What a role does not do reads "-" rather than 0.
            let node_only = |f: &dyn Fn(&FrameStats) -> u64| {
                if is_node == Some(false) {
                    "-".to_string()
                } else {
                    ms(f)
                }
            };
            let lights = plan
                .nodes
                .iter()
                .find(|p| p.node == **id)
                .map_or("-".to_string(), |p| p.lights.len().to_string());
            let passes = if is_node == Some(false) || stats.is_empty() {
                "-".to_string()
            } else {
                format!("{:.1}", mean(&values(&|s| s.shadow_passes as f64)))
            };
            let mut row = vec![
                id.to_string(),
                lights,
                passes,
                node_only(&|s| s.setup_us + s.pose_us),
                node_only(&|s| s.shadow_us),
                node_only(&|s| s.eye_us),
                node_only(&|s| s.readback_us),
                node_only(&|s| s.pack_us),
                if is_node == Some(true) {
                    "-".to_string()
                } else {
                    ms(&|s| s.composite_us)
                },
                ms(&|s| s.total_us),
            ];
            if spread {
                let totals = values(&|s| s.total_us as f64 / 1e3);
                let at = |p: f64| percentile_nearest_rank(&totals, p).map_or("-".into(), ms_text);
                row.push(format!("{} / {}", at(0.5), at(0.95)));
            }
            row.push(if stats.is_empty() {
                "-".into()
            } else {
                bytes(mean(&values(&|s| s.bytes_out as f64)))
            });
            let rss = stats.iter().map(|s| s.peak_rss_bytes).max().unwrap_or(0);
            row.push(if rss == 0 {
                "-".into()
            } else {
                format!("{:.0} MiB", rss as f64 / (1024.0 * 1024.0))
            });
            table.add_row(row);
        }
        for i in 1..header.len() {
            if let Some(c) = table.column_mut(i) {
                c.set_cell_alignment(CellAlignment::Right);
            }
        }
        format!(
            "per daemon, mean per frame over {} frame(s) (setup, shadow, eye, readback, pack: a \
             render node's steps, setup its CPU work before the passes;\ntotal: its whole frame, \
             waiting on inputs included):\n{table}",
            self.frames.len()
        )
    }

    /// One line per frame (latency, interval, image size).
    pub fn frame_lines(&self) -> String {
        let mut out = String::new();
        for f in &self.frames {
            let _ = writeln!(out, "{}", f.line(None));
        }
        out
    }

    /// Summary: latency and frame interval (mean, p50, p95), frames per second, node-seconds per
    /// frame.
    pub fn summary(&self, plan: &Plan) -> String {
        let n = self.frames.len().max(1) as f64;
        let latency: Vec<f64> = self.frames.iter().map(|f| f.latency_ms).collect();
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
        let image = mean(
            &self
                .frames
                .iter()
                .map(|f| f.sink_bytes as f64)
                .collect::<Vec<_>>(),
        );
        let mut s = format!(
            "{} frame(s): latency {} (request to complete image, up to {} frame(s) in flight)",
            self.frames.len(),
            spread(&latency),
            plan.frames_in_flight.max(1)
        );
        if !intervals.is_empty() {
            let _ = write!(
                s,
                "\nframe interval {} ({:.2} frames/s; the plan estimated {:.1} ms per frame)",
                spread(&intervals),
                1e3 / mean(&intervals),
                plan.est_frame_us as f64 / 1e3
            );
        }
        let _ = write!(
            s,
            "\nnode-seconds per frame {node_seconds:.3} s (render nodes' busy time) · image {} \
             per frame at the sink",
            bytes(image)
        );
        s
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_sort_as_people_count() {
        let mut v = vec!["comp-10", "comp-2", "comp-0", "node-1", "comp-1", "comp-02"];
        v.sort_by(|a, b| natural_cmp(a, b));
        assert_eq!(
            v,
            ["comp-0", "comp-1", "comp-2", "comp-02", "comp-10", "node-1"]
        );
        assert_eq!(natural_cmp("a", "a"), Ordering::Equal);
        assert_eq!(natural_cmp("a", "ab"), Ordering::Less);
        assert_eq!(natural_cmp("x9", "x10"), Ordering::Less);
    }

    #[test]
    fn percentiles_and_units() {
        let v: Vec<f64> = (1..=100).map(f64::from).collect();
        assert_eq!(percentile_nearest_rank(&v, 0.5), Some(50.0));
        assert_eq!(percentile_nearest_rank(&v, 0.95), Some(95.0));
        assert_eq!(percentile_nearest_rank(&[3.0], 0.95), Some(3.0));
        assert_eq!(percentile_nearest_rank::<f64>(&[], 0.5), None);
        assert_eq!(bytes(512.0), "512 B");
        assert_eq!(bytes(36864.0), "36.9 kB");
        assert_eq!(bytes(1_160_000.0), "1.16 MB");
        assert_eq!(spread(&[1.0]), "1.0 ms");
        assert!(spread(&[1.0, 3.0]).contains("p95 3.0 ms"));
    }
}
