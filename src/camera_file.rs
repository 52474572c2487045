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

/// The camera as OpenCV's `cv::FileStorage` writes it (`%YAML:1.0`, `!!opencv-matrix`).
pub fn to_opencv_yaml(camera: &Camera) -> String {
    let k = [
        camera.fx,
        camera.skew,
        camera.cx,
        0.0,
        camera.fy,
        camera.cy,
        0.0,
        0.0,
        1.0,
    ];
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
    let k = [
        camera.fx,
        camera.skew,
        camera.cx,
        0.0,
        camera.fy,
        camera.cy,
        0.0,
        0.0,
        1.0,
    ];
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
