//! Video4Linux2 capture (and v4l2loopback output) through our own small ioctl layer.
//!
//! Why not the `v4l` crate or bindgen: both generate the kernel structs at build time
//! with libclang, and our build machines (and the boat's) do not carry libclang. The
//! handful of structs crossline needs are written out in [`sys`], mirroring
//! `include/uapi/linux/videodev2.h`; unit tests pin their sizes, offsets and the
//! ioctl request numbers to the x86_64 ABI, so a layout slip fails `cargo test`
//! rather than returning `ENOTTY` on a camera.
//!
//! This module owns the device file descriptor, the format negotiation and the
//! memory-mapped buffer queue. It does not own threads, ring buffers or retries: the
//! daemon reopens the device when [`V4l2Error::is_retryable`] says so.
//!
//! # Capture
//! [`Device::open`] → [`Device::negotiate`] → [`Device::start`] → [`Stream::next_frame`]
//! in a loop. A [`Frame`] borrows the [`Stream`]: its bytes are the driver's buffer
//! itself, with no copy, and that buffer goes back to the driver at the next call of
//! `next_frame` (or when the stream is dropped). Dropping the stream turns streaming
//! off, unmaps the buffers and closes the device, on every path.
//!
//! ```no_run
//! use std::path::Path;
//! use std::time::Duration;
//! use crossline::capture::v4l2::{Device, FormatRequest, V4l2Error};
//!
//! fn capture(path: &Path, keep_going: impl Fn() -> bool) -> Result<(), V4l2Error> {
//!     let mut device = Device::open(path)?;
//!     let request = FormatRequest {
//!         fourccs: vec![*b"MJPG", *b"YUYV"],
//!         width: 1920,
//!         height: 1080,
//!         fps: 30,
//!     };
//!     let negotiated = device.negotiate(&request)?;
//!     eprintln!("{negotiated}; notes: {:?}", negotiated.fallbacks);
//!     let mut stream = device.start(4)?;
//!     while keep_going() {
//!         // None: no frame within the timeout, or a signal: check the flag, go on.
//!         if let Some(frame) = stream.next_frame(Duration::from_millis(500))? {
//!             let _ = (frame.sequence, frame.timestamp_nanos, frame.bytes.len());
//!         }
//!     }
//!     Ok(())
//! }
//! // On Err(e) with e.is_retryable() (unplugged, busy, a loopback without its
//! // writer), wait and call capture() again: it reopens the path as given.
//! ```
//!
//! # Output (v4l2loopback)
//! [`OutputDevice`] sets the OUTPUT format and writes each frame with `write(2)` on the
//! same file descriptor: v4l2loopback forgets the format when its last writer closes,
//! a reader's `G_FMT` fails until the first frame is written, and with
//! `exclusive_caps=1` the node advertises CAPTURE only while a writer holds it open.
//! The output is also switched on with `STREAMON`: v4l2loopback 0.12.7 gives the
//! node its OUTPUT capability back, when a writer closes, only after one that did.
//!
//! All of this was run against the kernel's `vivid` and v4l2loopback 0.12.7 (Linux
//! 6.1) in the VM harness (`tests/vm/`), including a camera unplugged mid-stream.

#![allow(unsafe_code)] // The kernel ABI: ioctl, poll, mmap. Each block says why it is sound.

mod error;
mod output;
pub mod sys;

pub use error::{caps_names, V4l2Error};
use error::{fourcc_str, ioctl_error, list_or_none, refused_reason};
pub use output::{OutputDevice, OutputFormat};

use std::fmt;
use std::fs::{File, OpenOptions};
use std::io::{self, Write};
use std::os::fd::{AsFd, BorrowedFd};
use std::os::unix::fs::OpenOptionsExt;
use std::path::{Path, PathBuf};
use std::time::Duration;

use crate::capture::dump::DumpHeader;
use sys::{Fract, Readiness};

/// The pixel formats crossline can record and decode, in the order it falls back to.
pub const USABLE_FOURCCS: [[u8; 4]; 3] = [*b"MJPG", *b"YUYV", *b"RGB3"];

/// `ioctl` with the error mapped and named after the request.
fn call<T: sys::Pod>(
    fd: BorrowedFd<'_>,
    path: &Path,
    request: sys::Request<T>,
    arg: &mut T,
) -> Result<(), V4l2Error> {
    sys::ioctl(fd, request, arg).map_err(|e| ioctl_error(path, request.name, e))
}

/// What the caller would like; the device decides. See [`Device::negotiate`].
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct FormatRequest {
    /// Pixel formats in order of preference, e.g. `[*b"MJPG", *b"YUYV"]`.
    pub fourccs: Vec<[u8; 4]>,
    /// 0 keeps the device's current size.
    pub width: u32,
    pub height: u32,
    /// Frames per second; 0 keeps the device's current rate.
    pub fps: u32,
}

