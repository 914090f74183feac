//! Claims on a stage (`Message::Claim`): a second coordinator session is refused `Busy` naming
//! the holder; with `take_over` the old link is told `TakenOver` and closed and the control queue
//! moves to the new one; a link of the holder's own session replaces the old one; an unclaimed
//! link is refused while a session holds the stage and is replaced by a claim; once the holder
//! leaves, unclaimed links are served again (a new one replacing the previous one, as before).

use crate::support;

use lightfold_harness::driver::{ControlClient, DriverError};
use lightfold_protocol::{ErrorCode, Layer, Message, PixelFormat};
use std::time::Duration;
use support::*;
use tokio::time::Instant;

const A: u64 = 0xa1;
const B: u64 = 0xb2;
const ILL: Layer = Layer::Illumination;

fn expect_error(code: ErrorCode, message: &str, want: ErrorCode, needles: &[&str]) {
    assert_eq!(code, want, "{message}");
    for n in needles {
        assert!(message.contains(n), "{message:?} should mention {n:?}");
    }
}

/// The stage closes the link: the next read fails (not by timing out).
async fn expect_closed(c: &mut ControlClient) {
    match c.next_message(Duration::from_secs(5)).await {
        Err(DriverError::Net(e)) if e.is_disconnect() => {}
        other => panic!("expected the stage to close the link, got {other:?}"),
    }
}

async fn ping(c: &mut ControlClient, seq: u64) -> Message {
    c.send_ping(seq).await.unwrap();
    c.next_message(WAIT).await.unwrap()
}

async fn claimed(stage: &Stage, session: u64, take_over: bool) -> ControlClient {
    let mut c = stage.control().await;
    c.claim(session, take_over, WAIT).await.unwrap();
    c
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn one_coordinator_session_holds_a_stage() {
    let stage = start_stage("claims-stage").await;
    let (_sink, sink_addr) = sink().await;
    let layers = [(ILL, PixelFormat::F32x6)];
    let cfg = |epoch| {
        config(
            epoch,
            (8, 4, 4),
            vec![input("up", &layers)],
            &[],
            &layers,
            &sink_addr,
        )
    };

    let mut free = stage.control().await;
    assert_eq!(ping(&mut free, 1).await, Message::Pong { seq: 1 });

    // Session A claims the stage (the unclaimed link is closed) and configures it.
    let mut a = claimed(&stage, A, false).await;
    expect_closed(&mut free).await;
    a.configure(cfg(1), WAIT).await.unwrap();

    // Session B without take-over: Busy, naming the stage, A's session and the way out.
    let mut b = stage.control().await;
    match b.claim(B, false, WAIT).await {
        Err(DriverError::Refused { code, message }) => expect_error(
            code,
            &message,
            ErrorCode::Busy,
            &[
                "claims-stage",
                "00000000000000a1",
                "--take-over",
                "127.0.0.1:",
            ],
        ),
        other => panic!("expected Busy, got {other:?}"),
    }
    expect_closed(&mut b).await;
    // An unclaimed link is refused too.
    let mut other = stage.control().await;
    match ping(&mut other, 2).await {
        Message::Error { code, message, .. } => {
            expect_error(code, &message, ErrorCode::Busy, &["00000000000000a1"])
        }
        m => panic!("expected Busy, got {m:?}"),
    }
    expect_closed(&mut other).await;
    assert_eq!(ping(&mut a, 3).await, Message::Pong { seq: 3 });

    // B takes over: A is told who took it and closed; B has the control queue.
    let mut b = claimed(&stage, B, true).await;
    match a.next_message(WAIT).await {
        Ok(Message::Error { code, message, .. }) => expect_error(
            code,
            &message,
            ErrorCode::TakenOver,
            &["claims-stage", "00000000000000b2"],
        ),
        m => panic!("expected TakenOver, got {m:?}"),
    }
    expect_closed(&mut a).await;
    b.configure(cfg(2), WAIT).await.unwrap();

    // B re-dials (same session): the new link replaces the old one, no take-over needed.
    let mut b2 = claimed(&stage, B, false).await;
    expect_closed(&mut b).await;
    b2.configure(cfg(3), WAIT).await.unwrap();

    // B leaves: the stage is free again.
    drop(b2);
    let deadline = Instant::now() + WAIT;
    let mut u1 = loop {
        let mut c = stage.control().await;
        match ping(&mut c, 4).await {
            Message::Pong { seq: 4 } => break c,
            Message::Error {
                code: ErrorCode::Busy,
                ..
            } if Instant::now() < deadline => {
                tokio::time::sleep(Duration::from_millis(50)).await;
            }
            m => panic!("the stage is still held after its holder left: {m:?}"),
        }
    };
    // Unclaimed links replace each other, as before claims.
    let mut u2 = stage.control().await;
    assert_eq!(ping(&mut u2, 5).await, Message::Pong { seq: 5 });
    expect_closed(&mut u1).await;
    u2.configure(cfg(4), WAIT).await.unwrap();
    stage.stop().await;
}

/// A coordinator that falls silent (stopped, hung, cut off, its link still open) is released
/// after the stage's `coordinator_silence`: another session then claims the stage without
/// `take_over`. One that keeps talking (the coordinator's keepalives) holds it.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_silent_coordinator_is_released() {
    let silence = Duration::from_millis(600);
    let stage = start_stage_with("silent-stage", |o| o.coordinator_silence = silence).await;

    // A speaks every 100 ms (as a coordinator's keepalives) for three silences, while B tries:
    // B is refused.
    let mut a = claimed(&stage, A, false).await;
    let (quiet_tx, mut quiet) = tokio::sync::oneshot::channel::<()>();
    let talker = tokio::spawn(async move {
        let mut seq = 10;
        loop {
            seq += 1;
            let sent = Instant::now();
            assert_eq!(ping(&mut a, seq).await, Message::Pong { seq });
            tokio::select! {
                _ = &mut quiet => return (a, sent),
                () = tokio::time::sleep(Duration::from_millis(100)) => {}
            }
        }
    });
    tokio::time::sleep(3 * silence).await;
    let mut b = stage.control().await;
    match b.claim(B, false, WAIT).await {
        Err(DriverError::Refused { code, .. }) => assert_eq!(code, ErrorCode::Busy),
        other => panic!("a coordinator that talks keeps its claim: {other:?}"),
    }
    quiet_tx.send(()).unwrap();
    let (mut a, fell_silent) = talker.await.unwrap();

    // Then A falls silent with its link open: the stage closes it, and B gets the stage.
    expect_closed_within(&mut a, 4 * silence).await;
    let released = fell_silent.elapsed();
    assert!(
        released >= silence,
        "released after {released:?}, before the {silence:?} of silence"
    );
    let mut b = claimed(&stage, B, false).await;
    assert_eq!(ping(&mut b, 1).await, Message::Pong { seq: 1 });
    stage.stop().await;
}

/// The stage closes the link within `within` (not by this side timing out).
async fn expect_closed_within(c: &mut ControlClient, within: Duration) {
    match c.next_message(within).await {
        Err(DriverError::Net(e)) if e.is_disconnect() => {}
        other => panic!("expected the stage to close the link within {within:?}, got {other:?}"),
    }
}
