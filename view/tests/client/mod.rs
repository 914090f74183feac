//! A WebSocket viewer for the tests: reads the view's messages with deadlines, keeping the
//! text messages that arrive while it waits for something else.

use futures::{SinkExt, StreamExt};
use serde_json::Value;
use std::collections::VecDeque;
use std::net::SocketAddr;
use std::time::Duration;
use tokio::io::{AsyncRead, AsyncWrite};
use tokio::net::TcpStream;
use tokio_tungstenite::tungstenite::Message;
use tokio_tungstenite::{MaybeTlsStream, WebSocketStream};

/// How long any one wait may take (lavapipe on two shared cores).
pub(crate) const WAIT: Duration = Duration::from_secs(120);

pub(crate) struct Frame {
    pub header: Value,
    pub jpeg: Vec<u8>,
}

pub(crate) struct Client<S = MaybeTlsStream<TcpStream>> {
    ws: WebSocketStream<S>,
    texts: VecDeque<Value>,
    frames: VecDeque<Frame>,
    next_id: u64,
}

/// A viewer that never reads.
pub(crate) struct Stalled {
    _ws: WebSocketStream<TcpStream>,
}

impl Client {
    pub(crate) async fn connect(addr: SocketAddr) -> Client {
        let url = format!("ws://{addr}/ws");
        let (ws, _) = tokio::time::timeout(WAIT, tokio_tungstenite::connect_async(url))
            .await
            .expect("connecting timed out")
            .expect("the view accepts a WebSocket");
        Client::over(ws)
    }

    /// Connects with a 4 KiB receive window and never reads after the handshake.
    pub(crate) async fn connect_stalled(addr: SocketAddr) -> Stalled {
        let socket = tokio::net::TcpSocket::new_v4().unwrap();
        socket.set_recv_buffer_size(4096).unwrap();
        let stream = socket.connect(addr).await.unwrap();
        let (ws, _) = tokio_tungstenite::client_async(format!("ws://{addr}/ws"), stream)
            .await
            .expect("the handshake");
        Stalled { _ws: ws }
    }
}

impl<S: AsyncRead + AsyncWrite + Unpin> Client<S> {
    /// A viewer on a WebSocket already open (over TLS, say).
    pub(crate) fn over(ws: WebSocketStream<S>) -> Client<S> {
        Client {
            ws,
            texts: VecDeque::new(),
            frames: VecDeque::new(),
            next_id: 1,
        }
    }

    /// What arrives within `within` (text messages, and how many frames), taking it all.
    pub(crate) async fn drain_for(&mut self, within: Duration) -> (Vec<Value>, usize) {
        let deadline = tokio::time::Instant::now() + within;
        while let Ok(m) = tokio::time::timeout_at(deadline, self.ws.next()).await {
            match m
                .expect("the view closed the socket")
                .expect("a WebSocket error")
            {
                Message::Text(t) => self.texts.push_back(serde_json::from_str(&t).unwrap()),
                Message::Binary(b) => self.frames.push_back(parse_frame(&b)),
                Message::Close(c) => panic!("the view closed the socket: {c:?}"),
                _ => {}
            }
        }
        let frames = self.frames.len();
        self.frames.clear();
        (self.texts.drain(..).collect(), frames)
    }

    async fn read(&mut self) {
        let m = tokio::time::timeout(WAIT, self.ws.next())
            .await
            .expect("no message from the view in time")
            .expect("the view closed the socket")
            .expect("a WebSocket error");
        match m {
            Message::Text(t) => self.texts.push_back(serde_json::from_str(&t).unwrap()),
            Message::Binary(b) => self.frames.push_back(parse_frame(&b)),
            Message::Close(c) => panic!("the view closed the socket: {c:?}"),
            _ => {}
        }
    }

    /// The next frame.
    pub(crate) async fn frame(&mut self) -> Frame {
        loop {
            if let Some(f) = self.frames.pop_front() {
                return f;
            }
            self.read().await;
        }
    }

    /// The next text message of type `kind` (others of that kind before it are consumed).
    pub(crate) async fn expect(&mut self, kind: &str) -> Value {
        loop {
            if let Some(i) = self.texts.iter().position(|t| t["type"] == kind) {
                return self.texts.remove(i).unwrap();
            }
            self.read().await;
        }
    }

    /// The first status (queued or new) that satisfies `pred`.
    pub(crate) async fn status_where(&mut self, pred: impl Fn(&Value) -> bool) -> Value {
        loop {
            let s = self.expect("status").await;
            if pred(&s) {
                return s;
            }
        }
    }

    pub(crate) async fn send(&mut self, v: &Value) {
        self.ws
            .send(Message::Text(v.to_string().into()))
            .await
            .expect("sending to the view");
    }

    /// Sends a steering message with an id; the revision its ack names.
    pub(crate) async fn steer(&mut self, mut v: Value) -> u64 {
        let id = self.next_id;
        self.next_id += 1;
        v["id"] = id.into();
        self.send(&v).await;
        // Every earlier message with an id was answered before this one (one ordered socket),
        // by an ack or, refused, by an error alone: an ack of another id is a stray.
        let ack = self.expect("ack").await;
        assert_eq!(ack["id"], id, "an ack for another message: {ack}");
        ack["revision"].as_u64().unwrap()
    }

    /// Sends `v` with an id; the answer to it: an `error` (which carries the id, and no ack
    /// follows it), or `None` when it was acked.
    pub(crate) async fn try_steer(&mut self, mut v: Value) -> Option<Value> {
        let id = self.next_id;
        self.next_id += 1;
        v["id"] = id.into();
        self.send(&v).await;
        loop {
            if let Some(i) = self
                .texts
                .iter()
                .position(|t| t["type"] == "error" && t["id"] == id)
            {
                return self.texts.remove(i);
            }
            if let Some(i) = self
                .texts
                .iter()
                .position(|t| t["type"] == "ack" && t["id"] == id)
            {
                self.texts.remove(i);
                return None;
            }
            self.read().await;
        }
    }

    /// The text messages of type `kind` read but not yet taken.
    pub(crate) fn texts_of(&self, kind: &str) -> Vec<Value> {
        self.texts
            .iter()
            .filter(|t| t["type"] == kind)
            .cloned()
            .collect()
    }

    /// Whether the view closes the socket within `within`.
    pub(crate) async fn closed_within(&mut self, within: Duration) -> bool {
        let deadline = tokio::time::Instant::now() + within;
        loop {
            match tokio::time::timeout_at(deadline, self.ws.next()).await {
                Err(_) => return false,
                Ok(None | Some(Err(_)) | Some(Ok(Message::Close(_)))) => return true,
                Ok(Some(Ok(_))) => {}
            }
        }
    }
}

fn parse_frame(b: &[u8]) -> Frame {
    assert!(b.len() >= 4, "a frame message of {} bytes", b.len());
    let n = u32::from_be_bytes([b[0], b[1], b[2], b[3]]) as usize;
    let header: Value = serde_json::from_slice(&b[4..4 + n]).unwrap();
    let jpeg = b[4 + n..].to_vec();
    assert_eq!(header["jpeg_bytes"].as_u64(), Some(jpeg.len() as u64));
    Frame { header, jpeg }
}
