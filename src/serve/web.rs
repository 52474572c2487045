//! The live view: a page in the browser that shows the growing cloud in 3D, the
//! daemon's status and a coverage map of the camera's view, served by `serve` on
//! `[serve] http_listen` (127.0.0.1:8080 by default; empty disables it).
//!
//! | path | what |
//! |---|---|
//! | `/` | the page (`web/index.html`, `web/app.js`) |
//! | `/vendor/three/…` | three.js, compiled in (`web/vendor/three/`) |
//! | `/status` | the newest status line ([`super::status`]), as JSON |
//! | `/ws` | the WebSocket of [`protocol`]: cloud, epochs and status |
//!
//! It runs on its own thread, `web`, with its own tokio runtime, apart from the cloud
//! stream's `net`: browsers cost the stream clients nothing. Each page is a
//! [`Subscription`](super::net::Subscription) to the cloud stream's hub, so a page
//! has the stream's bounded queue and its rules: one that falls behind is
//! resynchronised, then dropped; the solver and capture never wait for a page; its
//! kernel send buffer is `[serve] stream_send_buffer_kib`, as a stream client's. At
//! most `[serve] http_clients_max` pages are connected at once; more get 503.
//!
//! Shutdown: when `serve` stops, the pages get the final epoch and `end` (for up to
//! `[serve] drain_timeout_s`), then the runtime is dropped, which closes every
//! connection; [`WebListener::serve`] returns and the thread ends.

pub mod assets;
pub mod protocol;

use std::net::SocketAddr;
use std::sync::Arc;
use std::time::Duration;

use axum::extract::ws::{Message, WebSocket, WebSocketUpgrade};
use axum::extract::State;
use axum::http::{header, StatusCode, Uri};
use axum::response::{IntoResponse, Response};
use axum::routing::get;
use axum::Router;
use tokio::sync::{broadcast, Notify, Semaphore};

use super::lock;
use super::net::{Delivery, Hub, StatusFeed, Subscription};
use crate::camera::Camera;
use protocol::{Outgoing, Text, Translator};

