//! Frames on the two halves of a TCP stream without copying band payloads. The writer puts each
//! frame's head in a small buffer and hands head and payload to the kernel together (`writev`), so
//! a payload is written from wherever its `Bytes` live. The reader takes heads from a small buffer
//! and reads each band payload straight from the socket into a buffer from the link's pool,
//! hashing each piece for the checksum as it lands (while it is still in cache); the buffer
//! returns to the pool when the band's last `Bytes` is dropped, so a steady stream of bands reuses
//! warm pages instead of faulting in fresh ones for every band. Both judge frames with
//! `protocol::Codec`, and both keep their progress in `self`, so a read or write cancelled at an
//! `.await` (by a deadline or a `select!`) resumes where it stopped.

use crate::codec::CodecError;
use bytes::{Buf, Bytes, BytesMut};
use lightfold_protocol::BandHeader;
use lightfold_protocol::frame::{BAND_PREFIX_LEN, Codec, Frame, Head, PayloadCheck, check_payload};
use std::collections::VecDeque;
use std::io::IoSlice;
use std::sync::{Arc, Mutex};
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::tcp::{OwnedReadHalf, OwnedWriteHalf};

/// Queued bytes above which `feed` writes before queueing more (as `Framed` does).
const FEED_BOUNDARY: usize = 64 << 10;
/// Most slices handed to one `writev`.
const MAX_SLICES: usize = 64;
/// Most bytes one read into the head buffer asks for: whatever of a payload comes along with a
/// head is copied once, so this bounds the copy per band.
const READ_CHUNK: usize = 16 << 10;
/// Freed payload buffers a link keeps for reuse, by count and by bytes.
const POOL_BUFFERS: usize = 64;
const POOL_BYTES: usize = 128 << 20;

/// Writes frames, band payloads in place.
#[derive(Debug)]
pub(crate) struct FrameWriter {
    io: OwnedWriteHalf,
    codec: Codec,
    heads: BytesMut,
    /// Encoded bytes not yet written, in order: heads and payloads.
    queue: VecDeque<Bytes>,
    queued: usize,
}

impl FrameWriter {
    pub(crate) fn new(io: OwnedWriteHalf, max_frame: usize) -> FrameWriter {
        FrameWriter {
            io,
            codec: Codec::new(max_frame),
            heads: BytesMut::new(),
            queue: VecDeque::new(),
            queued: 0,
        }
    }

    /// Queues `frame` behind what is queued; nothing is written.
    fn push(&mut self, frame: Frame) -> Result<(), CodecError> {
        self.codec.encode_head(&frame, &mut self.heads)?;
        let head = self.heads.split().freeze();
        self.queued += head.len();
        self.queue.push_back(head);
        if let Frame::Band(_, payload) = frame
            && !payload.is_empty()
        {
            self.queued += payload.len();
            self.queue.push_back(payload);
        }
        Ok(())
    }

    /// Writes `frame` and everything queued before it.
    pub(crate) async fn send(&mut self, frame: Frame) -> Result<(), CodecError> {
        self.push(frame)?;
        self.flush().await
    }

    /// Queues `frame`, first writing what is queued if that is already a lot.
    pub(crate) async fn feed(&mut self, frame: Frame) -> Result<(), CodecError> {
        if self.queued >= FEED_BOUNDARY {
            self.flush().await?;
        }
        self.push(frame)
    }

    /// Writes everything queued.
    pub(crate) async fn flush(&mut self) -> Result<(), CodecError> {
        while !self.queue.is_empty() {
            let slices: Vec<IoSlice<'_>> = self
                .queue
                .iter()
                .take(MAX_SLICES)
                .map(|b| IoSlice::new(b))
                .collect();
            let written = self.io.write_vectored(&slices).await?;
            if written == 0 {
                return Err(std::io::Error::from(std::io::ErrorKind::WriteZero).into());
            }
            self.consume(written);
        }
        self.io.flush().await?;
        Ok(())
    }

