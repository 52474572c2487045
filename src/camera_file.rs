//! Camera calibration files: OpenCV `cv::FileStorage` YAML, ROS `camera_info` YAML, and
//! the `[camera]` table of crossline's TOML.
//!
//! Writers produce what OpenCV and ROS themselves write, so the files load in those
//! tools unchanged.

use crate::camera::Camera;

fn list(values: &[f64]) -> String {
    let items: Vec<String> = values.iter().map(|v| format!("{v:?}")).collect();
    format!("[ {} ]", items.join(", "))
}

/// The 3x3 camera matrix, row-major.
fn camera_matrix(camera: &Camera) -> [f64; 9] {
    [
        camera.fx,
        camera.skew,
        camera.cx,
        0.0,
        camera.fy,
        camera.cy,
        0.0,
        0.0,
        1.0,
    ]
}

/// The camera as OpenCV's `cv::FileStorage` writes it (`%YAML:1.0`, `!!opencv-matrix`).
pub fn to_opencv_yaml(camera: &Camera) -> String {
    let k = camera_matrix(camera);
    let d = camera.distortion.to_vec();
    format!(
        "%YAML:1.0\n---\nimage_width: {}\nimage_height: {}\ncamera_matrix: !!opencv-matrix\n   rows: 3\n   cols: 3\n   dt: d\n   data: {}\ndistortion_coefficients: !!opencv-matrix\n   rows: 1\n   cols: {}\n   dt: d\n   data: {}\n",
        camera.width,
        camera.height,
        list(&k),
        d.len(),
        list(&d)
    )
}

/// The camera as ROS `camera_calibration` writes `camera_info` YAML (model `plumb_bob`,
/// or `rational_polynomial` when a rational term is set).
pub fn to_ros_yaml(camera: &Camera, camera_name: &str) -> String {
    let k = camera_matrix(camera);
    let p = [
        camera.fx,
        camera.skew,
        camera.cx,
        0.0,
        0.0,
        camera.fy,
        camera.cy,
        0.0,
        0.0,
        0.0,
        1.0,
        0.0,
    ];
    let d = camera.distortion.to_vec();
    let model = if camera.distortion.is_rational() {
        "rational_polynomial"
    } else {
        "plumb_bob"
    };
    format!(
        "image_width: {}\nimage_height: {}\ncamera_name: {}\ncamera_matrix:\n  rows: 3\n  cols: 3\n  data: {}\ndistortion_model: {}\ndistortion_coefficients:\n  rows: 1\n  cols: {}\n  data: {}\nrectification_matrix:\n  rows: 3\n  cols: 3\n  data: [1, 0, 0, 0, 1, 0, 0, 0, 1]\nprojection_matrix:\n  rows: 3\n  cols: 4\n  data: {}\n",
        camera.width,
        camera.height,
        camera_name,
        list(&k),
        model,
        d.len(),
        list(&d),
        list(&p)
    )
}

use std::path::{Path, PathBuf};

use crate::camera::Distortion;

/// Why a calibration file could not be used. Messages name the file, the line where
/// known, and the key.
#[derive(Debug, thiserror::Error)]
pub enum CameraFileError {
    #[error("cannot read camera file {path}: {source}")]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("{path}:{line}: {message}")]
    Syntax {
        path: PathBuf,
        line: usize,
        message: String,
    },
    #[error("{path}: key `{key}`: {message}")]
    Key {
        path: PathBuf,
        key: String,
        message: String,
    },
    #[error("{path}: {bytes} bytes is not a camera file (at most {MAX_FILE_BYTES})")]
    TooLarge { path: PathBuf, bytes: u64 },
}

/// Largest camera file read (real ones are about a kilobyte): refused before parsing,
/// so no array in it can grow large.
pub const MAX_FILE_BYTES: u64 = 256 << 10;
/// Largest matrix side in a camera file (the projection matrix is 3x4).
pub const MAX_MATRIX_SIDE: usize = 16;
/// Focal lengths accepted, in pixels, and relative to the larger image side: a lens
/// of a focal length outside these is a damaged file, and would make the crossing
/// index's cells vanishingly small.
pub const FOCAL_PX: (f64, f64) = (1.0, 1e6);
pub const FOCAL_PER_SIDE: (f64, f64) = (0.01, 1000.0);

