//! Video files as input, with the real FFmpeg: an MP4 encoded from simulated frames
//! (H.264, yuv420p, as a GoPro writes) reconstructs like the frames themselves, a
//! cut-off one reads to its last whole frame, the serve replay keeps the container's
//! timestamps, and the errors say what is wrong. FFmpeg is required, not optional:
//! these tests fail, saying how to install it, where it is missing (.ci/run installs
//! it).

use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::OnceLock;
use std::time::Duration;

use crossline::capture::replay::{Rate, ReplaySource};
use crossline::capture::video::Window;
use crossline::capture::{FrameSource, Next};
use crossline::ply::read_ply;
use serde_json::Value;

use crate::util::{crossline, reconstruct, run_ok, stderr_of_failure};

/// Frames of the simulated scan. 960x540 rather than smaller: at 640x360 this scene
/// leaves the linear start of the self-calibration too few crosses to stand on in
/// some frames, and the solution then differs for reasons that are not the codec's.
const FRAMES: usize = 60;
const WIDTH: &str = "960";
const FPS: u64 = 30;

/// Fails the test, saying how to get FFmpeg, when it is not on PATH.
fn require_ffmpeg() {
    for tool in ["ffmpeg", "ffprobe"] {
        let found = Command::new(tool)
            .arg("-version")
            .output()
            .is_ok_and(|o| o.status.success());
        assert!(
            found,
            "{tool} is not installed: the video tests need the real FFmpeg; install it \
             with `apt-get install ffmpeg` (.ci/run does)"
        );
    }
}

/// A simulated scan as PNG frames and the same frames as an MP4, made once for all
/// the tests of this module (they only read it).
struct Scan {
    _dir: tempfile::TempDir,
    frames: PathBuf,
    mp4: PathBuf,
}

impl Scan {
    fn camera(&self) -> PathBuf {
        self.frames.join("camera.yml")
    }
}

fn scan() -> &'static Scan {
    static SCAN: OnceLock<Scan> = OnceLock::new();
    SCAN.get_or_init(|| {
        require_ffmpeg();
        let dir = tempfile::tempdir().expect("tempdir");
        let frames = dir.path().join("frames");
        run_ok(
            crossline()
                .args(["simulate", "--scene", "bricks", "--seed", "3"])
                .args(["--frames", &FRAMES.to_string(), "--width", WIDTH])
                .arg("--out")
                .arg(&frames),
        );
        let mp4 = dir.path().join("DIVE.MP4");
        // The index (moov atom) at the front, as cameras that survive a power cut
        // write it: a file cut off later still says what it holds.
        run_ok(
            Command::new("ffmpeg")
                .args(["-nostdin", "-hide_banner", "-loglevel", "error"])
                .args(["-framerate", &FPS.to_string(), "-i"])
                .arg(frames.join("frame_%06d.png"))
                .args(["-c:v", "libx264", "-pix_fmt", "yuv420p", "-crf", "12"])
                .args(["-movflags", "+faststart"])
                .arg(&mp4),
        );
        Scan {
            _dir: dir,
            frames,
            mp4,
        }
    })
}

fn json_file(path: &Path) -> Value {
    serde_json::from_str(&std::fs::read_to_string(path).expect("read JSON")).expect("JSON")
}

#[test]
fn an_mp4_reconstructs_like_its_frames_within_the_codec_loss() {
    let scan = scan();
    let tmp = tempfile::tempdir().expect("tempdir");
    let run = |input: &Path, name: &str| {
        let (cloud, report) = (
            tmp.path().join(format!("{name}.ply")),
            tmp.path().join(format!("{name}.json")),
        );
        run_ok(
            reconstruct(input, &scan.camera(), &cloud)
                .arg("--report")
                .arg(&report),
        );
        (cloud, json_file(&report))
    };
    let (frames_cloud, frames_report) = run(&scan.frames, "frames");
    let (video_cloud, video_report) = run(&scan.mp4, "video");
    assert_eq!(video_report["frames"], FRAMES);
    assert_eq!(frames_report["frames"], FRAMES);
    let solved = |r: &Value| r["planes_solved"].as_f64().expect("planes_solved");
    let (a, b) = (solved(&frames_report), solved(&video_report));
    assert!(a >= 60.0, "{a} planes solved from the frames");
    assert!(
        (a - b).abs() <= (0.02 * a).max(1.0),
        "planes solved: {a} from the frames, {b} from the MP4"
    );

    // Distances from the video's cloud to the frames' cloud, after the one global
    // scale the self-calibration cannot observe.
    let out = run_ok(
        crossline()
            .arg("compare")
            .arg(&video_cloud)
            .arg("--reference")
            .arg(&frames_cloud)
            .args(["--align", "scale", "--json"]),
    );
    let cmp: Value = serde_json::from_slice(&out.stdout).expect("compare JSON");
    let median = cmp["distances"]["median"]
        .as_f64()
        .unwrap_or_else(|| panic!("no distances.median in {cmp}"));
    let reference = read_ply(&frames_cloud).expect("frames cloud");
    let mut depth: Vec<f32> = reference.points.iter().map(|p| p[2]).collect();
    depth.sort_by(f32::total_cmp);
    let depth = f64::from(depth[depth.len() / 2]);
    eprintln!(
        "MP4 vs frames: {b} vs {a} planes, median distance {median:.3e} = {:.4} % of the median depth",
        100.0 * median / depth
    );
    assert!(
        median < 0.0005 * depth,
        "median distance {median} is not under 0.05 % of the median depth {depth}"
    );
}

