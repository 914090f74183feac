//! Frame requests from the steering state: one request whenever there is room in the pipeline
//! (fewer than `frames_in_flight` requested and not delivered) and something to show — the
//! steering changed since the last request, the scene's clock moved (an animation playing), a
//! viewer asked for a frame, or the view is continuous. Each request is built when it is sent, so
//! it carries the newest camera, lights and clip time.

use crate::hub::{Hub, Requested};
use lightfold_coordinator::control::FrameSpec;
use std::sync::Arc;
use tokio::sync::mpsc;
use tokio_util::sync::CancellationToken;

pub async fn run(
    hub: Arc<Hub>,
    tx: mpsc::Sender<FrameSpec>,
    in_flight: u64,
    stop: CancellationToken,
) {
    let mut steer = hub.steer.subscribe();
    let mut delivered = hub.delivered.subscribe();
    let mut requested: u64 = 0;
    let mut last: Option<Requested> = None;
    loop {
        // Room in the pipeline.
        while requested.saturating_sub(*delivered.borrow_and_update()) >= in_flight {
            tokio::select! {
                _ = stop.cancelled() => return,
                r = delivered.changed() => if r.is_err() { return },
            }
        }
        // Something to show.
        loop {
            let now = {
                let s = steer.borrow_and_update();
                Requested {
                    revision: s.revision,
                    time: s.clock.animated().then(|| s.clock.now()),
                }
            };
            // A playing animation has a new frame to show until it stops at its end.
            if hub.continuous || last != Some(now) {
                break;
            }
            tokio::select! {
                _ = stop.cancelled() => return,
                r = steer.changed() => if r.is_err() { return },
                _ = hub.render_now.notified() => break,
            }
        }
        let (spec, revision) = {
            let s = steer.borrow();
            (s.spec(), s.revision)
        };
        let at = Requested {
            revision,
            time: spec.time,
        };
        last = Some(at);
        requested += 1;
        hub.revisions
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .insert(requested, at);
        tokio::select! {
            _ = stop.cancelled() => return,
            r = tx.send(spec) => if r.is_err() { return },
        }
    }
}