/// The stream the driver agreed to.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Negotiated {
    pub fourcc: [u8; 4],
    pub width: u32,
    pub height: u32,
    /// 0 for compressed formats.
    pub bytes_per_line: u32,
    /// Largest buffer the driver will fill, in bytes.
    pub size_image: u32,
    /// Seconds per frame, as a fraction; 0/0 when the driver does not say.
    pub interval_num: u32,
    pub interval_den: u32,
    pub driver: String,
    pub card: String,
    pub bus_info: String,
    /// The path as given (e.g. a `/dev/v4l/by-id/` link), for messages and reopening.
    pub device: String,
    /// The device node it resolved to (e.g. `/dev/video2`).
    pub node: PathBuf,
    /// What differs from the request, one human-readable note each.
    pub fallbacks: Vec<String>,
}

impl Negotiated {
    pub fn dump_header(&self) -> DumpHeader {
        DumpHeader {
            fourcc: self.fourcc,
            width: self.width,
            height: self.height,
            bytes_per_line: self.bytes_per_line,
            interval_num: self.interval_num,
            interval_den: self.interval_den,
            device: self.device.clone(),
            card: self.card.clone(),
        }
    }

    /// Frames per second, if the driver reported an interval.
    pub fn fps(&self) -> Option<f64> {
        (self.interval_num > 0 && self.interval_den > 0)
            .then(|| self.interval_den as f64 / self.interval_num as f64)
    }
}

impl fmt::Display for Negotiated {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "{} {}x{}",
            fourcc_str(self.fourcc),
            self.width,
            self.height
        )?;
        if self.bytes_per_line > 0 {
            write!(f, " ({} bytes per line)", self.bytes_per_line)?;
        }
        match self.fps() {
            Some(fps) => write!(
                f,
                " at {fps:.3} fps ({}/{} s)",
                self.interval_num, self.interval_den
            )?,
            None => write!(f, " at an unreported frame rate")?,
        }
        write!(
            f,
            " from {} ({}, driver {}, {})",
            self.device, self.card, self.driver, self.bus_info
        )
    }
}

/// One frame size a format offers, with its frame intervals when the size is discrete.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum FrameSize {
    Discrete {
        width: u32,
        height: u32,
        /// Seconds per frame as (numerator, denominator); empty if not enumerable.
        intervals: Vec<(u32, u32)>,
    },
    /// Continuous sizes are stepwise with steps of 1.
    Stepwise {
        min_width: u32,
        max_width: u32,
        step_width: u32,
        min_height: u32,
        max_height: u32,
        step_height: u32,
    },
}

/// A pixel format the device offers for capture.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct FormatInfo {
    pub fourcc: [u8; 4],
    pub description: String,
    pub compressed: bool,
    pub sizes: Vec<FrameSize>,
}

/// A fourcc for people: `YUYV`, `Y16-BE` (V4L2's big-endian flag shown as v4l2-ctl
/// shows it), never a broken character.
pub fn fourcc_name(fourcc: [u8; 4]) -> String {
    fourcc_str(fourcc)
}

/// Which fourcc to ask for: the first requested one the device offers, else the first
/// of [`USABLE_FOURCCS`] it offers with a note saying so, else `None`.
pub fn choose_fourcc(
    requested: &[[u8; 4]],
    offered: &[[u8; 4]],
) -> Option<([u8; 4], Option<String>)> {
    if let Some(f) = requested.iter().find(|f| offered.contains(f)) {
        return Some((*f, None));
    }
    let f = USABLE_FOURCCS.iter().find(|f| offered.contains(f))?;
    let asked: Vec<String> = requested.iter().map(|f| fourcc_str(*f)).collect();
    // vivid offers some 90 formats: name the ones crossline reads, count the rest.
    let readable: Vec<String> = USABLE_FOURCCS
        .iter()
        .filter(|f| offered.contains(f))
        .map(|f| fourcc_str(*f))
        .collect();
    Some((
        *f,
        Some(format!(
            "asked for {}, which the device does not offer (of the {} formats it offers, crossline reads {}): using {}",
            list_or_none(&asked),
            offered.len(),
            readable.join(", "),
            fourcc_str(*f)
        )),
    ))
}

/// `1/fps` as a V4L2 fraction, in thousandths of a frame per second so that 29.97
/// becomes 1000/29970 (reduced: 100/2997).
pub fn interval_from_fps(fps: f64) -> Option<(u32, u32)> {
    if !(fps.is_finite() && fps > 0.0 && fps < 1e6) {
        return None;
    }
    let den = (fps * 1000.0).round() as u64;
    if den == 0 {
        return None;
    }
    let num = 1000u64;
    let g = gcd(num, den);
    Some(((num / g) as u32, (den / g) as u32))
}

fn gcd(mut a: u64, mut b: u64) -> u64 {
    while b != 0 {
        (a, b) = (b, a % b);
    }
    a
}

