//! The report of `lightfold soak`: what each injected fault led to, measured after the run from
//! the frames delivered, the coordinator's incidents and epochs and the injector's record — a
//! table of (metric, value) rows, a per-daemon table and per-fault and per-epoch rows — printed
//! on stdout and written as CSV and Markdown, with the failures that fail the soak.

use super::{Args, DaemonInfo, Delivery, Fault, Kind, Machine};
use crate::check::Check;
use anyhow::Context;
use lightfold_coordinator::control::{ControlOptions, Incident, IncidentKind, LiveSummary};
use lightfold_protocol::stats;
use lightfold_scene::Scene;
use lightfold_telemetry::outln;
use std::fmt::Write as _;
use std::path::Path;
use std::time::{Duration, Instant};

/// What the soak recorded, for the report.
pub(crate) struct ReportInput<'a> {
    pub args: &'a Args,
    pub scene: &'a Scene,
    pub nodes: usize,
    pub compositors: usize,
    pub control: ControlOptions,
    pub machine: &'a Machine,
    pub requested: u64,
    pub deliveries: &'a [Delivery],
    pub checks: &'a [Check],
    pub summary: &'a LiveSummary,
    pub faults: &'a [Fault],
    pub daemons: &'a [DaemonInfo],
    pub run_error: Option<&'a str>,
    pub run_time: Duration,
    pub notes: &'a [String],
    pub interrupted: bool,
}

/// What a fault led to, as measured after the run.
#[derive(Debug)]
struct Outcome {
    /// Signal → the coordinator's `Lost` incident for the daemon.
    lost: Option<Duration>,
    next_frame: Option<Duration>,
    fresh_frame: Option<Duration>,
    back: Option<Duration>,
}

/// How long a SIGSTOP lasted against the heartbeat timeout.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Stall {
    /// Shorter than the timeout: must not be declared lost.
    Short,
    /// At least the timeout but shorter than `sure`: the first unanswered heartbeat may go out
    /// up to one interval after the stop, so either outcome is right.
    Window,
    /// At least the timeout + one heartbeat interval + two loop ticks: must be declared lost.
    Long,
}

/// The soak's figures: one table of (metric, value) rows, the per-daemon table, and the
/// per-fault and per-epoch rows for the CSV files.
#[derive(Debug, Default)]
pub(crate) struct Report {
    title: String,
    rows: Vec<(String, String)>,
    daemons: Vec<[String; 6]>,
    faults: Vec<Vec<String>>,
    epochs: Vec<Vec<String>>,
    pub failures: Vec<String>,
}

fn ms(d: Duration) -> String {
    format!("{:.0}", d.as_secs_f64() * 1000.0)
}

fn secs(d: Duration) -> String {
    format!("{:.2} s", d.as_secs_f64())
}

/// "p50 / p95 / max ms (n = …)" of some durations (nearest-rank percentiles).
fn spread(v: &[Duration]) -> String {
    let pct = |p| stats::percentile_nearest_rank(v, p);
    match (pct(0.5), pct(0.95), v.iter().max()) {
        (Some(a), Some(b), Some(m)) => {
            format!("{} / {} / {} ms (n = {})", ms(a), ms(b), ms(*m), v.len())
        }
        _ => "– (n = 0)".into(),
    }
}

/// What an epoch was planned for: the first cause in its reason ("X lost: …", "X rejoined",
/// "frame failure: …", each maybe followed by "; then …").
fn replan_cause(reason: &str) -> &'static str {
    let first = reason.split("; then").next().unwrap_or(reason);
    if first.starts_with("frame failure") {
        "frame failure"
    } else if first.contains(" lost: ") {
        "loss"
    } else if first.trim_end().ends_with(" rejoined") {
        "rejoin"
    } else if first.starts_with("new light colours") {
        "steering"
    } else {
        "other"
    }
}

/// The faults with what each led to, and the heartbeat bounds their stalls are judged by.
struct Measured<'a> {
    i: &'a ReportInput<'a>,
    /// The end of the run, for a fault no later one on its daemon bounds.
    end: Instant,
    /// The heartbeat timeout, and the stall at or over which a loss is sure.
    hb: Duration,
    sure: Duration,
    /// The coordinator's `Lost` incidents.
    lost_incidents: Vec<&'a Incident>,
    /// Per fault, what it led to.
    outcomes: Vec<Outcome>,
}

