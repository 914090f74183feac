//! What the coordinator tells its operator about the cluster it drives: the adapter every node
//! renders on (a warning when one renders in software), the cluster's metrics, and one JSON line
//! per frame (`--stats FILE`); after a run, what it survived (lost and rejoined daemons, slow
//! frames, re-plans).

use crate::control::{FrameResult, IncidentKind, LiveSummary, Session};
use crate::report::FrameRecord;
use anyhow::Context;
use lightfold_protocol::{Capabilities, Role};
use std::io::Write;
use std::path::Path;
use std::time::Instant;

/// Whether a registered node renders on a software rasteriser. Nodes report only the adapter's
/// name, which names every software rasteriser wgpu can land on (`lightfold_telemetry::adapter`).
pub fn is_software(caps: &Capabilities) -> bool {
    caps.role == Role::Node && lightfold_telemetry::is_software_rasteriser(&caps.adapter, false)
}

/// The nodes' adapters: a table with `verbose`, else one line per kind of adapter; then a note
/// when every node renders on the CPU, a warning when some do. Also sets the
/// `lightfold_daemons` gauges.
pub fn adapters(session: &Session, verbose: bool) -> String {
    let nodes: Vec<&Capabilities> = session
        .daemons
        .values()
        .map(|d| &d.caps)
        .filter(|c| c.role == Role::Node)
        .collect();
    let compositors = session.daemons.len() - nodes.len();
    let software = nodes.iter().filter(|c| is_software(c)).count();
    lightfold_telemetry::record::daemons("node", true, software);
    lightfold_telemetry::record::daemons("node", false, nodes.len() - software);
    lightfold_telemetry::record::daemons("compositor", false, compositors);
    describe_adapters(&nodes, verbose)
}

/// What [`adapters`] says of `nodes`.
fn describe_adapters(nodes: &[&Capabilities], verbose: bool) -> String {
    let software = nodes.iter().filter(|c| is_software(c)).count();
    let mut out = String::new();
    if verbose {
        let mut t = comfy_table::Table::new();
        t.load_style(comfy_table::presets::NOTHING);
        t.set_header(["node", "adapter", "backend", "renders on", "threads"]);
        for c in nodes {
            let on = if is_software(c) {
                "CPU (software)"
            } else {
                "GPU"
            };
            t.add_row([
                c.daemon_id.clone(),
                c.adapter.clone(),
                c.backend.clone(),
                on.to_string(),
                c.threads.to_string(),
            ]);
        }
        out.push_str(&format!("adapters:\n{t}"));
    } else {
        // One line per kind of adapter, most common first.
        let mut kinds: Vec<((&str, &str), usize)> = Vec::new();
        for c in nodes {
            let k = (c.adapter.as_str(), c.backend.as_str());
            match kinds.iter_mut().find(|(x, _)| *x == k) {
                Some((_, n)) => *n += 1,
                None => kinds.push((k, 1)),
            }
        }
        kinds.sort_by_key(|k| std::cmp::Reverse(k.1));
        let parts: Vec<String> = kinds
            .iter()
            .map(|((adapter, backend), n)| format!("{n} × {adapter} ({backend})"))
            .collect();
        out.push_str(&format!("adapters: {}", parts.join(", ")));
    }
    if software > 0 {
        let names: Vec<&str> = nodes
            .iter()
            .filter(|c| is_software(c))
            .map(|c| c.daemon_id.as_str())
            .collect();
        let who = if software == nodes.len() {
            format!("all {software} node(s)")
        } else {
            format!(
                "{software} of {} node(s) ({})",
                nodes.len(),
                names.join(", ")
            )
        };
        // Said below; the log gets the same as an event. A cluster all on the CPU is one built
        // that way (a machine without a GPU, a test run): a note. Some nodes on the CPU beside
        // GPU nodes have most likely lost their GPU (a driver, a container's device): a warning.
        tracing::info!(nodes = %names.join(","), "{who} render on a software rasteriser");
        if software == nodes.len() {
            out.push_str(&format!(
                "\nnote: {who} render on a software rasteriser (the CPU), not a GPU: frames take \
                 seconds rather than milliseconds. Where a GPU is meant to be used, install its \
                 Vulkan driver, or start nodes with --require-gpu to refuse the CPU"
            ));
        } else {
            out.push_str(&format!(
                "\nwarning: {who} render on a software rasteriser (the CPU) while the others \
                 have a GPU: install the GPU's Vulkan driver on those machines (or check the \
                 container sees the device), or start nodes with --require-gpu to refuse this"
            ));
        }
    }
    out
}