/// A `timeval` as nanoseconds; negative times (which no driver sends) become 0.
pub fn nanos_from_timeval(tv: libc::timeval) -> u64 {
    let secs = u64::try_from(tv.tv_sec).unwrap_or(0);
    let micros = u64::try_from(tv.tv_usec).unwrap_or(0);
    secs.saturating_mul(1_000_000_000)
        .saturating_add(micros.saturating_mul(1000))
}

/// Opens `path` read-write and non-blocking (`O_CLOEXEC` is std's default), with the
/// errors a user can act on.
fn open_node(path: &Path, nonblocking: bool) -> Result<File, V4l2Error> {
    let mut options = OpenOptions::new();
    options.read(true).write(true);
    if nonblocking {
        options.custom_flags(libc::O_NONBLOCK);
    }
    options
        .open(path)
        .map_err(|source| match source.raw_os_error() {
            Some(libc::ENOENT) => V4l2Error::NotFound {
                path: path.to_path_buf(),
            },
            Some(libc::ENODEV | libc::ENXIO) => V4l2Error::DeviceLost {
                path: path.to_path_buf(),
                op: "open",
                source,
            },
            Some(libc::EBUSY) => V4l2Error::Busy {
                path: path.to_path_buf(),
                op: "open",
            },
            Some(libc::EACCES | libc::EPERM) => V4l2Error::PermissionDenied {
                path: path.to_path_buf(),
            },
            _ => V4l2Error::Open {
                path: path.to_path_buf(),
                source,
            },
        })
}

struct Identity {
    driver: String,
    card: String,
    bus_info: String,
    /// The caps of this node (`device_caps` when the driver fills it).
    caps: u32,
}

fn query_identity(fd: BorrowedFd<'_>, path: &Path) -> Result<Identity, V4l2Error> {
    let mut cap: sys::Capability = sys::zeroed();
    match sys::ioctl(fd, sys::VIDIOC_QUERYCAP, &mut cap) {
        Ok(()) => {}
        // ENOTTY: not a V4L2 node at all (a tty, /dev/null, a file). EINVAL: old
        // kernels' answer to an unknown ioctl.
        Err(e) if matches!(e.raw_os_error(), Some(libc::ENOTTY | libc::EINVAL)) => {
            return Err(V4l2Error::NotCapture {
                path: path.to_path_buf(),
                caps: 0,
            })
        }
        Err(e) => return Err(ioctl_error(path, "VIDIOC_QUERYCAP", e)),
    }
    let caps = if cap.capabilities & sys::V4L2_CAP_DEVICE_CAPS != 0 {
        cap.device_caps
    } else {
        cap.capabilities
    };
    Ok(Identity {
        driver: sys::c_string(&cap.driver),
        card: sys::c_string(&cap.card),
        bus_info: sys::c_string(&cap.bus_info),
        caps,
    })
}

/// An open V4L2 capture device, not yet streaming.
pub struct Device {
    file: File,
    path: PathBuf,
    node: PathBuf,
    identity: Identity,
    negotiated: Option<Negotiated>,
}

impl Device {
    /// Opens a capture node: `/dev/videoN` or a `/dev/v4l/by-id/…` link (resolved for
    /// the log; messages and [`Negotiated::device`] keep the name given). It must
    /// offer single-planar video capture with streaming I/O.
    pub fn open(path: &Path) -> Result<Device, V4l2Error> {
        let node = std::fs::canonicalize(path).map_err(|source| match source.kind() {
            io::ErrorKind::NotFound => V4l2Error::NotFound {
                path: path.to_path_buf(),
            },
            _ => V4l2Error::Open {
                path: path.to_path_buf(),
                source,
            },
        })?;
        let file = open_node(&node, true).map_err(|e| renamed(e, path))?;
        let identity = query_identity(file.as_fd(), path)?;
        let need = sys::V4L2_CAP_VIDEO_CAPTURE | sys::V4L2_CAP_STREAMING;
        if identity.caps & need != need {
            return Err(V4l2Error::NotCapture {
                path: path.to_path_buf(),
                caps: identity.caps,
            });
        }
        tracing::info!(
            "opened {} ({}): {}, driver {}, {}",
            path.display(),
            node.display(),
            identity.card,
            identity.driver,
            identity.bus_info
        );
        Ok(Device {
            file,
            path: path.to_path_buf(),
            node,
            identity,
            negotiated: None,
        })
    }

    /// The path as given to [`Device::open`].
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// The capture formats the device offers, each with its frame sizes and, for
    /// discrete sizes, frame intervals.
    pub fn formats(&self) -> Result<Vec<FormatInfo>, V4l2Error> {
        self.descriptions()?
            .into_iter()
            .map(|desc| {
                Ok(FormatInfo {
                    fourcc: sys::fourcc_bytes(desc.pixelformat),
                    description: sys::c_string(&desc.description),
                    compressed: desc.flags & sys::V4L2_FMT_FLAG_COMPRESSED != 0,
                    sizes: self.frame_sizes(desc.pixelformat)?,
                })
            })
            .collect()
    }

