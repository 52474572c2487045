//! crossline: a 3D scanner from a fixed camera and a hand-held cross line laser, in air
//! and under water, with no calibration of the laser (Bleier & Nüchter, "Low-Cost 3D
//! Laser Scanning in Air or Water Using Self-Calibrating Structured Light", ISPRS
//! Archives XLII-2/W3, 2017).
//!
//! The two laser planes of the cross are written `v · X = 1` in camera coordinates
//! (OpenCV axes: +X right, +Y down, +Z forward). Curves of different frames cross on
//! the fixed image plane; every crossing `u = (x, y, 1)` gives `(v_i − v_j) · u = 0`,
//! which fixes all planes up to a 4-DOF family that the orthogonality of each cross
//! reduces to one global scale.
//!
//! # Layout
//! The modules follow the data:
//! - [`camera`]: intrinsics, OpenCV distortion, point undistortion.
//! - [`camera_file`]: OpenCV `FileStorage` YAML, ROS `camera_info` and TOML readers/writers.
//! - [`capture`]: frame sources (V4L2 cameras through our own ioctl layer, replays), the
//!   dump format of recorded camera buffers, v4l2loopback output.
//! - [`ring`]: preallocated frame slots between the capture thread and the workers.
//! - [`simulate`]: analytic scenes, the hand-held projector, image formation, ground truth.
//! - [`extract`]: background model, Steger ridge detector, colour classes, linking.
//! - [`intersect`]: spatial index over curve segments, crossing points.
//! - [`solve`]: coplanarity system, gauge, orthogonality, robust re-solve, extension.
//! - [`cloud`]: triangulation, rejection, colour, scale.
//! - [`pipeline`]: the stages after extraction that `reconstruct` and `serve` share:
//!   crossings, the self-calibration, triangulation where the planes determine depth.
//! - [`reconstruct`]: offline recordings through the pipeline; [`config`]: its settings.
//! - [`ply`]: PLY point cloud reading and writing; [`e57`]: E57 export of the final cloud.
//! - [`serve`]: the live daemon: threads, incremental solver, checkpoints, sockets,
//!   the cloud stream protocol and status lines.
//! - [`compare`]: cloud-to-reference and cloud-to-truth accuracy evaluation.
//! - [`pfm`]: Portable Float Map I/O for depth maps.
//! - [`rng`]: the SplitMix64 hash and generator the solver and the simulator share.

pub mod camera;
pub mod camera_file;
pub mod capture;
pub mod cloud;
pub mod compare;
pub mod config;
pub mod e57;
pub mod extract;
pub mod intersect;
pub mod pfm;
pub mod pipeline;
pub mod ply;
pub mod reconstruct;
pub mod ring;
pub mod rng;
pub mod sample;
pub mod serve;
pub mod simulate;
pub mod solve;

/// Longest piece of user input an error message repeats.
pub const MAX_ECHO_CHARS: usize = 200;

/// `text` as an error message may echo it: at most [`MAX_ECHO_CHARS`] characters, the
/// rest replaced by a note of its length, so that one bad line of 20 KB does not
/// become a 20 KB message.
pub fn truncate_echo(text: &str) -> String {
    match text.char_indices().nth(MAX_ECHO_CHARS) {
        None => text.to_string(),
        Some((cut, _)) => format!("{}… ({} bytes in all)", &text[..cut], text.len()),
    }
}
