//! A producer's data link to its consumer (a node's to its compositor, a compositor's to the next
//! stage or the coordinator's sink). It is dialled (with retry until a deadline) as soon as a
//! configuration names the address, so configuration order does not matter and the first frame
//! does not pay for the connection; it is kept while the address stays the same, and dropped on
//! any send error so the next frame dials afresh (a DNS name is then resolved again). A consumer
//! that closes the link (a re-plan that left this producer out of its inputs for a while) is
//! noticed by a task that watches the link's reading half, so the next frame dials afresh instead
//! of writing into a closed connection. Consumers keep their writing half open while they hold a
//! link, so end-of-stream on the reading half means "let go" (ARCHITECTURE.md, Decisions).

use crate::{Identity, LinkWriter, NetError, Timeouts, dial_retry};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;
use tokio::task::JoinHandle;

#[derive(Debug)]
enum State {
    None,
    Dialling(JoinHandle<Result<(LinkWriter, Arc<AtomicBool>), NetError>>),
    /// The writer, and whether the compositor has closed the connection.
    Ready(Box<LinkWriter>, Arc<AtomicBool>),
}

/// A producer's one downstream data link.
#[derive(Debug)]
pub struct Downstream {
    me: Identity,
    timeouts: Timeouts,
    deadline: Duration,
    addr: String,
    state: State,
}

impl Downstream {
    pub fn new(me: Identity, timeouts: Timeouts, deadline: Duration) -> Downstream {
        Downstream {
            me,
            timeouts,
            deadline,
            addr: String::new(),
            state: State::None,
        }
    }

    /// The address the link points at (empty before the first `set_address`).
    pub fn address(&self) -> &str {
        &self.addr
    }

    /// Points the link at `addr`, dialling in the background unless it is already connected (or
    /// connecting) there.
    pub fn set_address(&mut self, addr: &str) {
        if addr == self.addr && !matches!(self.state, State::None) {
            return;
        }
        self.close();
        self.addr = addr.to_string();
        self.state = State::Dialling(self.spawn_dial());
    }

    fn spawn_dial(&self) -> JoinHandle<Result<(LinkWriter, Arc<AtomicBool>), NetError>> {
        let (addr, me, t, total) = (
            self.addr.clone(),
            self.me.clone(),
            self.timeouts,
            self.deadline,
        );
        tokio::spawn(async move {
            let link = dial_retry(&addr, &me, t, total).await?;
            tracing::info!(addr = %addr, peer = %link.peer.daemon_id, "data link up");
            // A consumer sends nothing on a data link: its reading half only tells when the
            // consumer has closed the connection.
            let (mut reader, writer) = link.split();
            let closed = Arc::new(AtomicBool::new(false));
            let flag = closed.clone();
            tokio::spawn(async move {
                while let Some(Ok(_)) = reader.next().await {}
                tracing::debug!(addr = %reader.addr, "the consumer closed the data link");
                flag.store(true, Ordering::Release);
            });
            Ok((writer, closed))
        })
    }

    /// The connected writer, waiting for a dial in progress (or starting one after an error).
    pub async fn writer(&mut self) -> Result<&mut LinkWriter, NetError> {
        if let State::Ready(_, closed) = &self.state
            && closed.load(Ordering::Acquire)
        {
            self.state = State::None;
        }
        if matches!(self.state, State::None) {
            self.state = State::Dialling(self.spawn_dial());
        }
        if let State::Dialling(handle) = &mut self.state {
            let result = match handle.await {
                Ok(r) => r,
                Err(e) => Err(NetError::Io {
                    addr: self.addr.clone(),
                    source: std::io::Error::other(e.to_string()),
                }),
            };
            match result {
                Ok((w, closed)) => self.state = State::Ready(Box::new(w), closed),
                Err(e) => {
                    self.state = State::None;
                    return Err(e);
                }
            }
        }
        match &mut self.state {
            State::Ready(w, _) => Ok(w),
            _ => Err(NetError::Closed {
                addr: self.addr.clone(),
            }),
        }
    }

    /// Drops the link (after a send error, or when the address changes).
    pub fn close(&mut self) {
        if let State::Dialling(h) = std::mem::replace(&mut self.state, State::None) {
            h.abort();
        }
    }
}

impl Drop for Downstream {
    fn drop(&mut self) {
        self.close();
    }
}
