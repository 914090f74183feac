//! What a coordinator's run shows its operator: the plan, the frames as they come (a progress
//! bar on a terminal, a line per frame on a log), every frame written as it completes, then the
//! frames, the timing table, the failover summary and the totals (`lightfold coordinator`,
//! `lightfold demo`'s coordinator).

use crate::control::{FrameResult, Session};
use crate::frames_out::{FramePattern, FrameWriter};
use crate::report::Report;
use crate::run::{RunOptions, RunOutcome};
use anyhow::{Context, bail};
use lightfold_scene::Scene;
use lightfold_telemetry::outln;
use std::path::PathBuf;
use std::time::Duration;
use tokio_util::sync::CancellationToken;

/// Where a job's results go and what it prints.
#[derive(Debug, Clone)]
pub struct JobOutput {
    /// The newest complete frame: PNG (sRGB at the scene's exposure) and EXR (linear radiance).
    pub out: PathBuf,
    pub exr: PathBuf,
    /// Every frame as it completes, when asked for.
    pub every: Option<FramePattern>,
    /// The last plan rendered with, as JSON.
    pub plan_json: Option<PathBuf>,
    /// One JSON line per frame (`StatsFile`).
    pub stats: Option<PathBuf>,
    /// The full plan and a line per frame, instead of the plan in a few lines.
    pub verbose: bool,
    /// A video assembled from the frame files after the run, at this many frames per second.
    pub video: Option<(PathBuf, f32)>,
    /// Stop the daemons after the run (otherwise they are detached, ready for the next).
    pub shutdown: bool,
}

/// A run stopped by its stop token (Ctrl-C, SIGTERM): not a failure of the command. The message
/// is the one line the run ends with.
#[derive(Debug)]
pub struct Interrupted(pub String);

impl std::fmt::Display for Interrupted {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.0)
    }
}

impl std::error::Error for Interrupted {}

/// A run's console and files, from before the first frame to the summary: [`Console::start`]
/// prints the adapters and opens the frame writer and stats file, [`Console::frame`] takes every
/// frame as the run delivers it (scripted frames through `run::render_until`, or the live
/// view's), [`Console::finish`] writes the plan and prints the summary.
#[allow(missing_debug_implementations)]
pub struct Console {
    job: JobOutput,
    start: std::time::Instant,
    serving: bool,
    frames: u32,
    report: Report,
    stats: crate::operator::StatsFile,
    progress: Progress,
    writer: FrameWriter,
}

impl Console {
    /// Before the first frame of `opts` (`serving`: the live view drives the frames, until
    /// stopped).
    pub fn start(
        session: &Session,
        scene: &Scene,
        opts: &RunOptions,
        job: JobOutput,
        serving: bool,
    ) -> anyhow::Result<Console> {
        let start = std::time::Instant::now();
        if let Some(p) = &job.every {
            p.create_dir()?;
        }
        outln!("{}", crate::operator::adapters(session, job.verbose));
        let stats = crate::operator::StatsFile::create(job.stats.as_deref(), start)?;
        lightfold_telemetry::health::set_serving(true);
        let progress = Progress::new(
            (!serving).then_some(opts.frames - opts.skip.len() as u32),
            std::io::IsTerminal::is_terminal(&std::io::stderr()),
        );
        let writer = FrameWriter::start(
            job.out.clone(),
            job.exr.clone(),
            job.every.clone(),
            scene.exposure,
        );
        Ok(Console {
            job,
            start,
            serving,
            frames: opts.frames,
            report: Report::default(),
            stats,
            progress,
            writer,
        })
    }

    /// A delivered frame: recorded, shown, written.
    pub fn frame(&mut self, frame: FrameResult) {
        let record = self.report.record(&frame);
        self.stats.frame(&frame, record);
        self.progress.frame(record);
        self.writer.send(frame);
    }