/// Reads a camera from an OpenCV `FileStorage` YAML, a ROS `camera_info` YAML, or a
/// crossline TOML file with a `[camera]` table (chosen by the `.toml` extension).
pub fn load(path: &Path) -> Result<Camera, CameraFileError> {
    let text = crate::config::read_capped(path, MAX_FILE_BYTES).map_err(|e| match e {
        Ok(bytes) => CameraFileError::TooLarge {
            path: path.to_path_buf(),
            bytes,
        },
        Err(source) => CameraFileError::Io {
            path: path.to_path_buf(),
            source,
        },
    })?;
    if path
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("toml"))
    {
        parse_toml(&text, path)
    } else {
        parse_yaml(&text, path)
    }
}

/// The `[camera]` table of a crossline TOML file:
///
/// ```toml
/// [camera]
/// width = 1920
/// height = 1080
/// fx = 1400.0
/// fy = 1400.0
/// cx = 959.5
/// cy = 539.5
/// skew = 0.0                                # optional
/// distortion = [-0.1, 0.02, 0.0, 0.0, 0.0]  # OpenCV order k1 k2 p1 p2 [k3 [k4 k5 k6]]
/// ```
#[derive(serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CameraTable {
    pub width: u32,
    pub height: u32,
    pub fx: f64,
    pub fy: f64,
    pub cx: f64,
    pub cy: f64,
    #[serde(default)]
    pub skew: f64,
    #[serde(default)]
    pub distortion: Vec<f64>,
}

impl CameraTable {
    pub fn to_camera(&self, path: &Path) -> Result<Camera, CameraFileError> {
        let distortion = if self.distortion.is_empty() {
            Distortion::default()
        } else {
            Distortion::from_slice(&self.distortion).ok_or_else(|| CameraFileError::Key {
                path: path.to_path_buf(),
                key: "camera.distortion".into(),
                message: format!(
                    "expected 4, 5 or 8 coefficients (k1 k2 p1 p2 [k3 [k4 k5 k6]]), found {}",
                    self.distortion.len()
                ),
            })?
        };
        let camera = Camera {
            width: self.width,
            height: self.height,
            fx: self.fx,
            fy: self.fy,
            cx: self.cx,
            cy: self.cy,
            skew: self.skew,
            distortion,
        };
        validate(camera, path)
    }
}

/// Parses the text of a crossline TOML camera file; `path` only labels errors.
pub fn parse_toml(text: &str, path: &Path) -> Result<Camera, CameraFileError> {
    #[derive(serde::Deserialize)]
    struct File {
        camera: Option<CameraTable>,
    }
    let file: File = toml::from_str(text).map_err(|e| {
        let line = e
            .span()
            .map(|s| text[..s.start.min(text.len())].lines().count().max(1))
            .unwrap_or(0);
        CameraFileError::Syntax {
            path: path.to_path_buf(),
            line,
            message: crate::truncate_echo(e.message()),
        }
    })?;
    let table = file.camera.ok_or_else(|| CameraFileError::Key {
        path: path.to_path_buf(),
        key: "camera".into(),
        message: "no [camera] table in this file".into(),
    })?;
    table.to_camera(path)
}

fn validate(camera: Camera, path: &Path) -> Result<Camera, CameraFileError> {
    let bad = |key: &str, message: String| CameraFileError::Key {
        path: path.to_path_buf(),
        key: key.into(),
        message,
    };
    let max_side = crate::capture::dump::MAX_SIDE;
    if camera.width == 0
        || camera.height == 0
        || camera.width > max_side
        || camera.height > max_side
    {
        return Err(bad(
            "image_width/image_height",
            format!(
                "image size must be 1 to {max_side} pixels a side, found {}x{}",
                camera.width, camera.height
            ),
        ));
    }
    let side = f64::from(camera.width.max(camera.height));
    let lo = FOCAL_PX.0.max(FOCAL_PER_SIDE.0 * side);
    let hi = FOCAL_PX.1.min(FOCAL_PER_SIDE.1 * side);
    for (key, value) in [("fx", camera.fx), ("fy", camera.fy)] {
        if !(value >= lo && value <= hi) {
            return Err(bad(
                key,
                format!(
                    "focal length must be {lo} to {hi} px for a {}x{} image, found {value}",
                    camera.width, camera.height
                ),
            ));
        }
    }
    let reach = 10.0 * side;
    for (key, value) in [("cx", camera.cx), ("cy", camera.cy), ("skew", camera.skew)] {
        if !(value.is_finite() && value.abs() <= reach) {
            return Err(bad(
                key,
                format!("must be a finite number within ±{reach} px, found {value}"),
            ));
        }
    }
    if camera.distortion.to_vec().iter().any(|c| !c.is_finite()) {
        return Err(bad(
            "distortion_coefficients",
            "must be finite numbers".into(),
        ));
    }
    Ok(camera)
}

