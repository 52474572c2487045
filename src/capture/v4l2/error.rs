//! The capture layer's errors ([`V4l2Error`]) and the words its messages are made of:
//! capability names, what a node lacks, fourccs as `v4l2-ctl` prints them, and an
//! ioctl's failure mapped to a vanished, busy or refusing device.

use std::io;
use std::path::{Path, PathBuf};

use super::sys;

#[derive(Debug, thiserror::Error)]
pub enum V4l2Error {
    #[error("{path}: no such device (is the camera plugged in and its driver loaded?)")]
    NotFound { path: PathBuf },
    #[error("{path}: permission denied (is this user in the `video` group?)")]
    PermissionDenied { path: PathBuf },
    #[error("cannot open {path}: {source}")]
    Open {
        path: PathBuf,
        #[source]
        source: io::Error,
    },
    #[error("{path} is not a V4L2 capture device: {}", capture_caps_problem(*.caps))]
    NotCapture { path: PathBuf, caps: u32 },
    #[error("{path} is not a V4L2 output device: {}", output_caps_problem(*.caps))]
    NotOutput { path: PathBuf, caps: u32 },
    #[error("{path} offers none of the pixel formats crossline reads (MJPG, YUYV, RGB3); it offers {}", list_or_none(.offered))]
    NoUsableFormat { path: PathBuf, offered: Vec<String> },
    #[error("{path} is busy ({op}): another program is using it")]
    Busy { path: PathBuf, op: &'static str },
    #[error("{path} went away ({op}): {source}")]
    DeviceLost {
        path: PathBuf,
        op: &'static str,
        #[source]
        source: io::Error,
    },
    #[error("{path}: {op} failed: {source}")]
    Ioctl {
        path: PathBuf,
        op: &'static str,
        #[source]
        source: io::Error,
    },
    #[error("{path}: frame of {len} bytes does not fit the output buffer of {size_image} bytes")]
    FrameTooLarge {
        path: PathBuf,
        len: usize,
        size_image: u32,
    },
}

impl V4l2Error {
    /// The device is missing, gone or taken: worth reopening after a pause (a camera
    /// re-enumerating on USB, a housing connector reseated). Format and capability
    /// errors are not: they will say the same next time.
    ///
    /// A v4l2loopback node whose writer has gone counts as missing: with
    /// `exclusive_caps=1` it shows OUTPUT but not CAPTURE, otherwise it offers no
    /// format, until a writer comes back.
    pub fn is_retryable(&self) -> bool {
        match self {
            V4l2Error::NotFound { .. } | V4l2Error::DeviceLost { .. } | V4l2Error::Busy { .. } => {
                true
            }
            V4l2Error::NotCapture { caps, .. } => {
                caps & sys::V4L2_CAP_VIDEO_OUTPUT != 0 && caps & sys::V4L2_CAP_STREAMING != 0
            }
            V4l2Error::NoUsableFormat { offered, .. } => offered.is_empty(),
            _ => false,
        }
    }

    /// The device (or its driver) disappeared while in use.
    pub fn is_device_lost(&self) -> bool {
        matches!(self, V4l2Error::DeviceLost { .. })
    }
}

pub(super) fn list_or_none(v: &[String]) -> String {
    if v.is_empty() {
        "nothing".into()
    } else {
        v.join(", ")
    }
}

/// Names of the capability bits crossline cares about.
pub fn caps_names(caps: u32) -> String {
    const NAMES: [(u32, &str); 8] = [
        (sys::V4L2_CAP_VIDEO_CAPTURE, "VIDEO_CAPTURE"),
        (sys::V4L2_CAP_VIDEO_OUTPUT, "VIDEO_OUTPUT"),
        (sys::V4L2_CAP_VIDEO_CAPTURE_MPLANE, "VIDEO_CAPTURE_MPLANE"),
        (sys::V4L2_CAP_VIDEO_OUTPUT_MPLANE, "VIDEO_OUTPUT_MPLANE"),
        (sys::V4L2_CAP_VIDEO_M2M, "VIDEO_M2M"),
        (sys::V4L2_CAP_META_CAPTURE, "META_CAPTURE"),
        (sys::V4L2_CAP_READWRITE, "READWRITE"),
        (sys::V4L2_CAP_STREAMING, "STREAMING"),
    ];
    let names: Vec<&str> = NAMES
        .iter()
        .filter(|(bit, _)| caps & bit != 0)
        .map(|(_, n)| *n)
        .collect();
    if names.is_empty() {
        format!("{caps:#010x}")
    } else {
        names.join(" | ")
    }
}

pub(super) fn capture_caps_problem(caps: u32) -> String {
    if caps == 0 {
        return "it does not answer VIDIOC_QUERYCAP".into();
    }
    let mut s = format!(
        "it offers {}; crossline needs VIDEO_CAPTURE with STREAMING",
        caps_names(caps)
    );
    if caps & sys::V4L2_CAP_VIDEO_CAPTURE_MPLANE != 0 {
        s.push_str(" (multi-planar capture is not supported)");
    }
    if caps & sys::V4L2_CAP_VIDEO_OUTPUT != 0 {
        s.push_str(" (a v4l2loopback node with exclusive_caps=1 shows CAPTURE only while a writer is attached)");
    }
    s
}

pub(super) fn output_caps_problem(caps: u32) -> String {
    if caps == 0 {
        "it does not answer VIDIOC_QUERYCAP".into()
    } else {
        format!(
            "it offers {}; feeding needs VIDEO_OUTPUT (a v4l2loopback node)",
            caps_names(caps)
        )
    }
}

/// A fourcc as text. V4L2 marks big-endian variants with bit 31 (the top bit of the
/// last byte); it is shown as `-BE`, as v4l2-ctl does, rather than as a broken character.
pub(super) fn fourcc_str(f: [u8; 4]) -> String {
    let big_endian = f[3] & 0x80 != 0;
    let bytes = [f[0], f[1], f[2], f[3] & 0x7f];
    let name = String::from_utf8_lossy(&bytes).trim_end().to_string();
    if big_endian {
        format!("{name}-BE")
    } else {
        name
    }
}

/// The errno text of a refused ioctl, for a note.
pub(super) fn refused_reason(e: &V4l2Error) -> String {
    match e {
        V4l2Error::Ioctl { source, .. } => source.to_string(),
        V4l2Error::Busy { .. } => "busy".into(),
        other => other.to_string(),
    }
}

/// Maps an ioctl failure: a vanished device, a busy one, or anything else.
pub(super) fn ioctl_error(path: &Path, op: &'static str, source: io::Error) -> V4l2Error {
    let path = path.to_path_buf();
    match source.raw_os_error() {
        Some(libc::ENODEV | libc::EIO | libc::ENXIO | libc::ESHUTDOWN) => {
            V4l2Error::DeviceLost { path, op, source }
        }
        Some(libc::EBUSY) => V4l2Error::Busy { path, op },
        _ => V4l2Error::Ioctl { path, op, source },
    }
}
