//! Opening a live camera as a frame source.

use std::path::Path;

use crossline::capture::FrameSource;
use crossline::serve::ServeConfig;

pub fn open_source(device: &Path, _config: &ServeConfig) -> anyhow::Result<Box<dyn FrameSource>> {
    anyhow::bail!(
        "{}: live V4L2 capture is not built into this crossline yet; use --replay",
        device.display()
    )
}
