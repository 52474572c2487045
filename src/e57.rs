//! E57 (ASTM E2807) export of a [`Cloud`], for survey tools and scan archives, through
//! the pure-Rust `e57` crate. PLY ([`crate::ply`]) stays the format every stage
//! exchanges; this module only writes the final cloud (and reads it back, for tests and
//! tools), chosen by a `.e57` extension.
//!
//! # What crossline writes
//! One E57 file holding one unstructured point cloud (one `data3D` entry):
//!
//! | E57 | from |
//! |---|---|
//! | `cartesianX/Y/Z`, 32-bit float | the cloud's points, camera frame (OpenCV axes: x right, y down, z forward), scene units, as in the PLY |
//! | `colorRed/Green/Blue`, integers 0–255 | the cloud's colours (when it has them) |
//! | `name`, `description` | the scan's name; provenance and the scale mode (median depth 1, a factor, or a known distance) |
//! | `sensorVendor`, `sensorModel`, `sensorSoftwareVersion` | `crossline`, the camera (device or video file and image size), this crossline's version |
//! | `acquisitionStart`, `acquisitionEnd` | when the frames were taken, as far as known (GPS time, not atomic-referenced) |
//! | `coordinateMetadata` (file) | the frame and units in words |
//!
//! No pose: the points are in the camera frame, as recorded. The PLY's per-point
//! `frame`, `laser` and `depth_sigma` have no standard E57 field and are left out.

use std::path::{Path, PathBuf};
use std::time::{SystemTime, UNIX_EPOCH};

use ::e57::{DateTime, E57Reader, E57Writer, Record, RecordValue};

use crate::ply::Cloud;

/// Seconds from the Unix epoch to the GPS epoch (1980-01-06 00:00 UTC).
const GPS_EPOCH_UNIX_S: f64 = 315_964_800.0;
/// GPS time runs ahead of UTC by the leap seconds since 1980 (18 since 2017).
const GPS_LEAP_S: f64 = 18.0;

/// True when `path` names an E57 file (by its extension, without case).
pub fn is_e57(path: &Path) -> bool {
    path.extension()
        .and_then(|e| e.to_str())
        .is_some_and(|e| e.eq_ignore_ascii_case("e57"))
}

/// What the file says about the scan besides its points.
#[derive(Clone, Debug, Default)]
pub struct ScanMeta {
    pub name: String,
    /// Provenance and the scale mode.
    pub description: String,
    /// The camera: device or video file, image size.
    pub sensor_model: Option<String>,
    pub acquisition_start: Option<SystemTime>,
    pub acquisition_end: Option<SystemTime>,
    /// Frame and units, in words.
    pub coordinate_metadata: Option<String>,
}