    /// After the run: the plan and summary printed, the daemons shut down (with
    /// `JobOutput::shutdown`) or detached, the video assembled; the run's error, if any, named.
    pub async fn finish(
        self,
        session: Session,
        outcome: RunOutcome,
        stop: &CancellationToken,
    ) -> anyhow::Result<()> {
        let Console {
            job,
            start,
            serving,
            frames,
            report,
            progress,
            writer,
            ..
        } = self;
        progress.finish();
        lightfold_telemetry::health::set_serving(false);
        let written = writer.finish();
        if let (Some(path), Some(plan)) = (&job.plan_json, &outcome.summary.plan) {
            let text = serde_json::to_string(plan).context("cannot write the plan as JSON")?;
            std::fs::write(path, text)
                .with_context(|| format!("cannot write {}", path.display()))?;
        }
        match &outcome.summary.plan {
            Some(plan) if job.verbose => outln!("{plan}"),
            Some(plan) => outln!("{}", plan.brief()),
            None => {}
        }
        if job.verbose && !report.frames.is_empty() {
            outln!("{}", report.frame_lines());
        }
        if let (Some(plan), false) = (&outcome.summary.plan, report.frames.is_empty()) {
            outln!("{}", report.table(plan));
            outln!("{}", report.summary(plan));
        }
        outln!(
            "{}",
            crate::operator::failover_summary(&outcome.summary, start)
        );
        if job.shutdown {
            session.shutdown().await;
        } else {
            session.detach();
        }
        let every = &job.every;
        if !written.skipped.is_empty() {
            let n = written.skipped.len();
            let shown: Vec<String> = written.skipped.iter().take(8).map(u64::to_string).collect();
            outln!(
                "warning: the files of {n} frame(s) were not written ({}{}): the disk was slower than \
                 the cluster for longer than the writer's queue holds; `--resume` renders them again",
                shown.join(", "),
                if n > 8 { ", …" } else { "" }
            );
        }
        if let Some(e) = written.error {
            return Err(e.context("writing frames"));
        }
        let delivered = outcome.summary.delivered;
        let of = if serving {
            String::new()
        } else {
            format!(" of {frames}")
        };
        if let Some(e) = outcome.error {
            if stop.is_cancelled() {
                return Err(Interrupted(format!(
                    "interrupted after {delivered}{of} frame(s); the frames done are written \
                     (while stopping: {e})"
                ))
                .into());
            }
            bail!("the run stopped after {delivered} frame(s): {e}");
        }
        if let (Some(p), true) = (every, written.frames > 0) {
            outln!(
                "wrote {} frame(s) as {}",
                written.frames,
                p.ffmpeg_input().replace(".png", ".{png,exr}")
            );
        }
        if stop.is_cancelled() && !serving {
            return Err(Interrupted(format!(
                "interrupted after {delivered}{of} frame(s); the frames done are written"
            ))
            .into());
        }
        if let (Some((video, rate)), Some(p)) = (&job.video, every) {
            crate::frames_out::assemble_video(p, video, *rate)?;
            outln!("wrote {}", video.display());
        }
        let (w, h) = written.size.context("no frame was rendered")?;
        outln!(
            "wrote {} and {} ({w}x{h}) in {:.2} s{}",
            job.out.display(),
            job.exr.display(),
            start.elapsed().as_secs_f64(),
            if serving { " (the view stopped)" } else { "" }
        );
        Ok(())
    }
}

/// How a run shows its frames while they come: a progress bar on a terminal; on a log (stderr
/// not a terminal) one line per frame, at most one a second for fast runs (the first and the
/// last frame always).
enum Progress {
    Bar(indicatif::ProgressBar),
    Lines {
        of: Option<u32>,
        last: Option<std::time::Instant>,
    },
    Quiet,
}

/// The least time between two frame lines on a log.
const LINE_EVERY: Duration = Duration::from_secs(1);

impl Progress {
    /// `frames`: how many the run renders (`None`: until stopped, the live view).
    fn new(frames: Option<u32>, terminal: bool) -> Progress {
        match frames {
            Some(n) if terminal && n > 1 => {
                let pb = indicatif::ProgressBar::new(n as u64);
                pb.set_style(
                    indicatif::ProgressStyle::with_template(
                        "{bar:40} {pos}/{len} frames {per_sec} eta {eta}",
                    )
                    .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
                );
                Progress::Bar(pb)
            }
            _ if terminal => Progress::Quiet,
            of => Progress::Lines { of, last: None },
        }
    }

    fn frame(&mut self, f: &crate::report::FrameRecord) {
        match self {
            Progress::Bar(pb) => pb.inc(1),
            Progress::Lines { of, last } => {
                let due = last.is_none_or(|t| t.elapsed() >= LINE_EVERY)
                    || of.is_some_and(|n| f.frame >= n as u64);
                if due {
                    *last = Some(std::time::Instant::now());
                    if lightfold_telemetry::logging::json() {
                        tracing::info!(
                            frame = f.frame,
                            latency_ms = f.latency_ms,
                            "{}",
                            f.line(*of)
                        );
                    } else {
                        eprintln!("{}", f.line(*of));
                    }
                }
            }
            Progress::Quiet => {}
        }
    }

    fn finish(self) {
        if let Progress::Bar(pb) = self {
            pb.finish_and_clear();
        }
    }
}
