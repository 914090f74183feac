//! One control link from a coordinator: send `Register`, then answer each message in order until
//! the coordinator leaves, says `Shutdown`, or the daemon is cancelled. A coordinator that
//! disconnects without `Shutdown` leaves the node running for the next one; a peer that is not a
//! coordinator, or that breaks the protocol, is logged and dropped.

use super::engine::Engine;
use lightfold_net::{Link, LinkWriter, NetError};
use lightfold_protocol::frame::Frame;
use lightfold_protocol::{Capabilities, ErrorCode, Message, Role};
use std::sync::Arc;
use tokio::sync::Mutex;
use tokio_util::sync::CancellationToken;

/// How a control session ended.
#[derive(Debug, PartialEq, Eq)]
pub enum Ended {
    /// The coordinator left (cleanly or not); the node keeps serving.
    Left,
    /// The coordinator asked the daemon to stop.
    Shutdown,
    /// The daemon is stopping.
    Cancelled,
}

/// Serves one authenticated control link.
pub async fn serve(
    link: Link,
    caps: Capabilities,
    engine: Arc<Mutex<Engine>>,
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
    loop {
        let frame = tokio::select! {
            _ = stop.cancelled() => return Ended::Cancelled,
            f = reader.next() => f,
        };
        let msg = match frame {
            None => {
                tracing::info!(%addr, "coordinator disconnected");
                return Ended::Left;
            }
            Some(Err(e)) => {
                tracing::warn!(%addr, error = %e, "control link failed");
                return Ended::Left;
            }
            Some(Ok(Frame::Control(m))) => m,
            Some(Ok(other)) => {
                let got = lightfold_net::describe(&other);
                let _ = reply(
                    &mut writer,
                    Message::Error {
                        code: ErrorCode::BadConfig,
                        message: format!("control link carries control messages only, got {got}"),
                    },
                )
                .await;
                continue;
            }
        };
        if msg == Message::Shutdown {
            tracing::info!(%addr, "shutdown requested by the coordinator");
            return Ended::Shutdown;
        }
        // The engine is shared with other control links; each message is handled whole, and a
        // cancellation interrupts a long render or transfer.
        let answer = tokio::select! {
            _ = stop.cancelled() => return Ended::Cancelled,
            a = handle(&engine, msg) => a,
        };
        if let Some(answer) = answer
            && let Err(e) = reply(&mut writer, answer).await
        {
            tracing::warn!(%addr, error = %e, "cannot answer the coordinator");
            return Ended::Left;
        }
    }
}

async fn reply(writer: &mut LinkWriter, msg: Message) -> Result<(), NetError> {
    writer.send_msg(msg).await
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
        } => engine.scene_chunk(hash, offset, data, last).await,
        Message::ConfigureNode(config) => Some(engine.configure(config).await),
        Message::RenderFrame {
            epoch,
            frame,
            camera,
            params,
        } => Some(engine.render_frame(epoch, frame, camera, params).await),
        Message::Ping { seq } => Some(Message::Pong { seq }),
        other => {
            let name = format!("{other:?}");
            let name = name.split(['(', ' ', '{']).next().unwrap_or("?");
            Some(Message::Error {
                code: ErrorCode::BadConfig,
                message: format!("a render node does not handle {name}"),
            })
        }
    }
}