#[test]
fn a_cut_off_mp4_is_read_to_its_last_whole_frame_with_a_warning() {
    let scan = scan();
    let tmp = tempfile::tempdir().expect("tempdir");
    let bytes = std::fs::read(&scan.mp4).expect("mp4");
    let cut = tmp.path().join("cut.mp4");
    std::fs::write(&cut, &bytes[..bytes.len() * 6 / 10]).expect("write");
    let report = tmp.path().join("report.json");
    let out = run_ok(
        reconstruct(&cut, &scan.camera(), &tmp.path().join("cut.ply"))
            .arg("--report")
            .arg(&report),
    );
    let read = json_file(&report)["frames"].as_u64().expect("frames");
    assert!(
        read > 0 && read < FRAMES as u64,
        "{read} frames of a file cut at 60 %"
    );
    let err = String::from_utf8_lossy(&out.stderr);
    let said = format!("read {read} whole frames of the {FRAMES}");
    assert!(err.contains("WARN") && err.contains(&said), "{err}");

    // Every whole frame is decoded: the same frames as the whole file's first ones.
    let whole = Window::default();
    let mut a = ReplaySource::open_video(&scan.mp4, whole, Rate::Max).expect("open");
    let mut b = ReplaySource::open_video(&cut, whole, Rate::Max).expect("open cut");
    let mut n = 0;
    loop {
        let (fa, fb) = (next_frame(&mut a), next_frame(&mut b));
        let Some((_, _, pixels)) = fb else { break };
        let (_, _, whole_pixels) = fa.expect("the whole file has more frames");
        assert!(
            pixels == whole_pixels,
            "frame {n} differs from the whole file's"
        );
        n += 1;
    }
    assert_eq!(n as u64, read);
}

/// The next frame of a replay: sequence, timestamp and pixels.
fn next_frame(source: &mut ReplaySource) -> Option<(u32, u64, Vec<u8>)> {
    loop {
        match source.next(Duration::from_millis(100)).expect("next") {
            Next::Frame(f) => return Some((f.sequence, f.timestamp_nanos, f.bytes.to_vec())),
            Next::End => return None,
            _ => {}
        }
    }
}

#[test]
fn a_replayed_video_keeps_the_container_timestamps_and_its_window() {
    let scan = scan();
    let window = Window {
        start_s: 0.5,
        duration_s: Some(1.0),
    };
    let mut source = ReplaySource::open_video(&scan.mp4, window, Rate::Max).expect("open");
    let header = source.header().clone();
    assert_eq!((&header.fourcc, header.width), (b"RGB3", 960));
    assert_eq!((header.interval_num, header.interval_den), (1, FPS as u32));
    let mut seen = Vec::new();
    while let Some((sequence, ts, pixels)) = next_frame(&mut source) {
        assert_eq!(pixels.len(), 3 * 960 * 540);
        seen.push((sequence, ts));
    }
    // Frames 15..45 of a 30 fps file: from 0.5 s for one second, at their times.
    assert_eq!(seen.len(), FPS as usize, "{seen:?}");
    for (sequence, ts) in seen {
        let want = u64::from(sequence) * 1_000_000_000 / FPS;
        assert!((15..45).contains(&sequence), "frame {sequence}");
        assert!(ts.abs_diff(want) < 1_000_000, "frame {sequence} at {ts} ns");
    }

    // And the daemon replays a window from the same start, ending with its cloud: one
    // and a half seconds, as the one second above holds too little of the sweep to
    // self-calibrate (its fixed-centre start ends 33° from orthogonal, and nothing is
    // triangulated: less, not wrong).
    let tmp = tempfile::tempdir().expect("tempdir");
    let dir = tmp.path();
    run_ok(
        crossline()
            .arg("serve")
            .arg("--camera")
            .arg(scan.camera())
            .arg("--replay")
            .arg(&scan.mp4)
            .args(["--rate", "max", "--start", "0.5", "--duration", "1.5"])
            .arg("--out-dir")
            .arg(dir.join("out"))
            .arg("--out")
            .arg(dir.join("cloud.ply"))
            .arg("--report")
            .arg(dir.join("report.json"))
            .args([
                "--status-socket",
                "",
                "--stream-unix",
                "",
                "--stream-tcp",
                "",
                "--http",
                "",
            ]),
    );
    let report = json_file(&dir.join("report.json"));
    assert_eq!(report["frames_processed"], 3 * FPS / 2, "{report}");
    assert!(read_ply(&dir.join("cloud.ply")).expect("cloud").len() > 1000);
}

#[test]
fn a_video_of_another_size_than_the_camera_is_a_clear_error() {
    let scan = scan();
    let tmp = tempfile::tempdir().expect("tempdir");
    let other = crate::util::fixtures().join("sim-bricks/camera.yml");
    let err = stderr_of_failure(&mut reconstruct(
        &scan.mp4,
        &other,
        &tmp.path().join("c.ply"),
    ));
    assert!(
        err.contains("960x540") && err.contains("480x270") && err.contains("DIVE.MP4"),
        "{err}"
    );
    // A window is for videos only.
    let err = stderr_of_failure(
        reconstruct(&scan.frames, &scan.camera(), &tmp.path().join("d.ply")).args(["--start", "1"]),
    );
    assert!(err.contains("--start"), "{err}");
}

#[test]
fn without_ffmpeg_a_video_input_says_how_to_install_it() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let video = tmp.path().join("dive.mp4");
    std::fs::write(&video, b"not decoded: ffprobe is missing").expect("write");
    let cam = crate::util::fixtures().join("sim-bricks/camera.yml");
    // An empty PATH: no ffprobe or ffmpeg to find.
    let err = stderr_of_failure(
        reconstruct(&video, &cam, &tmp.path().join("c.ply")).env("PATH", tmp.path()),
    );
    assert!(
        err.contains("ffprobe is not installed") && err.contains("apt-get install ffmpeg"),
        "{err}"
    );
}
