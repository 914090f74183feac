//! The one fake coordinator: a stand-in for everything around a daemon, over the real `net`
//! links, so a render node, a stage or a chain of stages can be exercised without planning: it
//! plays the coordinator (dial a daemon, read its `Register`, claim it, send it a scene, configure
//! it, request frames, collect `FrameDone` and errors), a producer (a node or upstream stage
//! streaming frames band-major) and a sink (the coordinator's data listener assembling frames).
//! Every wait has a deadline.
//!
//! Tests and benchmarks use it (the node's and the compositor's daemon tests, the compositor's
//! link benchmark, the CLI's chain of `lightfold compositor` processes, `lightfold bench node`);
//! a real cluster's coordinator speaks to its daemons through `lightfold_coordinator::control`.

use bytes::Bytes;
use lightfold_compositor::daemon::pixels::{pack, unpack};
use lightfold_net::{Identity, Link, LinkReader, LinkWriter, NetError, Timeouts, dial_retry};
use lightfold_protocol::{
    BandHeader, Capabilities, CompositorConfig, ErrorCode, Frame, FrameParams, FrameStats, Hash,
    Layer, Message, NodeConfig, PixelFormat, WireCamera,
};
use std::collections::VecDeque;
use std::time::Duration;
use tokio::net::TcpListener;
use tokio::time::Instant;