#[derive(Debug, thiserror::Error)]
pub enum WebError {
    #[error("cannot listen for the live view on {addr} ([serve] http_listen): {source}")]
    Bind {
        addr: String,
        #[source]
        source: std::io::Error,
    },
    #[error("cannot start the live view's runtime: {0}")]
    Runtime(#[source] std::io::Error),
}

/// What the live view shows, from the rest of the daemon.
pub struct WebContext {
    pub hub: Arc<Hub>,
    pub status: Arc<StatusFeed>,
    /// The camera the points are projected with for the coverage map.
    pub camera: Camera,
    pub max_clients: usize,
}

/// The bound port, ready to be served.
pub struct WebListener {
    runtime: tokio::runtime::Runtime,
    listener: tokio::net::TcpListener,
    pub addr: SocketAddr,
}

/// Binds `addr` (before the pipeline starts, so a bad address fails early), each
/// page's kernel send buffer `send_buffer_bytes` (see [`from_std`]).
pub fn bind(addr: &str, send_buffer_bytes: u32) -> Result<WebListener, WebError> {
    let listener = std::net::TcpListener::bind(addr).map_err(|source| WebError::Bind {
        addr: addr.to_string(),
        source,
    })?;
    from_std(listener, send_buffer_bytes)
}

/// Serves on a listener bound by the caller (the demo binds one to print its address).
/// Its pages' kernel send buffer is `send_buffer_bytes` (`[serve]
/// stream_send_buffer_kib`, as for the stream's TCP clients; 0 leaves the kernel's
/// autotuning, which on loopback grows to MiBs a page, a queue that `client_queue_mib`
/// does not bound). Set on the listener, which every accepted connection inherits.
pub fn from_std(
    listener: std::net::TcpListener,
    send_buffer_bytes: u32,
) -> Result<WebListener, WebError> {
    let addr = listener.local_addr().map_err(|source| WebError::Bind {
        addr: "?".into(),
        source,
    })?;
    let err = |source| WebError::Bind {
        addr: addr.to_string(),
        source,
    };
    super::net::set_send_buffer(&listener, send_buffer_bytes).map_err(err)?;
    listener.set_nonblocking(true).map_err(err)?;
    let runtime = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .map_err(WebError::Runtime)?;
    let listener = {
        let _guard = runtime.enter();
        tokio::net::TcpListener::from_std(listener).map_err(err)?
    };
    Ok(WebListener {
        runtime,
        listener,
        addr,
    })
}

struct AppState {
    ctx: WebContext,
    pages: Arc<Semaphore>,
}

impl WebListener {
    /// Serves until `stop` is notified, then gives the pages up to `drain` to receive
    /// the end of the stream. Runs on the calling thread.
    pub fn serve(self, ctx: WebContext, stop: Arc<Notify>, drain: Duration) {
        let WebListener {
            runtime, listener, ..
        } = self;
        let hub = ctx.hub.clone();
        let state = Arc::new(AppState {
            pages: Arc::new(Semaphore::new(ctx.max_clients.max(1))),
            ctx,
        });
        let app = Router::new()
            .route("/ws", get(upgrade))
            .route("/status", get(status_json))
            .fallback(asset)
            .with_state(state);
        runtime.block_on(async move {
            let server = tokio::spawn(async move {
                if let Err(e) = axum::serve(listener, app).await {
                    tracing::warn!("live view: {e}");
                }
            });
            stop.notified().await;
            hub.drain(drain).await;
            // The last messages leave the sessions' sockets.
            tokio::time::sleep(Duration::from_millis(50)).await;
            server.abort();
        });
        // Dropping the runtime drops every session, closing its connection.
        drop(runtime);
    }
}

async fn asset(uri: Uri) -> Response {
    match assets::find(uri.path()) {
        Some(a) => (
            [
                (header::CONTENT_TYPE, a.content_type),
                (header::CACHE_CONTROL, "no-cache"),
            ],
            a.body,
        )
            .into_response(),
        None => (StatusCode::NOT_FOUND, "not found").into_response(),
    }
}

async fn status_json(State(state): State<Arc<AppState>>) -> Response {
    let line = lock(&state.ctx.status.latest).clone();
    (
        [
            (header::CONTENT_TYPE, "application/json"),
            (header::CACHE_CONTROL, "no-cache"),
        ],
        line.to_string(),
    )
        .into_response()
}

/// Largest message a page may send (it has nothing to say; this bounds what is read).
const MAX_INCOMING_BYTES: usize = 4 << 10;

async fn upgrade(State(state): State<Arc<AppState>>, ws: WebSocketUpgrade) -> Response {
    let Ok(permit) = state.pages.clone().try_acquire_owned() else {
        tracing::warn!("live view: a page over [serve] http_clients_max was refused");
        return (
            StatusCode::SERVICE_UNAVAILABLE,
            "too many live views open ([serve] http_clients_max)",
        )
            .into_response();
    };
    ws.max_message_size(MAX_INCOMING_BYTES)
        .max_frame_size(MAX_INCOMING_BYTES)
        .on_upgrade(move |socket| async move {
            session(socket, &state).await;
            drop(permit);
        })
}

/// How a send ended.
enum Sent {
    Ok,
    /// The hub dropped the page while the send was stuck: tell it so, then close.
    Dropped,
    /// The page went away (or stayed stuck past the status timeout).
    Gone,
}

/// Sends one message, giving up when the hub drops the page meanwhile or after
/// `within`.
async fn send(
    socket: &mut WebSocket,
    sub: &Subscription,
    message: Message,
    within: Duration,
) -> Sent {
    tokio::select! {
        r = tokio::time::timeout(within, socket.send(message)) => match r {
            Ok(Ok(())) => Sent::Ok,
            _ => Sent::Gone,
        },
        () = sub.dropped() => Sent::Dropped,
    }
}

fn message_of(out: Outgoing) -> Message {
    match out {
        Outgoing::Text(t) => Message::Text(t.into()),
        Outgoing::Binary(b) => Message::Binary(b.into()),
    }
}

/// A cloud message is as slow as the page reading it: only the hub's bound decides.
const CLOUD_SEND_TIMEOUT: Duration = Duration::from_secs(3600);
/// A status line is a gauge: a page stuck that long on one is gone.
const STATUS_SEND_TIMEOUT: Duration = Duration::from_secs(5);

/// One page, from its upgrade until it goes away, is dropped, or the daemon stops.
async fn session(mut socket: WebSocket, state: &AppState) {
    let ctx = &state.ctx;
    let sub = ctx.hub.subscribe();
    let mut status_rx = ctx.status.tx.subscribe();
    let translator = Translator::new(ctx.camera.clone());
    tracing::info!("live view: a page connected");
    let latest = lock(&ctx.status.latest).clone();
    let mut sent = if latest.is_empty() {
        Sent::Ok
    } else {
        let m = Message::Text(latest.to_string().into());
        send(&mut socket, &sub, m, STATUS_SEND_TIMEOUT).await
    };
    while let Sent::Ok = sent {
        sent = tokio::select! {
            delivery = sub.next() => match delivery {
                Delivery::Message(m) => {
                    let r = match translator.translate(&m) {
                        Some(out) => send(&mut socket, &sub, message_of(out), CLOUD_SEND_TIMEOUT).await,
                        None => Sent::Ok,
                    };
                    if let Sent::Ok = r {
                        sub.delivered(m.len());
                    }
                    r
                }
                Delivery::Bye(reason) => {
                    say_bye(&mut socket, &reason).await;
                    return;
                }
            },
            line = status_rx.recv() => match line {
                Ok(line) => {
                    let m = Message::Text(line.to_string().into());
                    send(&mut socket, &sub, m, STATUS_SEND_TIMEOUT).await
                }
                // A page that falls behind skips status lines; status is a gauge.
                Err(broadcast::error::RecvError::Lagged(_)) => Sent::Ok,
                Err(broadcast::error::RecvError::Closed) => Sent::Gone,
            },
            incoming = socket.recv() => match incoming {
                Some(Ok(Message::Close(_))) | Some(Err(_)) | None => Sent::Gone,
                Some(Ok(_)) => Sent::Ok,
            },
        };
    }
    if let Sent::Dropped = sent {
        if let Delivery::Bye(reason) = sub.next().await {
            say_bye(&mut socket, &reason).await;
        }
    }
    tracing::info!("live view: a page disconnected");
}

async fn say_bye(socket: &mut WebSocket, reason: &str) {
    tracing::info!("live view: dropping a page: {reason}");
    let bye = Message::Text(Text::bye(reason).to_json().into());
    let _ = tokio::time::timeout(Duration::from_secs(1), async {
        socket.send(bye).await?;
        socket.send(Message::Close(None)).await
    })
    .await;
}

#[cfg(test)]
mod tests {
    use std::sync::atomic::Ordering;
    use std::time::Instant;