    fn consume(&mut self, mut n: usize) {
        self.queued -= n;
        while n > 0 {
            let Some(front) = self.queue.front_mut() else {
                return;
            };
            if front.len() > n {
                front.advance(n);
                return;
            }
            n -= front.len();
            self.queue.pop_front();
        }
    }
}

/// Reads frames, band payloads into pooled buffers.
#[derive(Debug)]
pub(crate) struct FrameReader {
    io: OwnedReadHalf,
    codec: Codec,
    /// Bytes read but not yet part of a returned frame.
    buf: BytesMut,
    /// The band whose payload is being read.
    partial: Option<Partial>,
    pool: Arc<Pool>,
}

#[derive(Debug)]
struct Partial {
    header: BandHeader,
    payload: Pooled,
    filled: usize,
    /// The checksum of `payload[..filled]`, hashed as each read lands (still in cache).
    check: PayloadCheck,
}

impl FrameReader {
    pub(crate) fn new(io: OwnedReadHalf, max_frame: usize) -> FrameReader {
        FrameReader {
            io,
            codec: Codec::new(max_frame),
            buf: BytesMut::new(),
            partial: None,
            pool: Arc::new(Pool::default()),
        }
    }

    /// Changes the largest frame accepted from here on (a link reads hello-sized frames until it
    /// is authenticated).
    pub(crate) fn set_max_frame(&mut self, max_frame: usize) {
        self.codec.max_frame = max_frame;
    }

    /// The next frame; `None` when the peer closed cleanly between frames.
    pub(crate) async fn next(&mut self) -> Option<Result<Frame, CodecError>> {
        loop {
            if let Some(p) = self.partial.as_mut() {
                let len = p.payload.len;
                if p.filled < len {
                    match self.io.read(&mut p.payload.buf[p.filled..len]).await {
                        Ok(0) => return Some(Err(eof())),
                        Ok(n) => {
                            p.check.update(&p.payload.buf[p.filled..p.filled + n]);
                            p.filled += n;
                        }
                        Err(e) => return Some(Err(e.into())),
                    }
                    continue;
                }
                let Some(Partial {
                    header,
                    payload,
                    check,
                    ..
                }) = self.partial.take()
                else {
                    continue;
                };
                return Some(match check.finish(&header) {
                    Ok(()) => Ok(Frame::Band(header, Bytes::from_owner(payload))),
                    Err(e) => Err(e.into()),
                });
            }
            let head = match self.codec.decode_head(&self.buf) {
                Err(e) => return Some(Err(e.into())),
                Ok(Head::Band(header)) => {
                    self.buf.advance(BAND_PREFIX_LEN);
                    let len = header.payload_len as usize;
                    if len == 0 {
                        return Some(match check_payload(&header, &[]) {
                            Ok(()) => Ok(Frame::Band(header, Bytes::new())),
                            Err(e) => Err(e.into()),
                        });
                    }
                    let mut payload = self.pool.take(len);
                    let have = self.buf.len().min(len);
                    payload.buf[..have].copy_from_slice(&self.buf[..have]);
                    self.buf.advance(have);
                    let mut check = PayloadCheck::default();
                    check.update(&payload.buf[..have]);
                    self.partial = Some(Partial {
                        header,
                        payload,
                        filled: have,
                        check,
                    });
                    continue;
                }
                Ok(Head::Other) => match self.codec.decode(&mut self.buf) {
                    Err(e) => return Some(Err(e.into())),
                    Ok(Some(frame)) => return Some(Ok(frame)),
                    Ok(None) => Head::Other,
                },
                Ok(Head::Incomplete) => Head::Incomplete,
            };
            // More bytes for the head buffer: the rest of a frame that is not a band (control
            // frames can be large), else a small chunk, so that little of a band's payload comes
            // this way.
            let rest = match (head, self.buf.first_chunk::<4>()) {
                (Head::Other, Some(prefix)) => {
                    (4 + u32::from_be_bytes(*prefix) as usize).saturating_sub(self.buf.len())
                }
                _ => 0,
            };
            let want = rest.max(READ_CHUNK);
            self.buf.reserve(want);
            match (&mut self.io)
                .take(want as u64)
                .read_buf(&mut self.buf)
                .await
            {
                Ok(0) if self.buf.is_empty() => return None,
                Ok(0) => return Some(Err(eof())),
                Ok(_) => {}
                Err(e) => return Some(Err(e.into())),
            }
        }
    }
}

