//! The daemon's sockets: the cloud stream ([`super::stream`]) over TCP and/or a Unix
//! socket, and the status socket (newline-delimited JSON, [`super::status`]).
//!
//! tokio serves the sockets only, on one thread named `net`. The pipeline hands
//! messages to the [`Hub`] with plain, never-blocking calls: each client has its own
//! bounded queue of shared messages, so a slow or stuck client costs the pipeline
//! nothing but a pointer per message, and is resynchronised or dropped (see the
//! protocol's docs) when its queue overflows.

use std::collections::VecDeque;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use tokio::io::AsyncWriteExt;
use tokio::sync::{broadcast, Notify};

use super::lock;
use super::stream::{self, EpochReason};

/// One framed message, shared by every queue it is in, and which latency it counts in
/// when written.
#[derive(Clone)]
struct Message {
    bytes: Arc<[u8]>,
    timed: Timed,
}

/// Which latency a `POINTS` message counts in (see [`NetStats`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Timed {
    /// Not timed (everything but `POINTS`, and points resent to catch a client up).
    No,
    /// A frame's points placed on its arrival.
    Frame,
    /// An epoch's cloud, or frames placed against it from its backlog.
    Epoch,
}

impl std::ops::Deref for Message {
    type Target = [u8];
    fn deref(&self) -> &[u8] {
        &self.bytes
    }
}

impl Message {
    /// The same bytes, counted in no latency (resent to catch a client up).
    fn untimed(&self) -> Self {
        Self {
            bytes: self.bytes.clone(),
            timed: Timed::No,
        }
    }
}

impl From<Vec<u8>> for Message {
    fn from(bytes: Vec<u8>) -> Self {
        Self {
            bytes: bytes.into(),
            timed: Timed::No,
        }
    }
}

#[derive(Default)]
struct ClientQueue {
    queue: VecDeque<Message>,
    bytes: usize,
    /// Bytes the client has read since it was last resynchronised.
    written_since_resync: u64,
    resyncs: u32,
    /// Set when the client is to be told goodbye and closed.
    bye: Option<String>,
    /// Counted as dropped when the drain ended with its stream unsent
    /// ([`Hub::cut_off_undrained`]).
    cut_off: bool,
}

struct Client {
    queue: Mutex<ClientQueue>,
    wake: Notify,
}

impl Client {
    fn push(&self, m: Message) {
        let mut q = lock(&self.queue);
        q.bytes += m.len();
        q.queue.push_back(m);
        drop(q);
        self.wake.notify_one();
    }
}

struct HubState {
    hello: Message,
    epoch: u32,
    /// The current epoch's messages from its `EPOCH` on: what a new client is sent.
    epoch_messages: Vec<Message>,
    end: Option<Message>,
    clients: Vec<Arc<Client>>,
}

/// Counters the status line reports.
#[derive(Default)]
pub struct NetStats {
    pub clients: AtomicU64,
    pub clients_total: AtomicU64,
    pub resyncs: AtomicU64,
    pub dropped_clients: AtomicU64,
    pub bytes_sent: AtomicU64,
    latencies_micros: Mutex<Vec<u64>>,
    epoch_latencies_micros: Mutex<Vec<u64>>,
}

/// Latency percentiles in milliseconds.
#[derive(Clone, Copy, Debug, Default, serde::Serialize)]
pub struct Latency {
    pub samples: usize,
    pub p50_ms: f64,
    pub p95_ms: f64,
    pub max_ms: f64,
}

const MAX_LATENCY_SAMPLES: usize = 1 << 20;

impl NetStats {
    fn record_latency(&self, timed: Timed, micros: u64) {
        let mut l = match timed {
            Timed::No => return,
            Timed::Frame => lock(&self.latencies_micros),
            Timed::Epoch => lock(&self.epoch_latencies_micros),
        };
        if l.len() < MAX_LATENCY_SAMPLES {
            l.push(micros);
        }
    }

    /// From a frame's capture to its points, placed on its arrival against the current
    /// epoch, fully written to a client's socket.
    pub fn latency(&self) -> Latency {
        Latency::of_micros(lock(&self.latencies_micros).clone())
    }

