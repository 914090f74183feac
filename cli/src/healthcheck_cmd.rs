//! `lightfold healthcheck`: asks a daemon's `/healthz` (or `/readyz`) and exits 0 when it answers
//! 200 — for engines whose probes run a command in the container (a container image's
//! `HEALTHCHECK`, which has no HTTP client in a slim image). Every step has a deadline.

use anyhow::{Context, bail};
use std::io::{Read, Write};
use std::net::{SocketAddr, TcpStream, ToSocketAddrs};
use std::time::Duration;

#[derive(Debug, clap::Args)]
pub(crate) struct Args {
    /// The daemon's `--metrics-listen` address; a wildcard host (`0.0.0.0`, `[::]`) is asked on
    /// loopback.
    #[arg(
        long,
        alias = "metrics-listen",
        env = "LIGHTFOLD_METRICS_LISTEN",
        default_value = "127.0.0.1:9300"
    )]
    pub addr: String,
    /// Ask `/readyz` (registered and configured, or serving) instead of `/healthz` (live).
    #[arg(long)]
    pub ready: bool,
    /// Seconds to wait for the answer.
    #[arg(long, default_value_t = 3.0)]
    pub timeout: f64,
}

/// The address to dial for a listen address: a wildcard host means this machine.
fn dial_addr(listen: &str) -> anyhow::Result<SocketAddr> {
    let mut a = listen
        .to_socket_addrs()
        .with_context(|| format!("bad address {listen:?}"))?
        .next()
        .with_context(|| format!("{listen:?} resolves to nothing"))?;
    if a.ip().is_unspecified() {
        a.set_ip(match a {
            SocketAddr::V4(_) => std::net::Ipv4Addr::LOCALHOST.into(),
            SocketAddr::V6(_) => std::net::Ipv6Addr::LOCALHOST.into(),
        });
    }
    Ok(a)
}

pub(crate) fn run(args: Args) -> anyhow::Result<()> {
    let wait = Duration::try_from_secs_f64(args.timeout)
        .ok()
        .filter(|d| !d.is_zero())
        .with_context(|| format!("--timeout {} is not a duration", args.timeout))?;
    let addr = dial_addr(&args.addr)?;
    let path = if args.ready { "/readyz" } else { "/healthz" };
    let mut s = TcpStream::connect_timeout(&addr, wait)
        .with_context(|| format!("cannot connect to {addr}"))?;
    s.set_read_timeout(Some(wait))?;
    s.set_write_timeout(Some(wait))?;
    write!(
        s,
        "GET {path} HTTP/1.1\r\nHost: {addr}\r\nConnection: close\r\n\r\n"
    )?;
    let mut reply = Vec::new();
    s.take(64 << 10)
        .read_to_end(&mut reply)
        .with_context(|| format!("no answer from {addr}{path}"))?;
    let reply = String::from_utf8_lossy(&reply);
    let status = reply.split_whitespace().nth(1).unwrap_or("");
    let body = reply.split_once("\r\n\r\n").map_or("", |x| x.1).trim();
    if status != "200" {
        bail!("{addr}{path}: {status} {body}");
    }
    lightfold_telemetry::outln!("{addr}{path}: {body}");
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_address_is_also_taken_as_metrics_listen() {
        #[derive(Debug, clap::Parser)]
        struct Cmd {
            #[command(flatten)]
            args: Args,
        }
        use clap::Parser;
        let a = Cmd::try_parse_from(["healthcheck", "--metrics-listen", "0.0.0.0:9400"]).unwrap();
        assert_eq!(a.args.addr, "0.0.0.0:9400");
        let b = Cmd::try_parse_from(["healthcheck", "--addr", "127.0.0.1:1"]).unwrap();
        assert_eq!(b.args.addr, "127.0.0.1:1");
    }

    #[test]
    fn a_wildcard_host_is_asked_on_loopback() {
        assert_eq!(
            dial_addr("0.0.0.0:9300").unwrap(),
            "127.0.0.1:9300".parse().unwrap()
        );
        assert_eq!(dial_addr("[::]:1").unwrap(), "[::1]:1".parse().unwrap());
        assert_eq!(
            dial_addr("10.1.2.3:9300").unwrap(),
            "10.1.2.3:9300".parse().unwrap()
        );
        assert!(dial_addr("nonsense").is_err());
    }
}
