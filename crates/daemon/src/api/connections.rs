//! Connection bookkeeping of the API server, so that slow or hostile clients cannot lock others out:
//!
//! - At most [`ConnectionLimits::max_connections`] connections are open at once.
//! - When every slot is taken, the oldest connection that is not serving a request (idle between requests, still
//!   sending its request headers, or trickling a request body) is closed to admit the newcomer. A client that
//!   holds connections open without finishing requests (slowloris) therefore cannot keep a new client out; only
//!   requests really being served are never cut.
//! - A connection whose writes make no progress for [`ConnectionLimits::write_timeout`] (a client that stopped
//!   reading, e.g. an event stream nobody consumes) is closed.
//!
//! Header and body read deadlines live with hyper (`header_read_timeout`) and the handlers (the body read of a
//! campaign submission); the number of event streams is bounded in [`super`].

use std::io;
use std::pin::Pin;
use std::sync::atomic::{AtomicU64, AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};
use std::task::{Context, Poll};
use std::time::Duration;

use tokio::io::{AsyncRead, AsyncWrite, ReadBuf};
use tokio::sync::Notify;
use tokio::time::{Instant, Sleep};

/// Limits of the server loop.
#[derive(Debug, Clone, Copy)]
pub struct ConnectionLimits {
    /// Connections open at most; past it the oldest idle one is closed, or the newcomer waits.
    pub max_connections: usize,
    /// Time a client has to send its request headers (from the connection's start or the previous response).
    pub header_read_timeout: Duration,
    /// A write blocked this long (the client does not read) ends the connection.
    pub write_timeout: Duration,
}

/// One open connection as the registry sees it.
#[derive(Debug)]
pub(crate) struct Conn {
    id: u64,
    opened: Instant,
    /// Requests in flight that must not be cut (a request reading its body is not counted while it reads).
    busy: AtomicUsize,
    evict: Notify,
}

impl Conn {
    /// Resolves when the registry wants this connection closed.
    pub(crate) async fn evicted(&self) {
        self.evict.notified().await;
    }
}

/// The open connections.
#[derive(Debug, Default)]
pub(crate) struct Registry {
    open: Mutex<Vec<Arc<Conn>>>,
    next_id: AtomicU64,
}

impl Registry {
    fn lock(&self) -> std::sync::MutexGuard<'_, Vec<Arc<Conn>>> {
        self.open.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// Register a new connection; it leaves the registry when the returned entry is dropped.
    pub(crate) fn open(self: &Arc<Self>) -> Entry {
        let conn = Arc::new(Conn {
            id: self.next_id.fetch_add(1, Ordering::Relaxed),
            opened: Instant::now(),
            busy: AtomicUsize::new(0),
            evict: Notify::new(),
        });
        self.lock().push(Arc::clone(&conn));
        Entry {
            registry: Arc::clone(self),
            conn,
        }
    }

    /// Ask the oldest connection that serves no request to close; false when every connection is busy.
    pub(crate) fn evict_oldest_idle(&self) -> bool {
        let open = self.lock();
        let victim = open
            .iter()
            .filter(|c| c.busy.load(Ordering::SeqCst) == 0)
            .min_by_key(|c| (c.opened, c.id));
        match victim {
            Some(c) => {
                // `notify_one` keeps the wake-up if the connection task is not waiting at this instant.
                c.evict.notify_one();
                true
            }
            None => false,
        }
    }

    /// Connections open now.
    pub(crate) fn len(&self) -> usize {
        self.lock().len()
    }
}

/// A registered connection; unregisters on drop.
#[derive(Debug)]
pub(crate) struct Entry {
    registry: Arc<Registry>,
    conn: Arc<Conn>,
}

impl Entry {
    pub(crate) fn conn(&self) -> &Arc<Conn> {
        &self.conn
    }
}

impl Drop for Entry {
    fn drop(&mut self) {
        let id = self.conn.id;
        self.registry.lock().retain(|c| c.id != id);
    }
}

/// Marks a request in flight on its connection (not evictable) for as long as it lives: created when the
/// request arrives, dropped with the response body once it is sent.
#[derive(Debug)]
pub(crate) struct Busy(Arc<Conn>);

impl Busy {
    pub(crate) fn new(conn: &Arc<Conn>) -> Busy {
        conn.busy.fetch_add(1, Ordering::SeqCst);
        Busy(Arc::clone(conn))
    }
}

impl Drop for Busy {
    fn drop(&mut self) {
        self.0.busy.fetch_sub(1, Ordering::SeqCst);
    }
}

/// The request's connection, in the request's extensions, so that a handler can say when it only waits for the
/// client (reading the body): then the connection may be closed under pressure.
#[derive(Debug, Clone)]
pub(crate) struct ConnTag(pub(crate) Arc<Conn>);

impl ConnTag {
    /// While the returned guard lives, this request does not keep its connection from being evicted.
    pub(crate) fn waiting_for_client(&self) -> WaitingForClient {
        self.0.busy.fetch_sub(1, Ordering::SeqCst);
        WaitingForClient(Arc::clone(&self.0))
    }
}