    /// From the capture of the newest frame an epoch's cloud (or a late placement
    /// against it) holds to those points written to a client's socket.
    pub fn epoch_latency(&self) -> Latency {
        Latency::of_micros(lock(&self.epoch_latencies_micros).clone())
    }
}

impl Latency {
    /// Percentiles of durations in microseconds.
    pub fn of_micros(mut l: Vec<u64>) -> Self {
        if l.is_empty() {
            return Self::default();
        }
        l.sort_unstable();
        let at = |q: f64| l[((l.len() - 1) as f64 * q).round() as usize] as f64 / 1000.0;
        Self {
            samples: l.len(),
            p50_ms: at(0.5),
            p95_ms: at(0.95),
            max_ms: at(1.0),
        }
    }
}

/// Fan-out of the cloud stream to every connected client.
pub struct Hub {
    state: Mutex<HubState>,
    queue_limit: usize,
    started: Instant,
    pub stats: NetStats,
}

impl Hub {
    pub fn new(hello_json: &str, queue_limit_bytes: usize, started: Instant) -> Self {
        Self {
            state: Mutex::new(HubState {
                hello: stream::hello(hello_json).into(),
                epoch: 0,
                epoch_messages: Vec::new(),
                end: None,
                clients: Vec::new(),
            }),
            queue_limit: queue_limit_bytes.max(1 << 16),
            started,
            stats: NetStats::default(),
        }
    }

    /// Starts epoch `epoch`: every client drops what it has queued (it is superseded)
    /// and gets the new `EPOCH`.
    pub fn begin_epoch(&self, epoch: u32, reason: EpochReason) {
        let m: Message = stream::epoch(epoch, reason).into();
        let mut s = lock(&self.state);
        s.epoch = epoch;
        s.epoch_messages = vec![m.clone()];
        s.end = None;
        for c in &s.clients {
            {
                let mut q = lock(&c.queue);
                q.queue.clear();
                q.bytes = 0;
            }
            c.push(m.clone());
        }
    }

    /// Appends points to the current epoch; `timed` says which latency they count in.
    pub fn push_points(&self, messages: Vec<Vec<u8>>, timed: Timed) {
        let mut s = lock(&self.state);
        for m in messages {
            let m = Message {
                bytes: m.into(),
                timed,
            };
            s.epoch_messages.push(m.clone());
            for c in &s.clients {
                c.push(m.clone());
            }
        }
        let overflowing: Vec<Arc<Client>> = s
            .clients
            .iter()
            .filter(|c| lock(&c.queue).bytes > self.queue_limit)
            .cloned()
            .collect();
        for c in overflowing {
            self.resync(&s, &c);
        }
    }

    /// The scan is complete: `END` to everyone.
    pub fn end(&self, total_points: u64) {
        let mut s = lock(&self.state);
        let m: Message = stream::end(s.epoch, total_points).into();
        s.end = Some(m.clone());
        for c in &s.clients {
            c.push(m.clone());
        }
    }

    fn resync(&self, s: &HubState, c: &Client) {
        let mut q = lock(&c.queue);
        if q.resyncs > 0 && q.written_since_resync == 0 {
            q.bye = Some(format!(
                "dropped: read nothing while {} MiB of cloud stream queued up, twice",
                self.queue_limit >> 20
            ));
            q.queue.clear();
            q.bytes = 0;
            drop(q);
            self.stats.dropped_clients.fetch_add(1, Ordering::Relaxed);
            c.wake.notify_one();
            return;
        }
        q.resyncs += 1;
        q.written_since_resync = 0;
        q.queue.clear();
        q.bytes = 0;
        let first: Message = stream::epoch(s.epoch, EpochReason::Resync).into();
        q.bytes += first.len();
        q.queue.push_back(first);
        for m in s.epoch_messages.iter().skip(1).chain(s.end.iter()) {
            q.bytes += m.len();
            q.queue.push_back(m.untimed());
        }
        // Resending the epoch shares the hub's messages, so it costs no memory: only
        // what arrives after it counts against the bound.
        q.bytes = 0;
        drop(q);
        self.stats.resyncs.fetch_add(1, Ordering::Relaxed);
        c.wake.notify_one();
    }

