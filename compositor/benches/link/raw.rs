//! The baseline of the link benchmark: the same bytes over plain TCP sockets in the stage's
//! topology, and the process CPU clock both are judged by.

use std::time::Instant;
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::{TcpListener, TcpStream};
use tokio::sync::mpsc;

/// CPU time (user + system) this process has used, in ms (from `/proc/self/stat`, 10 ms ticks:
/// only sums over many frames are meaningful).
pub(crate) fn cpu_ms() -> f64 {
    let stat = std::fs::read_to_string("/proc/self/stat").unwrap_or_default();
    // Fields after the parenthesised command name; utime and stime are fields 14 and 15.
    let rest = stat.rsplit_once(')').map_or("", |(_, r)| r);
    let f: Vec<&str> = rest.split_whitespace().collect();
    let ticks = |i: usize| f.get(i).and_then(|v| v.parse::<f64>().ok()).unwrap_or(0.0);
    (ticks(11) + ticks(12)) * 10.0
}

/// The same bytes over plain sockets: two senders → relay → receiver, the relay writing output
/// band k once it has read input band k of both senders (as the stage does, minus the work).
/// All four ends run in the caller's task, so on one thread: the kernel copies a byte out of a
/// socket on the core that just copied it in. Every buffer is allocated once and reused.
pub(crate) struct RawRelay {
    senders: Vec<TcpStream>,
    ins: Vec<TcpStream>,
    out: TcpStream,
    recv: TcpStream,
    in_sizes: Vec<Vec<usize>>,
    out_sizes: Vec<usize>,
    data: Vec<u8>,
    relay_buf: Vec<u8>,
    sink_buf: Vec<u8>,
}

impl RawRelay {
    pub(crate) async fn new(in_sizes: Vec<Vec<usize>>, out_sizes: Vec<usize>) -> RawRelay {
        let relay_l = TcpListener::bind("127.0.0.1:0").await.unwrap();
        let sink_l = TcpListener::bind("127.0.0.1:0").await.unwrap();
        let mut senders = Vec::new();
        let mut ins = Vec::new();
        for _ in 0..2 {
            let s = TcpStream::connect(relay_l.local_addr().unwrap())
                .await
                .unwrap();
            s.set_nodelay(true).unwrap();
            senders.push(s);
            ins.push(relay_l.accept().await.unwrap().0);
        }
        let out = TcpStream::connect(sink_l.local_addr().unwrap())
            .await
            .unwrap();
        out.set_nodelay(true).unwrap();
        let recv = sink_l.accept().await.unwrap().0;
        let max = in_sizes
            .iter()
            .flatten()
            .chain(&out_sizes)
            .copied()
            .max()
            .unwrap_or(0);
        RawRelay {
            senders,
            ins,
            out,
            recv,
            in_sizes,
            out_sizes,
            data: vec![1u8; max],
            relay_buf: vec![1u8; max],
            sink_buf: vec![1u8; max],
        }
    }

    /// One frame; returns its time in ms.
    pub(crate) async fn frame(&mut self) -> f64 {
        let start = Instant::now();
        let RawRelay {
            senders,
            ins,
            out,
            recv,
            in_sizes,
            out_sizes,
            data,
            relay_buf,
            sink_buf,
        } = self;
        let (i0, i1) = ins.split_at_mut(1);
        let (i0, i1) = (&mut i0[0], &mut i1[0]);
        let relay = relay_frame([i0, i1], out, in_sizes, out_sizes, relay_buf);
        let sink = receive(recv, out_sizes, sink_buf);
        let (s0, s1) = senders.split_at_mut(1);
        tokio::join!(
            send_raw(&mut s0[0], &in_sizes[0], data),
            send_raw(&mut s1[0], &in_sizes[1], data),
            relay,
            sink
        );
        start.elapsed().as_secs_f64() * 1e3
    }

    /// The same with the relay in a task of its own, which the runtime runs on a worker thread
    /// (as it runs a stage's tasks), while the senders and the receiver stay with the caller (as
    /// the producers and the sink of the stage path do): bytes then cross cores and threads wake
    /// each other, as they do for the stage.
    pub(crate) fn spawn_relay(self) -> SpawnedRelay {
        let RawRelay {
            senders,
            ins,
            out,
            recv,
            in_sizes,
            out_sizes,
            data,
            relay_buf,
            sink_buf,
        } = self;
        let (go, mut frames) = mpsc::channel::<()>(1);
        let (sizes, outs) = (in_sizes.clone(), out_sizes.clone());
        tokio::spawn(async move {
            let (mut ins, mut out, mut buf) = (ins, out, relay_buf);
            while frames.recv().await.is_some() {
                let (i0, i1) = ins.split_at_mut(1);
                relay_frame([&mut i0[0], &mut i1[0]], &mut out, &sizes, &outs, &mut buf).await;
            }
        });
        SpawnedRelay {
            senders,
            recv,
            in_sizes,
            out_sizes,
            data,
            sink_buf,
            go,
        }
    }
}

/// [`RawRelay`] with its relay in a task of its own ([`RawRelay::spawn_relay`]).
pub(crate) struct SpawnedRelay {
    senders: Vec<TcpStream>,
    recv: TcpStream,
    in_sizes: Vec<Vec<usize>>,
    out_sizes: Vec<usize>,
    data: Vec<u8>,
    sink_buf: Vec<u8>,
    go: mpsc::Sender<()>,
}

impl SpawnedRelay {
    /// One frame; returns its time in ms.
    pub(crate) async fn frame(&mut self) -> f64 {
        let start = Instant::now();
        self.go.send(()).await.unwrap();
        let (s0, s1) = self.senders.split_at_mut(1);
        tokio::join!(
            send_raw(&mut s0[0], &self.in_sizes[0], &self.data),
            send_raw(&mut s1[0], &self.in_sizes[1], &self.data),
            receive(&mut self.recv, &self.out_sizes, &mut self.sink_buf)
        );
        start.elapsed().as_secs_f64() * 1e3
    }
}

/// Reads band k of both inputs, then writes output band k.
async fn relay_frame(
    ins: [&mut TcpStream; 2],
    out: &mut TcpStream,
    in_sizes: &[Vec<usize>],
    out_sizes: &[usize],
    buf: &mut [u8],
) {
    let per_out = in_sizes[0].len() / out_sizes.len();
    let [i0, i1] = ins;
    for (band, &n) in out_sizes.iter().enumerate() {
        for k in band * per_out..(band + 1) * per_out {
            i0.read_exact(&mut buf[..in_sizes[0][k]]).await.unwrap();
            i1.read_exact(&mut buf[..in_sizes[1][k]]).await.unwrap();
        }
        out.write_all(&buf[..n]).await.unwrap();
    }
}

async fn receive(recv: &mut TcpStream, sizes: &[usize], buf: &mut [u8]) {
    for &n in sizes {
        recv.read_exact(&mut buf[..n]).await.unwrap();
    }
}

async fn send_raw(s: &mut TcpStream, sizes: &[usize], data: &[u8]) {
    for &n in sizes {
        s.write_all(&data[..n]).await.unwrap();
    }
}
