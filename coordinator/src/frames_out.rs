//! Writing frames as they complete: `--out`/`--exr` always hold the newest complete frame
//! (written beside the target and renamed over it), and a camera path keeps every frame under
//! `--frame-pattern` (`out/frame-%04d` → `out/frame-0001.png` and `.exr`, …); `--video` then
//! assembles the PNGs with `ffmpeg` when it is on the PATH.

use crate::control::FrameResult;
use anyhow::{Context, bail};
use std::path::{Path, PathBuf};

/// The default `--frame-pattern`.
pub const DEFAULT_PATTERN: &str = "out/frame-%04d";

/// Where each frame goes: a path with one `%d` or `%0Nd` (the frame number, from 1), without an
/// extension (`.png` and `.exr` are added) — the pattern `ffmpeg -i` takes.
#[derive(Debug, Clone, PartialEq)]
pub struct FramePattern {
    prefix: String,
    width: usize,
    suffix: String,
}

impl FramePattern {
    pub fn parse(s: &str) -> anyhow::Result<FramePattern> {
        let Some(at) = s.find('%') else {
            bail!("frame pattern {s:?} has no %d (or %04d) for the frame number");
        };
        let rest = &s[at + 1..];
        let digits: String = rest.chars().take_while(char::is_ascii_digit).collect();
        let after = &rest[digits.len()..];
        let Some(suffix) = after.strip_prefix('d') else {
            bail!("frame pattern {s:?}: only %d or %0Nd may follow the %");
        };
        if suffix.contains('%') {
            bail!("frame pattern {s:?} has more than one %");
        }
        let width: usize = if digits.is_empty() {
            0
        } else {
            digits
                .parse()
                .ok()
                .filter(|w| *w <= 12)
                .with_context(|| format!("frame pattern {s:?}: a width of at most 12 digits"))?
        };
        if s[..at].is_empty() && suffix.is_empty() {
            bail!("frame pattern {s:?} names no file");
        }
        Ok(FramePattern {
            prefix: s[..at].to_string(),
            width,
            suffix: suffix.to_string(),
        })
    }

    /// Frame `n`'s path, with `extension`.
    pub fn path(&self, n: u64, extension: &str) -> PathBuf {
        PathBuf::from(format!(
            "{}{:0w$}{}.{extension}",
            self.prefix,
            n,
            self.suffix,
            w = self.width
        ))
    }

    /// The pattern for `ffmpeg -i` (the PNGs).
    pub fn ffmpeg_input(&self) -> String {
        let spec = if self.width > 0 {
            format!("%0{}d", self.width)
        } else {
            "%d".to_string()
        };
        format!("{}{spec}{}.png", self.prefix, self.suffix)
    }

    /// The frames of `1..=frames` whose PNG and EXR are both written (`--resume`). Frames are
    /// written beside their name and renamed into it, so a file under its name is complete; a
    /// frame with one of its two files is rendered again.
    pub fn complete(&self, frames: u32) -> Vec<u64> {
        (1..=u64::from(frames))
            .filter(|&n| self.path(n, "exr").is_file() && self.path(n, "png").is_file())
            .collect()
    }

    /// Creates the folder the frames go to.
    pub fn create_dir(&self) -> anyhow::Result<()> {
        if let Some(dir) = self.path(1, "png").parent()
            && !dir.as_os_str().is_empty()
        {
            std::fs::create_dir_all(dir)
                .with_context(|| format!("cannot create the frame folder {}", dir.display()))?;
        }
        Ok(())
    }
}

/// What the frame writer's thread ends with: the size of the frames written, how many frame
/// files it wrote, the frames whose files it had to skip (the disk slower than the cluster for
/// longer than its queue absorbs), and the first error.
#[derive(Debug, Default)]
pub struct Written {
    pub size: Option<(u32, u32)>,
    pub frames: u64,
    pub skipped: Vec<u64>,
    pub error: Option<anyhow::Error>,
}

/// Bytes of frames the writer holds at most while the disk catches up (about twenty 1080p
/// frames): beyond it a frame's files are skipped, never the frame.
pub const QUEUE_BYTES: usize = 512 << 20;

/// A frame waiting for the writer, and whether its own files (`--frame-pattern`) are wanted;
/// either way it may be the newest, which goes to `--out`/`--exr`.
#[derive(Debug)]
struct Job {
    frame: FrameResult,
    files: bool,
}

#[derive(Debug, Default)]
struct Queue {
    jobs: std::collections::VecDeque<Job>,
    bytes: usize,
    closed: bool,
    skipped: Vec<u64>,
}

/// Writes frames off the event loop as they complete. The loop never waits for the disk: the
/// queue holds at most `budget` bytes of frames; past it a frame's pattern files are skipped
/// (and reported: `--resume` renders them again) while `--out` still gets the newest frame.
#[derive(Debug)]
pub struct FrameWriter {
    shared: Option<std::sync::Arc<(std::sync::Mutex<Queue>, std::sync::Condvar)>>,
    every: bool,
    budget: usize,
    thread: Option<std::thread::JoinHandle<Written>>,
}