impl<'a> Measured<'a> {
    /// Matches each fault with the `Lost` incident and the frames that followed it.
    fn measure(i: &'a ReportInput<'a>, end: Instant) -> Measured<'a> {
        let hb = i.control.heartbeat_timeout;
        let sure = hb + i.control.heartbeat + Duration::from_millis(100);
        let lost_incidents: Vec<&Incident> = i
            .summary
            .incidents
            .iter()
            .filter(|x| matches!(x.kind, IncidentKind::Lost { .. }))
            .collect();
        let id_of = |f: &Fault| i.daemons[f.daemon].id.as_str();
        let outcomes: Vec<Outcome> = (0..i.faults.len())
            .map(|k| {
                let f = &i.faults[k];
                // The fault's window on its daemon: from the signal to the next fault on it.
                let until = i.faults[k + 1..]
                    .iter()
                    .find(|g| g.daemon == f.daemon)
                    .map_or(end, |g| g.at);
                let lost_at = lost_incidents
                    .iter()
                    .find(|x| x.daemon == id_of(f) && x.at >= f.at && x.at < until)
                    .map(|x| x.at);
                let first = |p: &dyn Fn(&Delivery) -> bool| {
                    i.deliveries
                        .iter()
                        .find(|d| p(d))
                        .map(|d| d.at.duration_since(f.at))
                };
                Outcome {
                    lost: lost_at.map(|t| t.duration_since(f.at)),
                    next_frame: first(&|d| d.at > f.at),
                    fresh_frame: first(&|d| d.requested_at > f.at),
                    back: f
                        .back
                        .zip(f.resumed)
                        .map(|(b, r)| b.saturating_duration_since(r)),
                }
            })
            .collect();
        Measured {
            i,
            end,
            hb,
            sure,
            lost_incidents,
            outcomes,
        }
    }

    fn id_of(&self, f: &Fault) -> &'a str {
        self.i.daemons[f.daemon].id.as_str()
    }

    /// A SIGSTOP's length against the heartbeat timeout; `None` for another signal.
    fn stall(&self, k: &Kind) -> Option<Stall> {
        match k {
            Kind::Stop(d) if *d < self.hb => Some(Stall::Short),
            Kind::Stop(d) if *d < self.sure => Some(Stall::Window),
            Kind::Stop(_) => Some(Stall::Long),
            _ => None,
        }
    }

    /// The durations `get` measures of the faults of a kind `pred` accepts.
    fn pick(
        &self,
        pred: &dyn Fn(&Kind) -> bool,
        get: &dyn Fn(&Outcome) -> Option<Duration>,
    ) -> Vec<Duration> {
        self.i
            .faults
            .iter()
            .zip(&self.outcomes)
            .filter(|(f, _)| pred(&f.kind))
            .filter_map(|(_, o)| get(o))
            .collect()
    }

    /// The faults of a kind `pred` accepts.
    fn count(&self, pred: &dyn Fn(&Kind) -> bool) -> usize {
        self.i.faults.iter().filter(|f| pred(&f.kind)).count()
    }

    /// The faults of a kind `pred` accepts that their daemon was declared lost for.
    fn lost_count(&self, pred: &dyn Fn(&Kind) -> bool) -> usize {
        self.pick(pred, &|o: &Outcome| o.lost).len()
    }

    /// The faults (from 1) that must have been detected as losses and were not.
    fn missed(&self) -> Vec<usize> {
        let must_lose = |k: &Kind| !matches!(self.stall(k), Some(Stall::Short | Stall::Window));
        self.i
            .faults
            .iter()
            .zip(&self.outcomes)
            .enumerate()
            .filter(|(_, (f, o))| must_lose(&f.kind) && o.lost.is_none())
            .map(|(k, _)| k + 1)
            .collect()
    }

    /// The daemons of losses no fault explains: outside [signal, back in a frame] of every
    /// fault on it.
    fn stray(&self) -> Vec<&'a str> {
        let explained = |x: &Incident| {
            self.i.faults.iter().any(|f| {
                self.id_of(f) == x.daemon && x.at >= f.at && x.at <= f.back.unwrap_or(self.end)
            })
        };
        self.lost_incidents
            .iter()
            .filter(|x| !explained(x))
            .map(|x| x.daemon.as_str())
            .collect()
    }
}

