//! The live view in a real browser: `crossline serve` replays the simulated fixture,
//! headless Chromium opens the page through chromedriver (WebDriver, driven by
//! fantoccini), and the test reads what a person would see: the status, the 3D
//! canvas and the coverage map. The screenshot is kept as `target/live-view.png`.
//!
//! Chromium and chromedriver are system packages (`apt-get install chromium
//! chromium-driver`; `.ci/run` installs them). Without them the test fails saying so.

use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use fantoccini::{ClientBuilder, Locator};
use serde_json::{json, Value};

use crate::daemon::serve_on;

/// The first of `names` found on PATH.
fn on_path(names: &[&str]) -> Option<PathBuf> {
    let path = std::env::var_os("PATH")?;
    std::env::split_paths(&path)
        .flat_map(|dir| names.iter().map(move |n| dir.join(n)))
        .find(|p| p.is_file())
}

fn browser_and_driver() -> (PathBuf, PathBuf) {
    let how = "the live-view test needs headless Chromium and chromedriver: \
               apt-get install chromium chromium-driver (.ci/run installs them)";
    let chromium = on_path(&["chromium", "chromium-browser", "google-chrome"])
        .unwrap_or_else(|| panic!("no chromium on PATH; {how}"));
    let driver =
        on_path(&["chromedriver"]).unwrap_or_else(|| panic!("no chromedriver on PATH; {how}"));
    (chromium, driver)
}

/// A child process killed when the test ends, however it ends.
struct Killed(Child);

impl Drop for Killed {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

fn start_chromedriver(driver: &Path) -> (Killed, String) {
    let port = crate::util::free_port();
    let child = Command::new(driver)
        .arg(format!("--port={port}"))
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .expect("start chromedriver");
    let t = Instant::now();
    while std::net::TcpStream::connect(("127.0.0.1", port)).is_err() {
        assert!(
            t.elapsed() < Duration::from_secs(30),
            "chromedriver did not listen on {port}"
        );
        std::thread::sleep(Duration::from_millis(50));
    }
    (Killed(child), format!("http://127.0.0.1:{port}"))
}

/// Collects a child's stderr lines, and sends the live view's address when logged.
fn watch_stderr(child: &mut Child) -> (std::sync::mpsc::Receiver<String>, Arc<Mutex<Vec<String>>>) {
    let stderr = child.stderr.take().expect("piped stderr");
    let (tx, rx) = std::sync::mpsc::channel();
    let lines = Arc::new(Mutex::new(Vec::new()));
    let keep = lines.clone();
    std::thread::spawn(move || {
        for line in BufReader::new(stderr).lines().map_while(Result::ok) {
            if let Some(at) = line.find("live view at http://") {
                let url = line[at + "live view at ".len()..].trim().to_string();
                let _ = tx.send(url);
            }
            keep.lock().map(|mut l| l.push(line)).ok();
        }
    });
    (rx, lines)
}

/// Where the screenshot goes: `target/live-view.png` (the CI artefact).
fn screenshot_path() -> PathBuf {
    let target = std::env::var_os("CARGO_TARGET_DIR")
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("target"));
    target.join("live-view.png")
}

/// Pixels of `image` inside `rect` (CSS px, device pixel ratio 1) that differ from
/// `background` by more than a rendering tolerance in some channel.
fn pixels_off(image: &image::RgbaImage, rect: (f64, f64, f64, f64), background: [u8; 3]) -> usize {
    let (x0, y0, w, h) = rect;
    let mut n = 0;
    for y in y0.ceil() as u32..(y0 + h).floor() as u32 {
        for x in x0.ceil() as u32..(x0 + w).floor() as u32 {
            if let Some(p) = image.get_pixel_checked(x, y) {
                if (0..3).any(|c| p[c].abs_diff(background[c]) > 24) {
                    n += 1;
                }
            }
        }
    }
    n
}

/// Counts, in the page, the pixels of each canvas unlike its background, and the vivid
/// ones (a WebGL canvas is copied to a 2D one first; the page keeps its drawing buffer),
/// and returns them with the page's state: one script, so no message lands in between.
const COUNT_CANVASES: &str = r#"
    const [cloudBg, coverageBg] = arguments;
    const count = (id, bg) => {
        const src = document.getElementById(id);
        const c = document.createElement('canvas');
        c.width = src.width; c.height = src.height;
        const ctx = c.getContext('2d');
        ctx.drawImage(src, 0, 0);
        const d = ctx.getImageData(0, 0, c.width, c.height).data;
        let n = 0, vivid = 0;
        for (let i = 0; i < d.length; i += 4) {
            if (Math.abs(d[i] - bg[0]) > 24 || Math.abs(d[i + 1] - bg[1]) > 24 || Math.abs(d[i + 2] - bg[2]) > 24) n++;
            if (Math.max(d[i], d[i + 1], d[i + 2]) - Math.min(d[i], d[i + 1], d[i + 2]) > 128) vivid++;
        }
        return [n, c.width * c.height, vivid];
    };
    return {
        cloud: count('cloud', cloudBg),
        coverage: count('coverage', coverageBg),
        view: JSON.parse(JSON.stringify(window.crosslineView)),
    };