#[derive(Debug)]
pub(crate) struct WaitingForClient(Arc<Conn>);

impl Drop for WaitingForClient {
    fn drop(&mut self) {
        self.0.busy.fetch_add(1, Ordering::SeqCst);
    }
}

/// A byte stream whose writes fail with `TimedOut` when they make no progress for `timeout`.
#[derive(Debug)]
pub(crate) struct WriteDeadline<T> {
    inner: T,
    timeout: Duration,
    stalled: Option<Pin<Box<Sleep>>>,
}

impl<T> WriteDeadline<T> {
    pub(crate) fn new(inner: T, timeout: Duration) -> WriteDeadline<T> {
        WriteDeadline {
            inner,
            timeout,
            stalled: None,
        }
    }

    /// `Pending` from the inner stream: start (or keep) the clock, and fail once it runs out.
    fn pending<R>(&mut self, cx: &mut Context<'_>) -> Poll<io::Result<R>> {
        let timeout = self.timeout;
        let timer = self
            .stalled
            .get_or_insert_with(|| Box::pin(tokio::time::sleep(timeout)));
        match timer.as_mut().poll(cx) {
            Poll::Ready(()) => {
                self.stalled = None;
                Poll::Ready(Err(io::Error::new(
                    io::ErrorKind::TimedOut,
                    format!("the client read nothing for {timeout:?}"),
                )))
            }
            Poll::Pending => Poll::Pending,
        }
    }
}

impl<T: AsyncRead + Unpin> AsyncRead for WriteDeadline<T> {
    fn poll_read(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &mut ReadBuf<'_>,
    ) -> Poll<io::Result<()>> {
        Pin::new(&mut self.inner).poll_read(cx, buf)
    }
}

impl<T: AsyncWrite + Unpin> AsyncWrite for WriteDeadline<T> {
    fn poll_write(mut self: Pin<&mut Self>, cx: &mut Context<'_>, buf: &[u8]) -> Poll<io::Result<usize>> {
        match Pin::new(&mut self.inner).poll_write(cx, buf) {
            Poll::Pending => self.pending(cx),
            ready => {
                self.stalled = None;
                ready
            }
        }
    }

    fn poll_flush(mut self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<io::Result<()>> {
        match Pin::new(&mut self.inner).poll_flush(cx) {
            Poll::Pending => self.pending(cx),
            ready => {
                self.stalled = None;
                ready
            }
        }
    }

    fn poll_shutdown(mut self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<io::Result<()>> {
        Pin::new(&mut self.inner).poll_shutdown(cx)
    }

    fn poll_write_vectored(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        bufs: &[io::IoSlice<'_>],
    ) -> Poll<io::Result<usize>> {
        match Pin::new(&mut self.inner).poll_write_vectored(cx, bufs) {
            Poll::Pending => self.pending(cx),
            ready => {
                self.stalled = None;
                ready
            }
        }
    }

    fn is_write_vectored(&self) -> bool {
        self.inner.is_write_vectored()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[tokio::test(start_paused = true)]
    async fn the_oldest_idle_connection_is_evicted_and_busy_ones_never() {
        let registry = Arc::new(Registry::default());
        let a = registry.open();
        tokio::time::advance(Duration::from_millis(1)).await;
        let b = registry.open();
        tokio::time::advance(Duration::from_millis(1)).await;
        let c = registry.open();
        assert_eq!(registry.len(), 3);
        let busy_a = Busy::new(a.conn());
        // a is the oldest but busy: b goes.
        assert!(registry.evict_oldest_idle());
        let evicted = |e: &Entry| {
            let conn = Arc::clone(e.conn());
            async move {
                tokio::time::timeout(Duration::from_millis(1), conn.evicted())
                    .await
                    .is_ok()
            }
        };
        assert!(evicted(&b).await);
        assert!(!evicted(&a).await && !evicted(&c).await);
        drop(b);
        assert_eq!(registry.len(), 2);
        // A request reading its body does not protect its connection.
        let tag = ConnTag(Arc::clone(a.conn()));
        let waiting = tag.waiting_for_client();
        let busy_c = Busy::new(c.conn());
        assert!(registry.evict_oldest_idle());
        assert!(evicted(&a).await);
        drop(waiting);
        // Everything busy: nothing to evict.
        assert!(!registry.evict_oldest_idle());
        drop((busy_a, busy_c));
        assert!(registry.evict_oldest_idle());
    }

    #[tokio::test(start_paused = true)]
    async fn a_write_that_makes_no_progress_times_out() {
        // A duplex pipe with a tiny buffer that nobody reads.
        let (near, _far) = tokio::io::duplex(8);
        let mut stream = WriteDeadline::new(near, Duration::from_secs(5));
        use tokio::io::AsyncWriteExt;
        stream.write_all(b"12345678").await.expect("fits in the buffer");
        let start = Instant::now();
        let err = stream.write_all(b"more").await.expect_err("blocked");
        assert_eq!(err.kind(), io::ErrorKind::TimedOut);
        let waited = start.elapsed();
        assert!(
            waited >= Duration::from_secs(5) && waited < Duration::from_millis(5010),
            "{waited:?}"
        );
    }
}
