//! Claims on a node (`Message::Claim`): a second coordinator session is refused `Busy` naming
//! the holder; with `take_over` the old link is told `TakenOver` and closed; a link of the
//! holder's own session replaces the old one; an unclaimed link is refused while a session holds
//! the node, closed when one claims it, and served again once the holder leaves. Needs a GPU
//! adapter (the node calibrates at start-up): fails, never skips, without one.

use crate::daemon_support;

use daemon_support::*;
use lightfold_protocol::{ErrorCode, Message};
use std::time::Duration;
use tokio::time::Instant;

const A: u64 = 0xa1;
const B: u64 = 0xb2;

fn expect_error(m: &Message, code: ErrorCode, needles: &[&str]) {
    match m {
        Message::Error {
            code: c, message, ..
        } if *c == code => {
            for n in needles {
                assert!(message.contains(n), "{message:?} should mention {n:?}");
            }
        }
        _ => panic!("expected {code:?}, got {m:?}"),
    }
}

/// The node closes the link: the next read fails (not by timing out).
async fn expect_closed(c: &mut Coordinator) {
    match c.recv_within(Duration::from_secs(5)).await {
        Err(e) if e.is_disconnect() => {}
        other => panic!("expected the node to close the link, got {other:?}"),
    }
}

async fn ping(c: &mut Coordinator, seq: u64) -> Message {
    c.request(Message::Ping { seq }).await
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn one_coordinator_session_holds_a_node() {
    let mut node = start_node("node-claims", None).await;
    // Started and calibrated: an unclaimed link is served.
    let mut free = node.coordinator().await;
    assert_eq!(ping(&mut free, 1).await, Message::Pong { seq: 1 });

    // Session A claims the node; the unclaimed link is closed.
    let (mut a, answer) = Coordinator::claim(&node.addr, A, false).await;
    assert_eq!(answer, Message::Claimed { session: A });
    expect_closed(&mut free).await;
    assert_eq!(ping(&mut a, 2).await, Message::Pong { seq: 2 });

    // Session B without take-over: Busy, naming the node, A's session and the way out.
    let (mut b, answer) = Coordinator::claim(&node.addr, B, false).await;
    expect_error(
        &answer,
        ErrorCode::Busy,
        &[
            "node-claims",
            "00000000000000a1",
            "--take-over",
            "127.0.0.1:",
        ],
    );
    expect_closed(&mut b).await;
    // An unclaimed link is refused too.
    let mut other = node.coordinator().await;
    expect_error(
        &ping(&mut other, 3).await,
        ErrorCode::Busy,
        &["00000000000000a1"],
    );
    expect_closed(&mut other).await;
    // A still holds the node.
    assert_eq!(ping(&mut a, 4).await, Message::Pong { seq: 4 });

    // B takes over: A is told who took it and closed, then B is granted.
    let (mut b, answer) = Coordinator::claim(&node.addr, B, true).await;
    assert_eq!(answer, Message::Claimed { session: B });
    let told = a
        .recv_within(Duration::from_secs(5))
        .await
        .expect("A is told");
    expect_error(
        &told,
        ErrorCode::TakenOver,
        &["node-claims", "00000000000000b2"],
    );
    expect_closed(&mut a).await;
    assert_eq!(ping(&mut b, 5).await, Message::Pong { seq: 5 });

    // B re-dials (same session): the new link replaces the old one, no take-over needed.
    let (mut b2, answer) = Coordinator::claim(&node.addr, B, false).await;
    assert_eq!(answer, Message::Claimed { session: B });
    expect_closed(&mut b).await;
    assert_eq!(ping(&mut b2, 6).await, Message::Pong { seq: 6 });

    // B leaves: the node is free again, for an unclaimed link and for another session.
    drop(b2);
    let deadline = Instant::now() + Duration::from_secs(5);
    let mut free = loop {
        let mut c = node.coordinator().await;
        match ping(&mut c, 7).await {
            Message::Pong { seq: 7 } => break c,
            m if Instant::now() < deadline => {
                expect_error(&m, ErrorCode::Busy, &[]);
                tokio::time::sleep(Duration::from_millis(50)).await;
            }
            m => panic!("the node is still held after its holder left: {m:?}"),
        }
    };
    assert_eq!(ping(&mut free, 8).await, Message::Pong { seq: 8 });
    let (mut a, answer) = Coordinator::claim(&node.addr, A, false).await;
    assert_eq!(answer, Message::Claimed { session: A });
    assert_eq!(ping(&mut a, 9).await, Message::Pong { seq: 9 });
    drop(a);
    node.stop().await;
}