fn frame_bytes(f: &FrameResult) -> usize {
    f.image.data.len() * std::mem::size_of::<f32>()
}

impl FrameWriter {
    pub fn start(
        out: PathBuf,
        exr: PathBuf,
        every: Option<FramePattern>,
        exposure: f32,
    ) -> FrameWriter {
        Self::with_budget(out, exr, every, exposure, QUEUE_BYTES)
    }

    /// [`FrameWriter::start`] with a queue of `budget` bytes.
    pub fn with_budget(
        out: PathBuf,
        exr: PathBuf,
        every: Option<FramePattern>,
        exposure: f32,
        budget: usize,
    ) -> FrameWriter {
        let shared = std::sync::Arc::new((
            std::sync::Mutex::new(Queue::default()),
            std::sync::Condvar::new(),
        ));
        let queue = std::sync::Arc::clone(&shared);
        let has_every = every.is_some();
        let thread = std::thread::spawn(move || {
            let mut w = Written::default();
            let (lock, ready) = &*queue;
            loop {
                // Everything queued so far: every frame's files, then the newest into --out.
                let batch: Vec<Job> = {
                    let Ok(mut q) = lock.lock() else { break };
                    while q.jobs.is_empty() && !q.closed {
                        q = match ready.wait(q) {
                            Ok(q) => q,
                            Err(_) => return w,
                        };
                    }
                    if q.jobs.is_empty() {
                        w.skipped = std::mem::take(&mut q.skipped);
                        break;
                    }
                    q.jobs.drain(..).collect()
                };
                let mut newest = None;
                for job in batch {
                    if let (true, Some(p)) = (job.files, &every) {
                        // Complete or absent, whenever the process dies (`--resume` relies on
                        // it).
                        let f = &job.frame;
                        let (png, exr) = (p.path(f.frame, "png"), p.path(f.frame, "exr"));
                        match write_atomically(&f.image, &png, &exr, exposure) {
                            Ok(()) => w.frames += 1,
                            Err(e) => {
                                w.error.get_or_insert(e);
                            }
                        }
                    }
                    if let Ok(mut q) = lock.lock() {
                        q.bytes = q.bytes.saturating_sub(frame_bytes(&job.frame));
                    }
                    newest = Some(job.frame);
                }
                if let Some(last) = newest {
                    w.size = Some((last.image.width, last.image.height));
                    if let Err(e) = write_atomically(&last.image, &out, &exr, exposure) {
                        w.error.get_or_insert(e);
                    }
                }
            }
            w
        });
        FrameWriter {
            shared: Some(shared),
            every: has_every,
            budget,
            thread: Some(thread),
        }
    }

    /// Queues a frame without waiting: its files when the queue has room, else only as the
    /// newest frame (its files skipped and reported).
    pub fn send(&self, f: FrameResult) {
        let Some(shared) = &self.shared else { return };
        let (lock, ready) = &**shared;
        let Ok(mut q) = lock.lock() else { return };
        let size = frame_bytes(&f);
        let files = self.every && q.bytes + size <= self.budget;
        if self.every && !files {
            if q.skipped.is_empty() {
                tracing::warn!(
                    frame = f.frame,
                    "the disk is slower than the cluster: frame files are skipped while the \
                     writer's queue is full (--resume renders them again)"
                );
            }
            q.skipped.push(f.frame);
        }
        // A frame that only goes to --out supersedes one queued for the same.
        if !files
            && q.jobs.back().is_some_and(|j| !j.files)
            && let Some(old) = q.jobs.pop_back()
        {
            q.bytes = q.bytes.saturating_sub(frame_bytes(&old.frame));
        }
        q.bytes += size;
        q.jobs.push_back(Job { frame: f, files });
        ready.notify_one();
    }

    /// Waits for every queued frame to be written.
    pub fn finish(mut self) -> Written {
        if let Some(shared) = self.shared.take() {
            let (lock, ready) = &*shared;
            if let Ok(mut q) = lock.lock() {
                q.closed = true;
            }
            ready.notify_all();
        }
        match self.thread.take().map(|t| t.join()) {
            Some(Ok(r)) => r,
            Some(Err(_)) => Written {
                error: Some(anyhow::anyhow!("the frame writer panicked")),
                ..Written::default()
            },
            None => Written::default(),
        }
    }
}

/// Writes beside the target and renames over it, so a reader (or a crash) never sees half a file.
fn write_atomically(
    image: &lightfold_scene::Image,
    png: &Path,
    exr: &Path,
    exposure: f32,
) -> anyhow::Result<()> {
    let tmp = |p: &Path| {
        let name = p
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default();
        // Keep the extension last: the writers pick the format from it.
        p.with_file_name(format!(".partial-{name}"))
    };
    let (tp, te) = (tmp(png), tmp(exr));
    image.write_exr(&te)?;
    std::fs::rename(&te, exr).with_context(|| format!("cannot write {}", exr.display()))?;
    image.write_png(&tp, exposure)?;
    std::fs::rename(&tp, png).with_context(|| format!("cannot write {}", png.display()))?;
    Ok(())
}

