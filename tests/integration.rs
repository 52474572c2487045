//! Integration tests: the real `crossline` binary on real files.

mod daemon;
mod faults;
mod logs;
mod util;
mod video;
mod web;

use std::path::Path;

use crossline::ply::{read_ply, write_ply, Cloud};
use serde_json::Value;
use util::{crossline, fixtures, reconstruct, run_ok, stderr_of_failure};

fn json_of(stdout: &[u8]) -> Value {
    serde_json::from_slice(stdout).expect("valid JSON on stdout")
}

#[test]
fn simulate_writes_a_complete_folder_deterministically_on_any_thread_count() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let run = |threads: &str, out: &Path| {
        run_ok(
            crossline()
                .args([
                    "simulate",
                    "--scene",
                    "bricks",
                    "--frames",
                    "4",
                    "--width",
                    "192",
                    "--seed",
                    "11",
                    "--threads",
                    threads,
                    "--out",
                ])
                .arg(out),
        );
    };
    let (a, b) = (tmp.path().join("one"), tmp.path().join("two"));
    run("1", &a);
    run("2", &b);
    for name in [
        "frame_000000.png",
        "frame_000003.png",
        "background.png",
        "camera.yml",
        "camera_info.yaml",
        "scene.toml",
        "truth.json",
        "depth.pfm",
        "lit.png",
        "truth.ply",
    ] {
        assert!(a.join(name).is_file(), "{name} missing");
    }
    for i in 0..4 {
        let name = format!("frame_{i:06}.png");
        let (x, y) = (
            std::fs::read(a.join(&name)).expect("frame"),
            std::fs::read(b.join(&name)).expect("frame"),
        );
        assert!(x == y, "{name} differs between 1 and 2 threads");
    }
    // The camera file it writes is read back by the readers reconstruct uses.
    let cam = crossline::camera_file::load(&a.join("camera.yml")).expect("opencv yaml");
    let ros = crossline::camera_file::load(&a.join("camera_info.yaml")).expect("ros yaml");
    assert_eq!(cam, ros);
    assert_eq!(cam.width, 192);
    // The truth: orthogonal planes, one entry per frame.
    let truth: Value =
        serde_json::from_str(&std::fs::read_to_string(a.join("truth.json")).expect("truth"))
            .expect("json");
    let frames = truth["frames"].as_array().expect("frames");
    assert_eq!(frames.len(), 4);
    for f in frames {
        let p: Vec<Vec<f64>> = serde_json::from_value(f["planes"].clone()).expect("planes");
        let dot: f64 = (0..3).map(|k| p[0][k] * p[1][k]).sum();
        let norms = (0..3).map(|k| p[0][k] * p[0][k]).sum::<f64>().sqrt()
            * (0..3).map(|k| p[1][k] * p[1][k]).sum::<f64>().sqrt();
        assert!((dot / norms).abs() < 1e-9, "planes not orthogonal: {p:?}");
    }
    let ply = read_ply(&a.join("truth.ply")).expect("truth cloud");
    assert!(
        ply.len() > 192 * 108 / 2,
        "truth cloud has {} points",
        ply.len()
    );
}

#[test]
fn simulate_random_renders_a_drawn_scan_and_describes_it() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let out = tmp.path().join("sim");
    // Seed 5 draws a table top with PNG frames; --width overrides the draw.
    let args = [
        "simulate", "--random", "5", "--frames", "2", "--width", "320",
    ];
    run_ok(crossline().args(args).arg("--out").arg(&out));
    let described = run_ok(crossline().args(args).arg("--describe"));
    let line = String::from_utf8(described.stdout).expect("utf-8");
    let info: Value = serde_json::from_str(
        &std::fs::read_to_string(out.join("random.json")).expect("random.json"),
    )
    .expect("json");
    assert_eq!(info["version"], 1);
    assert_eq!(info["seed"], 5);
    assert_eq!(info["frames"], 2);
    assert_eq!(info["width"], 320);
    let kind = info["kind"].as_str().expect("kind");
    assert!(
        ["table", "room", "clutter", "underwater"].contains(&kind),
        "{kind}"
    );
    assert_eq!(line.trim_end(), info["summary"].as_str().expect("summary"));
    assert!(line.starts_with(kind) && line.contains("320x"), "{line}");
    let ext = if info["encoding"] == "jpeg" {
        "jpg"
    } else {
        "png"
    };
    for file in [
        format!("frame_000001.{ext}"),
        "truth.json".into(),
        "scene.toml".into(),
        "camera.yml".into(),
        "lit.png".into(),
    ] {
        assert!(out.join(&file).exists(), "{file} missing");
    }
    // The scene as rendered re-loads, and a --scene run of it is the same scene.
    let spec = crossline::simulate::load_scene_file(&out.join("scene.toml")).expect("scene");
    assert_eq!(spec.camera.width, 320);
    // --random and --scene exclude each other (a usage error, exit code 2).
    let refused = crossline()
        .args(["simulate", "--random", "5", "--scene", "room", "--out"])
        .arg(tmp.path().join("no"))
        .output()
        .expect("spawn crossline");
    let err = String::from_utf8_lossy(&refused.stderr);
    assert_eq!(refused.status.code(), Some(2), "{err}");
    assert!(err.contains("--random") && err.contains("--scene"), "{err}");
}