/// A node of the small YAML subset that OpenCV and ROS calibration files use: block
/// maps by indentation, flow sequences (possibly over several lines), scalars, and tags
/// such as `!!opencv-matrix` (ignored).
#[derive(Debug)]
enum Node {
    Scalar(String),
    Seq(Vec<String>),
    Map(Vec<(String, Node, usize)>),
}

struct Line<'a> {
    number: usize,
    indent: usize,
    text: &'a str,
}

fn parse_yaml_tree(text: &str, path: &Path) -> Result<Node, CameraFileError> {
    let mut lines = Vec::new();
    for (i, raw) in text.lines().enumerate() {
        let number = i + 1;
        let without_comment = match raw.find(" #") {
            Some(p) => &raw[..p],
            None if raw.trim_start().starts_with('#') => "",
            None => raw,
        };
        let trimmed = without_comment.trim_end();
        let body = trimmed.trim_start();
        if body.is_empty() || body.starts_with('%') || body == "---" || body == "..." {
            continue;
        }
        if trimmed.contains('\t') {
            return Err(CameraFileError::Syntax {
                path: path.to_path_buf(),
                line: number,
                message: "tab characters are not allowed in YAML indentation".into(),
            });
        }
        lines.push(Line {
            number,
            indent: trimmed.len() - body.len(),
            text: body,
        });
    }
    let mut pos = 0;
    let root = parse_map(&lines, &mut pos, 0, path)?;
    if let Some(line) = lines.get(pos) {
        return Err(CameraFileError::Syntax {
            path: path.to_path_buf(),
            line: line.number,
            message: "unexpected indentation".into(),
        });
    }
    Ok(root)
}

fn parse_map(
    lines: &[Line],
    pos: &mut usize,
    indent: usize,
    path: &Path,
) -> Result<Node, CameraFileError> {
    let syntax = |line: usize, message: String| CameraFileError::Syntax {
        path: path.to_path_buf(),
        line,
        message,
    };
    let mut entries = Vec::new();
    while let Some(line) = lines.get(*pos) {
        if line.indent < indent {
            break;
        }
        if line.indent > indent {
            return Err(syntax(line.number, "unexpected indentation".into()));
        }
        let Some(colon) = find_key_colon(line.text) else {
            return Err(syntax(
                line.number,
                format!(
                    "expected `key: value`, found `{}`",
                    crate::truncate_echo(line.text)
                ),
            ));
        };
        let key = line.text[..colon].trim().trim_matches('"').to_string();
        let mut value = line.text[colon + 1..].trim();
        if value.starts_with("!!") {
            value = value.split_once(' ').map(|(_, v)| v.trim()).unwrap_or("");
        }
        let number = line.number;
        *pos += 1;
        let node = if value.is_empty() {
            match lines.get(*pos) {
                Some(next) if next.indent > indent => parse_map(lines, pos, next.indent, path)?,
                _ => Node::Scalar(String::new()),
            }
        } else if value.starts_with('[') {
            let mut flow = value.to_string();
            while !flow.trim_end().ends_with(']') {
                let Some(next) = lines.get(*pos) else {
                    return Err(syntax(
                        number,
                        format!("`{key}`: unterminated `[` sequence"),
                    ));
                };
                flow.push(' ');
                flow.push_str(next.text);
                *pos += 1;
            }
            let inner = flow.trim().trim_start_matches('[').trim_end_matches(']');
            Node::Seq(
                inner
                    .split(',')
                    .map(|s| s.trim().to_string())
                    .filter(|s| !s.is_empty())
                    .collect(),
            )
        } else {
            Node::Scalar(value.trim_matches('"').trim_matches('\'').to_string())
        };
        entries.push((key, node, number));
    }
    Ok(Node::Map(entries))
}