#[derive(Debug, thiserror::Error)]
pub enum DriverError {
    #[error(transparent)]
    Net(#[from] NetError),
    #[error("the stage answered {code:?}: {message}")]
    Refused { code: ErrorCode, message: String },
    #[error("expected {expected}, got {got}")]
    Unexpected { expected: &'static str, got: String },
    #[error("no {what} within {after:?}")]
    Timeout { what: String, after: Duration },
    #[error("cannot pack {layer:?} as {format:?}: {reason}")]
    Pack {
        layer: Layer,
        format: PixelFormat,
        reason: String,
    },
    #[error("layer {layer:?} holds {got} values, a {width}x{height} frame needs {expected}")]
    Size {
        layer: Layer,
        width: u32,
        height: u32,
        expected: usize,
        got: usize,
    },
}

/// The coordinator's side of a daemon's control link.
#[derive(Debug)]
pub struct ControlClient {
    link: Link,
    pub capabilities: Capabilities,
    /// Messages read while waiting for something else, in arrival order.
    backlog: VecDeque<Message>,
}

impl ControlClient {
    /// Dials the daemon at `addr` (retrying until `within`) and reads its `Register`.
    pub async fn connect(
        addr: &str,
        me: &Identity,
        t: Timeouts,
        within: Duration,
    ) -> Result<ControlClient, DriverError> {
        let mut link = dial_retry(addr, me, t, within).await?;
        let capabilities = match link.recv_msg(within).await? {
            Message::Register(c) => c,
            other => {
                return Err(DriverError::Unexpected {
                    expected: "Register",
                    got: format!("{other:?}"),
                });
            }
        };
        Ok(ControlClient {
            link,
            capabilities,
            backlog: VecDeque::new(),
        })
    }

    /// Claims the stage for coordinator `session` (the first message after `Register`) and waits
    /// for `Claimed`; a refusal (`Busy`) becomes `Refused`, and the stage then closes the link.
    pub async fn claim(
        &mut self,
        session: u64,
        take_over: bool,
        within: Duration,
    ) -> Result<(), DriverError> {
        self.link
            .send_msg(Message::Claim { session, take_over })
            .await?;
        match self.read(Instant::now() + within, "Claimed").await? {
            Message::Claimed { session: s } if s == session => Ok(()),
            Message::Error { code, message, .. } => Err(DriverError::Refused { code, message }),
            other => Err(DriverError::Unexpected {
                expected: "Claimed",
                got: format!("{other:?}"),
            }),
        }
    }

    /// Sends a stage's configuration and waits for `Configured` (an `Error` becomes `Refused`).
    pub async fn configure(
        &mut self,
        config: CompositorConfig,
        within: Duration,
    ) -> Result<(), DriverError> {
        let epoch = config.epoch;
        self.configured(Message::ConfigureCompositor(config), epoch, within)
            .await
    }

    /// Sends a render node's configuration and waits for `Configured` (an `Error` becomes
    /// `Refused`).
    pub async fn configure_node(
        &mut self,
        config: NodeConfig,
        within: Duration,
    ) -> Result<(), DriverError> {
        let epoch = config.epoch;
        self.configured(Message::ConfigureNode(config), epoch, within)
            .await
    }

    async fn configured(
        &mut self,
        msg: Message,
        epoch: u64,
        within: Duration,
    ) -> Result<(), DriverError> {
        self.link.send_msg(msg).await?;
        let deadline = Instant::now() + within;
        loop {
            match self.read(deadline, "Configured").await? {
                Message::Configured { epoch: e } if e == epoch => return Ok(()),
                Message::Error { code, message, .. } => {
                    return Err(DriverError::Refused { code, message });
                }
                other => self.backlog.push_back(other),
            }
        }
    }

    /// Requests a frame.
    pub async fn render(
        &mut self,
        epoch: u64,
        frame: u64,
        params: FrameParams,
    ) -> Result<(), DriverError> {
        self.render_from(epoch, frame, None, params).await
    }

    /// Requests a frame from `camera` (`None`: the configured one).
    pub async fn render_from(
        &mut self,
        epoch: u64,
        frame: u64,
        camera: Option<WireCamera>,
        params: FrameParams,
    ) -> Result<(), DriverError> {
        let msg = Message::RenderFrame {
            epoch,
            frame,
            camera,
            params,
        };
        Ok(self.link.send_msg(msg).await?)
    }

    /// Offers a render node the scene encoded as `bytes` (content hash `hash`) and sends it in
    /// chunks of `chunk` bytes if the node asks for it; returns the triangles the node loaded, or
    /// `None` when it had the scene already.
    pub async fn send_scene(
        &mut self,
        hash: Hash,
        bytes: &[u8],
        chunk: usize,
        within: Duration,
    ) -> Result<Option<u64>, DriverError> {
        let deadline = Instant::now() + within;
        let offer = Message::SceneOffer {
            hash,
            size: bytes.len() as u64,
        };
        self.link.send_msg(offer).await?;
        match self.read(deadline, "SceneNeed").await? {
            Message::SceneNeed { need: false, .. } => return Ok(None),
            Message::SceneNeed { need: true, .. } => {}
            other => return Err(unexpected("SceneNeed", other)),
        }
        self.send_chunks(hash, bytes, chunk).await?;
        match self.read(deadline, "SceneReady").await? {
            Message::SceneReady { hash: h, triangles } if h == hash => Ok(Some(triangles)),
            other => Err(unexpected("SceneReady", other)),
        }
    }

    /// Sends `bytes` as the scene `hash` in chunks of `chunk` bytes (the last one marked), with
    /// no offer before and no answer awaited: what tests of a node's scene checks send.
    pub async fn send_chunks(
        &mut self,
        hash: Hash,
        bytes: &[u8],
        chunk: usize,
    ) -> Result<(), DriverError> {
        let chunk = chunk.max(1);
        let n = bytes.chunks(chunk).count().max(1);
        for (i, c) in bytes.chunks(chunk).enumerate() {
            self.link
                .send_msg(Message::SceneChunk {
                    hash,
                    offset: (i * chunk) as u64,
                    data: c.to_vec(),
                    last: i + 1 == n,
                })
                .await?;
        }
        Ok(())
    }

    /// Sends any message (a test's own protocol step).
    pub async fn send_msg(&mut self, msg: Message) -> Result<(), DriverError> {
        Ok(self.link.send_msg(msg).await?)
    }

    /// The next message straight from the link, its error as the link gives it (closed, timed
    /// out): for tests of how a daemon ends a link. The backlog is not consulted.
    pub async fn recv_raw(&mut self, within: Duration) -> Result<Message, NetError> {
        self.link.recv_msg(within).await
    }

    /// Tells the stage the plan of `epoch` leaves it out (`Message::Release`; no answer).
    pub async fn release(&mut self, epoch: u64) -> Result<(), DriverError> {
        Ok(self.link.send_msg(Message::Release { epoch }).await?)
    }

    /// The next message from the stage (backlog first).
    pub async fn next_message(&mut self, within: Duration) -> Result<Message, DriverError> {
        if let Some(m) = self.backlog.pop_front() {
            return Ok(m);
        }
        self.read(Instant::now() + within, "control message").await
    }

    /// Waits for `FrameDone` of `frame`; the first `Error` before it becomes `Refused`.
    pub async fn frame_done(
        &mut self,
        frame: u64,
        within: Duration,
    ) -> Result<FrameStats, DriverError> {
        let deadline = Instant::now() + within;
        if let Some(k) = self.backlog.iter().position(|m| is_done_or_error(m, frame)) {
            let m = self.backlog.remove(k).ok_or(DriverError::Timeout {
                what: "backlog".into(),
                after: within,
            })?;
            return done_or_refused(m);
        }
        loop {
            let m = self.read(deadline, "FrameDone").await?;
            if is_done_or_error(&m, frame) {
                return done_or_refused(m);
            }
            self.backlog.push_back(m);
        }
    }

    pub async fn send_ping(&mut self, seq: u64) -> Result<(), DriverError> {
        Ok(self.link.send_msg(Message::Ping { seq }).await?)
    }

    /// Asks the stage to exit.
    pub async fn shutdown(&mut self) -> Result<(), DriverError> {
        Ok(self.link.send_msg(Message::Shutdown).await?)
    }

    async fn read(
        &mut self,
        deadline: Instant,
        what: &'static str,
    ) -> Result<Message, DriverError> {
        let left = deadline.saturating_duration_since(Instant::now());
        match self.link.recv_msg(left).await {
            Err(NetError::Timeout { .. }) => Err(DriverError::Timeout {
                what: what.into(),
                after: left,
            }),
            r => Ok(r?),
        }
    }
}

fn unexpected(expected: &'static str, got: Message) -> DriverError {
    match got {
        Message::Error { code, message, .. } => DriverError::Refused { code, message },
        other => DriverError::Unexpected {
            expected,
            got: format!("{other:?}"),
        },
    }
}

fn is_done_or_error(m: &Message, frame: u64) -> bool {
    matches!(m, Message::FrameDone(s) if s.frame == frame) || matches!(m, Message::Error { .. })
}

fn done_or_refused(m: Message) -> Result<FrameStats, DriverError> {
    match m {
        Message::FrameDone(s) => Ok(s),
        Message::Error { code, message, .. } => Err(DriverError::Refused { code, message }),
        other => Err(DriverError::Unexpected {
            expected: "FrameDone",
            got: format!("{other:?}"),
        }),
    }
}

/// What a frame on a link looks like: its ids and band grid.
pub type FrameShape = lightfold_protocol::BandLayout;

/// One whole layer of a frame in memory: interleaved f32, `layer.channels()` values a pixel.
#[derive(Debug, Clone, PartialEq)]
pub struct LayerImage {
    pub layer: Layer,
    pub format: PixelFormat,
    pub data: Vec<f32>,
}

/// Packs band `b` of `img` (all-zero bands go out empty, as nodes send them).
pub fn pack_band(
    shape: &FrameShape,
    b: u32,
    img: &LayerImage,
) -> Result<(BandHeader, Bytes), DriverError> {
    let ch = img.layer.channels();
    let expected = shape.width as usize * shape.height as usize * ch;
    if img.data.len() != expected {
        return Err(DriverError::Size {
            layer: img.layer,
            width: shape.width,
            height: shape.height,
            expected,
            got: img.data.len(),
        });
    }
    let mut h = shape.header(b, img.layer, img.format);
    let (y0, y1) = shape.rows(b);
    let row = shape.width as usize * ch;
    let values = &img.data[y0 as usize * row..y1 as usize * row];
    if values.iter().all(|v| *v == 0.0) {
        h.empty = true;
        h.seal(&[]);
        return Ok((h, Bytes::new()));
    }
    let mut bytes = vec![0u8; values.len() / ch * img.format.bytes_per_pixel()];
    let saturated =
        pack(img.format, values, shape.scale, &mut bytes).map_err(|reason| DriverError::Pack {
            layer: img.layer,
            format: img.format,
            reason,
        })?;
    h.saturated = u32::try_from(saturated).unwrap_or(u32::MAX);
    h.seal(&bytes);
    Ok((h, Bytes::from(bytes)))
}

/// A producer's data link into a stage (plays a render node or an upstream stage).
#[derive(Debug)]
pub struct Producer {
    writer: LinkWriter,
}

impl Producer {
    /// Dials the consumer at `addr`, retrying until `within`.
    pub async fn connect(
        addr: &str,
        me: &Identity,
        t: Timeouts,
        within: Duration,
    ) -> Result<Producer, DriverError> {
        let link = dial_retry(addr, me, t, within).await?;
        let (_, writer) = link.split();
        Ok(Producer { writer })
    }

    /// Streams one frame band-major (band b of every layer, then band b+1); returns payload bytes.
    pub async fn send_frame(
        &mut self,
        shape: &FrameShape,
        layers: &[LayerImage],
    ) -> Result<u64, DriverError> {
        let mut bytes = 0;
        for b in 0..shape.bands() {
            for img in layers {
                let (h, payload) = pack_band(shape, b, img)?;
                bytes += payload.len() as u64;
                self.writer.send(Frame::Band(h, payload)).await?;
            }
        }
        Ok(bytes)
    }

    /// Sends one band as given (tests use it to send wrong ones).
    pub async fn send_band(
        &mut self,
        header: BandHeader,
        payload: Bytes,
    ) -> Result<(), DriverError> {
        Ok(self.writer.send(Frame::Band(header, payload)).await?)
    }
}

/// The coordinator's data listener: accepts the sink stage's link and assembles frames.
#[derive(Debug)]
pub struct Sink {
    listener: TcpListener,
    me: Identity,
    timeouts: Timeouts,
    /// The stage's link; the writing half is held open (never written) so that end-of-stream on
    /// the stage's side means this sink let the link go (`lightfold_net::Downstream`).
    link: Option<(LinkReader, LinkWriter)>,
}

impl Sink {
    pub fn new(listener: TcpListener, me: Identity, timeouts: Timeouts) -> Sink {
        Sink {
            listener,
            me,
            timeouts,
            link: None,
        }
    }

    /// Closes the stage's link, as a consumer does when a re-plan leaves that stage out; the
    /// stage dials again before its next band, and the next `next_band` accepts that link.
    pub fn let_go(&mut self) {
        self.link = None;
    }

    pub fn local_addr(&self) -> std::io::Result<std::net::SocketAddr> {
        self.listener.local_addr()
    }

    /// Receives one whole frame of `layers` with `shape`, unpacked, skipping bands of earlier
    /// frames; a band out of place is an error naming it.
    pub async fn recv_frame(
        &mut self,
        shape: &FrameShape,
        layers: &[(Layer, PixelFormat)],
        within: Duration,
    ) -> Result<Vec<LayerImage>, DriverError> {
        let deadline = Instant::now() + within;
        let mut out: Vec<LayerImage> = layers
            .iter()
            .map(|&(layer, format)| LayerImage {
                layer,
                format,
                data: vec![0.0; shape.width as usize * shape.height as usize * layer.channels()],
            })
            .collect();
        for b in 0..shape.bands() {
            for img in out.iter_mut() {
                // Bands of earlier frames are the streamed part of a frame a stage abandoned.
                let (h, payload) = loop {
                    let (h, p) = self.next_band(deadline).await?;
                    if (h.epoch, h.frame) >= (shape.epoch, shape.frame) {
                        break (h, p);
                    }
                };
                let want = shape.header(b, img.layer, img.format);
                let same = (h.epoch, h.frame, h.layer, h.format, h.y0, h.height, h.width)
                    == (
                        want.epoch,
                        want.frame,
                        want.layer,
                        want.format,
                        want.y0,
                        want.height,
                        want.width,
                    );
                if !same {
                    return Err(DriverError::Unexpected {
                        expected: "the next band of the frame",
                        got: format!("{h:?}"),
                    });
                }
                if h.empty {
                    continue;
                }
                let row = shape.width as usize * img.layer.channels();
                let dst = &mut img.data[h.y0 as usize * row..(h.y0 + h.height) as usize * row];
                unpack(h.format, &payload, h.scale, dst).map_err(|reason| DriverError::Pack {
                    layer: h.layer,
                    format: h.format,
                    reason,
                })?;
            }
        }
        Ok(out)
    }

    /// The next band, accepting the stage's link first if needed.
    pub async fn next_band(
        &mut self,
        deadline: Instant,
    ) -> Result<(BandHeader, Bytes), DriverError> {
        let after = deadline.saturating_duration_since(Instant::now());
        let timeout = |what: &str| DriverError::Timeout {
            what: what.into(),
            after,
        };
        if self.link.is_none() {
            let (stream, _) = tokio::time::timeout_at(deadline, self.listener.accept())
                .await
                .map_err(|_| timeout("connection to the sink"))?
                .map_err(|source| NetError::Io {
                    addr: "sink listener".into(),
                    source,
                })?;
            let link = lightfold_net::accept(stream, &self.me, self.timeouts).await?;
            self.link = Some(link.split());
        }
        let (link, _) = self.link.as_mut().ok_or_else(|| timeout("link"))?;
        loop {
            let frame = tokio::time::timeout_at(deadline, link.next())
                .await
                .map_err(|_| timeout("band"))?;
            match frame {
                None => {
                    self.link = None;
                    return Err(DriverError::Net(NetError::Closed {
                        addr: "sink stage".into(),
                    }));
                }
                Some(Err(e)) => return Err(e.into()),
                Some(Ok(Frame::Band(h, p))) => return Ok((h, p)),
                Some(Ok(_)) => continue,
            }
        }
    }
}
