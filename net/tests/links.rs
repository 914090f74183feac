//! Authenticated links over loopback: success both ways, wrong token, wrong role, deadlines.

use lightfold_net::{Identity, NetError, Timeouts, accept, dial};
use lightfold_protocol::{Message, Role};
use std::time::Duration;
use tokio::net::TcpListener;

fn quick() -> Timeouts {
    Timeouts {
        connect: Duration::from_secs(2),
        handshake: Duration::from_secs(2),
        send: Duration::from_secs(2),
        ..Timeouts::default()
    }
}

async fn serve_once(
    token: &'static [u8],
) -> (
    String,
    tokio::task::JoinHandle<Result<lightfold_net::Link, NetError>>,
) {
    let listener = TcpListener::bind("127.0.0.1:0").await.unwrap();
    let addr = listener.local_addr().unwrap().to_string();
    let h = tokio::spawn(async move {
        let (s, _) = listener.accept().await.unwrap();
        accept(s, &Identity::new(token, Role::Node, "node-a"), quick()).await
    });
    (addr, h)
}

#[tokio::test]
async fn authenticated_link_exchanges_messages() {
    let (addr, server) = serve_once(b"secret").await;
    let mut client = dial(
        &addr,
        &Identity::new(b"secret", Role::Coordinator, "coord"),
        quick(),
    )
    .await
    .unwrap();
    let mut server = server.await.unwrap().unwrap();
    assert_eq!(client.peer.daemon_id, "node-a");
    assert_eq!(client.peer.role, Role::Node);
    assert_eq!(server.peer.role, Role::Coordinator);
    client.expect_role(Role::Node).unwrap();
    assert!(client.expect_role(Role::Compositor).is_err());
    client.send_msg(Message::Ping { seq: 7 }).await.unwrap();
    assert_eq!(
        server.recv_msg(Duration::from_secs(2)).await.unwrap(),
        Message::Ping { seq: 7 }
    );
    let (mut r, mut w) = server.split();
    w.send_msg(Message::Pong { seq: 7 }).await.unwrap();
    assert_eq!(
        client.recv_msg(Duration::from_secs(2)).await.unwrap(),
        Message::Pong { seq: 7 }
    );
    drop(client);
    assert!(r.next().await.is_none(), "clean close is end of stream");
}

#[tokio::test]
async fn wrong_token_fails_on_both_sides() {
    let (addr, server) = serve_once(b"right").await;
    let e = dial(
        &addr,
        &Identity::new(b"wrong", Role::Coordinator, "coord"),
        quick(),
    )
    .await
    .unwrap_err();
    assert!(
        matches!(e, NetError::Handshake { .. } | NetError::Closed { .. }),
        "{e}"
    );
    let e = server.await.unwrap().unwrap_err();
    assert!(matches!(e, NetError::Handshake { .. }), "{e}");
    assert!(e.to_string().contains("handshake"), "{e}");
}

#[tokio::test]
async fn silent_peer_times_out_with_its_address() {
    let listener = TcpListener::bind("127.0.0.1:0").await.unwrap();
    let addr = listener.local_addr().unwrap().to_string();
    let _keep = tokio::spawn(async move {
        let (s, _) = listener.accept().await.unwrap();
        tokio::time::sleep(Duration::from_secs(10)).await;
        drop(s);
    });
    let mut t = quick();
    t.handshake = Duration::from_millis(300);
    let e = dial(&addr, &Identity::new(b"x", Role::Coordinator, "c"), t)
        .await
        .unwrap_err();
    assert!(
        matches!(
            e,
            NetError::Timeout {
                what: "handshake",
                ..
            }
        ),
        "{e}"
    );
    assert!(e.to_string().contains(&addr), "{e}");
}

#[tokio::test]
async fn refused_connection_names_the_address() {
    let listener = TcpListener::bind("127.0.0.1:0").await.unwrap();
    let addr = listener.local_addr().unwrap().to_string();
    drop(listener);
    let e = dial(&addr, &Identity::new(b"x", Role::Coordinator, "c"), quick())
        .await
        .unwrap_err();
    assert!(matches!(e, NetError::Connect { .. }), "{e}");
    assert!(e.to_string().contains(&addr), "{e}");
}