#[test]
fn reconstruct_then_compare_on_the_fixture() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let sim = fixtures().join("sim-bricks");
    let cloud = tmp.path().join("cloud.ply");
    let report = tmp.path().join("report.json");
    run_ok(
        reconstruct(&sim.join("frames.dump"), &sim.join("camera.yml"), &cloud)
            .arg("--report")
            .arg(&report),
    );
    let rep: Value =
        serde_json::from_str(&std::fs::read_to_string(&report).expect("report")).expect("json");
    assert_eq!(rep["version"], crossline::pipeline::REPORT_VERSION);
    assert_eq!(rep["frames"], 100);
    assert!(rep["crossings"].as_u64().expect("crossings") > 100);
    assert!(rep["planes_solved"].as_u64().expect("solved") >= 30);
    // The PLY has every attribute, aligned, and its median depth is 1 by default.
    let ply = read_ply(&cloud).expect("cloud");
    assert_eq!(rep["points"].as_u64(), Some(ply.len() as u64));
    assert!(ply.len() > 5000);
    assert_eq!(ply.colors.as_ref().map(Vec::len), Some(ply.len()));
    assert_eq!(ply.frames.as_ref().map(Vec::len), Some(ply.len()));
    assert!(ply.frames.iter().flatten().all(|&f| f < 100));
    assert!(ply.lasers.iter().flatten().all(|&l| l < 2));
    let mut z: Vec<f32> = ply.points.iter().map(|p| p[2]).collect();
    z.sort_by(f32::total_cmp);
    assert!(
        (z[z.len() / 2] - 1.0).abs() < 1e-3,
        "median depth {}",
        z[z.len() / 2]
    );

    let out = run_ok(
        crossline()
            .arg("compare")
            .arg(&cloud)
            .arg("--truth")
            .arg(&sim)
            .arg("--json"),
    );
    let cmp = json_of(&out.stdout);
    assert_eq!(cmp["mode"], "truth");
    let truth = &cmp["truth"];
    let median = truth["relative_error"]["median"].as_f64().expect("median");
    // A 480x270 JPEG scan of 100 frames: far from the full-resolution figures, but a
    // wrong plane solution is off by tens of percent.
    assert!(median < 0.03, "median relative depth error {median}");
    let coverage = truth["coverage"]["fraction"].as_f64().expect("coverage");
    assert!(coverage > 0.5, "coverage {coverage}");
    // The table top's ground truth is in metres at ~0.6 m; the cloud's median depth
    // is 1.
    let scale = truth["scale"].as_f64().expect("scale");
    assert!(scale > 0.3 && scale < 1.0, "scale {scale}");
}

/// Points on a sphere and a wall, in front of the camera.
fn analytic_cloud() -> Cloud {
    let mut points = Vec::new();
    for i in 0..60 {
        for j in 0..60 {
            let (a, b) = (
                i as f32 / 60.0 * std::f32::consts::TAU,
                j as f32 / 60.0 * std::f32::consts::PI,
            );
            points.push([
                0.3 * a.cos() * b.sin(),
                0.3 * a.sin() * b.sin(),
                2.0 + 0.3 * b.cos(),
            ]);
            points.push([i as f32 / 30.0 - 1.0, j as f32 / 30.0 - 1.0, 3.0]);
        }
    }
    Cloud {
        points,
        ..Default::default()
    }
}

