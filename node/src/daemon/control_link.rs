//! One control link from a coordinator. The node sends `Register`, reads the first message (a
//! `Claim`, answered `Claimed` or refused `Busy`, see `claim.rs`; anything else is the first
//! request of an unclaimed link), then serves the link in three parts:
//!
//! - a reader that answers `Ping` with `Pong` at once, whatever the node is doing (a coordinator
//!   takes a node that does not answer within a second for lost), stops on `Shutdown`, and queues
//!   every other message for the worker;
//! - a worker that applies the queued messages in order (one reply each, or none for a scene
//!   chunk that is not the last);
//! - one writer through which every reply goes.
//!
//! A `ConfigureNode`, `Release` (or `Shutdown`) preempts frames: the frame in progress is abandoned at once
//! and frames queued before the configuration are skipped; neither is answered. The session ends
//! when the coordinator leaves (the node keeps running for the next one), says `Shutdown`,
//! another coordinator takes the node over (`TakenOver` is sent first), or the daemon stops; a
//! frame in progress is then abandoned too. A peer that is not a coordinator is logged and
//! dropped.

use super::engine::{Engine, NextFrame};
use lightfold_net::claim::{Claims, FAREWELL, Ticket};
use lightfold_net::{Link, LinkReader, LinkWriter, NetError};
use lightfold_protocol::frame::Frame;
use lightfold_protocol::{Capabilities, ErrorCode, Message, Role};
use lightfold_telemetry::health::ControlLink;
use lightfold_telemetry::record;
use std::sync::Arc;
use tokio::sync::{Mutex, mpsc, watch};
use tokio_util::sync::CancellationToken;
use tracing::Instrument;

/// Requests waiting for the worker. When this many are queued the reader stops reading (and
/// answering pings) until the worker catches up: a coordinator waits for its answers long before.
const REQUESTS: usize = 16;
/// Replies waiting for the socket.
const REPLIES: usize = 64;

/// How a control session ended.
#[derive(Debug, PartialEq, Eq)]
pub(super) enum Ended {
    /// The coordinator left (cleanly or not), or another took over; the node keeps serving.
    Left,
    /// The coordinator asked the daemon to stop.
    Shutdown,
    /// The daemon is stopping.
    Cancelled,
}

/// A queued request and the number of frame-preempting messages (`ConfigureNode`) the reader
/// had seen when it arrived: a frame whose count is behind the reader's is stale.
#[derive(Debug)]
struct Request {
    msg: Message,
    fence: u64,
}

/// Serves one authenticated control link.
pub(super) async fn serve(
    link: Link,
    caps: Capabilities,
    engine: Arc<Mutex<Engine>>,
    claims: Arc<Claims>,
    silence: std::time::Duration,
    stop: CancellationToken,
) -> Ended {
    let addr = link.addr.clone();
    let peer = link.peer.daemon_id.clone();
    if let Err(e) = link.expect_role(Role::Coordinator) {
        tracing::warn!(%addr, %peer, error = %e, "refusing a control link");
        return Ended::Left;
    }
    let (mut reader, mut writer) = link.split();
    if let Err(e) = writer.send_msg(Message::Register(caps)).await {
        tracing::warn!(%addr, error = %e, "cannot register with the coordinator");
        return Ended::Left;
    }
    tracing::info!(%addr, %peer, "coordinator connected");
    // Registered from here; ready (`/readyz`) once this link has configured the node.
    let mut registered = ControlLink::open();
    let first = tokio::select! {
        _ = stop.cancelled() => return Ended::Cancelled,
        f = reader.next() => f,
    };
    let first = match first {
        None => {
            tracing::info!(%addr, "coordinator disconnected");
            return Ended::Left;
        }
        Some(Err(e)) => {
            tracing::warn!(%addr, error = %e, "control link failed");
            return Ended::Left;
        }
        Some(Ok(f)) => f,
    };
    let claim = match &first {
        Frame::Control(Message::Claim { session, take_over }) => Some((*session, *take_over)),
        _ => None,
    };
    let ticket = tokio::select! {
        _ = stop.cancelled() => return Ended::Cancelled,
        t = claims.enter(claim, &addr) => t,
    };
    let ticket = match ticket {
        Ok(t) => t,
        Err(refusal) => {
            let _ = writer.send_msg(refusal).await;
            return Ended::Left;
        }
    };
    // Only a claimed link is released when its coordinator falls silent (test drivers and
    // `lightfold bench` hold nothing and may pause).
    let silence = claim.map(|_| silence);
    let first = match claim {
        Some((session, _)) => {
            if let Err(e) = writer.send_msg(Message::Claimed { session }).await {
                tracing::warn!(%addr, error = %e, "cannot answer the claim");
                return Ended::Left;
            }
            None
        }
        None => Some(first),
    };
    let (ended, farewell) = run(
        &mut reader,
        &mut writer,
        Incoming { first, silence },
        &engine,
        &ticket,
        &stop,
        &mut registered,
    )
    .await;
    if let Some(msg) = farewell {
        let _ = tokio::time::timeout(FAREWELL, writer.send_msg(msg)).await;
    }
    // Close the link before letting go of the claim: whoever displaced it waits for this.
    drop((reader, writer));
    drop(ticket);
    ended
}