    fn add_client(&self) -> Arc<Client> {
        let mut s = lock(&self.state);
        let client = Arc::new(Client {
            queue: Mutex::new(ClientQueue::default()),
            wake: Notify::new(),
        });
        client.push(s.hello.clone());
        for m in s.epoch_messages.iter().chain(s.end.iter()) {
            client.push(m.untimed());
        }
        // What a new client catches up on is shared with the hub; only growth counts.
        lock(&client.queue).bytes = 0;
        s.clients.push(client.clone());
        self.stats.clients.fetch_add(1, Ordering::Relaxed);
        self.stats.clients_total.fetch_add(1, Ordering::Relaxed);
        client
    }

    fn remove_client(&self, client: &Arc<Client>) {
        let mut s = lock(&self.state);
        s.clients.retain(|c| !Arc::ptr_eq(c, client));
        self.stats.clients.fetch_sub(1, Ordering::Relaxed);
    }

    /// True when every client has been sent everything (or there are none).
    pub fn drained(&self) -> bool {
        let s = lock(&self.state);
        s.clients.iter().all(|c| lock(&c.queue).queue.is_empty())
    }

    /// At the end of the drain: counts as dropped, once each, the clients that still
    /// hold unsent stream (at least its `END`). They are closed with the cloud
    /// unfinished, which is what a dropped client is; before, one that never read and
    /// had only the final epoch queued (nothing came after it to find it behind) went
    /// uncounted. The stream's and the live view's threads both call it; a client is
    /// counted once.
    pub fn cut_off_undrained(&self) {
        let s = lock(&self.state);
        for c in &s.clients {
            let mut q = lock(&c.queue);
            if !q.queue.is_empty() && !q.cut_off && q.bye.is_none() {
                q.cut_off = true;
                self.stats.dropped_clients.fetch_add(1, Ordering::Relaxed);
            }
        }
    }

    /// The end of a serving thread's drain (the stream's and the live view's): waits
    /// until every client has taken the whole stream or `within` has passed, then
    /// counts those still holding some as dropped ([`Self::cut_off_undrained`]).
    pub async fn drain(&self, within: Duration) {
        let deadline = Instant::now() + within;
        while !self.drained() && Instant::now() < deadline {
            tokio::time::sleep(Duration::from_millis(20)).await;
        }
        self.cut_off_undrained();
    }

    /// Nanoseconds since the hub started: the clock of the frames' capture times.
    pub(super) fn now_nanos(&self) -> u64 {
        self.started.elapsed().as_nanos() as u64
    }
}

/// What a [`Subscription`] receives next.
pub enum Delivery {
    /// One framed cloud-stream message ([`super::stream`]), shared with the hub.
    Message(Arc<[u8]>),
    /// The hub dropped this subscriber (it fell behind twice); the reason to pass on.
    Bye(String),
}

/// A consumer of the cloud stream inside the daemon (the live web view,
/// [`super::web`]): a client of the hub like a socket client, with the same bounded
/// queue, resynchronisation and dropping, for a consumer that forwards the messages
/// somewhere else. It leaves the hub when dropped.
pub struct Subscription {
    hub: Arc<Hub>,
    client: Arc<Client>,
}

impl Hub {
    /// Joins the hub: the subscription first receives `HELLO`, the current epoch and
    /// `END` if the scan is finished, then everything after, as a socket client does.
    pub fn subscribe(self: &Arc<Self>) -> Subscription {
        Subscription {
            hub: self.clone(),
            client: self.add_client(),
        }
    }
}

impl Subscription {
    /// The next message, waiting for one. Cancel-safe: nothing is taken from the queue
    /// unless this returns.
    pub async fn next(&self) -> Delivery {
        loop {
            let notified = self.client.wake.notified();
            {
                let mut q = lock(&self.client.queue);
                if let Some(reason) = q.bye.take() {
                    return Delivery::Bye(reason);
                }
                if let Some(m) = q.queue.pop_front() {
                    q.bytes = q.bytes.saturating_sub(m.len());
                    return Delivery::Message(m.bytes);
                }
            }
            notified.await;
        }
    }

