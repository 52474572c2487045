//! The v4l2loopback OUTPUT side: [`OutputDevice`] sets the format and writes each
//! frame with `write(2)` (see the parent module's docs, *Output*).

use super::*;

/// What to write into a v4l2loopback device.
#[derive(Clone, Debug, PartialEq)]
pub struct OutputFormat {
    pub fourcc: [u8; 4],
    pub width: u32,
    pub height: u32,
    /// 0 lets the driver choose (and is right for MJPG).
    pub bytes_per_line: u32,
    /// Advertised to readers through S_PARM; the writer paces itself.
    pub fps: f64,
}

/// A v4l2loopback OUTPUT node that frames are written to, one `write(2)` per frame.
pub struct OutputDevice {
    file: File,
    path: PathBuf,
    size_image: u32,
    bytes_per_line: u32,
}

/// Room for one JPEG: far more than any camera's MJPEG frame at that size.
fn mjpeg_size_image(width: u32, height: u32) -> u32 {
    (u64::from(width) * u64::from(height) * 4)
        .clamp(1 << 20, 64 << 20)
        .try_into()
        .unwrap_or(64 << 20)
}

impl OutputDevice {
    /// Opens `path` (blocking writes), sets the OUTPUT format (a node that takes none
    /// is [`V4l2Error::NotOutput`]; a loopback already streaming another format is
    /// [`V4l2Error::Busy`]) and advertises the frame rate. Keep the value alive for as
    /// long as readers should see the format.
    pub fn open(path: &Path, format: &OutputFormat) -> Result<OutputDevice, V4l2Error> {
        let file = open_node(path, false)?;
        let fd = file.as_fd();
        let identity = query_identity(fd, path).map_err(|e| match e {
            V4l2Error::NotCapture { path, caps } => V4l2Error::NotOutput { path, caps },
            other => other,
        })?;
        // v4l2loopback with exclusive_caps=1 hides OUTPUT while a reader still holds
        // the stream of an earlier writer, yet takes a new writer of the same format:
        // so the capability is not checked here; an OUTPUT S_FMT that the driver does
        // not know is the refusal.
        let advertises_output = identity.caps & sys::V4L2_CAP_VIDEO_OUTPUT != 0;
        let compressed = &format.fourcc == b"MJPG" || &format.fourcc == b"JPEG";
        let mut f: sys::Format = sys::zeroed();
        f.type_ = sys::V4L2_BUF_TYPE_VIDEO_OUTPUT;
        let mut pix: sys::PixFormat = sys::zeroed();
        pix.width = format.width;
        pix.height = format.height;
        pix.pixelformat = sys::fourcc_code(format.fourcc);
        pix.field = sys::V4L2_FIELD_NONE;
        pix.colorspace = sys::V4L2_COLORSPACE_SRGB;
        pix.bytesperline = if compressed { 0 } else { format.bytes_per_line };
        pix.sizeimage = if compressed {
            mjpeg_size_image(format.width, format.height)
        } else {
            0
        };
        f.fmt.pix = pix;
        if let Err(e) = sys::ioctl(fd, sys::VIDIOC_S_FMT, &mut f) {
            if !advertises_output && matches!(e.raw_os_error(), Some(libc::EINVAL | libc::ENOTTY)) {
                return Err(V4l2Error::NotOutput {
                    path: path.to_path_buf(),
                    caps: identity.caps,
                });
            }
            return Err(ioctl_error(path, "VIDIOC_S_FMT", e));
        }
        // SAFETY: S_FMT for a VIDEO_OUTPUT type writes back the `pix` member.
        let got = unsafe { f.fmt.pix };
        if (got.width, got.height, got.pixelformat) != (pix.width, pix.height, pix.pixelformat) {
            return Err(V4l2Error::Ioctl {
                path: path.to_path_buf(),
                op: "VIDIOC_S_FMT",
                source: io::Error::new(
                    io::ErrorKind::InvalidInput,
                    format!(
                        "asked for {} {}x{}, the driver set {} {}x{}",
                        fourcc_str(format.fourcc),
                        format.width,
                        format.height,
                        fourcc_str(sys::fourcc_bytes(got.pixelformat)),
                        got.width,
                        got.height
                    ),
                ),
            });
        }
        if let Some((num, den)) = interval_from_fps(format.fps) {
            let mut parm: sys::StreamParm = sys::zeroed();
            parm.type_ = sys::V4L2_BUF_TYPE_VIDEO_OUTPUT;
            parm.parm.output = sys::OutputParm {
                capability: sys::V4L2_CAP_TIMEPERFRAME,
                outputmode: 0,
                timeperframe: Fract {
                    numerator: num,
                    denominator: den,
                },
                extendedmode: 0,
                writebuffers: 0,
                reserved: [0; 4],
            };
            if let Err(e) = sys::ioctl(fd, sys::VIDIOC_S_PARM, &mut parm) {
                tracing::warn!(
                    "{}: cannot advertise {} fps to readers: {e}",
                    path.display(),
                    format.fps
                );
            }
        }
        // v4l2loopback (0.12.7) gives an exclusive_caps=1 node its OUTPUT capability
        // back when a writer closes only if that writer called STREAMON: after a
        // write(2)-only writer the node advertises neither CAPTURE nor OUTPUT until the
        // module is reloaded. Best effort: other drivers may want REQBUFS first.
        let mut kind = sys::V4L2_BUF_TYPE_VIDEO_OUTPUT as libc::c_int;
        if let Err(e) = sys::ioctl(fd, sys::VIDIOC_STREAMON, &mut kind) {
            tracing::debug!("{}: VIDIOC_STREAMON (output): {e}", path.display());
        }
        tracing::info!(
            "{}: output {} {}x{}, {} bytes per line, buffers of {} bytes ({}, driver {})",
            path.display(),
            fourcc_str(sys::fourcc_bytes(got.pixelformat)),
            got.width,
            got.height,
            got.bytesperline,
            got.sizeimage,
            identity.card,
            identity.driver
        );
        Ok(OutputDevice {
            file,
            path: path.to_path_buf(),
            size_image: got.sizeimage,
            bytes_per_line: got.bytesperline,
        })
    }

    /// The driver's buffer size: the largest frame [`OutputDevice::write_frame`] takes.
    pub fn size_image(&self) -> u32 {
        self.size_image
    }

    pub fn bytes_per_line(&self) -> u32 {
        self.bytes_per_line
    }

    /// Writes one whole frame in one `write(2)`.
    pub fn write_frame(&mut self, bytes: &[u8]) -> Result<(), V4l2Error> {
        if self.size_image > 0 && bytes.len() > self.size_image as usize {
            return Err(V4l2Error::FrameTooLarge {
                path: self.path.clone(),
                len: bytes.len(),
                size_image: self.size_image,
            });
        }
        loop {
            match self.file.write(bytes) {
                Ok(n) if n == bytes.len() => return Ok(()),
                Ok(n) => {
                    return Err(ioctl_error(
                        &self.path,
                        "write",
                        io::Error::new(
                            io::ErrorKind::WriteZero,
                            format!("the driver took {n} of {} bytes", bytes.len()),
                        ),
                    ))
                }
                Err(e) if e.kind() == io::ErrorKind::Interrupted => continue,
                Err(e) => return Err(ioctl_error(&self.path, "write", e)),
            }
        }
    }
}
