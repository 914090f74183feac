//! The baseline of the link benchmark: the same bytes over plain TCP sockets in the stage's
//! topology, and the process CPU clock both are judged by.

use std::time::Instant;
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::{TcpListener, TcpStream};

/// CPU time (user + system) this process has used, in ms (from `/proc/self/stat`, 10 ms ticks:
/// only sums over many frames are meaningful).
pub fn cpu_ms() -> f64 {
    let stat = std::fs::read_to_string("/proc/self/stat").unwrap_or_default();
    // Fields after the parenthesised command name; utime and stime are fields 14 and 15.
    let rest = stat.rsplit_once(')').map_or("", |(_, r)| r);
    let f: Vec<&str> = rest.split_whitespace().collect();
    let ticks = |i: usize| f.get(i).and_then(|v| v.parse::<f64>().ok()).unwrap_or(0.0);
    (ticks(11) + ticks(12)) * 10.0
}

/// The same bytes over plain sockets: two senders → relay → receiver, the relay writing output
/// band k once it has read input band k of both senders (as the stage does, minus the work).
pub struct RawRelay {
    senders: Vec<TcpStream>,
    ins: Vec<TcpStream>,
    out: TcpStream,
    recv: TcpStream,
    in_sizes: Vec<Vec<usize>>,
    out_sizes: Vec<usize>,
    zeros: Vec<u8>,
}

impl RawRelay {
    pub async fn new(in_sizes: Vec<Vec<usize>>, out_sizes: Vec<usize>) -> RawRelay {
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
            zeros: vec![0u8; max],
        }
    }

    /// One frame; returns its time in ms.
    pub async fn frame(&mut self) -> f64 {
        let start = Instant::now();
        let RawRelay {
            senders,
            ins,
            out,
            recv,
            in_sizes,
            out_sizes,
            zeros,
        } = self;
        let (s0, s1) = senders.split_at_mut(1);
        let (i0, i1) = ins.split_at_mut(1);
        let per_out = in_sizes[0].len() / out_sizes.len();
        let relay = async {
            let mut buf = vec![0u8; zeros.len()];
            for (band, &n) in out_sizes.iter().enumerate() {
                for k in band * per_out..(band + 1) * per_out {
                    i0[0].read_exact(&mut buf[..in_sizes[0][k]]).await.unwrap();
                    i1[0].read_exact(&mut buf[..in_sizes[1][k]]).await.unwrap();
                }
                out.write_all(&buf[..n]).await.unwrap();
            }
        };
        let sink = async {
            let mut buf = vec![0u8; zeros.len()];
            for &n in out_sizes.iter() {
                recv.read_exact(&mut buf[..n]).await.unwrap();
            }
        };
        tokio::join!(
            send_raw(&mut s0[0], &in_sizes[0], zeros),
            send_raw(&mut s1[0], &in_sizes[1], zeros),
            relay,
            sink
        );
        start.elapsed().as_secs_f64() * 1e3
    }
}

async fn send_raw(s: &mut TcpStream, sizes: &[usize], zeros: &[u8]) {
    for &n in sizes {
        s.write_all(&zeros[..n]).await.unwrap();
    }
}
