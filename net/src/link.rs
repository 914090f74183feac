//! Authenticated links: dial or accept a TCP connection, run the handshake of
//! `protocol::handshake` (the token never crosses the wire), then exchange frames with a deadline on
//! every wait. Band payloads are written and read in place (`wire`).

use crate::codec::CodecError;
use crate::frame_io::{FrameReader, FrameWriter};
use lightfold_protocol::frame::{DEFAULT_MAX_FRAME, Frame, ProtocolError};
use lightfold_protocol::handshake::{Handshake, HandshakeError, PeerInfo};
use lightfold_protocol::{Message, Role};
use rand::RngCore;
use std::sync::Arc;
use std::time::Duration;
use tokio::net::TcpStream;
use tokio::time::timeout;

/// Who we are on every link: the shared token, our role and daemon id.
#[derive(Clone)]
pub struct Identity {
    pub token: Arc<[u8]>,
    pub role: Role,
    pub daemon_id: String,
}

impl std::fmt::Debug for Identity {
    // The token is never printed.
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Identity")
            .field("role", &self.role)
            .field("daemon_id", &self.daemon_id)
            .finish_non_exhaustive()
    }
}

impl Identity {
    pub fn new(token: &[u8], role: Role, daemon_id: impl Into<String>) -> Self {
        Identity {
            token: Arc::from(token),
            role,
            daemon_id: daemon_id.into(),
        }
    }
}

/// Deadlines and limits of a link.
#[derive(Debug, Clone, Copy)]
pub struct Timeouts {
    pub connect: Duration,
    pub handshake: Duration,
    /// Longest a single frame may take to be written (a stalled consumer beyond this is an error).
    pub send: Duration,
    pub max_frame: usize,
}

impl Default for Timeouts {
    fn default() -> Self {
        Timeouts {
            connect: Duration::from_secs(5),
            handshake: Duration::from_secs(5),
            send: Duration::from_secs(30),
            max_frame: DEFAULT_MAX_FRAME,
        }
    }
}

#[derive(Debug, thiserror::Error)]
pub enum NetError {
    #[error("cannot connect to {addr}: {source}")]
    Connect {
        addr: String,
        source: std::io::Error,
    },
    #[error("{what} with {addr} timed out after {after:?}")]
    Timeout {
        what: &'static str,
        addr: String,
        after: Duration,
    },
    #[error("handshake with {addr} failed: {source}")]
    Handshake {
        addr: String,
        source: HandshakeError,
    },
    #[error("protocol error on link with {addr}: {source}")]
    Protocol { addr: String, source: ProtocolError },
    #[error("i/o error on link with {addr}: {source}")]
    Io {
        addr: String,
        source: std::io::Error,
    },
    #[error("{addr} closed the connection")]
    Closed { addr: String },
    #[error("{addr} sent {got} where {expected} was expected")]
    Unexpected {
        addr: String,
        expected: &'static str,
        got: String,
    },
    #[error("{addr} is a {got:?}, expected a {expected:?}")]
    WrongRole {
        addr: String,
        expected: Role,
        got: Role,
    },
}

impl NetError {
    /// Whether the peer just went away (closed or reset the connection) without sending anything
    /// malformed: a TCP health probe or a port scan looks like this before the handshake, and is
    /// not worth a warning.
    pub fn is_disconnect(&self) -> bool {
        use std::io::ErrorKind::{BrokenPipe, ConnectionAborted, ConnectionReset, UnexpectedEof};
        match self {
            NetError::Closed { .. } => true,
            NetError::Io { source, .. } => matches!(
                source.kind(),
                UnexpectedEof | ConnectionReset | ConnectionAborted | BrokenPipe
            ),
            _ => false,
        }
    }

    fn from_codec(addr: &str, e: CodecError) -> NetError {
        match e {
            CodecError::Protocol(ProtocolError::Handshake(source)) => NetError::Handshake {
                addr: addr.to_string(),
                source,
            },
            CodecError::Protocol(source) => NetError::Protocol {
                addr: addr.to_string(),
                source,
            },
            CodecError::Io(source) => NetError::Io {
                addr: addr.to_string(),
                source,
            },
        }
    }
}

/// A short description of a frame for error messages (never its payload).
pub fn describe(frame: &Frame) -> String {
    match frame {
        Frame::Hello(_) => "a hello".into(),
        Frame::Proof(_) => "a proof".into(),
        Frame::Control(m) => format!("control message {}", message_name(m)),
        Frame::Band(h, _) => format!("a band of frame {}", h.frame),
    }
}

fn message_name(m: &Message) -> String {
    let dbg = format!("{m:?}");
    dbg.split(['(', ' ', '{']).next().unwrap_or("?").to_string()
}

/// An authenticated, framed connection.
#[derive(Debug)]
pub struct Link {
    reader: FrameReader,
    writer: FrameWriter,
    pub peer: PeerInfo,
    pub addr: String,
    pub timeouts: Timeouts,
}

/// The largest frame read from a peer before it is authenticated: a hello (magic, version, role,
/// a daemon id of at most 255 bytes, a nonce) or a proof, with their framing, fit in far less.
pub const PRE_AUTH_MAX_FRAME: usize = 1024;

