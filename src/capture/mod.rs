//! Frames from cameras and recordings. [`dump`] is the recording format of raw camera
//! buffers; the V4L2 capture and the live ring arrive with the daemon.

pub mod dump;