fn find_key_colon(text: &str) -> Option<usize> {
    let bytes = text.as_bytes();
    (0..bytes.len()).find(|&i| bytes[i] == b':' && (i + 1 == bytes.len() || bytes[i + 1] == b' '))
}

impl Node {
    fn get(&self, key: &str) -> Option<(&Node, usize)> {
        match self {
            Node::Map(entries) => entries
                .iter()
                .find(|(k, _, _)| k == key)
                .map(|(_, n, l)| (n, *l)),
            _ => None,
        }
    }
}

struct YamlCamera<'a> {
    root: Node,
    path: &'a Path,
}

impl YamlCamera<'_> {
    fn key_error(&self, key: &str, message: impl Into<String>) -> CameraFileError {
        CameraFileError::Key {
            path: self.path.to_path_buf(),
            key: key.to_string(),
            message: message.into(),
        }
    }

    fn find(&self, keys: &[&str]) -> Option<(&Node, usize, String)> {
        keys.iter()
            .find_map(|k| self.root.get(k).map(|(n, l)| (n, l, k.to_string())))
    }

    fn number(&self, node: &Node, key: &str, line: usize) -> Result<f64, CameraFileError> {
        match node {
            Node::Scalar(s) => s.parse::<f64>().map_err(|_| {
                self.key_error(
                    key,
                    format!(
                        "line {line}: expected a number, found `{}`",
                        crate::truncate_echo(s)
                    ),
                )
            }),
            _ => Err(self.key_error(key, format!("line {line}: expected a number"))),
        }
    }

    /// A matrix written as `!!opencv-matrix` or as a ROS `{rows, cols, data}` map.
    fn matrix(&self, keys: &[&str]) -> Result<Option<(usize, usize, Vec<f64>)>, CameraFileError> {
        let Some((node, line, key)) = self.find(keys) else {
            return Ok(None);
        };
        let dims = |name: &str| -> Result<usize, CameraFileError> {
            let (n, l) = node.get(name).ok_or_else(|| {
                self.key_error(&key, format!("line {line}: matrix has no `{name}`"))
            })?;
            let v = self.number(n, &format!("{key}.{name}"), l)?;
            // Checked as a float: `1e300 as usize` would wrap to usize::MAX.
            if !(1.0..=MAX_MATRIX_SIDE as f64).contains(&v) || v.fract() != 0.0 {
                return Err(self.key_error(
                    &key,
                    format!(
                        "line {l}: `{name}` must be an integer from 1 to {MAX_MATRIX_SIDE}, found {}",
                        if v.abs() < 1e16 { v.to_string() } else { format!("{v:e}") }
                    ),
                ));
            }
            Ok(v as usize)
        };
        let (rows, cols) = (dims("rows")?, dims("cols")?);
        let Some((Node::Seq(items), data_line)) = node.get("data") else {
            return Err(self.key_error(
                &key,
                format!("line {line}: matrix has no `data: [ ... ]` sequence"),
            ));
        };
        if items.len() != rows * cols {
            return Err(self.key_error(
                &format!("{key}.data"),
                format!(
                    "line {data_line}: {rows}x{cols} matrix needs {} values, found {}",
                    rows * cols,
                    items.len()
                ),
            ));
        }
        let data = items
            .iter()
            .map(|s| {
                s.parse::<f64>().map_err(|_| {
                    self.key_error(
                        &format!("{key}.data"),
                        format!(
                            "line {data_line}: expected a number, found `{}`",
                            crate::truncate_echo(s)
                        ),
                    )
                })
            })
            .collect::<Result<Vec<f64>, _>>()?;
        if data.len() != rows * cols {
            return Err(self.key_error(
                &format!("{key}.data"),
                format!(
                    "line {data_line}: {rows}x{cols} matrix needs {} values, found {}",
                    rows * cols,
                    data.len()
                ),
            ));
        }
        Ok(Some((rows, cols, data)))
    }

    fn integer(&self, keys: &[&str]) -> Result<Option<u32>, CameraFileError> {
        let Some((node, line, key)) = self.find(keys) else {
            return Ok(None);
        };
        let v = self.number(node, &key, line)?;
        if v < 1.0 || v.fract() != 0.0 || v > u32::MAX as f64 {
            return Err(self.key_error(&key, format!("line {line}: expected a positive integer")));
        }
        Ok(Some(v as u32))
    }
}