/// Assembles the frames' PNGs into `video` with `ffmpeg` (H.264, `fps` frames per second).
pub fn assemble_video(pattern: &FramePattern, video: &Path, fps: f32) -> anyhow::Result<()> {
    let out = std::process::Command::new("ffmpeg")
        .args(["-y", "-loglevel", "error", "-framerate"])
        .arg(fps.to_string())
        .arg("-i")
        .arg(pattern.ffmpeg_input())
        .args(["-c:v", "libx264", "-pix_fmt", "yuv420p"])
        // H.264 wants even dimensions.
        .args(["-vf", "pad=ceil(iw/2)*2:ceil(ih/2)*2"])
        .arg(video)
        .output();
    match out {
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => bail!(
            "--video needs ffmpeg on the PATH (Debian: apt install ffmpeg); the frames are in {}",
            pattern.ffmpeg_input()
        ),
        Err(e) => bail!("cannot run ffmpeg: {e}"),
        Ok(o) if !o.status.success() => bail!(
            "ffmpeg failed ({}): {}",
            o.status,
            String::from_utf8_lossy(&o.stderr).trim()
        ),
        Ok(_) => Ok(()),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn patterns_number_frames_like_printf_and_ffmpeg() {
        let p = FramePattern::parse("out/frame-%04d").unwrap();
        assert_eq!(p.path(1, "png"), PathBuf::from("out/frame-0001.png"));
        assert_eq!(p.path(12345, "exr"), PathBuf::from("out/frame-12345.exr"));
        assert_eq!(p.ffmpeg_input(), "out/frame-%04d.png");
        let q = FramePattern::parse("shot_%d_final").unwrap();
        assert_eq!(q.path(7, "png"), PathBuf::from("shot_7_final.png"));
        for bad in ["out/frame", "a%s", "a%04d%d", "%d%", "a%99d", "%d"] {
            assert!(FramePattern::parse(bad).is_err(), "{bad}");
        }
    }

    fn frame(n: u64) -> FrameResult {
        let mut image = lightfold_scene::Image::new(4, 3, 3);
        image.data.iter_mut().for_each(|v| *v = n as f32 / 10.0);
        let now = std::time::Instant::now();
        FrameResult {
            frame: n,
            wire_frame: n,
            epoch: 1,
            requested_at: now,
            received_at: now,
            latency_frames: 0,
            image,
            sink_bytes: 0,
            stats: Vec::new(),
        }
    }

    #[test]
    fn a_full_queue_skips_frame_files_never_the_newest_frame() {
        let dir = tempfile::tempdir().unwrap();
        let p = FramePattern::parse(&dir.path().join("f-%03d").to_string_lossy()).unwrap();
        let (out, exr) = (dir.path().join("out.png"), dir.path().join("out.exr"));
        // Room for every frame: all written.
        let w = FrameWriter::with_budget(out.clone(), exr.clone(), Some(p.clone()), 1.0, 1 << 20);
        for n in 1..=5 {
            w.send(frame(n));
        }
        let done = w.finish();
        assert!(done.error.is_none());
        assert_eq!((done.frames, done.skipped.len()), (5, 0));
        assert_eq!(p.complete(5), vec![1, 2, 3, 4, 5]);
        // No room at all (a disk that never keeps up): no frame file, the skips reported, and
        // --out still holds the newest frame.
        let q = FramePattern::parse(&dir.path().join("g-%03d").to_string_lossy()).unwrap();
        let w = FrameWriter::with_budget(out.clone(), exr.clone(), Some(q.clone()), 1.0, 0);
        for n in 1..=5 {
            w.send(frame(n));
        }
        let done = w.finish();
        assert_eq!((done.frames, done.skipped), (0, vec![1, 2, 3, 4, 5]));
        assert!(q.complete(5).is_empty());
        let newest = lightfold_scene::Image::read_exr(&exr).unwrap();
        assert_eq!(newest.data[0], 0.5);
    }

    #[test]
    fn complete_frames_have_both_files_under_their_names() {
        let dir = tempfile::tempdir().unwrap();
        let p = FramePattern::parse(&dir.path().join("f-%03d").to_string_lossy()).unwrap();
        let image = lightfold_scene::Image::new(2, 2, 3);
        write_atomically(&image, &p.path(1, "png"), &p.path(1, "exr"), 1.0).unwrap();
        write_atomically(&image, &p.path(3, "png"), &p.path(3, "exr"), 1.0).unwrap();
        // Frame 2 died between its files; frame 4 died half-way, beside its name.
        image.write_exr(&p.path(2, "exr")).unwrap();
        std::fs::write(dir.path().join(".partial-f-004.exr"), b"half").unwrap();
        assert_eq!(p.complete(5), vec![1, 3]);
        assert!(p.complete(0).is_empty());
    }
}