    /// ENUM_FMT alone (a bound guards against drivers that never say EINVAL).
    fn descriptions(&self) -> Result<Vec<sys::FmtDesc>, V4l2Error> {
        let fd = self.file.as_fd();
        let mut out = Vec::new();
        for index in 0..256 {
            let mut desc: sys::FmtDesc = sys::zeroed();
            desc.index = index;
            desc.type_ = sys::V4L2_BUF_TYPE_VIDEO_CAPTURE;
            match sys::ioctl(fd, sys::VIDIOC_ENUM_FMT, &mut desc) {
                Ok(()) => out.push(desc),
                Err(e) if e.raw_os_error() == Some(libc::EINVAL) => break,
                Err(e) => return Err(ioctl_error(&self.path, "VIDIOC_ENUM_FMT", e)),
            }
        }
        Ok(out)
    }

    fn frame_sizes(&self, pixelformat: u32) -> Result<Vec<FrameSize>, V4l2Error> {
        let fd = self.file.as_fd();
        let mut sizes = Vec::new();
        // A bound against drivers that never say EINVAL.
        for index in 0..256 {
            let mut e: sys::FrmSizeEnum = sys::zeroed();
            e.index = index;
            e.pixel_format = pixelformat;
            match sys::ioctl(fd, sys::VIDIOC_ENUM_FRAMESIZES, &mut e) {
                Ok(()) => {}
                // EINVAL ends the list; ENOTTY: the driver does not enumerate sizes.
                Err(err) if matches!(err.raw_os_error(), Some(libc::EINVAL | libc::ENOTTY)) => {
                    break
                }
                Err(err) => return Err(ioctl_error(&self.path, "VIDIOC_ENUM_FRAMESIZES", err)),
            }
            match e.type_ {
                sys::V4L2_FRMSIZE_TYPE_DISCRETE => {
                    // SAFETY: the driver filled the `discrete` member, as `type_` says;
                    // both members are Pod anyway.
                    let d = unsafe { e.size.discrete };
                    sizes.push(FrameSize::Discrete {
                        width: d.width,
                        height: d.height,
                        intervals: self.intervals(pixelformat, d.width, d.height)?,
                    });
                }
                sys::V4L2_FRMSIZE_TYPE_CONTINUOUS | sys::V4L2_FRMSIZE_TYPE_STEPWISE => {
                    // SAFETY: the driver filled the `stepwise` member, as `type_` says.
                    let s = unsafe { e.size.stepwise };
                    sizes.push(FrameSize::Stepwise {
                        min_width: s.min_width,
                        max_width: s.max_width,
                        step_width: s.step_width.max(1),
                        min_height: s.min_height,
                        max_height: s.max_height,
                        step_height: s.step_height.max(1),
                    });
                    break; // A stepwise answer is the only entry.
                }
                _ => break,
            }
        }
        Ok(sizes)
    }

    fn intervals(
        &self,
        pixelformat: u32,
        width: u32,
        height: u32,
    ) -> Result<Vec<(u32, u32)>, V4l2Error> {
        let fd = self.file.as_fd();
        let mut out = Vec::new();
        for index in 0..64 {
            let mut e: sys::FrmIvalEnum = sys::zeroed();
            e.index = index;
            e.pixel_format = pixelformat;
            e.width = width;
            e.height = height;
            match sys::ioctl(fd, sys::VIDIOC_ENUM_FRAMEINTERVALS, &mut e) {
                Ok(()) => {}
                Err(err) if matches!(err.raw_os_error(), Some(libc::EINVAL | libc::ENOTTY)) => {
                    break
                }
                Err(err) => return Err(ioctl_error(&self.path, "VIDIOC_ENUM_FRAMEINTERVALS", err)),
            }
            if e.type_ != sys::V4L2_FRMIVAL_TYPE_DISCRETE {
                break; // Continuous or stepwise ranges: S_PARM will say what it gets.
            }
            // SAFETY: the driver filled the `discrete` member, as `type_` says.
            let f = unsafe { e.interval.discrete };
            out.push((f.numerator, f.denominator));
        }
        Ok(out)
    }