#[test]
fn compare_recovers_a_known_scale_and_offset() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let reference = analytic_cloud();
    let scaled = Cloud {
        points: reference
            .points
            .iter()
            .map(|p| p.map(|c| c * 1.6))
            .collect(),
        ..Default::default()
    };
    let (ref_path, cloud_path) = (tmp.path().join("ref.ply"), tmp.path().join("cloud.ply"));
    write_ply(&ref_path, &reference, &[]).expect("write");
    write_ply(&cloud_path, &scaled, &[]).expect("write");
    let out = run_ok(
        crossline()
            .arg("compare")
            .arg(&cloud_path)
            .arg("--reference")
            .arg(&ref_path)
            .args(["--align", "scale", "--json"]),
    );
    let rep = json_of(&out.stdout);
    let s = rep["alignment"]["scale"].as_f64().expect("scale");
    assert!((s - 1.0 / 1.6).abs() < 1e-3, "scale {s}");
    assert!(rep["distances"]["median"].as_f64().expect("median") < 1e-4);

    // Without alignment the reported distance is the offset that was added.
    let shifted = Cloud {
        points: reference
            .points
            .iter()
            .map(|p| [p[0], p[1], p[2] - 0.01])
            .collect(),
        ..Default::default()
    };
    write_ply(&cloud_path, &shifted, &[]).expect("write");
    let out = run_ok(
        crossline()
            .arg("compare")
            .arg(&cloud_path)
            .arg("--reference")
            .arg(&ref_path)
            .args(["--align", "none", "--json"]),
    );
    let rep = json_of(&out.stdout);
    // Wall points moved along the wall's normal by exactly 0.01.
    let p95 = rep["distances"]["p95"].as_f64().expect("p95");
    assert!((p95 - 0.01).abs() < 1e-4, "p95 distance {p95}");
}

#[test]
fn bad_inputs_are_named_in_the_error() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let sim = fixtures().join("sim-bricks");
    // A missing camera file.
    let out = tmp.path().join("x.ply");
    let reconstruct = |input: &Path, camera: &Path| reconstruct(input, camera, &out);
    let err = stderr_of_failure(&mut reconstruct(
        &sim.join("frames.dump"),
        Path::new("no-such-camera.yml"),
    ));
    assert!(err.contains("no-such-camera.yml"), "{err}");
    // A camera file with a broken matrix: file and key.
    let bad = tmp.path().join("bad.yml");
    let text = std::fs::read_to_string(sim.join("camera.yml")).expect("camera");
    std::fs::write(&bad, text.replace("cols: 3", "cols: 4")).expect("write");
    let err = stderr_of_failure(&mut reconstruct(&sim.join("frames.dump"), &bad));
    assert!(
        err.contains("bad.yml") && err.contains("camera_matrix"),
        "{err}"
    );
    // A config key that does not exist: file, line and key.
    let cfg = tmp.path().join("c.toml");
    std::fs::write(&cfg, "[solve]\nmax_global_plane = 3\n").expect("write");
    let err = stderr_of_failure(
        reconstruct(&sim.join("frames.dump"), &sim.join("camera.yml"))
            .arg("--config")
            .arg(&cfg),
    );
    assert!(
        err.contains("c.toml:2") && err.contains("max_global_plane"),
        "{err}"
    );
    // A truncated PLY.
    let ply = tmp.path().join("t.ply");
    write_ply(&ply, &analytic_cloud(), &[]).expect("write");
    let bytes = std::fs::read(&ply).expect("read");
    std::fs::write(&ply, &bytes[..bytes.len() - 100]).expect("write");
    let err = stderr_of_failure(
        crossline()
            .arg("compare")
            .arg(&ply)
            .arg("--reference")
            .arg(&ply),
    );
    assert!(err.contains("t.ply") && err.contains("truncated"), "{err}");
    // A folder with no frames.
    let empty = tmp.path().join("empty");
    std::fs::create_dir(&empty).expect("mkdir");
    let err = stderr_of_failure(&mut reconstruct(&empty, &sim.join("camera.yml")));
    assert!(err.contains("no frames"), "{err}");
}