/// The delivered frames, counted and checked.
struct Frames<'a> {
    /// Distinct frame numbers delivered.
    distinct: usize,
    out_of_order: usize,
    duplicated: usize,
    /// Frames requested and never delivered.
    lost: u64,
    wrong: Vec<&'a Check>,
    unchecked: usize,
    /// The largest share of channels outside the bound, and energy ratio off 1, of any frame.
    worst_outside: f64,
    worst_energy: f64,
}

impl<'a> Frames<'a> {
    fn count(i: &'a ReportInput<'a>) -> Frames<'a> {
        let mut numbers: Vec<u64> = i.deliveries.iter().map(|d| d.frame).collect();
        let out_of_order = numbers.windows(2).filter(|w| w[1] <= w[0]).count();
        numbers.sort_unstable();
        let before = numbers.len();
        numbers.dedup();
        let duplicated = before - numbers.len();
        let in_range = numbers.iter().filter(|&&n| n <= i.requested).count() as u64;
        let worst_outside = i
            .checks
            .iter()
            .map(|c| c.outside as f64 / c.channels.max(1) as f64)
            .fold(0.0f64, f64::max);
        let worst_energy = i
            .checks
            .iter()
            .map(|c| (c.energy_ratio - 1.0).abs())
            .fold(0.0f64, f64::max);
        Frames {
            distinct: numbers.len(),
            out_of_order,
            duplicated,
            lost: i.requested.saturating_sub(in_range),
            wrong: i.checks.iter().filter(|c| !c.ok).collect(),
            unchecked: i.deliveries.len().saturating_sub(i.checks.len()),
            worst_outside,
            worst_energy,
        }
    }
}

impl Report {
    pub(crate) fn build(i: &ReportInput<'_>) -> Report {
        let end = Instant::now();
        let m = Measured::measure(i, end);
        let frames = Frames::count(i);
        let mut r = Report {
            title: title(i, m.hb),
            ..Report::default()
        };
        frame_rows(&m, &frames, &mut r.rows);
        detection_rows(&m, &mut r.rows);
        recovery_rows(&m, &mut r.rows);
        r.tables(&m);
        r.failures = failures(i, &frames);
        r
    }

    /// The per-daemon table, and the per-fault and per-epoch rows (seconds since the first
    /// fault).
    fn tables(&mut self, m: &Measured<'_>) {
        let i = m.i;
        for d in i.daemons {
            let faults = i.faults.iter().filter(|f| m.id_of(f) == d.id).count();
            self.daemons.push([
                d.id.clone(),
                d.role.to_string(),
                d.starts.to_string(),
                faults.to_string(),
                format!("{:.1}", d.hwm_kib as f64 / 1024.0),
                format!("{:.1}", d.cpu_done),
            ]);
        }
        let t0 = i.faults.first().map_or(m.end, |f| f.at);
        let since = |t: Instant| format!("{:.3}", t.saturating_duration_since(t0).as_secs_f64());
        for (k, (f, o)) in i.faults.iter().zip(&m.outcomes).enumerate() {
            let opt = |d: Option<Duration>| d.map_or(String::new(), ms);
            self.faults.push(vec![
                (k + 1).to_string(),
                since(f.at),
                m.id_of(f).to_string(),
                f.kind.name().to_string(),
                match f.kind {
                    Kind::Stop(d) => ms(d),
                    _ => String::new(),
                },
                opt(f.exited.map(|e| e.saturating_duration_since(f.at))),
                opt(f.resumed.map(|e| e.saturating_duration_since(f.at))),
                opt(o.lost),
                opt(o.next_frame),
                opt(o.fresh_frame),
                opt(o.back),
                f.notes.join(" | "),
            ]);
        }
        for e in &i.summary.epochs {
            self.epochs.push(vec![
                e.epoch.to_string(),
                since(e.at),
                ms(e.configure),
                e.nodes.to_string(),
                e.stages.to_string(),
                e.k.to_string(),
                e.lights_moved.to_string(),
                e.reason.clone(),
            ]);
        }
    }

