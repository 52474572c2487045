//! Unit tests of the video source that need no FFmpeg: the probe's parsing, the
//! window, and the error when the tools are missing. The decoding itself is tested
//! with the real ffmpeg in tests/video.

use super::*;

/// ffprobe's JSON for five frames at 30 fps in a 1/15360 time base, the third without
/// a timestamp, and an index listing eight frames (a cut-off file).
const PROBE: &str = r#"{
    "frames": [
        {"best_effort_timestamp": 0, "side_data_list": [{}]},
        {"best_effort_timestamp": 512},
        {},
        {"best_effort_timestamp": 1536},
        {"best_effort_timestamp": 2048}
    ],
    "programs": [],
    "streams": [{"codec_name": "h264", "width": 640, "height": 360,
                 "avg_frame_rate": "30/1", "time_base": "1/15360", "nb_frames": "8",
                 "tags": {"creation_time": "2024-05-01T10:00:00.000000Z"}}],
    "format": {"tags": {}}
}"#;

#[test]
fn the_probe_gives_container_timestamps_in_nanoseconds_and_keeps_the_window() {
    let path = Path::new("dive.mp4");
    let all = parse_probe(PROBE.as_bytes(), path, Window::default()).expect("parse");
    assert_eq!(
        (all.width, all.height, all.codec.as_str()),
        (640, 360, "h264")
    );
    assert_eq!(all.frame_rate, Some((30, 1)));
    assert_eq!((all.decodable, all.listed), (5, Some(8)));
    assert_eq!(
        all.creation_time.as_deref(),
        Some("2024-05-01T10:00:00.000000Z")
    );
    let nanos: Vec<u64> = all.frames.iter().map(|f| f.timestamp_nanos).collect();
    // 512 ticks of 1/15360 s are 1/30 s; the missing one is an interval after its
    // predecessor.
    assert_eq!(nanos, [0, 33_333_333, 66_666_666, 100_000_000, 133_333_333]);
    let header = all.header();
    assert_eq!((header.interval_num, header.interval_den), (1, 30));
    assert_eq!(header.bytes_per_line, 1920);

    let part = Window {
        start_s: 1.0 / 30.0,
        duration_s: Some(2.0 / 30.0),
    };
    let some = parse_probe(PROBE.as_bytes(), path, part).expect("parse");
    let indices: Vec<u64> = some.frames.iter().map(|f| f.index).collect();
    assert_eq!(indices, [1, 2]);
}

#[test]
fn a_probe_without_video_or_size_is_a_clear_error() {
    let path = Path::new("song.mp4");
    let err = parse_probe(br#"{"streams": [], "frames": []}"#, path, Window::default())
        .expect_err("no video");
    assert!(matches!(err, VideoError::NoVideo { .. }), "{err}");
    let err = parse_probe(b"not json", path, Window::default()).expect_err("junk");
    assert!(err.to_string().contains("song.mp4"), "{err}");
}

#[test]
fn a_missing_ffprobe_says_how_to_install_ffmpeg() {
    let tools = Tools {
        ffmpeg: "crossline-test-no-such-ffmpeg".into(),
        ffprobe: "crossline-test-no-such-ffprobe".into(),
    };
    let err = VideoFile::probe_with(Path::new("dive.mp4"), Window::default(), &tools)
        .expect_err("not installed");
    let text = err.to_string();
    assert!(matches!(err, VideoError::NotInstalled { .. }), "{text}");
    assert!(text.contains("apt-get install ffmpeg"), "{text}");
    assert!(text.contains("crossline-test-no-such-ffprobe"), "{text}");
}

#[test]
fn a_window_must_be_seconds_forward() {
    let path = Path::new("dive.mp4");
    for bad in [
        Window {
            start_s: -1.0,
            duration_s: None,
        },
        Window {
            start_s: 0.0,
            duration_s: Some(0.0),
        },
        Window {
            start_s: f64::NAN,
            duration_s: None,
        },
    ] {
        let err = VideoFile::probe(path, bad).expect_err("refused before running ffprobe");
        assert!(matches!(err, VideoError::Window { .. }), "{err}");
    }
    assert!(is_video(Path::new("DIVE.MP4")) && is_video(Path::new("a.mkv")));
    assert!(!is_video(Path::new("frames.dump")));
}