#[test]
fn a_simulated_dump_reconstructs_like_its_frames_and_a_cut_one_still_reads() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let (files, dump) = (tmp.path().join("files"), tmp.path().join("dump"));
    for (format, out) in [("jpeg", &files), ("dump", &dump)] {
        run_ok(
            crossline()
                .args([
                    "simulate", "--scene", "bricks", "--frames", "100", "--width", "480",
                ])
                .args([
                    "--seed",
                    "3",
                    "--jpeg-quality",
                    "90",
                    "--format",
                    format,
                    "--out",
                ])
                .arg(out),
        );
    }
    let camera = files.join("camera.yml");
    let run = |input: &Path, out: &Path| {
        reconstruct(input, &camera, out)
            .args(["--scale", "1"])
            .output()
            .expect("spawn")
    };
    let (a, b) = (tmp.path().join("a.ply"), tmp.path().join("b.ply"));
    let ra = run(&files, &a);
    let rb = run(&dump.join("frames.dump"), &b);
    // The same JPEG frames through either container: the same cloud.
    assert!(
        ra.status.success(),
        "{}",
        String::from_utf8_lossy(&ra.stderr)
    );
    assert!(
        rb.status.success(),
        "{}",
        String::from_utf8_lossy(&rb.stderr)
    );
    let (ca, cb) = (read_ply(&a).expect("a"), read_ply(&b).expect("b"));
    assert!(ca.len() > 1000);
    assert_eq!(ca, cb);
    // Cut the dump inside its last frame: the whole frames before it are used, and the
    // log says where the recording stopped.
    let bytes = std::fs::read(dump.join("frames.dump")).expect("dump");
    let cut = tmp.path().join("cut.dump");
    std::fs::write(&cut, &bytes[..bytes.len() - 1000]).expect("write");
    let out = reconstruct(&cut, &camera, &tmp.path().join("c.ply"))
        .output()
        .expect("spawn");
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("99 whole frames") && err.contains("cut off"),
        "{err}"
    );
    assert!(!err.contains("panicked"), "{err}");
    // Not a dump at all.
    let junk = tmp.path().join("junk.dump");
    std::fs::write(&junk, b"hello").expect("write");
    let err = stderr_of_failure(&mut reconstruct(&junk, &camera, &tmp.path().join("d.ply")));
    assert!(
        err.contains("junk.dump") && err.contains("not a crossline dump"),
        "{err}"
    );
}

#[test]
fn known_distance_puts_the_cloud_in_metres() {
    // Two reconstructed points far apart, their true positions from the fixture's depth
    // map, and the distance between them given to reconstruct: the cloud then comes out
    // at the truth's scale (compare's best scale is 1).
    let tmp = tempfile::tempdir().expect("tempdir");
    let sim = fixtures().join("sim-bricks");
    let camera = crossline::camera_file::load(&sim.join("camera.yml")).expect("camera");
    let depth = crossline::pfm::read_pfm(&sim.join("depth.pfm")).expect("depth");
    let first = tmp.path().join("first.ply");
    run_ok(&mut reconstruct(
        &sim.join("frames.dump"),
        &sim.join("camera.yml"),
        &first,
    ));
    let cloud = read_ply(&first).expect("cloud");
    let pixel_of = |p: &[f32; 3]| {
        let v = nalgebra::Vector3::new(p[0] as f64, p[1] as f64, p[2] as f64);
        camera.pixel_from_camera(&v).expect("in front")
    };
    let true_point = |px: [f64; 2]| {
        let (u, v) = (px[0].round() as usize, px[1].round() as usize);
        let z = depth.data[v * depth.width as usize + u] as f64;
        camera.ray_from_pixel(u as f64, v as f64).expect("ray") * z
    };
    // The leftmost and rightmost points at least 10 px inside the image.
    let by_u = |p: &&[f32; 3]| pixel_of(p)[0];
    let inside = |p: &&[f32; 3]| {
        let [u, v] = pixel_of(p);
        u > 10.0 && v > 10.0 && u < camera.width as f64 - 10.0 && v < camera.height as f64 - 10.0
    };
    let left = cloud
        .points
        .iter()
        .filter(inside)
        .min_by(|a, b| by_u(a).total_cmp(&by_u(b)));
    let right = cloud
        .points
        .iter()
        .filter(inside)
        .max_by(|a, b| by_u(a).total_cmp(&by_u(b)));
    let (left, right) = (left.expect("points"), right.expect("points"));
    let (pa, pb) = (pixel_of(left), pixel_of(right));
    let (pa, pb) = (
        [pa[0].round(), pa[1].round()],
        [pb[0].round(), pb[1].round()],
    );
    let distance = (true_point(pa) - true_point(pb)).norm();
    let scaled = tmp.path().join("scaled.ply");
    let arg = format!(
        "--known-distance={},{},{},{},{distance}",
        pa[0], pa[1], pb[0], pb[1]
    );
    run_ok(reconstruct(&sim.join("frames.dump"), &sim.join("camera.yml"), &scaled).arg(&arg));
    let out = run_ok(
        crossline()
            .arg("compare")
            .arg(&scaled)
            .arg("--truth")
            .arg(&sim)
            .arg("--json"),
    );
    let scale = json_of(&out.stdout)["truth"]["scale"]
        .as_f64()
        .expect("scale");
    assert!(
        (scale - 1.0).abs() < 0.03,
        "best scale after --known-distance: {scale}"
    );
}