    /// Sets the format and frame rate closest to `req` that the device offers, and
    /// reads back what the driver actually set. Differences from the request are in
    /// [`Negotiated::fallbacks`] and logged as warnings; they are not errors. Fails
    /// only if the device offers none of [`USABLE_FOURCCS`].
    pub fn negotiate(&mut self, req: &FormatRequest) -> Result<Negotiated, V4l2Error> {
        let fd = self.file.as_fd();
        let path = self.path.clone();
        let mut fallbacks = Vec::new();

        // Frame sizes are the driver's to round to in S_FMT; only the fourccs matter.
        let offered: Vec<[u8; 4]> = self
            .descriptions()?
            .iter()
            .map(|d| sys::fourcc_bytes(d.pixelformat))
            .collect();
        tracing::debug!(
            "{} offers {}",
            self.path.display(),
            offered
                .iter()
                .map(|f| fourcc_str(*f))
                .collect::<Vec<_>>()
                .join(", ")
        );
        let Some((fourcc, note)) = choose_fourcc(&req.fourccs, &offered) else {
            return Err(V4l2Error::NoUsableFormat {
                path,
                offered: offered.iter().map(|f| fourcc_str(*f)).collect(),
            });
        };
        fallbacks.extend(note);

        let mut format: sys::Format = sys::zeroed();
        format.type_ = sys::V4L2_BUF_TYPE_VIDEO_CAPTURE;
        call(fd, &path, sys::VIDIOC_G_FMT, &mut format)?;
        // SAFETY: G_FMT for a VIDEO_CAPTURE type fills the `pix` member.
        let mut pix = unsafe { format.fmt.pix };
        if req.width > 0 && req.height > 0 {
            pix.width = req.width;
            pix.height = req.height;
        }
        pix.pixelformat = sys::fourcc_code(fourcc);
        pix.field = sys::V4L2_FIELD_NONE;
        // Let the driver compute these for the new size.
        pix.bytesperline = 0;
        pix.sizeimage = 0;
        format.fmt.pix = pix;
        if let Err(e) = sys::ioctl(fd, sys::VIDIOC_S_FMT, &mut format) {
            // v4l2loopback's capture side takes its format from the writer and may
            // refuse S_FMT (EBUSY, EINVAL): stream in the current format if usable.
            let refused = ioctl_error(&path, "VIDIOC_S_FMT", e);
            if !matches!(&refused, V4l2Error::Busy { .. } | V4l2Error::Ioctl { .. }) {
                return Err(refused);
            }
            format = sys::zeroed();
            format.type_ = sys::V4L2_BUF_TYPE_VIDEO_CAPTURE;
            call(fd, &path, sys::VIDIOC_G_FMT, &mut format)?;
            // SAFETY: G_FMT for a VIDEO_CAPTURE type fills the `pix` member.
            let current = unsafe { format.fmt.pix };
            if !USABLE_FOURCCS.contains(&sys::fourcc_bytes(current.pixelformat)) {
                return Err(refused);
            }
            fallbacks.push(format!(
                "the driver refused to set the format ({}); using its current one",
                refused_reason(&refused)
            ));
        }
        // SAFETY: S_FMT (or G_FMT) wrote the format in force into the `pix` member.
        let got = unsafe { format.fmt.pix };
        let got_fourcc = sys::fourcc_bytes(got.pixelformat);
        if got_fourcc != fourcc {
            if !USABLE_FOURCCS.contains(&got_fourcc) {
                return Err(V4l2Error::NoUsableFormat {
                    path,
                    offered: offered.iter().map(|f| fourcc_str(*f)).collect(),
                });
            }
            fallbacks.push(format!(
                "asked for {}, the driver set {}",
                fourcc_str(fourcc),
                fourcc_str(got_fourcc)
            ));
        }
        if req.width > 0 && req.height > 0 && (got.width, got.height) != (req.width, req.height) {
            fallbacks.push(format!(
                "asked for {}x{}, the driver set {}x{}",
                req.width, req.height, got.width, got.height
            ));
        }
        if got.field != sys::V4L2_FIELD_NONE {
            fallbacks.push(format!(
                "the driver delivers field order {} instead of progressive frames",
                got.field
            ));
        }

        let (interval_num, interval_den) = self.set_frame_rate(req.fps, &mut fallbacks)?;

        let negotiated = Negotiated {
            fourcc: got_fourcc,
            width: got.width,
            height: got.height,
            bytes_per_line: got.bytesperline,
            size_image: got.sizeimage,
            interval_num,
            interval_den,
            driver: self.identity.driver.clone(),
            card: self.identity.card.clone(),
            bus_info: self.identity.bus_info.clone(),
            device: self.path.display().to_string(),
            node: self.node.clone(),
            fallbacks,
        };
        tracing::info!("negotiated {negotiated}");
        for note in &negotiated.fallbacks {
            tracing::warn!("{}: {note}", self.path.display());
        }
        self.negotiated = Some(negotiated.clone());
        Ok(negotiated)
    }

