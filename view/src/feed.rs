//! Frame requests from the steering state: one request whenever there is room in the pipeline
//! (fewer than `frames_in_flight` requested and not delivered) and something to show — the
//! steering changed since the last request, a viewer asked for a frame, or the view is
//! continuous. Each request is built when it is sent, so it carries the newest camera and lights.

use crate::hub::Hub;
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
    let mut last_revision: Option<u64> = None;
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
            let (revision, playing) = {
                let s = steer.borrow_and_update();
                (s.revision, s.clock.playing())
            };
            // A playing animation always has a new frame to show.
            if hub.continuous || playing || last_revision != Some(revision) {
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
        last_revision = Some(revision);
        requested += 1;
        hub.revisions
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .insert(requested, revision);
        tokio::select! {
            _ = stop.cancelled() => return,
            r = tx.send(spec) => if r.is_err() { return },
        }
    }
}
