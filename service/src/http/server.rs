//! Serving the router with the limits a long-running service needs (axum's `serve` has none):
//! a header timeout that also closes idle keep-alive connections, a request timeout, a cap on
//! open connections that one client cannot use to lock the others out, and a shutdown deadline
//! after which open requests are cut (a client holding an unfinished request once kept SIGTERM
//! from finishing for a minute and more).

use std::collections::HashMap;
use std::future::Future;
use std::sync::atomic::{AtomicU64, AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use axum::body::Body;
use axum::extract::Request;
use axum::middleware::Next;
use axum::response::{IntoResponse, Response};
use axum::Router;
use hyper_util::rt::{TokioIo, TokioTimer};
use hyper_util::service::TowerToHyperService;
use tokio::net::TcpListener;
use tokio::sync::{watch, Notify, Semaphore};
use tokio::task::JoinSet;
use tower::ServiceExt;

use super::AppError;
use crate::config::HttpConfig;

/// What the connection cap did (shown in `/api/v1/status` and counted for the metrics).
#[derive(Debug, Default)]
pub struct HttpCounters {
    /// Closed at once: every slot was serving a request.
    pub connections_refused: AtomicU64,
    /// Idle connections closed to admit a new one when every slot was taken.
    pub connections_evicted: AtomicU64,
    pub connections_cut_at_shutdown: AtomicU64,
}

/// How long the acceptor waits for an evicted connection to give its slot back.
const EVICTION_WAIT: Duration = Duration::from_millis(200);

/// One open connection as the acceptor sees it when every slot is taken.
#[derive(Debug, Default)]
struct OpenConnection {
    /// Requests being served on it now.
    serving: AtomicUsize,
    /// When it was accepted or last finished a request (ms since the server started).
    last_active_ms: AtomicU64,
    /// Asks its task to close it (honoured only while it serves nothing).
    evict: Notify,
}

/// Every open connection, so that a full house can make room: a client that opens every slot
/// and sends nothing (or keeps them idle) once kept `/healthz` and the scrapes out, 2 of 61
/// probes answered. The longest-idle connection gives its slot to the newcomer; only when every
/// slot is serving a request is the newcomer refused.
#[derive(Debug)]
struct OpenConnections {
    started: Instant,
    next_id: AtomicU64,
    by_id: Mutex<HashMap<u64, Arc<OpenConnection>>>,
}

impl OpenConnections {
    fn new() -> Self {
        OpenConnections {
            started: Instant::now(),
            next_id: AtomicU64::new(0),
            by_id: Mutex::new(HashMap::new()),
        }
    }

    fn now_ms(&self) -> u64 {
        self.started.elapsed().as_millis() as u64
    }

    fn open(&self) -> (u64, Arc<OpenConnection>) {
        let id = self.next_id.fetch_add(1, Ordering::Relaxed);
        let connection = Arc::new(OpenConnection::default());
        connection
            .last_active_ms
            .store(self.now_ms(), Ordering::Relaxed);
        self.lock().insert(id, connection.clone());
        (id, connection)
    }

    fn close(&self, id: u64) {
        self.lock().remove(&id);
    }

    /// Asks the longest-idle connection to close; false when every one is serving.
    fn evict_idlest(&self) -> bool {
        let by_id = self.lock();
        let idlest = by_id
            .values()
            .filter(|c| c.serving.load(Ordering::Acquire) == 0)
            .min_by_key(|c| c.last_active_ms.load(Ordering::Relaxed));
        match idlest {
            Some(connection) => {
                connection.evict.notify_one();
                true
            }
            None => false,
        }
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, HashMap<u64, Arc<OpenConnection>>> {
        // The map holds no invariant a panicking holder could break.
        self.by_id.lock().unwrap_or_else(|e| e.into_inner())
    }
}

/// Marks a connection as serving a request while alive.
struct Serving {
    connection: Arc<OpenConnection>,
    open: Arc<OpenConnections>,
}

impl Serving {
    fn start(connection: &Arc<OpenConnection>, open: &Arc<OpenConnections>) -> Self {
        connection.serving.fetch_add(1, Ordering::AcqRel);
        Serving {
            connection: connection.clone(),
            open: open.clone(),
        }
    }
}

impl Drop for Serving {
    fn drop(&mut self) {
        self.connection
            .last_active_ms
            .store(self.open.now_ms(), Ordering::Relaxed);
        self.connection.serving.fetch_sub(1, Ordering::AcqRel);
    }
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
    let open = Arc::new(OpenConnections::new());
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
                let slot = match slots.clone().try_acquire_owned() {
                    Ok(slot) => Some(slot),
                    Err(_) if open.evict_idlest() => {
                        match tokio::time::timeout(EVICTION_WAIT, slots.clone().acquire_owned()).await {
                            Ok(Ok(slot)) => {
                                counters.connections_evicted.fetch_add(1, Ordering::Relaxed);
                                Some(slot)
                            }
                            _ => None,
                        }
                    }
                    Err(_) => None,
                };
                let Some(slot) = slot else {
                    counters.connections_refused.fetch_add(1, Ordering::Relaxed);
                    drop(stream);
                    continue;
                };
                let (id, this) = open.open();
                let service = {
                    let (app, this, open) = (app.clone(), this.clone(), open.clone());
                    tower::service_fn(move |request: Request<hyper::body::Incoming>| {
                        let serving = Serving::start(&this, &open);
                        let app = app.clone();
                        async move {
                            let response = app.oneshot(request).await;
                            drop(serving);
                            response
                        }
                    })
                };
                let connection =
                    builder.serve_connection(TokioIo::new(stream), TowerToHyperService::new(service));
                let mut close = close_rx.clone();
                let open = open.clone();
                connections.spawn(async move {
                    let _slot = slot;
                    tokio::pin!(connection);
                    let finished = loop {
                        tokio::select! {
                            finished = connection.as_mut() => break Some(finished),
                            _ = close.changed() => {
                                connection.as_mut().graceful_shutdown();
                                break Some(connection.await);
                            }
                            () = this.evict.notified() => {
                                // A request may have begun since it was chosen: then it stays.
                                if this.serving.load(Ordering::Acquire) == 0 {
                                    break None;
                                }
                            }
                        }
                    };
                    open.close(id);
                    if let Some(Err(e)) = finished {
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