    /// S_PARM to `1/fps` when the driver allows it, then G_PARM to read back what it
    /// runs at. Drivers that cannot set or report a rate are notes, not errors.
    fn set_frame_rate(
        &self,
        fps: u32,
        fallbacks: &mut Vec<String>,
    ) -> Result<(u32, u32), V4l2Error> {
        let fd = self.file.as_fd();
        let mut parm: sys::StreamParm = sys::zeroed();
        parm.type_ = sys::V4L2_BUF_TYPE_VIDEO_CAPTURE;
        match sys::ioctl(fd, sys::VIDIOC_G_PARM, &mut parm) {
            Ok(()) => {}
            Err(e) if matches!(e.raw_os_error(), Some(libc::ENOTTY | libc::EINVAL)) => {
                if fps > 0 {
                    fallbacks.push(format!(
                        "asked for {fps} fps, the driver neither sets nor reports a frame rate"
                    ));
                }
                return Ok((0, 0));
            }
            Err(e) => return Err(ioctl_error(&self.path, "VIDIOC_G_PARM", e)),
        }
        // SAFETY: G_PARM for a VIDEO_CAPTURE type fills the `capture` member.
        let capture = unsafe { parm.parm.capture };
        if fps > 0 {
            if capture.capability & sys::V4L2_CAP_TIMEPERFRAME == 0 {
                // Not settable (v4l2loopback: the writer sets it); the read-back below
                // says whether that matters.
                tracing::debug!(
                    "{}: the driver does not let the frame rate be set",
                    self.path.display()
                );
            } else {
                let mut set: sys::StreamParm = sys::zeroed();
                set.type_ = sys::V4L2_BUF_TYPE_VIDEO_CAPTURE;
                let mut c = capture;
                c.timeperframe = Fract {
                    numerator: 1,
                    denominator: fps,
                };
                set.parm.capture = c;
                if let Err(e) = sys::ioctl(fd, sys::VIDIOC_S_PARM, &mut set) {
                    // Only a vanished device is fatal: a refused rate (EINVAL, or EBUSY
                    // from v4l2loopback while its writer owns the rate) leaves the
                    // current one, read back below.
                    match ioctl_error(&self.path, "VIDIOC_S_PARM", e) {
                        lost @ V4l2Error::DeviceLost { .. } => return Err(lost),
                        refused => fallbacks.push(format!(
                            "asked for {fps} fps, the driver refused ({})",
                            refused_reason(&refused)
                        )),
                    }
                }
            }
        }
        let mut back: sys::StreamParm = sys::zeroed();
        back.type_ = sys::V4L2_BUF_TYPE_VIDEO_CAPTURE;
        call(fd, &self.path, sys::VIDIOC_G_PARM, &mut back)?;
        // SAFETY: G_PARM for a VIDEO_CAPTURE type fills the `capture` member.
        let t = unsafe { back.parm.capture }.timeperframe;
        if t.numerator == 0 || t.denominator == 0 {
            if fps > 0 {
                fallbacks.push(format!(
                    "asked for {fps} fps, the driver does not report its frame rate"
                ));
            }
            return Ok((0, 0));
        }
        let got_fps = t.denominator as f64 / t.numerator as f64;
        // UVC intervals are in 100 ns units: 333333/10000000 s is 30 fps.
        if fps > 0 && (got_fps / fps as f64 - 1.0).abs() > 1e-3 {
            fallbacks.push(format!(
                "asked for {fps} fps, the driver runs at {got_fps:.3} fps ({}/{} s)",
                t.numerator, t.denominator
            ));
        }
        Ok((t.numerator, t.denominator))
    }

    /// The format currently set, for [`Device::start`] without [`Device::negotiate`].
    fn current(&self) -> Result<Negotiated, V4l2Error> {
        let fd = self.file.as_fd();
        let mut format: sys::Format = sys::zeroed();
        format.type_ = sys::V4L2_BUF_TYPE_VIDEO_CAPTURE;
        call(fd, &self.path, sys::VIDIOC_G_FMT, &mut format)?;
        // SAFETY: G_FMT for a VIDEO_CAPTURE type fills the `pix` member.
        let pix = unsafe { format.fmt.pix };
        let mut ignored = Vec::new();
        let (interval_num, interval_den) = self.set_frame_rate(0, &mut ignored)?;
        Ok(Negotiated {
            fourcc: sys::fourcc_bytes(pix.pixelformat),
            width: pix.width,
            height: pix.height,
            bytes_per_line: pix.bytesperline,
            size_image: pix.sizeimage,
            interval_num,
            interval_den,
            driver: self.identity.driver.clone(),
            card: self.identity.card.clone(),
            bus_info: self.identity.bus_info.clone(),
            device: self.path.display().to_string(),
            node: self.node.clone(),
            fallbacks: Vec::new(),
        })
    }