/// Dials `addr` (a DNS name is resolved on every call) and authenticates.
pub async fn dial(addr: &str, me: &Identity, t: Timeouts) -> Result<Link, NetError> {
    let stream = match timeout(t.connect, TcpStream::connect(addr)).await {
        Err(_) => {
            return Err(NetError::Timeout {
                what: "connect",
                addr: addr.to_string(),
                after: t.connect,
            });
        }
        Ok(Err(source)) => {
            return Err(NetError::Connect {
                addr: addr.to_string(),
                source,
            });
        }
        Ok(Ok(s)) => s,
    };
    handshake(stream, addr.to_string(), me, true, t).await
}

/// Dials until it succeeds or `total` has passed (for peers that are still starting, or whose
/// handshake slots are full). Handshake failures are not retried: a wrong token or version stays
/// wrong.
pub async fn dial_retry(
    addr: &str,
    me: &Identity,
    t: Timeouts,
    total: Duration,
) -> Result<Link, NetError> {
    let start = tokio::time::Instant::now();
    let mut wait = Duration::from_millis(20);
    loop {
        match dial(addr, me, t).await {
            Ok(link) => return Ok(link),
            // Refused, unanswered, or closed before the handshake: a listener whose handshake
            // slots are all taken (`gate`) closes new connections at once, and frees a slot
            // within its handshake deadline.
            Err(e)
                if matches!(
                    e,
                    NetError::Connect { .. }
                        | NetError::Timeout {
                            what: "connect",
                            ..
                        }
                ) || e.is_disconnect() =>
            {
                if start.elapsed() + wait >= total {
                    return Err(e);
                }
                tokio::time::sleep(wait).await;
                wait = (wait * 2).min(Duration::from_millis(500));
            }
            Err(e) => return Err(e),
        }
    }
}

/// Authenticates an accepted connection.
pub async fn accept(stream: TcpStream, me: &Identity, t: Timeouts) -> Result<Link, NetError> {
    let addr = stream
        .peer_addr()
        .map(|a| a.to_string())
        .unwrap_or_else(|_| "unknown peer".into());
    handshake(stream, addr, me, false, t).await
}

async fn handshake(
    stream: TcpStream,
    addr: String,
    me: &Identity,
    dialer: bool,
    t: Timeouts,
) -> Result<Link, NetError> {
    let _ = stream.set_nodelay(true);
    let (read, write) = stream.into_split();
    // Until the peer has proved it holds the token, only hello- and proof-sized frames are read:
    // a larger length prefix fails the handshake before anything is allocated.
    let mut reader = FrameReader::new(read, PRE_AUTH_MAX_FRAME.min(t.max_frame));
    let mut writer = FrameWriter::new(write, t.max_frame);
    let mut nonce = [0u8; 32];
    rand::rng().fill_bytes(&mut nonce);
    let mut hs = Handshake::new(&me.token, me.role, &me.daemon_id, nonce, dialer);
    let run = async {
        send_frame(&mut writer, &addr, Frame::Hello(hs.hello())).await?;
        let peer_hello = match next_frame(&mut reader, &addr).await? {
            Frame::Hello(h) => h,
            other => {
                return Err(NetError::Unexpected {
                    addr: addr.clone(),
                    expected: "a hello",
                    got: describe(&other),
                });
            }
        };
        let proof = hs
            .receive_hello(peer_hello)
            .map_err(|source| NetError::Handshake {
                addr: addr.clone(),
                source,
            })?;
        send_frame(&mut writer, &addr, Frame::Proof(proof)).await?;
        let peer_proof = match next_frame(&mut reader, &addr).await? {
            Frame::Proof(p) => p,
            other => {
                return Err(NetError::Unexpected {
                    addr: addr.clone(),
                    expected: "a proof",
                    got: describe(&other),
                });
            }
        };
        hs.verify(peer_proof).map_err(|source| NetError::Handshake {
            addr: addr.clone(),
            source,
        })
    };
    let peer = match timeout(t.handshake, run).await {
        Err(_) => {
            return Err(NetError::Timeout {
                what: "handshake",
                addr,
                after: t.handshake,
            });
        }
        Ok(r) => r?,
    };
    reader.set_max_frame(t.max_frame);
    Ok(Link {
        reader,
        writer,
        peer,
        addr,
        timeouts: t,
    })
}

async fn send_frame(writer: &mut FrameWriter, addr: &str, frame: Frame) -> Result<(), NetError> {
    writer
        .send(frame)
        .await
        .map_err(|e| NetError::from_codec(addr, e))
}

async fn next_frame(reader: &mut FrameReader, addr: &str) -> Result<Frame, NetError> {
    match reader.next().await {
        None => Err(NetError::Closed {
            addr: addr.to_string(),
        }),
        Some(r) => r.map_err(|e| NetError::from_codec(addr, e)),
    }
}

impl Link {
    /// Errors unless the peer has the expected role.
    pub fn expect_role(&self, expected: Role) -> Result<(), NetError> {
        if self.peer.role != expected {
            return Err(NetError::WrongRole {
                addr: self.addr.clone(),
                expected,
                got: self.peer.role,
            });
        }
        Ok(())
    }