    pub(crate) fn print(&self) {
        outln!("\n{}\n", self.title);
        let wk = self
            .rows
            .iter()
            .map(|(k, _)| k.chars().count())
            .max()
            .unwrap_or(0);
        for (k, v) in &self.rows {
            outln!("{k:<wk$}  {v}");
        }
        outln!(
            "\n{:<8} {:<10} {:>9} {:>6} {:>13} {:>8}",
            "daemon",
            "role",
            "processes",
            "faults",
            "peak RSS MiB",
            "CPU s"
        );
        for d in &self.daemons {
            outln!(
                "{:<8} {:<10} {:>9} {:>6} {:>13} {:>8}",
                d[0],
                d[1],
                d[2],
                d[3],
                d[4],
                d[5]
            );
        }
        for f in &self.failures {
            outln!("FAILED: {f}");
        }
    }

    pub(crate) fn write(&self, dir: &Path) -> anyhow::Result<()> {
        write_csv(
            &dir.join("soak.csv"),
            &["metric", "value"],
            self.rows.iter().map(|(k, v)| vec![k.clone(), v.clone()]),
        )?;
        write_csv(
            &dir.join("daemons.csv"),
            &[
                "daemon",
                "role",
                "processes",
                "faults",
                "peak_rss_mib",
                "cpu_s",
            ],
            self.daemons.iter().map(|d| d.to_vec()),
        )?;
        write_csv(
            &dir.join("faults.csv"),
            &[
                "fault",
                "at_s",
                "daemon",
                "signal",
                "stall_ms",
                "exited_ms",
                "running_again_ms",
                "detected_ms",
                "next_frame_ms",
                "first_new_frame_ms",
                "folded_back_ms",
                "notes",
            ],
            self.faults.iter().cloned(),
        )?;
        write_csv(
            &dir.join("epochs.csv"),
            &[
                "epoch",
                "at_s",
                "configure_ms",
                "nodes",
                "stages",
                "k",
                "lights_moved",
                "reason",
            ],
            self.epochs.iter().cloned(),
        )?;
        let mut md = format!("{}\n\n| metric | value |\n|---|---|\n", self.title);
        for (k, v) in &self.rows {
            let _ = writeln!(md, "| {} | {} |", md_cell(k), md_cell(v));
        }
        md.push_str(
            "\n| daemon | role | processes | faults | peak RSS (VmHWM, MiB) | CPU s |\n\
             |---|---|---:|---:|---:|---:|\n",
        );
        for d in &self.daemons {
            let _ = writeln!(md, "| {} |", d.join(" | "));
        }
        for f in &self.failures {
            let _ = writeln!(md, "\n**FAILED:** {}", md_cell(f));
        }
        std::fs::write(dir.join("soak.md"), md)?;
        Ok(())
    }
}

/// The report's title: the command, the scene, the cluster and the machine.
fn title(i: &ReportInput<'_>, hb: Duration) -> String {
    let (w, h) = (i.scene.camera.width, i.scene.camera.height);
    let m = i.machine;
    format!(
        "`lightfold soak --faults {} --seed {}{}`: scene {} {w}x{h}, {} light samples, K = {}, \
         {} render nodes + {} compositors, heartbeat {} ms / timeout {} ms; {} ({} cores, \
         {:.0} GiB), frames checked on {}",
        i.args.faults,
        i.args.seed,
        if i.args.steer_every > 0 {
            format!(" --steer-every {}", i.args.steer_every)
        } else {
            String::new()
        },
        i.scene.name,
        i.summary.plan.as_ref().map_or(0, |p| p.active.len()),
        i.args.lights_per_node,
        i.nodes,
        i.compositors,
        i.control.heartbeat.as_millis(),
        hb.as_millis(),
        m.cpu,
        m.cores,
        m.memory_gib,
        m.checker
    )
}