#[derive(Debug, thiserror::Error)]
pub enum E57Error {
    #[error("cannot write E57 {path}: {source}")]
    Write {
        path: PathBuf,
        #[source]
        source: ::e57::Error,
    },
    #[error("cannot read E57 {path}: {source}")]
    Read {
        path: PathBuf,
        #[source]
        source: ::e57::Error,
    },
    #[error("{path}: {message}")]
    Format { path: PathBuf, message: String },
    #[error("cannot replace {path}: {source}")]
    Rename {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
}

fn gps_time(t: SystemTime) -> Option<DateTime> {
    let unix = t.duration_since(UNIX_EPOCH).ok()?.as_secs_f64();
    Some(DateTime {
        gps_time: unix - GPS_EPOCH_UNIX_S + GPS_LEAP_S,
        atomic_reference: false,
    })
}

/// A GUID for the file and the cloud: E57 wants unique strings, not a particular
/// algorithm; time, process and a counter make them unique enough without a crate.
fn guid(salt: &str) -> String {
    use std::hash::{Hash, Hasher};
    static COUNTER: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(0);
    let nanos = SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map_or(0, |d| d.as_nanos());
    let n = COUNTER.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
    let mut h = std::collections::hash_map::DefaultHasher::new();
    (nanos, std::process::id(), n, salt).hash(&mut h);
    let (a, b) = (h.finish(), (nanos as u64) ^ n.rotate_left(32));
    format!(
        "{{{:08x}-{:04x}-4{:03x}-{:04x}-{:012x}}}",
        a >> 32,
        (a >> 16) & 0xffff,
        a & 0xfff,
        (b >> 48) & 0x3fff | 0x8000,
        b & 0xffff_ffff_ffff
    )
}

/// Writes `cloud` to `path` as E57 (see the module doc for the fields).
pub fn write_e57(path: &Path, cloud: &Cloud, meta: &ScanMeta) -> Result<(), E57Error> {
    let err = |source| E57Error::Write {
        path: path.to_path_buf(),
        source,
    };
    let colors = cloud.colors.as_deref();
    if let Some(c) = colors.filter(|c| c.len() != cloud.len()) {
        return Err(E57Error::Format {
            path: path.to_path_buf(),
            message: format!("{} colours for {} points", c.len(), cloud.len()),
        });
    }
    let mut writer = E57Writer::from_file(path, &guid("file")).map_err(err)?;
    writer.set_creation(gps_time(SystemTime::now()));
    writer.set_coordinate_metadata(meta.coordinate_metadata.clone());
    let mut prototype = vec![
        Record::CARTESIAN_X_F32,
        Record::CARTESIAN_Y_F32,
        Record::CARTESIAN_Z_F32,
    ];
    if colors.is_some() {
        prototype.extend([
            Record::COLOR_RED_U8,
            Record::COLOR_GREEN_U8,
            Record::COLOR_BLUE_U8,
        ]);
    }
    let mut pc = writer
        .add_pointcloud(&guid("cloud"), prototype)
        .map_err(err)?;
    pc.set_name(Some(meta.name.clone()));
    pc.set_description(Some(meta.description.clone()));
    pc.set_sensor_vendor(Some("crossline".into()));
    pc.set_sensor_model(meta.sensor_model.clone());
    pc.set_sensor_sw_version(Some(format!("crossline {}", env!("CARGO_PKG_VERSION"))));
    pc.set_acquisition_start(meta.acquisition_start.and_then(gps_time));
    pc.set_acquisition_end(meta.acquisition_end.and_then(gps_time));
    for (i, p) in cloud.points.iter().enumerate() {
        let mut values: Vec<RecordValue> = p.iter().map(|&v| RecordValue::Single(v)).collect();
        if let Some(c) = colors.and_then(|c| c.get(i)) {
            values.extend(c.iter().map(|&v| RecordValue::Integer(i64::from(v))));
        }
        pc.add_point(values).map_err(err)?;
    }
    pc.finalize().map_err(err)?;
    writer.finalize().map_err(err)
}

/// [`write_e57`] to a temporary file beside `path`, renamed over it: a crash leaves
/// the previous file, never half of one.
pub fn write_e57_atomic(path: &Path, cloud: &Cloud, meta: &ScanMeta) -> Result<(), E57Error> {
    let tmp = path.with_extension("e57.tmp");
    write_e57(&tmp, cloud, meta)?;
    std::fs::rename(&tmp, path).map_err(|source| E57Error::Rename {
        path: path.to_path_buf(),
        source,
    })
}

/// The first point cloud of an E57 file: points, and colours when it has them (0–255
/// as written; other colour ranges are scaled to it).
pub fn read_e57(path: &Path) -> Result<Cloud, E57Error> {
    let err = |source| E57Error::Read {
        path: path.to_path_buf(),
        source,
    };
    let mut reader = E57Reader::from_file(path).map_err(err)?;
    let pc = reader
        .pointclouds()
        .into_iter()
        .next()
        .ok_or_else(|| E57Error::Format {
            path: path.to_path_buf(),
            message: "no point cloud in the file".into(),
        })?;
    let has_color = pc.has_color();
    let mut cloud = Cloud {
        colors: has_color.then(Vec::new),
        ..Default::default()
    };
    let mut points = reader.pointcloud_simple(&pc).map_err(err)?;
    points.apply_pose(false);
    for point in points {
        let point = point.map_err(err)?;
        let ::e57::CartesianCoordinate::Valid { x, y, z } = point.cartesian else {
            continue;
        };
        cloud.points.push([x as f32, y as f32, z as f32]);
        if let Some(colors) = cloud.colors.as_mut() {
            let c = point.color.unwrap_or(::e57::Color {
                red: 0.0,
                green: 0.0,
                blue: 0.0,
            });
            // Normalised to 0–1 by the reader from the file's colour limits.
            let byte = |v: f32| (v * 255.0).round().clamp(0.0, 255.0) as u8;
            colors.push([byte(c.red), byte(c.green), byte(c.blue)]);
        }
    }
    Ok(cloud)
}

/// The metadata this file would write, for reading back in tests.
pub fn read_meta(path: &Path) -> Result<ScanMeta, E57Error> {
    let reader = E57Reader::from_file(path).map_err(|source| E57Error::Read {
        path: path.to_path_buf(),
        source,
    })?;
    let from_gps = |t: Option<DateTime>| {
        t.and_then(|t| {
            let unix = t.gps_time + GPS_EPOCH_UNIX_S - GPS_LEAP_S;
            (unix >= 0.0).then(|| UNIX_EPOCH + std::time::Duration::from_secs_f64(unix))
        })
    };
    let coordinate_metadata = reader.coordinate_metadata().map(str::to_owned);
    let pc = reader.pointclouds().into_iter().next();
    Ok(ScanMeta {
        name: pc.as_ref().and_then(|p| p.name.clone()).unwrap_or_default(),
        description: pc
            .as_ref()
            .and_then(|p| p.description.clone())
            .unwrap_or_default(),
        sensor_model: pc.as_ref().and_then(|p| p.sensor_model.clone()),
        acquisition_start: from_gps(pc.as_ref().and_then(|p| p.acquisition_start.clone())),
        acquisition_end: from_gps(pc.as_ref().and_then(|p| p.acquisition_end.clone())),
        coordinate_metadata,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cloud() -> Cloud {
        // Values that do not round-trip through a short decimal, negative and large
        // ones, and every colour byte in some channel.
        let points: Vec<[f32; 3]> = (0..300)
            .map(|i| {
                let t = i as f32;
                [t.sin() * 1.7, -t * 0.013_7, 1.0 + t.sqrt() * 123.456]
            })
            .collect();
        let colors = (0..300)
            .map(|i| [(i % 256) as u8, (255 - i % 256) as u8, (i * 7 % 256) as u8])
            .collect();
        Cloud {
            points,
            colors: Some(colors),
            frames: Some(vec![3; 300]),
            ..Default::default()
        }
    }

    #[test]
    fn a_cloud_reads_back_with_its_points_colours_and_metadata() {
        let dir = tempfile::tempdir().expect("tempdir");
        let path = dir.path().join("scan.e57");
        let start = UNIX_EPOCH + std::time::Duration::from_secs(1_714_557_600);
        let meta = ScanMeta {
            name: "dive 3".into(),
            description: "crossline reconstruct; scale: median depth 1".into(),
            sensor_model: Some("DIVE.MP4 (h264) 960x540".into()),
            acquisition_start: Some(start),
            acquisition_end: Some(start + std::time::Duration::from_secs(180)),
            coordinate_metadata: Some("camera frame, OpenCV axes".into()),
        };
        let written = cloud();
        write_e57_atomic(&path, &written, &meta).expect("write");
        let back = read_e57(&path).expect("read");
        assert_eq!(back.len(), written.len());
        for (a, b) in written.points.iter().zip(&back.points) {
            for k in 0..3 {
                assert!(
                    (a[k] - b[k]).abs() <= f32::EPSILON * a[k].abs().max(1.0),
                    "{a:?} read back as {b:?}"
                );
            }
        }
        assert_eq!(back.colors, written.colors);
        let m = read_meta(&path).expect("meta");
        assert_eq!(m.name, "dive 3");
        assert!(m.description.contains("median depth"), "{}", m.description);
        assert_eq!(m.sensor_model, meta.sensor_model);
        assert_eq!(m.coordinate_metadata, meta.coordinate_metadata);
        let secs = |t: Option<SystemTime>| {
            t.and_then(|t| t.duration_since(UNIX_EPOCH).ok())
                .map(|d| d.as_secs_f64())
        };
        let got = secs(m.acquisition_start).expect("acquisition start");
        assert!((got - 1_714_557_600.0).abs() < 1e-3, "{got}");
        assert!(secs(m.acquisition_end).expect("end") - got > 179.9);
    }

    #[test]
    fn an_empty_or_colourless_cloud_is_a_valid_file() {
        let dir = tempfile::tempdir().expect("tempdir");
        let empty = dir.path().join("empty.E57");
        assert!(is_e57(&empty) && !is_e57(Path::new("scan.ply")));
        write_e57(&empty, &Cloud::default(), &ScanMeta::default()).expect("write");
        assert!(read_e57(&empty).expect("read").is_empty());
        let plain = Cloud {
            colors: None,
            ..cloud()
        };
        let path = dir.path().join("plain.e57");
        write_e57(&path, &plain, &ScanMeta::default()).expect("write");
        let back = read_e57(&path).expect("read");
        assert_eq!((back.len(), back.colors), (300, None));
        // Mismatched attributes are refused, not written short.
        let bad = Cloud {
            colors: Some(vec![[1, 2, 3]]),
            ..cloud()
        };
        let err = write_e57(&dir.path().join("bad.e57"), &bad, &ScanMeta::default())
            .expect_err("1 colour for 300 points");
        assert!(
            err.to_string().contains("1 colours for 300 points"),
            "{err}"
        );
    }
}
