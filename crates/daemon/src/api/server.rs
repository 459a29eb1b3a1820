//! The server loop: accepting connections on the listener under the [`ConnectionLimits`], serving each with
//! hyper, and the daemon's whole life ([`run_daemon`]): queue and API up, then a bounded, orderly shutdown.

use std::convert::Infallible;
use std::net::SocketAddr;
use std::sync::Arc;
use std::time::Duration;

use axum::Router;
use tokio::net::TcpListener;
use tokio::sync::{Semaphore, mpsc};

use super::{ApiConfig, CONNECTION_DRAIN, ConnectionLimits, check_listen, connections, router};
use crate::service::{Service, Shutdown};

/// Serve `app` on `listener` until `shutdown` with the default [`ConnectionLimits`] (see [`serve_with`]).
pub async fn serve(listener: TcpListener, app: Router, shutdown: Shutdown, complete: mpsc::Sender<()>) {
    serve_with(listener, app, ConnectionLimits::default(), shutdown, complete).await;
}

/// Serve `app` on `listener` until `shutdown`, then let open connections finish (bounded). `_complete` is
/// dropped when every connection has ended. Connections are bounded and policed as [`connections`] says.
pub async fn serve_with(
    listener: TcpListener,
    app: Router,
    limits: ConnectionLimits,
    mut shutdown: Shutdown,
    complete: mpsc::Sender<()>,
) {
    let slots = Arc::new(Semaphore::new(limits.max_connections.max(1)));
    let registry = Arc::new(connections::Registry::default());
    loop {
        let (stream, peer) = tokio::select! {
            accepted = listener.accept() => match accepted {
                Ok(a) => a,
                Err(e) => {
                    // Out of file descriptors and the like: back off instead of spinning.
                    tracing::warn!("accept failed: {e}");
                    tokio::time::sleep(Duration::from_millis(100)).await;
                    continue;
                }
            },
            _ = shutdown.recv() => break,
        };
        let permit = match Arc::clone(&slots).try_acquire_owned() {
            Ok(p) => p,
            Err(_) => {
                // Full: close the oldest connection that is not being served, else wait for one to end.
                if registry.evict_oldest_idle() {
                    tracing::warn!(%peer, open = registry.len(), "connection limit reached: closing the oldest idle connection");
                } else {
                    tracing::warn!(%peer, open = registry.len(), "connection limit reached: every connection is busy, waiting");
                }
                tokio::select! {
                    p = Arc::clone(&slots).acquire_owned() => match p { Ok(p) => p, Err(_) => break },
                    _ = shutdown.recv() => break,
                }
            }
        };
        let entry = registry.open();
        let mut conn_shutdown = shutdown.clone();
        let complete = complete.clone();
        let app = app.clone();
        tokio::spawn(async move {
            let _permit = permit;
            let _complete = complete;
            serve_connection(stream, peer, app, entry, limits, &mut conn_shutdown).await;
        });
    }
    tracing::info!("no longer accepting connections");
}

/// One connection: HTTP/1.1 with the header deadline, the write deadline, eviction, and the requests marked
/// busy while they are served.
async fn serve_connection(
    stream: tokio::net::TcpStream,
    peer: SocketAddr,
    app: Router,
    entry: connections::Entry,
    limits: ConnectionLimits,
    shutdown: &mut Shutdown,
) {
    use http_body_util::BodyExt;
    use hyper_util::rt::{TokioIo, TokioTimer};
    use hyper_util::service::TowerToHyperService;

    let conn = Arc::clone(entry.conn());
    let inner = TowerToHyperService::new(app);
    let tracked = Arc::clone(&conn);
    let service = hyper::service::service_fn(move |mut request: hyper::Request<hyper::body::Incoming>| {
        let busy = connections::Busy::new(&tracked);
        request
            .extensions_mut()
            .insert(connections::ConnTag(Arc::clone(&tracked)));
        let response = hyper::service::Service::call(&inner, request);
        async move {
            let response = response.await?;
            // The request counts as served until its response body is sent (event streams: until they end).
            Ok::<_, Infallible>(response.map(|body| {
                axum::body::Body::new(body.map_frame(move |frame| {
                    let _ = &busy;
                    frame
                }))
            }))
        }
    });
    let io = TokioIo::new(connections::WriteDeadline::new(stream, limits.write_timeout));
    let mut builder = hyper::server::conn::http1::Builder::new();
    builder
        .timer(TokioTimer::new())
        .header_read_timeout(limits.header_read_timeout);
    let http = builder.serve_connection(io, service);
    let mut http = std::pin::pin!(http);
    tokio::select! {
        r = http.as_mut() => {
            if let Err(e) = r { tracing::debug!(%peer, "connection ended: {e}"); }
        }
        _ = conn.evicted() => {
            tracing::debug!(%peer, "connection closed to admit a new client");
        }
        _ = shutdown.recv() => {
            http.as_mut().graceful_shutdown();
            let _ = tokio::time::timeout(CONNECTION_DRAIN, http).await;
        }
    }
    drop(entry);
}

/// Run the daemon on a bound listener: the campaign queue and the API, until `signal` completes; then stop the
/// running campaign at a safe point and wait for every task to finish. A listener that breaks the token rule
/// ([`check_listen`]) is refused: nothing is served.
pub async fn run_daemon(
    listener: TcpListener,
    service: Service,
    config: &ApiConfig,
    signal: impl std::future::Future<Output = ()>,
) {
    match listener.local_addr() {
        Ok(addr) => {
            if let Err(e) = check_listen(addr, config.token.as_deref()) {
                tracing::error!("{e}");
                return;
            }
        }
        Err(e) => {
            tracing::error!("cannot read the listening address: {e}");
            return;
        }
    }
    let trigger = crate::service::ShutdownTrigger::new();
    let (complete_tx, mut complete_rx) = mpsc::channel::<()>(1);
    let queue = {
        let service = service.clone();
        let shutdown = trigger.subscribe();
        let complete = complete_tx.clone();
        tokio::spawn(async move { service.run_queue(shutdown, complete).await })
    };
    let mut config = config.clone();
    if config.listen_addr.is_none() {
        config.listen_addr = listener.local_addr().ok();
    }
    let app = router(service, &config, trigger.subscribe());
    let server = tokio::spawn(serve_with(
        listener,
        app,
        config.connection_limits(),
        trigger.subscribe(),
        complete_tx.clone(),
    ));
    drop(complete_tx);
    signal.await;
    tracing::info!("shutting down");
    trigger.trigger();
    // Every task holds a completion sender: recv() returns None once all are gone.
    let _ = complete_rx.recv().await;
    let _ = queue.await;
    let _ = server.await;
    tracing::info!("shutdown complete");
}