fn eof() -> CodecError {
    std::io::Error::new(
        std::io::ErrorKind::UnexpectedEof,
        "bytes remaining on stream",
    )
    .into()
}

/// Payload buffers handed back by dropped bands.
#[derive(Debug, Default)]
struct Pool {
    free: Mutex<Vec<Vec<u8>>>,
}

impl Pool {
    /// A buffer for `len` payload bytes: the most recently freed one large enough (its pages
    /// are the likeliest to still be in cache), else a new one.
    fn take(self: &Arc<Self>, len: usize) -> Pooled {
        let reused = {
            let mut free = self.free.lock().unwrap_or_else(|e| e.into_inner());
            let last = free.iter().rposition(|b| b.len() >= len);
            last.map(|i| free.remove(i))
        };
        Pooled {
            buf: reused.unwrap_or_else(|| vec![0; len]),
            len,
            pool: Arc::clone(self),
        }
    }

    fn put(&self, buf: Vec<u8>) {
        let mut free = self.free.lock().unwrap_or_else(|e| e.into_inner());
        let held: usize = free.iter().map(Vec::len).sum();
        if free.len() < POOL_BUFFERS && held + buf.len() <= POOL_BYTES {
            free.push(buf);
        }
    }
}

/// A payload in a pooled buffer (its first `len` bytes); back to the pool on drop.
#[derive(Debug)]
struct Pooled {
    buf: Vec<u8>,
    len: usize,
    pool: Arc<Pool>,
}

impl AsRef<[u8]> for Pooled {
    fn as_ref(&self) -> &[u8] {
        &self.buf[..self.len]
    }
}

