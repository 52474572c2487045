//! The daemon's listeners, bound before any work so that a bad address fails first:
//! the cloud stream (TCP, Unix) and the status socket ([`net`]), served on thread
//! `net`, and the live view ([`web`]), served on thread `web`. Both drain their clients
//! for at most `[serve] drain_timeout_s` once told to stop.

use std::sync::Arc;
use std::thread::{Scope, ScopedJoinHandle};
use std::time::Instant;

use tokio::sync::Notify;

use super::{net, seconds, web, ServeConfig, ServeError};
use crate::camera::Camera;
use crate::capture::dump::DumpHeader;

/// The bound sockets, and the hub and status feed their clients read.
pub(super) struct Listeners {
    net: net::Listeners,
    web: Option<web::WebListener>,
    pub hub: Arc<net::Hub>,
    pub feed: Arc<net::StatusFeed>,
}

impl Listeners {
    /// Binds `[serve] stream_tcp`, `stream_unix`, `status_socket` (each unless empty)
    /// and the live view: `http` when the caller bound it, else `[serve] http_listen`.
    pub(super) fn bind(
        cfg: &ServeConfig,
        http: Option<std::net::TcpListener>,
        header: &DumpHeader,
        scan_id: &str,
        started: Instant,
    ) -> Result<Self, ServeError> {
        let none_if_empty = |s: &str| (!s.is_empty()).then(|| s.to_string());
        let send_buffer_bytes =
            u32::try_from(cfg.stream_send_buffer_kib.saturating_mul(1024)).unwrap_or(u32::MAX);
        let endpoints = net::Endpoints {
            stream_tcp: none_if_empty(&cfg.stream_tcp),
            stream_unix: none_if_empty(&cfg.stream_unix).map(Into::into),
            status_unix: none_if_empty(&cfg.status_socket).map(Into::into),
            max_clients: cfg.stream_clients_max,
            send_buffer_bytes,
        };
        let listeners = net::bind(&endpoints)?;
        if let Some(addr) = listeners.tcp_addr {
            tracing::info!(%addr, "cloud stream listening");
        }
        let web = match http {
            Some(l) => Some(web::from_std(l, send_buffer_bytes)?),
            None => none_if_empty(&cfg.http_listen)
                .map(|a| web::bind(&a, send_buffer_bytes))
                .transpose()?,
        };
        if let Some(l) = &web {
            tracing::info!("live view at http://{}/", l.addr);
        }
        // What every stream client hears first ([`super::stream::hello`]).
        let hello = serde_json::json!({
            "width": header.width,
            "height": header.height,
            "scan": scan_id,
            "daemon": concat!("crossline ", env!("CARGO_PKG_VERSION")),
        })
        .to_string();
        let queue_bytes = cfg.client_queue_mib.saturating_mul(1 << 20);
        Ok(Self {
            net: listeners,
            web,
            hub: Arc::new(net::Hub::new(&hello, queue_bytes, started)),
            feed: Arc::new(net::StatusFeed::new()),
        })
    }

    /// Starts threads `net` and `web` in `s`. The returned [`Serving`] stops them; so
    /// does dropping it (an error while the other threads start), so that the scope
    /// can end.
    pub(super) fn spawn<'scope, 'env>(
        self,
        s: &'scope Scope<'scope, 'env>,
        camera: &Camera,
        cfg: &ServeConfig,
    ) -> Result<Serving<'scope>, ServeError> {
        let drain = seconds(cfg.drain_timeout_s, 0.0, 3600.0);
        let mut serving = Serving {
            stop: Arc::new(Notify::new()),
            web_stop: Arc::new(Notify::new()),
            handles: Vec::new(),
        };
        let (hub, feed, stop) = (self.hub.clone(), self.feed.clone(), serving.stop.clone());
        let net = self.net;
        serving.handles.push(spawn_named(s, "net", move || {
            net.serve(hub, feed, stop, drain)
        })?);
        if let Some(l) = self.web {
            let ctx = web::WebContext {
                hub: self.hub.clone(),
                status: self.feed.clone(),
                camera: camera.clone(),
                max_clients: cfg.http_clients_max,
            };
            let stop = serving.web_stop.clone();
            serving
                .handles
                .push(spawn_named(s, "web", move || l.serve(ctx, stop, drain))?);
        }
        Ok(serving)
    }
}

/// Threads `net` and `web` while they serve.
pub(super) struct Serving<'scope> {
    stop: Arc<Notify>,
    web_stop: Arc<Notify>,
    handles: Vec<ScopedJoinHandle<'scope, ()>>,
}

impl Serving<'_> {
    /// Tells both threads to drain their clients and end, and waits for them.
    pub(super) fn stop(mut self) {
        self.notify();
        for h in std::mem::take(&mut self.handles) {
            let _ = h.join();
        }
    }

    fn notify(&self) {
        // A permit is stored when the thread is not waiting yet: the stop is not lost.
        self.stop.notify_one();
        self.web_stop.notify_one();
    }
}

impl Drop for Serving<'_> {
    fn drop(&mut self) {
        self.notify();
    }
}

/// Spawns thread `name` in `s`.
pub(super) fn spawn_named<'scope, 'env, T: Send + 'scope>(
    s: &'scope Scope<'scope, 'env>,
    name: &str,
    f: impl FnOnce() -> T + Send + 'scope,
) -> Result<ScopedJoinHandle<'scope, T>, ServeError> {
    spawn_sized(s, name, None, f)
}

/// [`spawn_named`] with a stack of `stack_bytes` (the default when `None`).
pub(super) fn spawn_sized<'scope, 'env, T: Send + 'scope>(
    s: &'scope Scope<'scope, 'env>,
    name: &str,
    stack_bytes: Option<usize>,
    f: impl FnOnce() -> T + Send + 'scope,
) -> Result<ScopedJoinHandle<'scope, T>, ServeError> {
    let builder = std::thread::Builder::new().name(name.into());
    let builder = match stack_bytes {
        Some(bytes) => builder.stack_size(bytes),
        None => builder,
    };
    builder
        .spawn_scoped(s, f)
        .map_err(|source| ServeError::Thread {
            name: name.into(),
            source,
        })
}