/// The reader, worker and writer of a granted link, until one of them ends, the link is
/// displaced (then with the message to send it last) or the daemon stops.
async fn run(
    reader: &mut LinkReader,
    writer: &mut LinkWriter,
    incoming: Incoming,
    engine: &Mutex<Engine>,
    ticket: &Ticket,
    stop: &CancellationToken,
    registered: &mut ControlLink,
) -> (Ended, Option<Message>) {
    let (out, replies) = mpsc::channel(REPLIES);
    let (queue, requests) = mpsc::channel(REQUESTS);
    let (fence, fence_rx) = watch::channel(0u64);
    let read = read(reader, incoming, &out, &queue, &fence);
    let work = work(engine, requests, fence_rx, out.clone());
    let write = write(writer, replies, registered);
    tokio::select! {
        _ = stop.cancelled() => (Ended::Cancelled, None),
        farewell = ticket.revoked() => (Ended::Left, farewell),
        ended = read => (ended, None),
        () = work => (Ended::Left, None),
        () = write => (Ended::Left, None),
    }
}

/// What the reader starts from: the link's first frame when it was not a claim, and how long a
/// claimed link may bring nothing before it is released (`None`: unclaimed, never).
struct Incoming {
    first: Option<Frame>,
    silence: Option<std::time::Duration>,
}

/// Reads the link: pings are answered here, `Shutdown` ends the session, the rest is queued.
async fn read(
    reader: &mut LinkReader,
    incoming: Incoming,
    out: &mpsc::Sender<Message>,
    queue: &mpsc::Sender<Request>,
    fence: &watch::Sender<u64>,
) -> Ended {
    let addr = reader.addr.clone();
    let Incoming {
        first: mut next,
        silence,
    } = incoming;
    loop {
        let frame = match next.take() {
            Some(f) => f,
            None => match reader.next_within(silence).await {
                None => {
                    tracing::info!(%addr, "coordinator disconnected");
                    return Ended::Left;
                }
                Some(Err(NetError::Timeout {
                    what: "silence",
                    after,
                    ..
                })) => {
                    lightfold_telemetry::health::released_silent_coordinator(&addr, after);
                    return Ended::Left;
                }
                Some(Err(e)) => {
                    tracing::warn!(%addr, error = %e, "control link failed");
                    return Ended::Left;
                }
                Some(Ok(f)) => f,
            },
        };
        let msg = match frame {
            Frame::Control(m) => m,
            other => {
                let got = lightfold_net::describe(&other);
                let refusal = Message::error(
                    ErrorCode::BadConfig,
                    format!("control link carries control messages only, got {got}"),
                );
                if out.send(refusal).await.is_err() {
                    return Ended::Left;
                }
                continue;
            }
        };
        match msg {
            Message::Ping { seq } => {
                if out.send(Message::Pong { seq }).await.is_err() {
                    return Ended::Left;
                }
            }
            Message::Shutdown => {
                tracing::info!(%addr, "shutdown requested by the coordinator");
                return Ended::Shutdown;
            }
            msg => {
                if matches!(msg, Message::ConfigureNode(_) | Message::Release { .. }) {
                    fence.send_modify(|f| *f += 1);
                }
                let request = Request {
                    fence: *fence.borrow(),
                    msg,
                };
                if queue.send(request).await.is_err() {
                    return Ended::Left;
                }
            }
        }
    }
}