/// `--stats FILE`: one JSON object per frame, flushed as each frame arrives (so a run that is
/// stopped keeps every frame it finished).
#[derive(Debug)]
pub struct StatsFile {
    out: Option<std::io::BufWriter<std::fs::File>>,
    start: Instant,
    path: String,
}

impl StatsFile {
    pub fn create(path: Option<&Path>, start: Instant) -> anyhow::Result<StatsFile> {
        let out = match path {
            Some(p) => Some(std::io::BufWriter::new(
                std::fs::File::create(p)
                    .with_context(|| format!("cannot create --stats {}", p.display()))?,
            )),
            None => None,
        };
        Ok(StatsFile {
            out,
            start,
            path: path.map(|p| p.display().to_string()).unwrap_or_default(),
        })
    }

    /// Records a frame in the metrics and, with `--stats`, as a line. A write error is logged
    /// once and ends the file, not the run.
    pub fn frame(&mut self, r: &FrameResult, rec: &FrameRecord) {
        let latency = r.received_at.saturating_duration_since(r.requested_at);
        lightfold_telemetry::record::frame_delivered(latency, r.sink_bytes, &r.stats);
        let Some(out) = &mut self.out else {
            return;
        };
        let line = frame_line(r, rec, self.start);
        let written = serde_json::to_writer(&mut *out, &line)
            .map_err(std::io::Error::other)
            .and_then(|()| out.write_all(b"\n"))
            .and_then(|()| out.flush());
        if let Err(e) = written {
            tracing::warn!(
                "cannot write --stats {}: {e}; no more frames go there",
                self.path
            );
            self.out = None;
        }
    }
}

fn ms(us: u64) -> f64 {
    us as f64 / 1e3
}

/// One frame as a JSON object (field names carry their units).
pub fn frame_line(r: &FrameResult, rec: &FrameRecord, start: Instant) -> serde_json::Value {
    let daemons: Vec<serde_json::Value> = rec
        .stats
        .iter()
        .map(|s| {
            serde_json::json!({
                "daemon": s.daemon_id,
                "shadow_ms": ms(s.shadow_us),
                "eye_ms": ms(s.eye_us),
                "readback_ms": ms(s.readback_us),
                "pack_ms": ms(s.pack_us),
                "send_ms": ms(s.send_us),
                "composite_ms": ms(s.composite_us),
                "total_ms": ms(s.total_us),
                "shadow_passes": s.shadow_passes,
                "lights": s.lights_rendered.len(),
                "bytes_out": s.bytes_out,
                "empty_bands": s.empty_bands,
                "saturated": s.saturated,
                "peak_rss_bytes": s.peak_rss_bytes,
            })
        })
        .collect();
    serde_json::json!({
        "frame": rec.frame,
        "wire_frame": r.wire_frame,
        "epoch": r.epoch,
        "requested_s": r.requested_at.saturating_duration_since(start).as_secs_f64(),
        "received_s": r.received_at.saturating_duration_since(start).as_secs_f64(),
        "latency_ms": rec.latency_ms,
        "interval_ms": rec.interval_ms,
        "latency_frames": rec.latency_frames,
        "sink_bytes": rec.sink_bytes,
        "width": r.image.width,
        "height": r.image.height,
        "daemons": daemons,
    })
}

/// Slow frames `(reported at, frame, waited ms, daemons waited on)` in one line: how many, the
/// first and the longest wait, and the daemons waited on most often.
fn slow_summary(
    slow: &[(std::time::Instant, u64, u128, Vec<&str>)],
    at: impl Fn(std::time::Instant) -> f64,
) -> Option<String> {
    let first = slow.first()?;
    let longest = slow.iter().max_by_key(|s| s.2)?;
    let mut often: Vec<(&str, usize)> = Vec::new();
    for who in slow.iter().flat_map(|s| &s.3) {
        match often.iter_mut().find(|(d, _)| d == who) {
            Some((_, n)) => *n += 1,
            None => often.push((who, 1)),
        }
    }
    often.sort_by(|a, b| b.1.cmp(&a.1).then(a.0.cmp(b.0)));
    let shown: Vec<String> = often
        .iter()
        .take(4)
        .map(|(d, n)| format!("{d} ({n})"))
        .collect();
    Some(format!(
        "\n  {:>7.2} s  slow: {} frame(s) waited past the slow threshold (first frame {}, {} ms; \
         longest frame {}, {} ms); waited on most: {}{}",
        at(first.0),
        slow.len(),
        first.1,
        first.2,
        longest.1,
        longest.2,
        shown.join(", "),
        if often.len() > shown.len() {
            format!(" and {} more", often.len() - shown.len())
        } else {
            String::new()
        }
    ))
}