/// The rows of the faults injected, the run and the frames.
fn frame_rows(m: &Measured<'_>, frames: &Frames<'_>, rows: &mut Vec<(String, String)>) {
    let i = m.i;
    let (hb, sure) = (m.hb, m.sure);
    let is = |c: Stall| move |k: &Kind| m.stall(k) == Some(c);
    let machine = i.machine;
    let load_mean = stats::mean(&machine.load).unwrap_or(0.0);
    let load_max = machine.load.iter().copied().fold(0.0f64, f64::max);
    let mut row = |k: String, v: String| rows.push((k, v));
    row(
        "faults injected".into(),
        format!(
            "{} ({} SIGKILL, {} SIGSTOP, {} SIGTERM)",
            i.faults.len(),
            m.count(&|k| *k == Kind::Kill),
            m.count(&|k| matches!(k, Kind::Stop(_))),
            m.count(&|k| *k == Kind::Term)
        ),
    );
    row(
        "SIGSTOP lengths".into(),
        format!(
            "{} shorter than {}, {} from {} to {}, {} of {} or more",
            m.count(&is(Stall::Short)),
            secs(hb),
            m.count(&is(Stall::Window)),
            secs(hb),
            secs(sure),
            m.count(&is(Stall::Long)),
            secs(sure)
        ),
    );
    row(
        "run time".into(),
        format!(
            "{:.1} s{}; load average {load_mean:.1} mean, {load_max:.1} max",
            i.run_time.as_secs_f64(),
            if i.interrupted { " (interrupted)" } else { "" }
        ),
    );
    row("frames requested".into(), i.requested.to_string());
    row("frames delivered".into(), i.deliveries.len().to_string());
    row("frames lost".into(), frames.lost.to_string());
    row("frames duplicated".into(), frames.duplicated.to_string());
    row(
        "frames out of order".into(),
        frames.out_of_order.to_string(),
    );
    // The session's target: no gap between delivered frames above 2 s plus one frame interval.
    let gaps: Vec<Duration> = i
        .deliveries
        .windows(2)
        .map(|w| w[1].at.saturating_duration_since(w[0].at))
        .collect();
    let typical = stats::median(&gaps).unwrap_or_default();
    let bar = Duration::from_secs(2) + typical;
    let largest = gaps.iter().max().copied().unwrap_or_default();
    row(
        "largest gap between delivered frames".into(),
        format!(
            "{:.2} s (median interval {:.3} s; {} gap(s) over 2 s + one interval)",
            largest.as_secs_f64(),
            typical.as_secs_f64(),
            gaps.iter().filter(|g| **g > bar).count()
        ),
    );
    row(
        "frames wrong".into(),
        format!(
            "{} of {} checked (worst frame: {:.3} % of channels outside the bound; energy off by \
             {:.3} %)",
            frames.wrong.len(),
            i.checks.len(),
            frames.worst_outside * 100.0,
            frames.worst_energy * 100.0
        ),
    );
    row(
        "frame rate".into(),
        format!(
            "{:.2} frames/s over the run",
            frames.distinct as f64 / i.run_time.as_secs_f64().max(1e-9)
        ),
    );
}