#[tokio::test]
async fn garbage_instead_of_a_hello_is_a_clear_error() {
    use tokio::io::AsyncWriteExt;
    let listener = TcpListener::bind("127.0.0.1:0").await.unwrap();
    let addr = listener.local_addr().unwrap();
    let server = tokio::spawn(async move {
        let (s, _) = listener.accept().await.unwrap();
        accept(s, &Identity::new(b"t", Role::Node, "n"), quick()).await
    });
    let mut raw = tokio::net::TcpStream::connect(addr).await.unwrap();
    raw.write_all(b"GET / HTTP/1.1\r\nHost: x\r\n\r\n")
        .await
        .unwrap();
    let e = server.await.unwrap().unwrap_err();
    assert!(
        matches!(e, NetError::Protocol { .. } | NetError::Handshake { .. }),
        "{e}"
    );
}

/// A health probe (connect, then close without a byte) is a disconnect, not an attack; garbage
/// is not.
#[tokio::test]
async fn a_probe_is_a_disconnect_and_garbage_is_not() {
    use tokio::io::AsyncWriteExt;
    let (addr, server) = serve_once(b"secret").await;
    drop(tokio::net::TcpStream::connect(&addr).await.unwrap());
    let e = server.await.unwrap().expect_err("no handshake");
    assert!(e.is_disconnect(), "{e}");

    let (addr, server) = serve_once(b"secret").await;
    let mut s = tokio::net::TcpStream::connect(&addr).await.unwrap();
    s.write_all(b"GET / HTTP/1.1\r\nHost: x\r\n\r\n")
        .await
        .unwrap();
    let e = server.await.unwrap().expect_err("not a lightfold peer");
    assert!(!e.is_disconnect(), "{e}");
}

/// The daemon skeleton: authenticated peers reach the handler (each on its own task), a peer
/// with the wrong token and a silent one never do and do not hold up the next, and cancelling
/// `stop` ends the loop.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn serve_hands_authenticated_links_to_the_handler_until_stopped() {
    let listener = TcpListener::bind("127.0.0.1:0").await.unwrap();
    let addr = listener.local_addr().unwrap().to_string();
    let me = Identity::new(b"secret", Role::Node, "node-a");
    let stop = tokio_util::sync::CancellationToken::new();
    let tracker = tokio_util::task::TaskTracker::new();
    let (seen_tx, mut seen) = tokio::sync::mpsc::unbounded_channel::<String>();
    let server = {
        let (stop, tracker) = (stop.clone(), tracker.clone());
        tokio::spawn(async move {
            lightfold_net::serve(&listener, &me, quick(), &stop, &tracker, "test", {
                move |mut link: lightfold_net::Link| {
                    let seen = seen_tx.clone();
                    async move {
                        let _ = seen.send(link.peer.daemon_id.clone());
                        // Echo one ping, so the client knows it was served.
                        if let Ok(Message::Ping { seq }) = link.recv_msg(quick().send).await {
                            let _ = link.send_msg(Message::Pong { seq }).await;
                        }
                    }
                }
            })
            .await
        })
    };
    // A silent peer (never says hello) first: it must not block the ones after it.
    let _silent = tokio::net::TcpStream::connect(&addr).await.unwrap();
    let wrong = dial(
        &addr,
        &Identity::new(b"wrong", Role::Coordinator, "bad"),
        quick(),
    )
    .await;
    assert!(wrong.is_err(), "a wrong token is refused");
    for id in ["coord-1", "coord-2"] {
        let mut c = dial(
            &addr,
            &Identity::new(b"secret", Role::Coordinator, id),
            quick(),
        )
        .await
        .unwrap();
        c.send_msg(Message::Ping { seq: 1 }).await.unwrap();
        assert_eq!(
            c.recv_msg(Duration::from_secs(2)).await.unwrap(),
            Message::Pong { seq: 1 }
        );
        assert_eq!(seen.recv().await.as_deref(), Some(id));
    }
    assert!(
        seen.try_recv().is_err(),
        "only authenticated peers reach the handler"
    );
    stop.cancel();
    tokio::time::timeout(Duration::from_secs(5), server)
        .await
        .expect("serve ends when stopped")
        .unwrap();
    tracker.close();
    tokio::time::timeout(Duration::from_secs(5), tracker.wait())
        .await
        .expect("the connections' tasks end");
}