"#;

/// Waits for two animation frames, so that what the page received is drawn.
const NEXT_FRAMES: &str =
    "return await new Promise(r => requestAnimationFrame(() => requestAnimationFrame(() => r(true))));";

/// The cloud's clear colour and the empty coverage cell, as `web/app.js` draws them.
const CLOUD_BACKGROUND: [u8; 3] = [0x10, 0x14, 0x18];
const COVERAGE_EMPTY: [u8; 3] = [24, 32, 40];

/// What the test saw on the page at one moment.
struct Reading {
    /// The page's state before the screenshot, and after the canvases were counted.
    before: Value,
    after: Value,
    shot: Shot,
    /// Pixels unlike the background, all pixels, and vivid pixels, of each canvas.
    cloud: (u64, u64, u64),
    coverage: (u64, u64, u64),
}

impl Reading {
    /// One epoch from the screenshot to the counts, and points in it.
    fn stable(&self) -> bool {
        self.before["epoch"] == self.after["epoch"]
            && self.before["count"].as_u64().unwrap_or(0) > 0
            && self.after["count"].as_u64().unwrap_or(0) > 0
    }
}

/// The screenshot, and its pixels unlike the background in the lower half of the 3D
/// view (below the colour toggle) and in the coverage map.
struct Shot {
    png: Vec<u8>,
    cloud_px: usize,
    coverage_px: usize,
}

/// Reads the page: two animation frames so that what it received is drawn, its state,
/// a screenshot, then both canvases and its state again in one script (atomic with
/// respect to the page's message handlers).
async fn read_page(client: &fantoccini::Client) -> Reading {
    client
        .execute(NEXT_FRAMES, vec![])
        .await
        .expect("animation frames");
    let before = client
        .execute("return window.crosslineView;", vec![])
        .await
        .expect("the page's state");
    let png = client.screenshot().await.expect("screenshot");
    let image = image::load_from_memory(&png)
        .expect("a PNG screenshot")
        .to_rgba8();
    let rect = |id: &'static str| async move {
        client
            .find(Locator::Id(id))
            .await
            .expect("a canvas")
            .rectangle()
            .await
            .expect("its place")
    };
    let cloud_rect = rect("cloud").await;
    let lower = (
        cloud_rect.0,
        cloud_rect.1 + cloud_rect.3 / 2.0,
        cloud_rect.2,
        cloud_rect.3 / 2.0,
    );
    let shot = Shot {
        cloud_px: pixels_off(&image, lower, CLOUD_BACKGROUND),
        coverage_px: pixels_off(&image, rect("coverage").await, COVERAGE_EMPTY),
        png,
    };
    let v = client
        .execute(
            COUNT_CANVASES,
            vec![json!(CLOUD_BACKGROUND), json!(COVERAGE_EMPTY)],
        )
        .await
        .expect("count canvas pixels");
    let n = |c: &Value, i: usize| c[i].as_u64().unwrap_or(0);
    let three = |c: &Value| (n(c, 0), n(c, 1), n(c, 2));
    Reading {
        before,
        after: v["view"].clone(),
        shot,
        cloud: three(&v["cloud"]),
        coverage: three(&v["coverage"]),
    }
}