/// The rows of how faults were detected: signal to `Lost` by kind, process exits, stalls
/// ridden out, and losses missed or unexplained.
fn detection_rows(m: &Measured<'_>, rows: &mut Vec<(String, String)>) {
    let i = m.i;
    let (hb, sure) = (m.hb, m.sure);
    let kill = |k: &Kind| *k == Kind::Kill;
    let term = |k: &Kind| *k == Kind::Term;
    let is = |c: Stall| move |k: &Kind| m.stall(k) == Some(c);
    let lost = |o: &Outcome| o.lost;
    let missed = m.missed();
    let stray = m.stray();
    let mut row = |k: String, v: String| rows.push((k, v));
    row(
        "detection (p50 / p95 / max): SIGKILL".into(),
        spread(&m.pick(&kill, &lost)),
    );
    row("detection: SIGTERM".into(), spread(&m.pick(&term, &lost)));
    row(
        format!("detection: SIGSTOP ≥ {}", secs(sure)),
        spread(&m.pick(&is(Stall::Long), &lost)),
    );
    row(
        format!("detection: SIGSTOP {}–{}", secs(hb), secs(sure)),
        format!(
            "{} ({} of {} declared lost)",
            spread(&m.pick(&is(Stall::Window), &lost)),
            m.lost_count(&is(Stall::Window)),
            m.count(&is(Stall::Window))
        ),
    );
    let exits = |pred: &dyn Fn(&Kind) -> bool| {
        i.faults
            .iter()
            .filter(|f| pred(&f.kind))
            .filter_map(|f| f.exited.map(|e| e.saturating_duration_since(f.at)))
            .collect::<Vec<Duration>>()
    };
    row(
        "process exit (signal → reaped): SIGKILL".into(),
        spread(&exits(&kill)),
    );
    row("process exit: SIGTERM".into(), spread(&exits(&term)));
    row(
        format!("SIGSTOP < {} ridden out (not declared lost)", secs(hb)),
        format!(
            "{} of {} ({} declared lost)",
            m.count(&is(Stall::Short)) - m.lost_count(&is(Stall::Short)),
            m.count(&is(Stall::Short)),
            m.lost_count(&is(Stall::Short))
        ),
    );
    row(
        "losses expected but not detected".into(),
        if missed.is_empty() {
            "0".into()
        } else {
            format!("{} (faults {missed:?})", missed.len())
        },
    );
    row(
        "losses no fault explains".into(),
        if stray.is_empty() {
            "0".into()
        } else {
            format!("{} ({})", stray.len(), stray.join(", "))
        },
    );
}

/// The rows of recovery (fault to frames, daemon back in a frame), re-plans, incidents, failed
/// restarts, and the run's error and notes.
fn recovery_rows(m: &Measured<'_>, rows: &mut Vec<(String, String)>) {
    let i = m.i;
    let hb = m.hb;
    let kill = |k: &Kind| *k == Kind::Kill;
    let term = |k: &Kind| *k == Kind::Term;
    let is = |c: Stall| move |k: &Kind| m.stall(k) == Some(c);
    let any = |_: &Kind| true;
    let causes = |c: &str| {
        i.summary
            .epochs
            .iter()
            .skip(1)
            .filter(|e| replan_cause(&e.reason) == c)
            .count()
    };
    let incidents = |p: &dyn Fn(&IncidentKind) -> bool| {
        i.summary.incidents.iter().filter(|x| p(&x.kind)).count()
    };
    let mut row = |k: String, v: String| rows.push((k, v));
    row(
        "recovery (p50 / p95 / max): fault → next frame delivered".into(),
        spread(&m.pick(&any, &|o| o.next_frame)),
    );
    let fresh = |o: &Outcome| o.fresh_frame;
    row(
        "recovery: fault → first frame requested after it delivered".into(),
        spread(&m.pick(&any, &fresh)),
    );
    row(
        "recovery to a new frame: SIGKILL".into(),
        spread(&m.pick(&kill, &fresh)),
    );
    row(
        "recovery to a new frame: SIGTERM".into(),
        spread(&m.pick(&term, &fresh)),
    );
    row(
        format!("recovery to a new frame: SIGSTOP < {}", secs(hb)),
        spread(&m.pick(&is(Stall::Short), &fresh)),
    );
    row(
        format!("recovery to a new frame: SIGSTOP ≥ {}", secs(hb)),
        spread(&m.pick(
            &|k| matches!(m.stall(k), Some(Stall::Window | Stall::Long)),
            &fresh,
        )),
    );
    row(
        "fold-back: daemon running again → in a delivered frame".into(),
        spread(&m.pick(&any, &|o| o.back)),
    );
    row(
        "faults whose daemon was not folded back".into(),
        i.faults
            .iter()
            .filter(|f| f.back.is_none())
            .count()
            .to_string(),
    );
    row(
        "re-plans".into(),
        format!(
            "{} ({} after a loss, {} after a rejoin, {} after a frame failure, {} for steered \
             colours, {} other)",
            i.summary.epochs.len().saturating_sub(1),
            causes("loss"),
            causes("rejoin"),
            causes("frame failure"),
            causes("steering"),
            causes("other")
        ),
    );
    row(
        "frame requests sent again".into(),
        i.summary.rerequested.to_string(),
    );
    row(
        "incidents: Lost / Slow / Rejoined".into(),
        format!(
            "{} / {} / {}",
            m.lost_incidents.len(),
            incidents(&|k| matches!(k, IncidentKind::Slow { .. })),
            incidents(&|k| *k == IncidentKind::Rejoined)
        ),
    );
    row(
        "restarts that failed (port busy, …)".into(),
        i.faults
            .iter()
            .map(|f| f.restart_tries)
            .sum::<u32>()
            .to_string(),
    );
    if let Some(e) = i.run_error {
        row("run error".into(), e.to_string());
    }
    for n in i.notes {
        row("note".into(), n.clone());
    }
}