/// `crossline inspect` output as one JSON value per line.
fn json_lines(stdout: &[u8]) -> Vec<Value> {
    String::from_utf8_lossy(stdout)
        .lines()
        .map(|l| serde_json::from_str(l).expect("one JSON object per line"))
        .collect()
}

#[test]
fn inspect_lists_a_dump_and_says_where_a_cut_one_stops() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let sim = tmp.path().join("sim");
    run_ok(
        crossline()
            .args([
                "simulate", "--scene", "bricks", "--frames", "6", "--width", "320",
            ])
            .args(["--format", "dump", "--out"])
            .arg(&sim),
    );
    let dump = sim.join("frames.dump");
    let png = tmp.path().join("f3.png");
    let out = run_ok(
        crossline()
            .arg("inspect")
            .arg(&dump)
            .args(["--frames", "--decode", "3", "--png"])
            .arg(&png),
    );
    let lines = json_lines(&out.stdout);
    assert_eq!(lines.len(), 1 + 6 + 1 + 1, "{lines:?}");
    let header = &lines[0];
    assert_eq!(header["type"], "header");
    assert_eq!(header["fourcc"], "MJPG");
    assert_eq!(header["width"], 320);
    let frames = &lines[1..7];
    for (i, f) in frames.iter().enumerate() {
        assert_eq!(f["type"], "frame");
        assert_eq!(f["index"], i);
        assert_eq!(f["sequence"], i);
        assert_eq!(f["crc32"].as_str().map(str::len), Some(8), "{f}");
    }
    // The CRC is of the payload as reconstruct reads it.
    let bytes = std::fs::read(&dump).expect("dump");
    let (offset, len) = (
        frames[2]["offset"].as_u64().expect("offset") as usize,
        frames[2]["bytes"].as_u64().expect("bytes") as usize,
    );
    let crc = format!(
        "{:08x}",
        crc32fast::hash(&bytes[offset + 24..offset + 24 + len])
    );
    assert_eq!(frames[2]["crc32"], crc.as_str());
    let decode = &lines[7];
    assert_eq!(decode["type"], "decode");
    assert_eq!(
        (decode["index"].clone(), decode["width"].clone()),
        (3.into(), 320.into())
    );
    let decoded = image::open(&png).expect("png").into_rgb8();
    assert_eq!(decoded.width(), 320);
    let end = &lines[8];
    assert_eq!(end["status"], "clean");
    assert_eq!(end["frames"], 6);
    assert_eq!(end["dropped"], 0);
    assert_eq!(end["bytes_read"], bytes.len());

    // Cut inside frame 4: frames 0..4 are listed and decodable, the end says where, and
    // the exit status says the dump is damaged.
    let cut = tmp.path().join("cut.dump");
    let at = frames[4]["offset"].as_u64().expect("offset") as usize + 100;
    std::fs::write(&cut, &bytes[..at]).expect("write");
    let out = crossline()
        .arg("inspect")
        .arg(&cut)
        .args(["--frames", "--decode", "3"])
        .output()
        .expect("spawn");
    assert_eq!(out.status.code(), Some(1));
    let lines = json_lines(&out.stdout);
    let end = lines.last().expect("end line");
    assert_eq!(end["type"], "end");
    assert_eq!(end["status"], "truncated");
    assert_eq!(end["frames"], 4);
    assert_eq!(end["bytes_read"], frames[4]["offset"]);
    assert!(
        end["message"]
            .as_str()
            .is_some_and(|m| m.contains("after 4 whole frames")),
        "{end}"
    );
    assert_eq!(lines.iter().filter(|l| l["type"] == "frame").count(), 4);
    assert!(lines.iter().any(|l| l["type"] == "decode"));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("cut.dump") && err.contains("truncated"),
        "{err}"
    );
    // A frame past the damage cannot be decoded, and the error says how many there are.
    let err = stderr_of_failure(crossline().arg("inspect").arg(&cut).args(["--decode", "5"]));
    assert!(err.contains("4 whole frames"), "{err}");
    // A flipped payload byte is corruption, not truncation.
    let mut damaged = bytes.clone();
    damaged[frames[1]["offset"].as_u64().expect("offset") as usize + 40] ^= 0x20;
    std::fs::write(&cut, &damaged).expect("write");
    let out = crossline()
        .arg("inspect")
        .arg(&cut)
        .output()
        .expect("spawn");
    assert_eq!(out.status.code(), Some(1));
    let end = json_lines(&out.stdout).pop().expect("end");
    assert_eq!(
        (end["status"].clone(), end["frames"].clone()),
        ("corrupt".into(), 1.into())
    );
}