#[test]
fn live_view_in_chromium_shows_status_cloud_and_coverage() {
    let (chromium, driver) = browser_and_driver();
    let (_driver, webdriver_url) = start_chromedriver(&driver);
    let tmp = tempfile::tempdir().expect("tempdir");
    let dir = tmp.path();
    let runtime = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .expect("runtime");
    runtime.block_on(async {
        // The browser first, so that it is up before the short replay starts.
        let mut caps = serde_json::Map::new();
        caps.insert(
            "goog:chromeOptions".into(),
            json!({
                "binary": chromium,
                "args": [
                    "--headless=new",
                    "--no-sandbox",
                    "--disable-dev-shm-usage",
                    "--window-size=1280,860",
                    "--hide-scrollbars",
                    // WebGL without a GPU: ANGLE on SwiftShader, Chromium's CPU renderer.
                    "--use-angle=swiftshader",
                    "--enable-unsafe-swiftshader",
                    // A profile of its own: a browser left over from another run
                    // cannot hold its lock.
                    format!("--user-data-dir={}", dir.join("chromium-profile").display()),
                ],
            }),
        );
        // Chromium sometimes does not come up within chromedriver's wait on a loaded
        // machine; a second try is a new browser, not a retry of the test's checks.
        let mut tries = 0;
        let client = loop {
            tries += 1;
            match ClientBuilder::new(hyper_util::client::legacy::connect::HttpConnector::new())
                .capabilities(caps.clone())
                .connect(&webdriver_url)
                .await
            {
                Ok(client) => break client,
                Err(e) if tries < 3 => eprintln!("live view: no Chromium session yet ({e}); again"),
                Err(e) => panic!("no Chromium session through chromedriver after {tries} tries: {e}"),
            }
        };

        let started = Instant::now();
        let mut child = serve_on(dir, &crate::daemon::dump(), "realtime", "127.0.0.1:0")
            .stderr(Stdio::piped())
            .spawn()
            .expect("spawn serve");
        let (urls, log) = watch_stderr(&mut child);
        let mut child = Killed(child);
        let url = urls
            .recv_timeout(Duration::from_secs(30))
            .unwrap_or_else(|_| panic!("serve logged no live view address:\n{:?}", log.lock().map(|l| l.join("\n"))));
        client.goto(&url).await.expect("open the live view");

        // Until the page shows processed frames and holds points.
        let mut processed = 0u64;
        let mut view = Value::Null;
        let t = Instant::now();
        while t.elapsed() < Duration::from_secs(60) {
            let text = client
                .find(Locator::Id("st-frames_processed"))
                .await
                .expect("the status table")
                .text()
                .await
                .expect("its text");
            processed = text.trim().parse().unwrap_or(0);
            view = client
                .execute("return window.crosslineView;", vec![])
                .await
                .expect("the page's state");
            if processed > 0 && view["count"].as_u64().unwrap_or(0) > 0 {
                break;
            }
            tokio::time::sleep(Duration::from_millis(100)).await;
        }
        assert!(processed > 0, "the page never showed processed frames; page state {view}");
        assert!(view["count"].as_u64().unwrap_or(0) > 0, "the page never received points: {view}");
        // The page clears its cloud and coverage map when a new epoch starts, and the
        // replay keeps running while the test reads, so one reading is the canvases,
        // the screenshot and the page's state all within one epoch holding points.
        // A reading that an epoch cut in two is taken again.
        let mut reading = None;
        for _ in 0..20 {
            let r = read_page(&client).await;
            if r.stable() {
                reading = Some(r);
                break;
            }
            tokio::time::sleep(Duration::from_millis(100)).await;
        }
        let seen_after = started.elapsed();
        let Reading { before, after, shot, cloud, coverage, .. } =
            reading.expect("twenty readings of the page were all cut by a new epoch or empty");
        let (cloud_px, cloud_all, rgb_vivid) = cloud;
        let (coverage_px, coverage_all, _) = coverage;
        let path = screenshot_path();
        std::fs::create_dir_all(path.parent().expect("target dir")).expect("target dir");
        std::fs::write(&path, &shot.png).expect("write the screenshot");
        let covered = after["coveredCells"].as_u64().unwrap_or(0);
        eprintln!(
            "live view: page showed {processed} processed frames and {} points (epoch {}) {:.1} s \
             after serve started; 3D canvas {cloud_px} of {cloud_all} px lit ({} in the lower half \
             of the screenshot); coverage {coverage_px} of {coverage_all} cells marked ({} px on \
             the screenshot); {}",
            after["count"],
            before["epoch"],
            seen_after.as_secs_f64(),
            shot.cloud_px,
            shot.coverage_px,
            path.display()
        );
        assert_eq!(after["webgl"], true, "no WebGL in headless Chromium: {after}");
        assert!(cloud_px > 500, "the 3D canvas shows almost no points: {cloud_px} of {cloud_all}");
        assert!(shot.cloud_px > 500, "the screenshot shows almost no points: {}", shot.cloud_px);
        assert!(coverage_px > 0 && shot.coverage_px > 0, "the coverage map is empty: {after}");
        assert!(coverage_px < coverage_all, "the coverage map is full: {coverage_px} of {coverage_all}");
        assert!(covered > 0, "the page counted no covered cells: {after}");

        // Colour by depth: the camera's muted colours become a vivid hue ramp.
        client
            .find(Locator::Css("input[name=colour][value=depth]"))
            .await
            .expect("the depth toggle")
            .click()
            .await
            .expect("click it");
        let mut depth_vivid = 0;
        for _ in 0..20 {
            let r = read_page(&client).await;
            if r.stable() {
                depth_vivid = r.cloud.2;
                break;
            }
            tokio::time::sleep(Duration::from_millis(100)).await;
        }
        eprintln!("live view: vivid pixels {rgb_vivid} coloured by RGB, {depth_vivid} by depth");
        assert!(
            depth_vivid > 500 && depth_vivid > 2 * rgb_vivid,
            "colouring by depth changed little: {rgb_vivid} vivid pixels by RGB, {depth_vivid} by depth"
        );

        // The page follows the scan to its end, then the web server stops with serve.
        let status = tokio::task::spawn_blocking(move || {
            let t = Instant::now();
            loop {
                if let Some(s) = child.0.try_wait().expect("wait") {
                    return s;
                }
                assert!(t.elapsed() < Duration::from_secs(60), "serve did not finish");
                std::thread::sleep(Duration::from_millis(50));
            }
        })
        .await
        .expect("wait for serve");
        assert!(status.success(), "serve failed: {status}");
        let addr = url.trim_start_matches("http://").trim_end_matches('/').to_string();
        assert!(
            std::net::TcpStream::connect(&addr).is_err(),
            "the live view still listens on {addr} after serve exited"
        );
        let ended: Value = client
            .execute("return window.crosslineView;", vec![])
            .await
            .expect("the page's state");
        assert_eq!(ended["ended"], true, "the page did not receive the end of the scan: {ended}");
        // It holds the final cloud, all of it.
        let report: Value = serde_json::from_str(
            &std::fs::read_to_string(dir.join("report.json")).expect("report"),
        )
        .expect("report JSON");
        assert_eq!(ended["count"], report["points"], "page {ended}, report {report}");
        client.close().await.expect("close the browser");
    });
}