    /// Resolves once the hub has decided to drop this subscriber: a forward stuck on a
    /// slow consumer gives up then.
    pub async fn dropped(&self) {
        wait_for_bye(&self.client).await;
    }

    /// `bytes` of stream messages were passed on: the consumer is reading, so a
    /// resynchronisation of it is not yet a reason to drop it.
    pub fn delivered(&self, bytes: usize) {
        self.hub
            .stats
            .bytes_sent
            .fetch_add(bytes as u64, Ordering::Relaxed);
        lock(&self.client.queue).written_since_resync += bytes as u64;
    }
}

impl Drop for Subscription {
    fn drop(&mut self) {
        self.hub.remove_client(&self.client);
    }
}

/// Resolves once the client is to be dropped.
async fn wait_for_bye(client: &Client) {
    loop {
        let notified = client.wake.notified();
        let bye = lock(&client.queue).bye.is_some();
        if bye {
            return;
        }
        notified.await;
    }
}

/// Serves one stream client until the stream ends, it goes away or it is dropped.
async fn serve_client<W: AsyncWriteExt + Unpin>(hub: Arc<Hub>, mut w: W) {
    let client = hub.add_client();
    loop {
        let (bye, next) = {
            let mut q = lock(&client.queue);
            match q.bye.take() {
                Some(reason) => (Some(reason), None),
                None => {
                    let m = q.queue.pop_front();
                    if let Some(m) = &m {
                        q.bytes = q.bytes.saturating_sub(m.len());
                    }
                    (None, m)
                }
            }
        };
        if let Some(reason) = bye {
            let bye = stream::bye(&reason);
            let _ = tokio::time::timeout(Duration::from_secs(1), w.write_all(&bye)).await;
            break;
        }
        match next {
            Some(m) => {
                let wrote = tokio::select! {
                    r = w.write_all(&m) => r.is_ok(),
                    // A bye while stuck in a write: give up on this write.
                    () = wait_for_bye(&client) => false,
                };
                if !wrote {
                    let bye = lock(&client.queue).bye.is_some();
                    if bye {
                        continue;
                    }
                    break;
                }
                hub.stats
                    .bytes_sent
                    .fetch_add(m.len() as u64, Ordering::Relaxed);
                lock(&client.queue).written_since_resync += m.len() as u64;
                if let Some(t) = stream::captured_nanos(&m).filter(|&t| t > 0) {
                    hub.stats
                        .record_latency(m.timed, hub.now_nanos().saturating_sub(t) / 1000);
                }
                if m.len() >= 5 && m[4] == stream::END {
                    let _ = w.flush().await;
                    break;
                }
            }
            None => {
                let notified = client.wake.notified();
                let empty = {
                    let q = lock(&client.queue);
                    q.queue.is_empty() && q.bye.is_none()
                };
                if empty {
                    notified.await;
                }
            }
        }
    }
    let _ = w.shutdown().await;
    hub.remove_client(&client);
}

/// Where the sockets listen.
#[derive(Clone, Debug)]
pub struct Endpoints {
    pub stream_tcp: Option<String>,
    pub stream_unix: Option<PathBuf>,
    pub status_unix: Option<PathBuf>,
    /// Stream clients served at once (TCP and Unix together), and as many status
    /// clients: each holds a file descriptor, and the final cloud needs some too.
    pub max_clients: usize,
    /// The kernel send buffer of each TCP stream client (`[serve]
    /// stream_send_buffer_kib`; 0: the kernel's autotuning). What a client has not
    /// read is bounded by this and the client queue together.
    pub send_buffer_bytes: u32,
}

/// Connections over the cap: accepted and closed at once (so the backlog does not
/// fill with them), warned about once, counted at debug level after that.
fn refuse(refused: &AtomicU64, what: &str, max: usize) {
    if refused.fetch_add(1, Ordering::Relaxed) == 0 {
        tracing::warn!(
            "{what}: {max} clients already connected ([serve] stream_clients_max); closing new connections while they are"
        );
    } else {
        tracing::debug!("{what}: refused a client over the cap of {max}");
    }
}