    use super::*;
    use crate::serve::stream::{self, EpochReason, Point};

    /// A batch of points larger than the smallest queue bound (64 KiB).
    fn big_batch(epoch: u32) -> Vec<Vec<u8>> {
        let p = Point {
            xyz: [0.1, 0.2, 1.0],
            rgb: [1, 2, 3],
            laser: 0,
            frame: 7,
        };
        stream::points(epoch, 0, &vec![p; 4000])
    }

    fn next(rt: &tokio::runtime::Runtime, sub: &Subscription) -> Delivery {
        rt.block_on(async {
            tokio::time::timeout(Duration::from_secs(5), sub.next())
                .await
                .expect("a delivery")
        })
    }

    fn runtime() -> tokio::runtime::Runtime {
        tokio::runtime::Builder::new_current_thread()
            .enable_all()
            .build()
            .expect("runtime")
    }

    /// A page that has read nothing when the drain ends, with only the final epoch
    /// queued (too little to overflow its queue), is counted as dropped, once.
    #[test]
    fn a_page_cut_off_at_the_end_of_the_drain_is_counted_dropped_once() {
        let hub = Arc::new(Hub::new("{}", 1 << 20, Instant::now()));
        let sub = hub.subscribe();
        hub.begin_epoch(1, EpochReason::Final);
        hub.push_points(big_batch(1), crate::serve::net::Timed::No);
        hub.end(4000);
        assert!(!hub.drained());
        hub.cut_off_undrained();
        hub.cut_off_undrained();
        assert_eq!(hub.stats.dropped_clients.load(Ordering::Relaxed), 1);
        assert_eq!(hub.stats.resyncs.load(Ordering::Relaxed), 0);
        drop(sub);
        // A page that has read everything is not counted.
        let rt = runtime();
        let sub = hub.subscribe();
        while !hub.drained() {
            let _ = next(&rt, &sub);
        }
        hub.cut_off_undrained();
        assert_eq!(hub.stats.dropped_clients.load(Ordering::Relaxed), 1);
    }