/// Applies queued requests in order and queues their answers.
async fn work(
    engine: &Mutex<Engine>,
    mut requests: mpsc::Receiver<Request>,
    mut fence: watch::Receiver<u64>,
    out: mpsc::Sender<Message>,
) {
    // A request taken early (to render its frame while the previous one streams), handled next.
    let mut held: Option<Request> = None;
    loop {
        let Some(Request { msg, fence: seen }) = (match held.take() {
            Some(r) => Some(r),
            None => requests.recv().await,
        }) else {
            return;
        };
        let answer = match msg {
            Message::RenderFrame {
                epoch,
                frame,
                camera,
                params,
            } => {
                // The next request, if it is already here: a frame of the same configuration is
                // rendered on the device while this one's bands go out.
                held = requests.try_recv().ok();
                let next = held.as_ref().and_then(|r| match &r.msg {
                    Message::RenderFrame {
                        epoch,
                        frame,
                        camera,
                        params,
                    } if r.fence == seen => Some(NextFrame {
                        epoch: *epoch,
                        frame: *frame,
                        camera: *camera,
                        params: params.clone(),
                    }),
                    _ => None,
                });
                if *fence.borrow() > seen {
                    record::frame_failed("preempted");
                    tracing::info!(
                        frame,
                        epoch,
                        "frame skipped: a new configuration follows it"
                    );
                    continue;
                }
                // The engine is shared with other (unclaimed) links; each request is handled
                // whole, except that a new configuration abandons a frame.
                let mut engine = engine.lock().await;
                let done = tokio::select! {
                    biased;
                    () = preempted(&mut fence, seen) => None,
                    a = engine
                        .render_frame(epoch, frame, camera, params, next)
                        .instrument(tracing::info_span!("frame", epoch, frame)) => Some(a),
                };
                match done {
                    Some(answer) => {
                        if matches!(answer, Message::Error { .. }) {
                            record::frame_failed("refused");
                        }
                        answer
                    }
                    None => {
                        record::frame_failed("preempted");
                        engine.abandon();
                        tracing::info!(
                            frame,
                            epoch,
                            "frame abandoned: a new configuration arrived"
                        );
                        continue;
                    }
                }
            }
            other => match handle(engine, other).await {
                Some(answer) => answer,
                None => continue,
            },
        };
        if out.send(answer).await.is_err() {
            return;
        }
    }
}

/// Resolves once the reader has seen a frame-preempting message after `seen` of them.
async fn preempted(fence: &mut watch::Receiver<u64>, seen: u64) {
    if fence.wait_for(|f| *f > seen).await.is_err() {
        // The reader is gone: the session is ending anyway.
        std::future::pending::<()>().await;
    }
}

/// Writes replies in order, and counts what they report (frames done, configurations applied).
async fn write(
    writer: &mut LinkWriter,
    mut replies: mpsc::Receiver<Message>,
    registered: &mut ControlLink,
) {
    while let Some(msg) = replies.recv().await {
        match &msg {
            Message::FrameDone(stats) => record::frame_done(stats),
            Message::Configured { epoch } => {
                registered.configured();
                record::plan_epoch(*epoch);
            }
            _ => {}
        }
        if let Err(e) = writer.send_msg(msg).await {
            tracing::warn!(addr = %writer.addr, error = %e, "cannot answer the coordinator");
            return;
        }
    }
}

async fn handle(engine: &Mutex<Engine>, msg: Message) -> Option<Message> {
    let mut engine = engine.lock().await;
    match msg {
        Message::SceneOffer { hash, size } => Some(engine.scene_offer(hash, size).await),
        Message::SceneChunk {
            hash,
            offset,
            data,
            last,
        } => {
            record::bytes_in("scene", data.len() as u64);
            engine.scene_chunk(hash, offset, data, last).await
        }
        Message::ConfigureNode(config) => Some(engine.configure(config).await),
        Message::Release { epoch } => {
            engine.release(epoch);
            None
        }
        other => {
            let name = format!("{other:?}");
            let name = name.split(['(', ' ', '{']).next().unwrap_or("?");
            Some(Message::error(
                ErrorCode::BadConfig,
                format!("a render node does not handle {name}"),
            ))
        }
    }
}