    /// Allocates `buffers` driver buffers (the driver may grant a different number),
    /// maps and queues them all, and starts streaming. Without a prior
    /// [`Device::negotiate`], streams in the device's current format. On error the
    /// device is closed and any mapped buffers are unmapped.
    pub fn start(self, buffers: u32) -> Result<Stream, V4l2Error> {
        let negotiated = match &self.negotiated {
            Some(n) => n.clone(),
            None => self.current()?,
        };
        let Device { file, path, .. } = self;
        let fd = file.as_fd();
        let mut req: sys::RequestBuffers = sys::zeroed();
        req.count = buffers.max(1);
        req.type_ = sys::V4L2_BUF_TYPE_VIDEO_CAPTURE;
        req.memory = sys::V4L2_MEMORY_MMAP;
        call(fd, &path, sys::VIDIOC_REQBUFS, &mut req)?;
        if req.count == 0 {
            return Err(V4l2Error::Ioctl {
                path,
                op: "VIDIOC_REQBUFS",
                source: io::Error::new(io::ErrorKind::OutOfMemory, "the driver granted no buffers"),
            });
        }
        if req.count != buffers {
            tracing::warn!(
                "{}: asked for {buffers} buffers, the driver granted {}",
                path.display(),
                req.count
            );
        }
        let mut mappings = Vec::with_capacity(req.count as usize);
        for index in 0..req.count {
            let mut buf: sys::Buffer = sys::zeroed();
            buf.index = index;
            buf.type_ = sys::V4L2_BUF_TYPE_VIDEO_CAPTURE;
            buf.memory = sys::V4L2_MEMORY_MMAP;
            call(fd, &path, sys::VIDIOC_QUERYBUF, &mut buf)?;
            // SAFETY: QUERYBUF of an MMAP buffer fills `m.offset`.
            let offset = unsafe { buf.m.offset };
            let mapping = sys::Mapping::new(fd, buf.length as usize, offset)
                .map_err(|e| ioctl_error(&path, "mmap", e))?;
            mappings.push(mapping);
        }
        for index in 0..req.count {
            queue(fd, &path, index)?;
        }
        let mut kind: libc::c_int = sys::V4L2_BUF_TYPE_VIDEO_CAPTURE as libc::c_int;
        call(fd, &path, sys::VIDIOC_STREAMON, &mut kind)?;
        tracing::info!(
            "{}: streaming with {} buffers of {} bytes",
            path.display(),
            mappings.len(),
            mappings.first().map_or(0, |m| m.byte_len())
        );
        Ok(Stream {
            file,
            path,
            negotiated,
            mappings,
            held: None,
            streaming: true,
        })
    }
}

/// An error from opening the resolved node, named after the path the caller gave.
fn renamed(e: V4l2Error, path: &Path) -> V4l2Error {
    let path = path.to_path_buf();
    match e {
        V4l2Error::NotFound { .. } => V4l2Error::NotFound { path },
        V4l2Error::Open { source, .. } => V4l2Error::Open { path, source },
        V4l2Error::DeviceLost { op, source, .. } => V4l2Error::DeviceLost { path, op, source },
        V4l2Error::Busy { op, .. } => V4l2Error::Busy { path, op },
        V4l2Error::PermissionDenied { .. } => V4l2Error::PermissionDenied { path },
        other => other,
    }
}

fn queue(fd: BorrowedFd<'_>, path: &Path, index: u32) -> Result<(), V4l2Error> {
    let mut buf: sys::Buffer = sys::zeroed();
    buf.index = index;
    buf.type_ = sys::V4L2_BUF_TYPE_VIDEO_CAPTURE;
    buf.memory = sys::V4L2_MEMORY_MMAP;
    call(fd, path, sys::VIDIOC_QBUF, &mut buf)
}

/// A streaming capture device. `Send`: the daemon moves it into its capture thread.
pub struct Stream {
    file: File,
    path: PathBuf,
    negotiated: Negotiated,
    mappings: Vec<sys::Mapping>,
    /// The buffer lent out as the last [`Frame`], re-queued at the next call.
    held: Option<u32>,
    streaming: bool,
}

/// One dequeued buffer. It borrows the [`Stream`], so it must be dropped (or its
/// bytes copied) before the next [`Stream::next_frame`], which hands the buffer back
/// to the driver.
pub struct Frame<'a> {
    /// The driver's frame counter; a jump of more than one means the driver dropped
    /// frames (usually because every buffer was held by us).
    pub sequence: u32,
    /// When the driver captured the frame (usually `CLOCK_MONOTONIC`, see
    /// [`Frame::monotonic`]), in nanoseconds.
    pub timestamp_nanos: u64,
    /// `V4L2_BUF_FLAG_*`; `V4L2_BUF_FLAG_ERROR` (0x40) marks a frame the driver knows
    /// is damaged.
    pub flags: u32,
    /// The payload (`bytesused` bytes of the buffer).
    pub bytes: &'a [u8],
}

impl fmt::Debug for Frame<'_> {
    /// The payload's length, not its megabytes.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("Frame")
            .field("sequence", &self.sequence)
            .field("timestamp_nanos", &self.timestamp_nanos)
            .field("flags", &format_args!("{:#x}", self.flags))
            .field("bytes", &self.bytes.len())
            .finish()
    }
}