/// Parses an OpenCV `FileStorage` YAML (`%YAML:1.0`, `!!opencv-matrix`) or a ROS
/// `camera_info` YAML; `path` only labels errors.
pub fn parse_yaml(text: &str, path: &Path) -> Result<Camera, CameraFileError> {
    let root = parse_yaml_tree(text, path)?;
    let file = YamlCamera { root, path };
    const K_KEYS: [&str; 4] = ["camera_matrix", "cameraMatrix", "K", "intrinsics"];
    const D_KEYS: [&str; 5] = [
        "distortion_coefficients",
        "dist_coeffs",
        "distCoeffs",
        "distortion",
        "D",
    ];
    let (rows, cols, k) = file.matrix(&K_KEYS)?.ok_or_else(|| {
        file.key_error("camera_matrix", "missing (expected a 3x3 `camera_matrix`)")
    })?;
    if rows != 3 || cols != 3 {
        return Err(file.key_error(
            "camera_matrix",
            format!("expected a 3x3 matrix, found {rows}x{cols}"),
        ));
    }
    if k[3] != 0.0 || k[6] != 0.0 || k[7] != 0.0 || k[8] != 1.0 {
        return Err(file.key_error("camera_matrix", "expected [fx s cx; 0 fy cy; 0 0 1]"));
    }
    let distortion = match file.matrix(&D_KEYS)? {
        None => Distortion::default(),
        Some((rows, cols, d)) => {
            if rows != 1 && cols != 1 {
                return Err(file.key_error(
                    "distortion_coefficients",
                    format!("expected a 1xN or Nx1 vector, found {rows}x{cols}"),
                ));
            }
            let supported = match d.len() {
                4 | 5 | 8 => d.as_slice(),
                12 | 14 if d[8..].iter().all(|&c| c == 0.0) => &d[..8],
                n => {
                    return Err(file.key_error(
                        "distortion_coefficients",
                        format!(
                            "expected 4, 5 or 8 coefficients (12 or 14 only with zero thin-prism and tilt terms), found {n}"
                        ),
                    ))
                }
            };
            Distortion::from_slice(supported)
                .ok_or_else(|| file.key_error("distortion_coefficients", "unsupported length"))?
        }
    };
    if let Some((Node::Scalar(model), line, key)) = file.find(&["distortion_model"]) {
        if !matches!(model.as_str(), "plumb_bob" | "rational_polynomial" | "") {
            return Err(file.key_error(
                &key,
                format!(
                    "line {line}: unsupported distortion model `{model}` (expected plumb_bob or rational_polynomial)"
                ),
            ));
        }
    }
    let width = file.integer(&["image_width", "width"])?;
    let height = file.integer(&["image_height", "height"])?;
    let (width, height) = match (width, height) {
        (Some(w), Some(h)) => (w, h),
        _ => match file.find(&["image_size", "imageSize"]) {
            Some((Node::Seq(items), line, key)) if items.len() == 2 => {
                let parse = |s: &String| {
                    s.parse::<u32>().map_err(|_| {
                        file.key_error(&key, format!("line {line}: expected [width, height]"))
                    })
                };
                (parse(&items[0])?, parse(&items[1])?)
            }
            _ => {
                return Err(file.key_error(
                    "image_width",
                    "missing image size (expected image_width and image_height)",
                ))
            }
        },
    };
    let camera = Camera {
        width,
        height,
        fx: k[0],
        fy: k[4],
        cx: k[2],
        cy: k[5],
        skew: k[1],
        distortion,
    };
    validate(camera, path)
}

