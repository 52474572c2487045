//! Opening a live camera as a frame source.

use std::path::Path;
use std::time::Duration;

use anyhow::Context;
use crossline::capture::FrameSource;
use crossline::serve::ServeConfig;

#[cfg(target_os = "linux")]
pub fn open_source(device: &Path, config: &ServeConfig) -> anyhow::Result<Box<dyn FrameSource>> {
    use crossline::capture::live::{LiveParams, LiveSource};
    use crossline::capture::v4l2::FormatRequest;
    let fourccs = config
        .formats
        .iter()
        .map(|f| {
            let b = f.trim().to_ascii_uppercase().into_bytes();
            <[u8; 4]>::try_from(b.as_slice()).map_err(|_| {
                anyhow::anyhow!(
                    "[serve] formats: {f:?} is not a four-character code such as MJPG or YUYV"
                )
            })
        })
        .collect::<anyhow::Result<Vec<_>>>()?;
    let params = LiveParams {
        request: FormatRequest {
            fourccs,
            width: config.width,
            height: config.height,
            fps: config.fps,
        },
        buffers: config.buffers.max(2),
        max_backoff: Duration::from_secs_f64(config.reconnect_max_backoff_s.max(0.1)),
    };
    let src = LiveSource::open(device, params)
        .with_context(|| format!("opening the camera {}", device.display()))?;
    Ok(Box::new(src))
}

#[cfg(not(target_os = "linux"))]
pub fn open_source(device: &Path, _config: &ServeConfig) -> anyhow::Result<Box<dyn FrameSource>> {
    anyhow::bail!(
        "{}: live capture needs Linux (V4L2); use --replay",
        device.display()
    )
}