    pub async fn send(&mut self, frame: Frame) -> Result<(), NetError> {
        let (addr, after) = (self.addr.clone(), self.timeouts.send);
        match timeout(after, send_frame(&mut self.writer, &addr, frame)).await {
            Err(_) => Err(NetError::Timeout {
                what: "send",
                addr,
                after,
            }),
            Ok(r) => r,
        }
    }

    pub async fn send_msg(&mut self, msg: Message) -> Result<(), NetError> {
        self.send(Frame::Control(msg)).await
    }

    /// The next frame, waiting at most `within`.
    pub async fn recv(&mut self, within: Duration) -> Result<Frame, NetError> {
        let addr = self.addr.clone();
        match timeout(within, next_frame(&mut self.reader, &addr)).await {
            Err(_) => Err(NetError::Timeout {
                what: "receive",
                addr,
                after: within,
            }),
            Ok(r) => r,
        }
    }

    /// The next control message, waiting at most `within`.
    pub async fn recv_msg(&mut self, within: Duration) -> Result<Message, NetError> {
        match self.recv(within).await? {
            Frame::Control(m) => Ok(m),
            other => Err(NetError::Unexpected {
                addr: self.addr.clone(),
                expected: "a control message",
                got: describe(&other),
            }),
        }
    }

    /// Splits into independently owned reading and writing halves.
    pub fn split(self) -> (LinkReader, LinkWriter) {
        (
            LinkReader {
                reader: self.reader,
                addr: self.addr.clone(),
            },
            LinkWriter {
                writer: self.writer,
                addr: self.addr,
                send_timeout: self.timeouts.send,
            },
        )
    }
}

/// The reading half of a [`Link`].
#[derive(Debug)]
pub struct LinkReader {
    reader: FrameReader,
    pub addr: String,
}

impl LinkReader {
    /// The next frame; `None` when the peer closed cleanly. No deadline: callers `select!` this
    /// against cancellation or wrap it in their own deadline.
    pub async fn next(&mut self) -> Option<Result<Frame, NetError>> {
        self.reader
            .next()
            .await
            .map(|r| r.map_err(|e| NetError::from_codec(&self.addr, e)))
    }

    /// [`LinkReader::next`], or a `Timeout { what: "silence" }` error when `silence` (if given)
    /// passes with nothing read: how a daemon notices a coordinator that stopped, hung or was
    /// cut off without closing its link (coordinators send keepalives well within it).
    pub async fn next_within(
        &mut self,
        silence: Option<Duration>,
    ) -> Option<Result<Frame, NetError>> {
        let Some(after) = silence.filter(|d| !d.is_zero()) else {
            return self.next().await;
        };
        match timeout(after, self.next()).await {
            Ok(next) => next,
            Err(_) => Some(Err(NetError::Timeout {
                what: "silence",
                addr: self.addr.clone(),
                after,
            })),
        }
    }

    pub async fn recv(&mut self, within: Duration) -> Result<Frame, NetError> {
        match timeout(within, self.next()).await {
            Err(_) => Err(NetError::Timeout {
                what: "receive",
                addr: self.addr.clone(),
                after: within,
            }),
            Ok(None) => Err(NetError::Closed {
                addr: self.addr.clone(),
            }),
            Ok(Some(r)) => r,
        }
    }
}

/// The writing half of a [`Link`]; every send has a deadline.
#[derive(Debug)]
pub struct LinkWriter {
    writer: FrameWriter,
    pub addr: String,
    pub send_timeout: Duration,
}

impl LinkWriter {
    pub async fn send(&mut self, frame: Frame) -> Result<(), NetError> {
        let after = self.send_timeout;
        match timeout(after, self.writer.send(frame)).await {
            Err(_) => Err(NetError::Timeout {
                what: "send",
                addr: self.addr.clone(),
                after,
            }),
            Ok(r) => r.map_err(|e| NetError::from_codec(&self.addr, e)),
        }
    }

    pub async fn send_msg(&mut self, msg: Message) -> Result<(), NetError> {
        self.send(Frame::Control(msg)).await
    }

    /// Queues a frame without flushing (the next `send` or `flush` writes it); for bursts of bands.
    pub async fn feed(&mut self, frame: Frame) -> Result<(), NetError> {
        let after = self.send_timeout;
        match timeout(after, self.writer.feed(frame)).await {
            Err(_) => Err(NetError::Timeout {
                what: "send",
                addr: self.addr.clone(),
                after,
            }),
            Ok(r) => r.map_err(|e| NetError::from_codec(&self.addr, e)),
        }
    }

    pub async fn flush(&mut self) -> Result<(), NetError> {
        let after = self.send_timeout;
        match timeout(after, self.writer.flush()).await {
            Err(_) => Err(NetError::Timeout {
                what: "send",
                addr: self.addr.clone(),
                after,
            }),
            Ok(r) => r.map_err(|e| NetError::from_codec(&self.addr, e)),
        }
    }
}
