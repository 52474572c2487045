//! PLY point clouds: the cloud type every stage exchanges, and its reading and writing.
//!
//! # What crossline writes (format version 1)
//! `binary_little_endian 1.0`, one `vertex` element with, in this order:
//!
//! | property | type | meaning |
//! |---|---|---|
//! | x, y, z | float | position in camera coordinates (OpenCV axes), scene units |
//! | red, green, blue | uchar | colour (present when the cloud has colours) |
//! | frame | uint | frame index the point came from (present when known) |
//! | laser | uchar | laser index 0 or 1 within its frame (present when known) |
//! | distance | float | point-to-reference distance (written by `compare` only) |
//!
//! A `comment crossline ply 1` line names the version; other comments carry provenance.
//! CloudCompare, MeshLab and Open3D read this layout (extra properties are kept as
//! scalar fields).

use std::io::{BufWriter, Write};
use std::path::Path;

/// Version written in the `comment crossline ply N` header line.
pub const PLY_VERSION: u32 = 1;

/// A point cloud with optional per-point attributes. Every present attribute vector has
/// exactly `points.len()` entries.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Cloud {
    pub points: Vec<[f32; 3]>,
    pub colors: Option<Vec<[u8; 3]>>,
    pub frames: Option<Vec<u32>>,
    pub lasers: Option<Vec<u8>>,
    pub distances: Option<Vec<f32>>,
}

impl Cloud {
    pub fn len(&self) -> usize {
        self.points.len()
    }

    pub fn is_empty(&self) -> bool {
        self.points.is_empty()
    }
}

#[derive(Debug, thiserror::Error)]
pub enum PlyError {
    #[error("cannot read or write {path}: {source}")]
    Io {
        path: std::path::PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("{path}: {message}")]
    Format {
        path: std::path::PathBuf,
        message: String,
    },
}

/// Writes `cloud` as binary little-endian PLY; `comments` become header comment lines.
pub fn write_ply(path: &Path, cloud: &Cloud, comments: &[String]) -> Result<(), PlyError> {
    let io = |source| PlyError::Io {
        path: path.to_path_buf(),
        source,
    };
    let n = cloud.len();
    for (name, len) in [
        ("colors", cloud.colors.as_ref().map(Vec::len)),
        ("frames", cloud.frames.as_ref().map(Vec::len)),
        ("lasers", cloud.lasers.as_ref().map(Vec::len)),
        ("distances", cloud.distances.as_ref().map(Vec::len)),
    ] {
        if let Some(len) = len {
            if len != n {
                return Err(PlyError::Format {
                    path: path.to_path_buf(),
                    message: format!("{name} has {len} entries for {n} points"),
                });
            }
        }
    }
    let file = std::fs::File::create(path).map_err(io)?;
    let mut w = BufWriter::with_capacity(1 << 20, file);
    let mut header = String::from("ply\nformat binary_little_endian 1.0\n");
    header.push_str(&format!("comment crossline ply {PLY_VERSION}\n"));
    for c in comments {
        header.push_str(&format!("comment {}\n", c.replace('\n', " ")));
    }
    header.push_str(&format!(
        "element vertex {n}\nproperty float x\nproperty float y\nproperty float z\n"
    ));
    if cloud.colors.is_some() {
        header.push_str("property uchar red\nproperty uchar green\nproperty uchar blue\n");
    }
    if cloud.frames.is_some() {
        header.push_str("property uint frame\n");
    }
    if cloud.lasers.is_some() {
        header.push_str("property uchar laser\n");
    }
    if cloud.distances.is_some() {
        header.push_str("property float distance\n");
    }
    header.push_str("end_header\n");
    w.write_all(header.as_bytes()).map_err(io)?;
    let mut rec = Vec::with_capacity(32);
    for i in 0..n {
        rec.clear();
        for c in cloud.points[i] {
            rec.extend_from_slice(&c.to_le_bytes());
        }
        if let Some(colors) = &cloud.colors {
            rec.extend_from_slice(&colors[i]);
        }
        if let Some(frames) = &cloud.frames {
            rec.extend_from_slice(&frames[i].to_le_bytes());
        }
        if let Some(lasers) = &cloud.lasers {
            rec.push(lasers[i]);
        }
        if let Some(d) = &cloud.distances {
            rec.extend_from_slice(&d[i].to_le_bytes());
        }
        w.write_all(&rec).map_err(io)?;
    }
    w.flush().map_err(io)?;
    Ok(())
}