/// The newest status line and the feed of new ones.
pub struct StatusFeed {
    pub latest: Mutex<Arc<str>>,
    pub tx: broadcast::Sender<Arc<str>>,
}

impl StatusFeed {
    pub fn new() -> Self {
        let (tx, _) = broadcast::channel(64);
        Self {
            latest: Mutex::new(Arc::from("")),
            tx,
        }
    }

    /// Publishes a line (without its newline). Never blocks.
    pub fn publish(&self, line: String) {
        let line: Arc<str> = Arc::from(line);
        *lock(&self.latest) = line.clone();
        let _ = self.tx.send(line);
    }
}

impl Default for StatusFeed {
    fn default() -> Self {
        Self::new()
    }
}

#[derive(Debug, thiserror::Error)]
pub enum NetError {
    #[error("cannot listen on {what}: {source}")]
    Bind {
        what: String,
        #[source]
        source: std::io::Error,
    },
    #[error("cannot start the socket runtime: {0}")]
    Runtime(#[source] std::io::Error),
}

fn bind_unix(path: &Path, mode: u32) -> Result<tokio::net::UnixListener, NetError> {
    use std::os::unix::fs::{DirBuilderExt, PermissionsExt};
    let err = |source| NetError::Bind {
        what: path.display().to_string(),
        source,
    };
    if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).map_err(err)?;
    }
    // A socket file left by a crashed run would refuse the bind.
    if std::fs::symlink_metadata(path).is_ok_and(|m| {
        use std::os::unix::fs::FileTypeExt;
        m.file_type().is_socket()
    }) {
        let _ = std::fs::remove_file(path);
    }
    // `bind` creates the socket with the mode the umask leaves: bind it in a fresh
    // directory only we can enter, set its mode there, then move it into place, so it
    // is never reachable with a wider mode than `mode`.
    let dir = path.parent().filter(|d| !d.as_os_str().is_empty());
    let private = dir
        .unwrap_or(Path::new("."))
        .join(format!(".crossline-bind-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&private);
    std::fs::DirBuilder::new()
        .mode(0o700)
        .create(&private)
        .map_err(err)?;
    let staged = private.join("socket");
    let bound = tokio::net::UnixListener::bind(&staged)
        .and_then(|l| {
            std::fs::set_permissions(&staged, std::fs::Permissions::from_mode(mode))?;
            std::fs::rename(&staged, path)?;
            Ok(l)
        })
        .map_err(err);
    let _ = std::fs::remove_dir_all(&private);
    let l = bound?;
    Ok(l)
}

/// The bound sockets, ready to be served.
pub struct Listeners {
    runtime: tokio::runtime::Runtime,
    tcp: Option<tokio::net::TcpListener>,
    stream_unix: Option<tokio::net::UnixListener>,
    status_unix: Option<tokio::net::UnixListener>,
    pub tcp_addr: Option<std::net::SocketAddr>,
    paths: Vec<PathBuf>,
    max_clients: usize,
}

/// Sets a TCP listener's kernel send buffer to `bytes`, which every connection it
/// accepts inherits (0 leaves the kernel's autotuning, which on loopback grows to MiBs
/// per client, a queue that `client_queue_mib` does not bound). The cloud stream's and
/// the live view's listeners both go through here.
pub(super) fn set_send_buffer(listener: &std::net::TcpListener, bytes: u32) -> std::io::Result<()> {
    if bytes > 0 {
        socket2::SockRef::from(listener).set_send_buffer_size(bytes as usize)?;
    }
    Ok(())
}

/// Binds every socket (before the pipeline starts, so a bad address fails early).
pub fn bind(endpoints: &Endpoints) -> Result<Listeners, NetError> {
    let runtime = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .map_err(NetError::Runtime)?;
    let _guard = runtime.enter();
    let mut paths = Vec::new();
    let tcp = match &endpoints.stream_tcp {
        Some(addr) => {
            let err = |source| NetError::Bind {
                what: format!("tcp {addr}"),
                source,
            };
            let std_l = std::net::TcpListener::bind(addr).map_err(err)?;
            set_send_buffer(&std_l, endpoints.send_buffer_bytes).map_err(err)?;
            std_l.set_nonblocking(true).map_err(err)?;
            Some(tokio::net::TcpListener::from_std(std_l).map_err(err)?)
        }
        None => None,
    };
    let tcp_addr = tcp.as_ref().and_then(|l| l.local_addr().ok());
    let stream_unix = match &endpoints.stream_unix {
        Some(p) => {
            paths.push(p.clone());
            Some(bind_unix(p, 0o660)?)
        }
        None => None,
    };
    let status_unix = match &endpoints.status_unix {
        Some(p) => {
            paths.push(p.clone());
            Some(bind_unix(p, 0o660)?)
        }
        None => None,
    };
    drop(_guard);
    Ok(Listeners {
        runtime,
        tcp,
        stream_unix,
        status_unix,
        tcp_addr,
        paths,
        max_clients: endpoints.max_clients.max(1),
    })
}

impl Listeners {
    /// Serves until `stop` is notified, then gives stream clients up to `drain` to
    /// receive the end of the stream. Runs on the calling thread.
    pub fn serve(self, hub: Arc<Hub>, status: Arc<StatusFeed>, stop: Arc<Notify>, drain: Duration) {
        let Listeners {
            runtime,
            tcp,
            stream_unix,
            status_unix,
            paths,
            max_clients,
            ..
        } = self;
        runtime.block_on(async move {
            let mut tasks = tokio::task::JoinSet::new();
            let streams = Arc::new(tokio::sync::Semaphore::new(max_clients));
            let statuses = Arc::new(tokio::sync::Semaphore::new(max_clients));
            let refused = Arc::new(AtomicU64::new(0));
            if let Some(l) = tcp {
                let (hub, streams, refused) = (hub.clone(), streams.clone(), refused.clone());
                tasks.spawn(async move {
                    loop {
                        match l.accept().await {
                            Ok((sock, peer)) => {
                                let Ok(permit) = streams.clone().try_acquire_owned() else {
                                    refuse(&refused, "cloud stream", max_clients);
                                    continue;
                                };
                                tracing::info!(%peer, "cloud stream client connected");
                                let _ = sock.set_nodelay(true);
                                let hub = hub.clone();
                                tokio::spawn(async move {
                                    serve_client(hub, sock).await;
                                    drop(permit);
                                });
                            }
                            Err(e) => {
                                tracing::warn!("cloud stream accept: {e}");
                                tokio::time::sleep(Duration::from_millis(100)).await;
                            }
                        }
                    }
                });
            }
            if let Some(l) = stream_unix {
                let (hub, streams, refused) = (hub.clone(), streams.clone(), refused.clone());
                tasks.spawn(async move {
                    loop {
                        match l.accept().await {
                            Ok((sock, _)) => {
                                let Ok(permit) = streams.clone().try_acquire_owned() else {
                                    refuse(&refused, "cloud stream", max_clients);
                                    continue;
                                };
                                tracing::info!("cloud stream client connected (unix)");
                                let hub = hub.clone();
                                tokio::spawn(async move {
                                    serve_client(hub, sock).await;
                                    drop(permit);
                                });
                            }
                            Err(e) => {
                                tracing::warn!("cloud stream accept: {e}");
                                tokio::time::sleep(Duration::from_millis(100)).await;
                            }
                        }
                    }
                });
            }
            if let Some(l) = status_unix {
                let status = status.clone();
                tasks.spawn(async move {
                    loop {
                        match l.accept().await {
                            Ok((sock, _)) => {
                                let Ok(permit) = statuses.clone().try_acquire_owned() else {
                                    refuse(&refused, "status socket", max_clients);
                                    continue;
                                };
                                let status = status.clone();
                                tokio::spawn(async move {
                                    serve_status(status, sock).await;
                                    drop(permit);
                                });
                            }
                            Err(e) => {
                                tracing::warn!("status accept: {e}");
                                tokio::time::sleep(Duration::from_millis(100)).await;
                            }
                        }
                    }
                });
            }
            stop.notified().await;
            hub.drain(drain).await;
            // One more status line carries the final state to listeners.
            tokio::time::sleep(Duration::from_millis(20)).await;
            tasks.abort_all();
        });
        for p in paths {
            let _ = std::fs::remove_file(p);
        }
    }
}

async fn serve_status(status: Arc<StatusFeed>, mut sock: tokio::net::UnixStream) {
    let mut rx = status.tx.subscribe();
    let first = lock(&status.latest).clone();
    if !first.is_empty() && write_line(&mut sock, &first).await.is_err() {
        return;
    }
    loop {
        match rx.recv().await {
            Ok(line) => {
                if write_line(&mut sock, &line).await.is_err() {
                    return;
                }
            }
            // A listener that falls behind skips lines; status is a gauge.
            Err(broadcast::error::RecvError::Lagged(_)) => {}
            Err(broadcast::error::RecvError::Closed) => return,
        }
    }
}

async fn write_line(sock: &mut tokio::net::UnixStream, line: &str) -> std::io::Result<()> {
    let mut b = Vec::with_capacity(line.len() + 1);
    b.extend_from_slice(line.as_bytes());
    b.push(b'\n');
    tokio::time::timeout(Duration::from_secs(5), sock.write_all(&b))
        .await
        .map_err(|_| std::io::Error::new(std::io::ErrorKind::TimedOut, "status client stuck"))?
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Each stream client's connection has the send buffer of `[serve]
    /// stream_send_buffer_kib` (Linux reports twice what was set), not the kernel's
    /// autotuned one.
    #[test]
    fn a_stream_client_has_the_configured_send_buffer() {
        let set = 48 * 1024;
        let listeners = bind(&Endpoints {
            stream_tcp: Some("127.0.0.1:0".into()),
            stream_unix: None,
            status_unix: None,
            max_clients: 4,
            send_buffer_bytes: set,
        })
        .expect("bind");
        let addr = listeners.tcp_addr.expect("a TCP address");
        let client = std::net::TcpStream::connect(addr).expect("connect");
        let tcp = listeners.tcp.as_ref().expect("the TCP listener");
        let (conn, _) = listeners.runtime.block_on(tcp.accept()).expect("accept");
        let size = socket2::SockRef::from(&conn)
            .send_buffer_size()
            .expect("SO_SNDBUF");
        assert_eq!(size, 2 * set as usize, "a stream client's send buffer");
        drop(client);
    }

    /// A bound socket is never reachable with a wider mode than it is given: while
    /// one is bound at the same path again and again, a thread watching that path
    /// sees no mode but 0660 (bind alone would leave the umask's, 0755 under the
    /// usual 022, until a chmod).
    #[test]
    fn a_socket_is_never_seen_with_another_mode_than_its_own() {
        use std::os::unix::fs::PermissionsExt;
        use std::sync::atomic::AtomicBool;
        let dir = tempfile::tempdir().expect("tempdir");
        let path = dir.path().join("s.sock");
        let stop = Arc::new(AtomicBool::new(false));
        let watcher = {
            let (path, stop) = (path.clone(), stop.clone());
            std::thread::spawn(move || {
                let mut seen = std::collections::BTreeSet::new();
                while !stop.load(Ordering::Relaxed) {
                    if let Ok(m) = std::fs::symlink_metadata(&path) {
                        seen.insert(m.permissions().mode() & 0o777);
                    }
                }
                seen
            })
        };
        let runtime = tokio::runtime::Builder::new_current_thread()
            .enable_io()
            .build()
            .expect("runtime");
        let _entered = runtime.enter();
        for _ in 0..2000 {
            drop(bind_unix(&path, 0o660).expect("bind"));
        }
        stop.store(true, Ordering::Relaxed);
        let seen = watcher.join().expect("watcher");
        let modes: Vec<String> = seen.iter().map(|m| format!("{m:o}")).collect();
        assert_eq!(modes, ["660"], "modes seen at {}", path.display());
    }
}
