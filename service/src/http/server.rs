//! Serving the router with the limits a long-running service needs (axum's `serve` has none):
//! a header timeout that also closes idle keep-alive connections, a request timeout, a cap on
//! open connections, and a shutdown deadline after which open requests are cut (a client
//! holding an unfinished request once kept SIGTERM from finishing for a minute and more).

use std::future::Future;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;
use std::time::Duration;

use axum::body::Body;
use axum::extract::Request;
use axum::middleware::Next;
use axum::response::{IntoResponse, Response};
use axum::Router;
use hyper_util::rt::{TokioIo, TokioTimer};
use hyper_util::service::TowerToHyperService;
use tokio::net::TcpListener;
use tokio::sync::{watch, Semaphore};
use tokio::task::JoinSet;

use super::AppError;
use crate::config::HttpConfig;

/// Connections refused because `http.max_connections` were open (shown in `/api/v1/status`'s
/// log line and counted here for the metrics).
#[derive(Debug, Default)]
pub struct HttpCounters {
    pub connections_refused: AtomicU64,
    pub connections_cut_at_shutdown: AtomicU64,
}

/// Rejects oversized request targets and header sections with JSON 414 / 431 and answers 503
/// `timeout` when a request takes longer than `request_timeout_ms`. (Beyond hyper's own buffer
/// limit of ~400 KB, hyper closes the connection itself.)
pub async fn limits(
    axum::extract::State(config): axum::extract::State<Arc<HttpConfig>>,
    request: Request<Body>,
    next: Next,
) -> Response {
    let uri_bytes = request.uri().to_string().len();
    if uri_bytes > config.max_uri_bytes {
        return AppError::UriTooLong {
            bytes: uri_bytes,
            max: config.max_uri_bytes,
        }
        .into_response();
    }
    let header_bytes: usize = request
        .headers()
        .iter()
        .map(|(name, value)| name.as_str().len() + value.len() + 4)
        .sum();
    if header_bytes > config.max_header_bytes {
        return AppError::HeadersTooLarge {
            bytes: header_bytes,
            max: config.max_header_bytes,
        }
        .into_response();
    }
    let timeout = Duration::from_millis(config.request_timeout_ms);
    match tokio::time::timeout(timeout, next.run(request)).await {
        Ok(response) => response,
        Err(_) => AppError::Timeout(timeout).into_response(),
    }
}

/// Serves `app` on `listener` until `shutdown` resolves, then lets open requests finish for
/// `shutdown_deadline_ms` and cuts the connections still open.
pub async fn serve(
    listener: TcpListener,
    app: Router,
    config: &HttpConfig,
    counters: Arc<HttpCounters>,
    shutdown: impl Future<Output = ()>,
) {
    let slots = Arc::new(Semaphore::new(config.max_connections));
    let (close_tx, close_rx) = watch::channel(false);
    let mut builder = hyper::server::conn::http1::Builder::new();
    builder
        .timer(TokioTimer::new())
        .header_read_timeout(Duration::from_millis(config.header_timeout_ms))
        .keep_alive(true);
    let mut connections = JoinSet::new();
    tokio::pin!(shutdown);
    loop {
        tokio::select! {
            () = &mut shutdown => break,
            accepted = listener.accept() => {
                let stream = match accepted {
                    Ok((stream, _peer)) => stream,
                    Err(e) => {
                        // Out of file descriptors and the like: wait a little, keep serving.
                        tracing::warn!("accepting a connection failed: {e}");
                        tokio::time::sleep(Duration::from_millis(50)).await;
                        continue;
                    }
                };
                let Ok(slot) = slots.clone().try_acquire_owned() else {
                    counters.connections_refused.fetch_add(1, Ordering::Relaxed);
                    drop(stream);
                    continue;
                };
                let service = TowerToHyperService::new(app.clone());
                let connection = builder.serve_connection(TokioIo::new(stream), service);
                let mut close = close_rx.clone();
                connections.spawn(async move {
                    let _slot = slot;
                    tokio::pin!(connection);
                    let finished = tokio::select! {
                        finished = connection.as_mut() => finished,
                        _ = close.changed() => {
                            connection.as_mut().graceful_shutdown();
                            connection.await
                        }
                    };
                    if let Err(e) = finished {
                        tracing::debug!("connection ended: {e}");
                    }
                });
            }
            Some(_) = connections.join_next(), if !connections.is_empty() => {}
        }
    }
    drop(listener);
    let _ = close_tx.send(true);
    let deadline = tokio::time::sleep(Duration::from_millis(config.shutdown_deadline_ms));
    tokio::pin!(deadline);
    loop {
        tokio::select! {
            next = connections.join_next() => if next.is_none() { break },
            () = &mut deadline => {
                let open = connections.len() as u64;
                counters.connections_cut_at_shutdown.fetch_add(open, Ordering::Relaxed);
                tracing::warn!(open, "shutdown deadline reached: cutting open connections");
                connections.abort_all();
                break;
            }
        }
    }
}