/// A page that opens the WebSocket and then reads nothing (a frozen browser tab). Its
/// receive buffer is fixed small: loopback TCP would otherwise grow it to tens of MiB
/// and take in the whole scan.
fn stuck_page(addr: &str) -> std::net::TcpStream {
    use std::io::{Read, Write};
    let sock =
        socket2::Socket::new(socket2::Domain::IPV4, socket2::Type::STREAM, None).expect("a socket");
    sock.set_recv_buffer_size(4096).expect("SO_RCVBUF");
    let to: std::net::SocketAddr = addr.parse().expect("the live view's address");
    sock.connect(&to.into()).expect("connect to the live view");
    let mut s: std::net::TcpStream = sock.into();
    write!(
        s,
        "GET /ws HTTP/1.1\r\nHost: {addr}\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n\
         Sec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\nSec-WebSocket-Version: 13\r\n\r\n"
    )
    .expect("upgrade request");
    // Read the 101 response only, then never again.
    let mut head = Vec::new();
    let mut byte = [0u8; 1];
    while !head.ends_with(b"\r\n\r\n") {
        s.read_exact(&mut byte).expect("upgrade response");
        head.push(byte[0]);
    }
    let head = String::from_utf8_lossy(&head);
    assert!(head.starts_with("HTTP/1.1 101"), "{head}");
    s
}

/// The scan runs to its end, every frame processed, with a page that never reads: the
/// hub never waits for a page. (Whether the page is resynchronised or dropped depends
/// on how much the kernel's socket buffers took in; those rules are tested
/// deterministically in `src/serve/web.rs`.)
#[test]
fn a_page_that_reads_nothing_does_not_slow_the_scan() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let dir = tmp.path();
    let config = dir.join("c.toml");
    std::fs::write(
        &config,
        "[serve]\nclient_queue_mib = 0\ndrain_timeout_s = 1.0\n",
    )
    .expect("config");
    let mut child = serve_on(dir, &crate::daemon::dump(), "realtime", "127.0.0.1:0")
        .arg("--config")
        .arg(&config)
        .stderr(Stdio::piped())
        .spawn()
        .expect("spawn serve");
    let (urls, log) = watch_stderr(&mut child);
    let mut child = Killed(child);
    let url = urls
        .recv_timeout(Duration::from_secs(30))
        .unwrap_or_else(|_| {
            panic!(
                "no live view address:\n{:?}",
                log.lock().map(|l| l.join("\n"))
            )
        });
    let addr = url.trim_start_matches("http://").trim_end_matches('/');
    let page = stuck_page(addr);
    let t = Instant::now();
    let status = loop {
        if let Some(s) = child.0.try_wait().expect("wait") {
            break s;
        }
        assert!(
            t.elapsed() < Duration::from_secs(60),
            "serve did not finish with a stuck page"
        );
        std::thread::sleep(Duration::from_millis(50));
    };
    drop(page);
    assert!(status.success(), "serve failed: {status}");
    let report: Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("report.json")).expect("report"))
            .expect("report JSON");
    assert_eq!(report["frames_processed"], 100, "{report}");
    assert_eq!(
        report["stream_clients_total"], 1,
        "the page followed the hub: {report}"
    );
    let log = log.lock().map(|l| l.join("\n")).unwrap_or_default();
    eprintln!(
        "stuck page: serve took {:.1} s; resyncs {}, dropped {}",
        t.elapsed().as_secs_f64(),
        report["stream_resyncs"],
        report["stream_dropped_clients"]
    );
    assert!(log.contains("live view: a page connected"), "{log}");
}