/// What `record` and `feed` can show without a camera or v4l2loopback: every refusal
/// names the path and exits 1. Real devices are exercised in the VM harness.
#[cfg(target_os = "linux")]
#[test]
fn record_and_feed_refuse_what_is_not_a_video_device() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let out = tmp.path().join("out.dump");
    let err = stderr_of_failure(
        crossline()
            .args(["record", "--device", "/dev/null", "--out"])
            .arg(&out),
    );
    assert!(
        err.contains("/dev/null is not a V4L2 capture device"),
        "{err}"
    );
    assert!(!out.exists(), "no dump without a camera");
    let missing = tmp.path().join("video7");
    let err = stderr_of_failure(
        crossline()
            .args(["record", "--frames", "3", "--device"])
            .arg(&missing)
            .arg("--out")
            .arg(&out),
    );
    assert!(err.contains("no such device"), "{err}");
    assert!(err.contains(&missing.display().to_string()), "{err}");

    // A valid dump into something that is not a v4l2loopback node.
    let dump = tmp.path().join("in.dump");
    let header = crossline::capture::dump::DumpHeader {
        fourcc: *b"YUYV",
        width: 4,
        height: 2,
        bytes_per_line: 8,
        interval_num: 1,
        interval_den: 30,
        device: "/dev/video0".into(),
        card: "test".into(),
    };
    let mut w = crossline::capture::dump::DumpWriter::create(&dump, &header).expect("create");
    w.write_frame(0, 0, 0, &[128; 16]).expect("write");
    w.finish().expect("finish");
    let err = stderr_of_failure(
        crossline()
            .args(["feed", "--device", "/dev/null", "--input"])
            .arg(&dump),
    );
    assert!(
        err.contains("/dev/null is not a V4L2 output device"),
        "{err}"
    );
    let err = stderr_of_failure(
        crossline()
            .args(["feed", "--device", "/dev/null", "--input"])
            .arg(tmp.path().join("none.dump")),
    );
    assert!(err.contains("none.dump"), "{err}");
    assert_eq!(err.matches("os error 2").count(), 1, "cause once: {err}");
}

#[test]
fn reconstruct_writes_e57_by_the_extension_with_the_plys_points_and_colours() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let sim = fixtures().join("sim-bricks");
    let (ply, e57) = (tmp.path().join("scan.ply"), tmp.path().join("scan.e57"));
    for out in [&ply, &e57] {
        run_ok(&mut reconstruct(
            &sim.join("frames.dump"),
            &sim.join("camera.yml"),
            out,
        ));
    }
    let (a, b) = (
        read_ply(&ply).expect("ply"),
        crossline::e57::read_e57(&e57).expect("e57"),
    );
    assert!(a.len() > 5000, "{} points", a.len());
    assert_eq!(a.points, b.points);
    assert_eq!(a.colors, b.colors);
    let meta = crossline::e57::read_meta(&e57).expect("meta");
    assert!(meta.description.contains("MedianDepth"), "{meta:?}");
    assert!(meta.sensor_model.is_some_and(|m| m.contains("480x270")));
}