impl Drop for Pooled {
    fn drop(&mut self) {
        self.pool.put(std::mem::take(&mut self.buf));
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use lightfold_protocol::{Layer, Message, PixelFormat};
    use std::time::Duration;
    use tokio::net::{TcpListener, TcpStream};

    const MAX: usize = 64 << 20;

    async fn pair() -> (TcpStream, TcpStream) {
        let listener = TcpListener::bind("127.0.0.1:0").await.unwrap();
        let dial = TcpStream::connect(listener.local_addr().unwrap());
        let (a, b) = tokio::join!(dial, listener.accept());
        (a.unwrap(), b.unwrap().0)
    }

    /// A sealed band of `pixels` f16x6 pixels (one row), payload bytes from `seed`.
    fn band(frame: u64, pixels: u32, seed: u8) -> Frame {
        let payload: Vec<u8> = (0..pixels as usize * 12)
            .map(|i| (i as u8).wrapping_mul(31) ^ seed)
            .collect();
        let mut h = BandHeader {
            frame,
            epoch: 1,
            layer: Layer::Illumination,
            format: PixelFormat::F16x6,
            x0: 0,
            y0: 0,
            width: pixels,
            height: 1,
            scale: 1.0,
            empty: pixels == 0,
            payload_len: 0,
            checksum: 0,
            saturated: 0,
        };
        h.seal(&payload);
        Frame::Band(h, Bytes::from(payload))
    }

    fn encoded(frames: &[Frame]) -> Vec<u8> {
        let mut out = BytesMut::new();
        for f in frames {
            Codec::new(MAX).encode(f, &mut out).unwrap();
        }
        out.to_vec()
    }

    #[tokio::test]
    async fn bands_and_messages_cross_unchanged() {
        let (a, b) = pair().await;
        let mut writer = FrameWriter::new(a.into_split().1, MAX);
        let mut reader = FrameReader::new(b.into_split().0, MAX);
        let frames = vec![
            Frame::Control(Message::Ping { seq: 1 }),
            band(1, 0, 0),
            band(2, 1, 1),
            band(3, 262_144, 2),
            Frame::Control(Message::Pong { seq: 2 }),
            band(4, 1_001, 3),
            band(5, 262_144, 4),
            band(6, 5, 5),
        ];
        let sent = frames.clone();
        let send = tokio::spawn(async move {
            // Both ways of writing: one by one, and a burst fed then flushed.
            for f in sent[..4].iter().cloned() {
                writer.send(f).await.unwrap();
            }
            for f in sent[4..].iter().cloned() {
                writer.feed(f).await.unwrap();
            }
            writer.flush().await.unwrap();
        });
        for f in &frames {
            let got = reader.next().await.unwrap().unwrap();
            assert_eq!(&got, f);
        }
        send.await.unwrap();
        assert!(reader.next().await.is_none(), "clean close between frames");
    }

    #[tokio::test]
    async fn a_dropped_band_lends_its_buffer_to_the_next() {
        let (mut a, b) = pair().await;
        let mut reader = FrameReader::new(b.into_split().0, MAX);
        let bytes = encoded(&[band(1, 100_000, 1), band(2, 100_000, 2), band(3, 90_000, 3)]);
        a.write_all(&bytes).await.unwrap();
        let Frame::Band(_, first) = reader.next().await.unwrap().unwrap() else {
            panic!("not a band");
        };
        let at = first.as_ptr();
        drop(first);
        let Frame::Band(_, second) = reader.next().await.unwrap().unwrap() else {
            panic!("not a band");
        };
        assert_eq!(second.as_ptr(), at, "the freed buffer was not reused");
        // While the second is held, the third needs a buffer of its own.
        let Frame::Band(_, third) = reader.next().await.unwrap().unwrap() else {
            panic!("not a band");
        };
        assert_ne!(third.as_ptr(), at);
    }

    #[tokio::test]
    async fn a_read_cut_short_by_a_deadline_resumes() {
        let (mut a, b) = pair().await;
        let mut reader = FrameReader::new(b.into_split().0, MAX);
        let frames = [
            band(1, 200_000, 7),
            Frame::Control(Message::Ping { seq: 3 }),
        ];
        let bytes = encoded(&frames);
        let write = tokio::spawn(async move {
            // The head split across writes, then the payload in pieces.
            for piece in bytes.chunks(bytes.len() / 9 + 1).flat_map(|c| {
                let (x, y) = c.split_at(c.len().min(30));
                [x.to_vec(), y.to_vec()]
            }) {
                a.write_all(&piece).await.unwrap();
                tokio::time::sleep(Duration::from_millis(3)).await;
            }
        });
        let mut got = Vec::new();
        let mut cut = 0;
        while got.len() < frames.len() {
            match tokio::time::timeout(Duration::from_millis(1), reader.next()).await {
                Err(_) => cut += 1,
                Ok(f) => got.push(f.unwrap().unwrap()),
            }
        }
        write.await.unwrap();
        assert!(cut > 5, "the reads were never interrupted ({cut})");
        assert_eq!(got, frames);
    }

    #[tokio::test]
    async fn a_corrupt_payload_and_a_cut_stream_are_errors() {
        let (mut a, b) = pair().await;
        let mut reader = FrameReader::new(b.into_split().0, MAX);
        let mut bytes = encoded(&[band(1, 1000, 1)]);
        let last = bytes.len() - 1;
        bytes[last] ^= 1;
        a.write_all(&bytes).await.unwrap();
        let e = reader.next().await.unwrap().unwrap_err();
        assert!(
            matches!(
                e,
                CodecError::Protocol(lightfold_protocol::ProtocolError::ChecksumMismatch { .. })
            ),
            "{e}"
        );

        let (mut a, b) = pair().await;
        let mut reader = FrameReader::new(b.into_split().0, MAX);
        let bytes = encoded(&[band(1, 1000, 1)]);
        a.write_all(&bytes[..bytes.len() - 10]).await.unwrap();
        drop(a);
        let e = reader.next().await.unwrap().unwrap_err();
        assert!(e.to_string().contains("bytes remaining"), "{e}");
    }
}