#[cfg(test)]
mod tests {
    use super::*;

    const OPENCV: &str = "%YAML:1.0
---
calibration_time: \"Mon Nov  2 10:00:00 2026\"
image_width: 1280
image_height: 720
flags: 0
camera_matrix: !!opencv-matrix
   rows: 3
   cols: 3
   dt: d
   data: [ 9.1234567890000000e+02, 0., 6.4050000000000000e+02, 0.,
       9.1500000000000000e+02, 3.6025000000000000e+02, 0., 0., 1. ]
distortion_coefficients: !!opencv-matrix
   rows: 5
   cols: 1
   dt: d
   data: [ -2.8e-01, 9.0e-02, 1.2e-03, -7.0e-04, -1.2e-02 ]
avg_reprojection_error: 2.1e-01
";

    #[test]
    fn reads_opencv_filestorage_as_opencv_writes_it() {
        let cam = parse_yaml(OPENCV, Path::new("cam.yml")).expect("parses");
        assert_eq!((cam.width, cam.height), (1280, 720));
        assert_eq!(cam.fx, 912.3456789);
        assert_eq!(cam.fy, 915.0);
        assert_eq!(cam.cx, 640.5);
        assert_eq!(cam.cy, 360.25);
        assert_eq!(cam.distortion.k1, -0.28);
        assert_eq!(cam.distortion.p2, -7.0e-4);
        assert_eq!(cam.distortion.k3, -0.012);
    }

    fn sample() -> Camera {
        Camera {
            width: 1920,
            height: 1080,
            fx: 1401.25,
            fy: 1399.5,
            cx: 961.1,
            cy: 538.9,
            skew: 0.0,
            distortion: Distortion {
                k1: -0.11,
                k2: 0.031,
                p1: 0.0004,
                p2: -0.0002,
                k3: 0.001,
                ..Default::default()
            },
        }
    }

    #[test]
    fn writers_round_trip_through_readers() {
        let cam = sample();
        let back = parse_yaml(&to_opencv_yaml(&cam), Path::new("a.yml")).expect("opencv");
        assert_eq!(back, cam);
        let back = parse_yaml(&to_ros_yaml(&cam, "test"), Path::new("b.yaml")).expect("ros");
        assert_eq!(back, cam);
        let rational = Camera {
            distortion: Distortion {
                k4: 0.01,
                k6: -0.002,
                ..cam.distortion
            },
            ..cam
        };
        let back = parse_yaml(&to_opencv_yaml(&rational), Path::new("c.yml")).expect("8");
        assert_eq!(back, rational);
    }

    #[test]
    fn four_coefficient_row_vector_and_toml_table() {
        let text = OPENCV
            .replace("rows: 5\n   cols: 1", "rows: 1\n   cols: 4")
            .replace(", -1.2e-02 ]", " ]");
        let cam = parse_yaml(&text, Path::new("c.yml")).expect("4 coefficients");
        assert_eq!(cam.distortion.k3, 0.0);
        assert_eq!(cam.distortion.p1, 1.2e-3);
        let toml = "[camera]\nwidth = 640\nheight = 480\nfx = 500.0\nfy = 501.0\ncx = 319.5\ncy = 239.5\ndistortion = [-0.1, 0.01, 0.0, 0.0]\n";
        let cam = parse_toml(toml, Path::new("c.toml")).expect("toml");
        assert_eq!(cam.fy, 501.0);
        assert_eq!(cam.distortion.k2, 0.01);
    }