/// What the run survived: one line per lost, stalled or rejoined daemon and per re-plan, and one
/// for all slow frames.
pub fn failover_summary(s: &LiveSummary, start: std::time::Instant) -> String {
    let mut out = String::new();
    let at = |t: std::time::Instant| t.saturating_duration_since(start).as_secs_f64();
    let lost = s
        .incidents
        .iter()
        .filter(|i| matches!(i.kind, IncidentKind::Lost { .. }))
        .count();
    out.push_str(&format!(
        "failover: {} frame(s) delivered, {} daemon(s) lost, {} re-plan(s), {} frame request(s) sent again",
        s.delivered,
        lost,
        s.epochs.len().saturating_sub(1),
        s.rerequested
    ));
    if s.tile_steps > 0 {
        let rows: Vec<String> = s
            .tile_rows
            .iter()
            .map(|r| format!("{}–{}", r[0], r[1]))
            .collect();
        out.push_str(&format!(
            "\ntiles: rows {} after {} balancing step(s)",
            rows.join(", "),
            s.tile_steps
        ));
    }
    if s.saturated > 0 {
        out.push_str(&format!(
            "\nsaturated: {} value(s) in {} frame(s) were clamped to their link format's range \
             (per daemon in --stats; a seed64 link's scale follows its measured maximum once a frame's reports are back, after --frames-in-flight frames)",
            s.saturated, s.saturated_frames
        ));
    }
    // Slow frames: one line for all of them.
    let mut slow: Vec<(std::time::Instant, u64, u128, Vec<&str>)> = Vec::new();
    for i in &s.incidents {
        let what = match &i.kind {
            IncidentKind::Lost { reason } => format!("lost: {reason}"),
            IncidentKind::Slow { frame, waited } => {
                match slow.iter_mut().find(|x| x.1 == *frame) {
                    Some(x) => x.3.push(&i.daemon),
                    None => slow.push((i.at, *frame, waited.as_millis(), vec![&i.daemon])),
                }
                continue;
            }
            IncidentKind::Rejoined => "rejoined".to_string(),
        };
        out.push_str(&format!("\n  {:>7.2} s  {}  {what}", at(i.at), i.daemon));
    }
    if let Some(line) = slow_summary(&slow, at) {
        out.push_str(&line);
    }
    if !s.stopped.is_empty() {
        out.push_str(&format!(
            "\n  stopping: {} stopped with the run (not lost){}",
            s.stopped.join(", "),
            match s.abandoned {
                0 => String::new(),
                n => format!("; {n} frame(s) not finished"),
            }
        ));
    }
    for e in s.epochs.iter().skip(1) {
        out.push_str(&format!(
            "\n  {:>7.2} s  epoch {}: {} node(s), {} stage(s), K = {}, {} light(s) moved, configured in {} ms ({})",
            at(e.at),
            e.epoch,
            e.nodes,
            e.stages,
            e.k,
            e.lights_moved,
            e.configure.as_millis(),
            e.reason
        ));
    }
    out
}

#[cfg(test)]
mod tests {
    use super::describe_adapters;
    use lightfold_protocol::{Capabilities, Role};

    fn node(id: &str, adapter: &str) -> Capabilities {
        Capabilities {
            adapter: adapter.into(),
            backend: "vulkan".into(),
            ..Capabilities::unmeasured(Role::Node, id)
        }
    }

    #[test]
    fn a_cluster_all_on_the_cpu_is_noted_and_a_mixed_one_warned_about() {
        let cpu = node("a", "llvmpipe (LLVM 15.0.6, 256 bits)");
        let cpu2 = node("b", "llvmpipe (LLVM 15.0.6, 256 bits)");
        let gpu = node("c", "NVIDIA H100 80GB HBM3");
        let all = describe_adapters(&[&cpu, &cpu2], false);
        assert!(
            all.contains("note: all 2 node(s) render on a software"),
            "{all}"
        );
        assert!(!all.contains("warning"), "{all}");
        let mixed = describe_adapters(&[&cpu, &gpu], false);
        assert!(mixed.contains("warning: 1 of 2 node(s) (a)"), "{mixed}");
        let none = describe_adapters(&[&gpu], false);
        assert!(
            !none.contains("note") && !none.contains("warning"),
            "{none}"
        );
    }
}
