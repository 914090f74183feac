//! Frame requests from the steering state: one request whenever there is room in the pipeline
//! (fewer than `frames_in_flight` requested and not delivered) and something to show — the
//! steering changed since the last request, the scene's clock moved (an animation playing), a
//! viewer asked for a frame, the view is continuous, or, refining when idle, the next step is due.
//! Each request is built when it is sent, so it carries the newest camera, lights and clip time.
//!
//! Refinement (`crate::refine`): once nothing has changed for `Ladder::after` since the last
//! input and the frame of the step before was delivered, the next request asks for the next
//! step; anything new to show drops back to level 0 (the session's quality) in the request that
//! shows it.

use crate::hub::{Hub, Requested};
use lightfold_coordinator::control::FrameSpec;
use std::sync::Arc;
use tokio::sync::mpsc;
use tokio_util::sync::CancellationToken;

/// What a frame shows, refinement aside: a new one is something new to show.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Shown {
    revision: u64,
    time: Option<f32>,
}

pub(crate) async fn run(
    hub: Arc<Hub>,
    tx: mpsc::Sender<FrameSpec>,
    in_flight: u64,
    stop: CancellationToken,
) {
    let mut steer = hub.steer.subscribe();
    let mut delivered = hub.delivered.subscribe();
    let mut requested: u64 = 0;
    let mut last: Option<Shown> = None;
    // The refinement level of the last request, and the frame that first asked for it.
    let mut level: u32 = 0;
    let mut level_frame: u64 = 0;
    let top = hub.refine.as_ref().map_or(0, |l| l.top());
    let after = hub.refine.as_ref().map(|l| l.after).unwrap_or_default();
    loop {
        // Room in the pipeline.
        while requested.saturating_sub(*delivered.borrow_and_update()) >= in_flight {
            tokio::select! {
                _ = stop.cancelled() => return,
                r = delivered.changed() => if r.is_err() { return },
            }
        }
        // Something to show, and at which level: new content drops back to level 0.
        let (next_level, fresh, checked) = loop {
            let (now, changed_at) = {
                let s = steer.borrow_and_update();
                let shown = Shown {
                    revision: s.revision,
                    time: s.clock.animated().then(|| s.clock.now()),
                };
                (shown, s.changed_at)
            };
            // A playing animation has a new frame to show until it stops at its end.
            if last != Some(now) {
                break (0, true, now);
            }
            // Refining: the next step once idle long enough and the step before is delivered.
            let due = (level < top).then(|| tokio::time::Instant::from_std(changed_at + after));
            let shown_step = *delivered.borrow_and_update() >= level_frame;
            if hub.continuous {
                let idle = due.is_some_and(|d| d <= tokio::time::Instant::now());
                break (
                    if idle && shown_step { level + 1 } else { level },
                    false,
                    now,
                );
            }
            let wait = async {
                match due {
                    Some(at) if shown_step => tokio::time::sleep_until(at).await,
                    _ => std::future::pending().await,
                }
            };
            tokio::select! {
                _ = stop.cancelled() => return,
                r = steer.changed() => if r.is_err() { return },
                r = delivered.changed(), if due.is_some() && !shown_step => {
                    if r.is_err() { return }
                }
                _ = hub.render_now.notified() => break (level, false, now),
                () = wait => break (level + 1, false, now),
            }
        };
        let (mut spec, revision) = {
            let s = steer.borrow();
            (s.spec(), s.revision)
        };
        let shown = Shown {
            revision,
            time: spec.time,
        };
        // An input that came after the check is new content: at the session's quality.
        let (next_level, fresh) = if shown == checked {
            (next_level, fresh)
        } else {
            (0, true)
        };
        let step = hub.refine.as_ref().and_then(|l| l.step(next_level));
        spec.refine = step.map(|s| s.refine);
        last = Some(shown);
        requested += 1;
        // The next step waits for the frame showing the last input, or the step's own frame.
        if fresh || next_level != level {
            level_frame = requested;
        }
        level = next_level;
        hub.revisions
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .insert(
                requested,
                Requested {
                    revision,
                    time: spec.time,
                    refine: step,
                },
            );
        tokio::select! {
            _ = stop.cancelled() => return,
            r = tx.send(spec) => if r.is_err() { return },
        }
    }
}