/// What fails the soak: frames lost, delivered twice, out of order, unchecked or wrong, and a
/// failed run.
fn failures(i: &ReportInput<'_>, frames: &Frames<'_>) -> Vec<String> {
    let mut failures = Vec::new();
    let mut fail = |n: usize, what: &str| {
        if n > 0 {
            failures.push(format!("{n} frame(s) {what}"));
        }
    };
    fail(frames.lost as usize, "lost");
    fail(frames.duplicated, "delivered twice");
    fail(frames.out_of_order, "out of order");
    fail(frames.unchecked, "delivered but not checked");
    let wrong = &frames.wrong;
    if !wrong.is_empty() {
        let list: Vec<String> = wrong
            .iter()
            .take(5)
            .map(|c| {
                format!(
                    "frame {}: {} of {} channels outside, energy ratio {:.4}, worst |diff| {}{}",
                    c.frame,
                    c.outside,
                    c.channels,
                    c.energy_ratio,
                    c.worst,
                    c.error
                        .as_deref()
                        .map_or(String::new(), |e| format!(", {e}"))
                )
            })
            .collect();
        failures.push(format!(
            "{} frame(s) wrong ({})",
            wrong.len(),
            list.join("; ")
        ));
    }
    if let Some(e) = i.run_error {
        failures.push(format!("the run failed: {e}"));
    }
    failures
}

fn write_csv(
    path: &Path,
    header: &[&str],
    rows: impl Iterator<Item = Vec<String>>,
) -> anyhow::Result<()> {
    let mut w =
        csv::Writer::from_path(path).with_context(|| format!("cannot write {}", path.display()))?;
    w.write_record(header)?;
    for r in rows {
        w.write_record(&r)?;
    }
    w.flush()
        .with_context(|| format!("cannot write {}", path.display()))
}

fn md_cell(s: &str) -> String {
    s.replace('|', "\\|").replace('\n', " ")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn percentiles_are_nearest_rank() {
        let v: Vec<Duration> = (1..=20).map(Duration::from_millis).collect();
        let pct = stats::percentile_nearest_rank::<Duration>;
        assert_eq!(pct(&v, 0.5), Some(Duration::from_millis(10)));
        assert_eq!(pct(&v, 0.95), Some(Duration::from_millis(19)));
        assert_eq!(pct(&v, 1.0), Some(Duration::from_millis(20)));
        assert_eq!(pct(&[], 0.5), None);
        assert_eq!(spread(&[]), "– (n = 0)");
        assert_eq!(spread(&v), "10 / 19 / 20 ms (n = 20)");
    }

    #[test]
    fn replans_are_classified_by_their_first_cause() {
        assert_eq!(
            replan_cause("node-1 lost: its control link ended: x"),
            "loss"
        );
        assert_eq!(
            replan_cause("node-1 lost: no answer; then a daemon rejoined"),
            "loss"
        );
        assert_eq!(replan_cause("comp-2 rejoined"), "rejoin");
        assert_eq!(replan_cause("comp-2 rejoined; then node-1 lost"), "rejoin");
        assert_eq!(
            replan_cause("frame failure: comp-1 reported Timeout"),
            "frame failure"
        );
        assert_eq!(
            replan_cause(
                "new light colours at frame 41 split the colour group of node-0: re-planning"
            ),
            "steering"
        );
    }
}