    /// Each page's connection has the send buffer of `[serve] stream_send_buffer_kib`
    /// (Linux reports twice what was set), not the kernel's autotuned one, which on
    /// loopback grows to MiBs that `client_queue_mib` does not bound.
    #[test]
    fn a_page_has_the_configured_send_buffer() {
        let set = 48 * 1024;
        let web = bind("127.0.0.1:0", set).expect("bind");
        let client = std::net::TcpStream::connect(web.addr).expect("connect");
        let (page, _) = web.runtime.block_on(web.listener.accept()).expect("accept");
        let size = socket2::SockRef::from(&page)
            .send_buffer_size()
            .expect("SO_SNDBUF");
        assert_eq!(size, 2 * set as usize, "a page's send buffer");
        drop(client);
    }

    #[test]
    fn a_page_that_reads_nothing_is_resynchronised_then_dropped() {
        let rt = runtime();
        let hub = Arc::new(Hub::new("{}", 0, Instant::now()));
        let sub = hub.subscribe();
        hub.begin_epoch(1, EpochReason::First);
        hub.push_points(big_batch(1), crate::serve::net::Timed::No);
        assert_eq!(hub.stats.resyncs.load(Ordering::Relaxed), 1);
        // Still nothing read when the queue overflows again: dropped, and told why.
        hub.push_points(big_batch(1), crate::serve::net::Timed::No);
        assert_eq!(hub.stats.dropped_clients.load(Ordering::Relaxed), 1);
        match next(&rt, &sub) {
            Delivery::Bye(reason) => assert!(reason.contains("read nothing"), "{reason}"),
            Delivery::Message(m) => panic!("expected a bye, got a message of type {}", m[4]),
        }
        drop(sub);
        assert_eq!(hub.stats.clients.load(Ordering::Relaxed), 0);
    }

    #[test]
    fn a_page_that_reads_is_resynchronised_with_the_epoch_again() {
        let rt = runtime();
        let hub = Arc::new(Hub::new("{}", 0, Instant::now()));
        let sub = hub.subscribe();
        let kinds = |n: usize| -> Vec<u8> {
            (0..n)
                .map(|_| match next(&rt, &sub) {
                    Delivery::Message(m) => {
                        sub.delivered(m.len());
                        m[4]
                    }
                    Delivery::Bye(reason) => panic!("dropped: {reason}"),
                })
                .collect()
        };
        assert_eq!(kinds(1), [stream::HELLO]);
        hub.begin_epoch(1, EpochReason::First);
        hub.push_points(big_batch(1), crate::serve::net::Timed::No);
        // Overflowed: the queue is replaced by the epoch again, from a resync EPOCH.
        let Delivery::Message(first) = next(&rt, &sub) else {
            panic!("dropped after one overflow");
        };
        assert_eq!(
            (first[4], first[9]),
            (stream::EPOCH, EpochReason::Resync as u8)
        );
        sub.delivered(first.len());
        assert_eq!(kinds(1), [stream::POINTS]);
        // It reads, so a second overflow resynchronises it again instead of dropping it.
        hub.push_points(big_batch(1), crate::serve::net::Timed::No);
        assert_eq!(hub.stats.resyncs.load(Ordering::Relaxed), 2);
        assert_eq!(hub.stats.dropped_clients.load(Ordering::Relaxed), 0);
        hub.end(8000);
        assert_eq!(
            kinds(4),
            [stream::EPOCH, stream::POINTS, stream::POINTS, stream::END]
        );
        assert!(hub.drained());
    }
}