    #[test]
    fn bad_files_name_the_file_and_key() {
        let err = parse_yaml(
            &OPENCV.replace("rows: 3\n   cols: 3", "rows: 3\n   cols: 4"),
            Path::new("cam.yml"),
        )
        .expect_err("shape");
        let msg = err.to_string();
        assert!(
            msg.contains("cam.yml") && msg.contains("camera_matrix"),
            "{msg}"
        );
        let err = parse_yaml(&OPENCV.replace("-2.8e-01", "oops"), Path::new("cam.yml"))
            .expect_err("number");
        let msg = err.to_string();
        assert!(
            msg.contains("distortion_coefficients.data") && msg.contains("oops"),
            "{msg}"
        );
        let err = parse_yaml(
            &OPENCV.replace("camera_matrix", "camera_matrox"),
            Path::new("cam.yml"),
        )
        .expect_err("missing");
        assert!(err.to_string().contains("camera_matrix"));
        let err = parse_yaml(
            &OPENCV.replace("image_width: 1280\nimage_height: 720\n", ""),
            Path::new("cam.yml"),
        )
        .expect_err("size");
        assert!(err.to_string().contains("image_width"));
        let err = parse_toml("[camera]\nwidth = 640\n", Path::new("c.toml")).expect_err("toml");
        assert!(err.to_string().contains("c.toml:"), "{err}");
        let err = parse_toml(
            "[camera]\nwidth = 640\nheight = 480\nfx = 500.0\nfy = 501.0\ncx = 319.5\ncy = 239.5\ndistortion = [1.0, 2.0]\n",
            Path::new("c.toml"),
        )
        .expect_err("distortion length");
        assert!(err.to_string().contains("camera.distortion"), "{err}");
    }

    #[test]
    fn absurd_focal_lengths_and_matrix_sizes_are_refused() {
        let yaml = to_opencv_yaml(&sample()).replace(&format!("{:?}", sample().fx), "1e300");
        let err = parse_yaml(&yaml, Path::new("cam.yml")).expect_err("fx 1e300");
        assert!(err.to_string().contains("`fx`"), "{err}");
        let toml =
            "[camera]\nwidth = 640\nheight = 480\nfx = 1e308\nfy = 500.0\ncx = 320.0\ncy = 240.0\n";
        let err = parse_toml(toml, Path::new("cam.toml")).expect_err("fx 1e308");
        assert!(err.to_string().contains("focal length must be"), "{err}");
        let toml = toml.replace("1e308", "0.5");
        assert!(
            parse_toml(&toml, Path::new("cam.toml")).is_err(),
            "fx 0.5 px"
        );
        let toml = toml.replace("0.5", "500.0");
        parse_toml(&toml, Path::new("cam.toml")).expect("a sane camera");
        // `rows: 1e300` is reported as written, not as a wrapped usize.
        let yaml = to_opencv_yaml(&sample()).replacen("rows: 3", "rows: 1e300", 1);
        let err = parse_yaml(&yaml, Path::new("cam.yml")).expect_err("rows");
        let msg = err.to_string();
        assert!(msg.contains("found 1e300"), "{msg}");
        assert!(!msg.contains("18446744073709551615"), "{msg}");
    }

    #[test]
    fn a_huge_camera_file_is_refused_before_parsing() {
        let dir = tempfile::tempdir().expect("tempdir");
        let path = dir.path().join("cam.toml");
        let mut text = String::from("[camera]\ndistortion = [");
        while (text.len() as u64) <= MAX_FILE_BYTES {
            text.push_str("0.0, ");
        }
        text.push_str("0.0]\n");
        std::fs::write(&path, &text).expect("write");
        let err = load(&path).expect_err("too large");
        assert!(matches!(err, CameraFileError::TooLarge { .. }), "{err}");
        // A ROS file whose unused rectification_matrix holds a huge array likewise.
        let path = dir.path().join("camera_info.yaml");
        let ros = to_ros_yaml(&sample(), "cam");
        let long = format!("data: [1{}]", ", 0".repeat(MAX_FILE_BYTES as usize / 3));
        let text = ros.replacen("data: [1, 0, 0, 0, 1, 0, 0, 0, 1]", &long, 1);
        assert!(text.len() as u64 > MAX_FILE_BYTES);
        std::fs::write(&path, &text).expect("write");
        let err = load(&path).expect_err("too large");
        assert!(matches!(err, CameraFileError::TooLarge { .. }), "{err}");
    }

    #[test]
    fn a_long_bad_line_is_echoed_shortened() {
        let line = "x".repeat(20_000);
        let err = parse_yaml(&format!("image_width: 640\n{line}\n"), Path::new("c.yml"))
            .expect_err("no colon");
        assert!(
            err.to_string().len() < 1000,
            "{} bytes",
            err.to_string().len()
        );
    }
}