impl Frame<'_> {
    /// The driver flagged this frame as damaged (`V4L2_BUF_FLAG_ERROR`).
    pub fn is_error(&self) -> bool {
        self.flags & sys::V4L2_BUF_FLAG_ERROR != 0
    }

    /// The timestamp is from `CLOCK_MONOTONIC` (comparable with `clock_gettime`).
    pub fn monotonic(&self) -> bool {
        self.flags & sys::V4L2_BUF_FLAG_TIMESTAMP_MASK == sys::V4L2_BUF_FLAG_TIMESTAMP_MONOTONIC
    }
}

impl Stream {
    pub fn negotiated(&self) -> &Negotiated {
        &self.negotiated
    }

    /// The path as given to [`Device::open`].
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// How many buffers the driver granted.
    pub fn buffer_count(&self) -> usize {
        self.mappings.len()
    }

    /// Waits up to `timeout` for the next frame. `Ok(None)` if none came in time or a
    /// signal interrupted the wait (check your stop flag and call again). The buffer of
    /// the previous frame is re-queued first. A vanished device is
    /// [`V4l2Error::DeviceLost`]; after any error, drop the stream and reopen.
    pub fn next_frame(&mut self, timeout: Duration) -> Result<Option<Frame<'_>>, V4l2Error> {
        let fd = self.file.as_fd();
        if let Some(index) = self.held.take() {
            queue(fd, &self.path, index)?;
        }
        match sys::poll_readable(fd, timeout).map_err(|e| ioctl_error(&self.path, "poll", e))? {
            Readiness::Readable => {}
            Readiness::TimedOut | Readiness::Interrupted => return Ok(None),
            Readiness::Failed(revents) => {
                return Err(V4l2Error::DeviceLost {
                    path: self.path.clone(),
                    op: "poll",
                    source: io::Error::other(format!("poll reported {}", poll_bits(revents))),
                })
            }
        }
        let mut buf: sys::Buffer = sys::zeroed();
        buf.type_ = sys::V4L2_BUF_TYPE_VIDEO_CAPTURE;
        buf.memory = sys::V4L2_MEMORY_MMAP;
        match sys::ioctl(fd, sys::VIDIOC_DQBUF, &mut buf) {
            Ok(()) => {}
            // Readable but nothing to dequeue (another reader was faster): a timeout.
            Err(e) if e.kind() == io::ErrorKind::WouldBlock => return Ok(None),
            Err(e) => return Err(ioctl_error(&self.path, "VIDIOC_DQBUF", e)),
        }
        let Some(mapping) = self.mappings.get(buf.index as usize) else {
            return Err(V4l2Error::Ioctl {
                path: self.path.clone(),
                op: "VIDIOC_DQBUF",
                source: io::Error::new(
                    io::ErrorKind::InvalidData,
                    format!(
                        "driver returned buffer index {} of {}",
                        buf.index,
                        self.mappings.len()
                    ),
                ),
            });
        };
        self.held = Some(buf.index);
        let timestamp_nanos = nanos_from_timeval(buf.timestamp);
        tracing::trace!(
            sequence = buf.sequence,
            timestamp_nanos,
            bytes = buf.bytesused,
            flags = buf.flags,
            index = buf.index,
            "frame"
        );
        // SAFETY: buffer `buf.index` is dequeued: it belongs to user space until we
        // QBUF it, which happens only in `next_frame`/`drop`, both needing `&mut self`,
        // which the returned `Frame` (borrowing `self`) rules out while it lives.
        let bytes = unsafe { mapping.bytes(buf.bytesused as usize) };
        Ok(Some(Frame {
            sequence: buf.sequence,
            timestamp_nanos,
            flags: buf.flags,
            bytes,
        }))
    }
}

fn poll_bits(revents: i16) -> String {
    let mut names = Vec::new();
    for (bit, name) in [
        (libc::POLLERR, "POLLERR"),
        (libc::POLLHUP, "POLLHUP"),
        (libc::POLLNVAL, "POLLNVAL"),
    ] {
        if revents & bit != 0 {
            names.push(name);
        }
    }
    names.join(" | ")
}

impl Drop for Stream {
    fn drop(&mut self) {
        if self.streaming {
            let mut kind: libc::c_int = sys::V4L2_BUF_TYPE_VIDEO_CAPTURE as libc::c_int;
            if let Err(e) = sys::ioctl(self.file.as_fd(), sys::VIDIOC_STREAMOFF, &mut kind) {
                // A vanished device cannot stop; closing releases everything anyway.
                tracing::debug!("{}: VIDIOC_STREAMOFF: {e}", self.path.display());
            }
            self.streaming = false;
        }
        // Unmap before the file closes (field order would do it the other way round).
        self.mappings.clear();
    }
}

#[cfg(test)]
mod tests;
