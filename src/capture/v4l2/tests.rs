//! Unit tests of the ioctl layer that need no camera: names and messages, a missing
//! node, `/dev/null` and a regular file refused, the format choice and its fallbacks,
//! frame rates and timestamps, dump headers from a negotiated stream. The devices
//! themselves are tested in the VM harness (`tests/vm/`).

use super::*;

#[test]
fn big_endian_fourccs_print_as_v4l2_ctl_shows_them() {
    assert_eq!(fourcc_str(*b"YUYV"), "YUYV");
    assert_eq!(fourcc_str(*b"Y16 "), "Y16");
    assert_eq!(fourcc_str([b'Y', b'1', b'6', b' ' | 0x80]), "Y16-BE");
}

#[test]
fn dev_null_is_not_a_capture_device_and_the_message_says_which_path() {
    let err = Device::open(Path::new("/dev/null"))
        .err()
        .expect("/dev/null must be refused");
    assert!(
        matches!(err, V4l2Error::NotCapture { caps: 0, .. }),
        "{err:?}"
    );
    let msg = err.to_string();
    assert!(
        msg.contains("/dev/null is not a V4L2 capture device"),
        "{msg}"
    );
    assert!(!err.is_retryable());

    let err = OutputDevice::open(
        Path::new("/dev/null"),
        &OutputFormat {
            fourcc: *b"YUYV",
            width: 64,
            height: 48,
            bytes_per_line: 128,
            fps: 30.0,
        },
    )
    .err()
    .expect("/dev/null must be refused");
    assert!(
        matches!(err, V4l2Error::NotOutput { caps: 0, .. }),
        "{err:?}"
    );
    assert!(err.to_string().contains("/dev/null"), "{err}");
}

#[test]
fn a_missing_device_is_not_found_and_retryable() {
    let path = Path::new("/dev/v4l/by-id/usb-no-such-camera-video-index0");
    let err = Device::open(path).err().expect("missing");
    assert!(matches!(err, V4l2Error::NotFound { .. }), "{err:?}");
    assert!(
        err.to_string().contains(&path.display().to_string()),
        "{err}"
    );
    assert!(err.is_retryable());
    let dir = tempfile::tempdir().expect("tempdir");
    let err = OutputDevice::open(
        &dir.path().join("video9"),
        &OutputFormat {
            fourcc: *b"MJPG",
            width: 64,
            height: 48,
            bytes_per_line: 0,
            fps: 30.0,
        },
    )
    .err()
    .expect("missing");
    assert!(matches!(err, V4l2Error::NotFound { .. }), "{err:?}");
}

#[test]
fn a_regular_file_is_not_a_capture_device() {
    let dir = tempfile::tempdir().expect("tempdir");
    let p = dir.path().join("video0");
    std::fs::write(&p, b"not a camera").expect("write");
    let err = Device::open(&p).err().expect("refused");
    assert!(matches!(err, V4l2Error::NotCapture { .. }), "{err:?}");
}

#[test]
fn the_first_requested_format_the_device_offers_wins() {
    let offered = [*b"YUYV", *b"MJPG", *b"NV12"];
    assert_eq!(
        choose_fourcc(&[*b"MJPG", *b"YUYV"], &offered),
        Some((*b"MJPG", None))
    );
    assert_eq!(
        choose_fourcc(&[*b"RGB3", *b"YUYV"], &offered),
        Some((*b"YUYV", None))
    );
}

#[test]
fn an_unoffered_request_falls_back_with_a_note_or_fails() {
    let (f, note) = choose_fourcc(&[*b"MJPG"], &[*b"NV12", *b"RGB3"]).expect("fallback");
    assert_eq!(&f, b"RGB3");
    let note = note.expect("a note");
    assert!(
        note.contains("asked for MJPG")
            && note.contains("of the 2 formats it offers, crossline reads RGB3"),
        "{note}"
    );
    assert_eq!(choose_fourcc(&[*b"MJPG"], &[*b"NV12", *b"H264"]), None);
    let err = V4l2Error::NoUsableFormat {
        path: "/dev/video3".into(),
        offered: vec!["NV12".into(), "H264".into()],
    };
    assert!(err.to_string().contains("it offers NV12, H264"), "{err}");
}

#[test]
fn frame_rates_become_reduced_intervals() {
    assert_eq!(interval_from_fps(30.0), Some((1, 30)));
    assert_eq!(interval_from_fps(29.97), Some((100, 2997)));
    assert_eq!(interval_from_fps(0.5), Some((2, 1)));
    assert_eq!(interval_from_fps(0.0), None);
    assert_eq!(interval_from_fps(f64::NAN), None);
}

#[test]
fn timestamps_become_nanoseconds() {
    let tv = libc::timeval {
        tv_sec: 12,
        tv_usec: 345_678,
    };
    assert_eq!(nanos_from_timeval(tv), 12_345_678_000);
    let tv = libc::timeval {
        tv_sec: -1,
        tv_usec: 0,
    };
    assert_eq!(nanos_from_timeval(tv), 0);
}

#[test]
fn capability_messages_name_what_is_missing() {
    let err = V4l2Error::NotCapture {
        path: "/dev/video1".into(),
        caps: sys::V4L2_CAP_VIDEO_OUTPUT | sys::V4L2_CAP_STREAMING,
    };
    let msg = err.to_string();
    assert!(msg.contains("VIDEO_OUTPUT | STREAMING"), "{msg}");
    assert!(msg.contains("exclusive_caps"), "{msg}");
    assert!(err.is_retryable(), "a loopback node waiting for its writer");
    let err = V4l2Error::NotCapture {
        path: "/dev/video1".into(),
        caps: sys::V4L2_CAP_VIDEO_M2M | sys::V4L2_CAP_STREAMING,
    };
    assert!(!err.is_retryable());
}

#[test]
fn negotiated_streams_make_dump_headers() {
    let n = Negotiated {
        fourcc: *b"YUYV",
        width: 640,
        height: 480,
        bytes_per_line: 1280,
        size_image: 614_400,
        interval_num: 1,
        interval_den: 30,
        driver: "vivid".into(),
        card: "vivid".into(),
        bus_info: "platform:vivid-000".into(),
        device: "/dev/video0".into(),
        node: "/dev/video0".into(),
        fallbacks: vec![],
    };
    let h = n.dump_header();
    assert_eq!(
        (
            h.fourcc,
            h.width,
            h.height,
            h.bytes_per_line,
            h.interval_den
        ),
        (*b"YUYV", 640, 480, 1280, 30)
    );
    assert_eq!(n.fps(), Some(30.0));
    assert!(n.to_string().starts_with("YUYV 640x480"), "{n}");
}

#[test]
fn streams_can_move_to_a_capture_thread() {
    fn is_send<T: Send>() {}
    is_send::<Stream>();
    is_send::<Device>();
    is_send::<OutputDevice>();
}
