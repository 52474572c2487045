//! Frames from cameras and recordings:
//! - [`dump`]: the recording format of raw camera buffers.
//! - [`v4l2`] (Linux): capture from V4L2 cameras through our own ioctl layer, and
//!   writing frames into a v4l2loopback device.
//!
//! The live ring between capture and the workers arrives with the daemon.

pub mod dump;
#[cfg(target_os = "linux")]
pub mod v4l2;
