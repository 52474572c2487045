//! The range every number of `crossline.toml` must lie in, checked once after parsing.
//!
//! Serde checks types; this checks sizes. A count of 10⁹ rounds, a million worker
//! threads, a ring of 10⁸ slots or a duration of `inf` seconds is refused here, naming
//! the key and the value, instead of hanging, aborting on allocation or panicking in
//! `Duration::from_secs_f64` later. Every float must also be finite. A test keeps the
//! table complete: each number of the default config has an entry.

use toml::Value;

use crate::extract::background::MAX_MEDIAN_FRAMES;

/// `(section.key, least, greatest)`; for arrays the bound applies to every element.
/// Generous on purpose: the point is to refuse what cannot be meant, not to tune.
pub const BOUNDS: &[(&str, f64, f64)] = &[
    ("background.median_frames", 1.0, MAX_MEDIAN_FRAMES as f64),
    ("background.warmup_frames", 1.0, 10_000.0),
    ("background.sample_every", 1.0, 10_000.0),
    ("background.refresh_every", 1.0, 100_000.0),
    ("extract.high_contrast", 0.0, 1000.0),
    ("extract.low_contrast", 0.0, 1000.0),
    ("extract.faint_start_contrast", 0.0, 1000.0),
    ("extract.faint_min_length_px", 0.0, 1e5),
    ("extract.block_contrast", 0.0, 1000.0),
    ("extract.min_curve_length_px", 0.0, 1e5),
    ("extract.dp_tolerance_px", 0.0, 1000.0),
    ("extract.max_link_angle_deg", 0.0, 180.0),
    ("extract.min_value", 0.0, 255.0),
    ("extract.min_saturation", 0.0, 1.0),
    ("extract.lasers.hue_deg", 0.0, 360.0),
    ("extract.lasers.display_rgb", 0.0, 255.0),
    ("intersect.refine_radius_px", 0.0, 1000.0),
    ("solve.max_global_planes", 1.0, 100_000.0),
    ("solve.max_anchor_poses", 2.0, 5_000.0),
    ("solve.min_crossings_per_plane", 1.0, 10_000.0),
    ("solve.min_global_crossings", 1.0, 1e7),
    ("solve.min_sin_angle", 0.0, 1.0),
    ("solve.min_curve_bend_px", 0.0, 1e5),
    ("solve.outlier_mad_k", 0.0, 1000.0),
    ("solve.robust_rounds", 0.0, 1000.0),
    ("solve.refine_rounds", 0.0, 100.0),
    ("solve.uncertain_plane_ratio", 0.0, 1e9),
    ("solve.max_outlier_fraction", 0.0, 1.0),
    ("solve.min_curve_strength", 0.0, 1e9),
    ("solve.min_crossing_strength", 0.0, 1e9),
    ("triangulate.min_ray_plane_angle_deg", 0.0, 90.0),
    ("triangulate.max_crossing_disagreement", 0.0, 1e6),
    ("triangulate.min_disagreeing_crossings", 0.0, 1e7),
    ("triangulate.blame_strength_ratio", 0.0, 1e9),
    ("triangulate.curve_end_points", 0.0, 1e5),
    ("triangulate.max_depth_sigma", 0.0, 1e9),
    ("serve.width", 1.0, crate::capture::dump::MAX_SIDE as f64),
    ("serve.height", 1.0, crate::capture::dump::MAX_SIDE as f64),
    ("serve.fps", 1.0, 1000.0),
    ("serve.buffers", 1.0, 64.0),
    ("serve.ring_slots", 1.0, 256.0),
    ("serve.workers", 0.0, 256.0),
    ("serve.record_rotate_mib", 1.0, 1_048_576.0),
    ("serve.checkpoint_interval_s", 0.05, 86_400.0),
    ("serve.min_planes_first_solve", 1.0, 1e6),
    ("serve.solve_growth", 1.0, 100.0),
    ("serve.epoch_duty", 0.01, 1.0),
    ("serve.status_interval_ms", 10.0, 3_600_000.0),
    ("serve.client_queue_mib", 0.0, 4096.0),
    ("serve.stream_send_buffer_kib", 0.0, 65536.0),
    ("serve.stream_clients_max", 1.0, 4096.0),
    ("serve.drain_timeout_s", 0.0, 3600.0),
    ("serve.reconnect_max_backoff_s", 0.1, 3600.0),
    ("serve.http_clients_max", 1.0, 4096.0),
];

/// Longest list any key takes (lasers, formats, hue ranges).
pub const MAX_LIST: usize = 64;

/// The first number of the parsed file out of range: `(section.key, value as
/// written, what was expected)`. Walks the file as written (not the typed config), so
/// `nan` and `inf` are seen as such.
pub fn check(config: &Value) -> Option<(String, String, String)> {
    let mut found = None;
    walk(config, "", &mut found);
    found
}

fn walk(value: &Value, key: &str, found: &mut Option<(String, String, String)>) {
    if found.is_some() {
        return;
    }
    match value {
        Value::Table(map) => {
            for (k, v) in map {
                let path = if key.is_empty() {
                    k.clone()
                } else {
                    format!("{key}.{k}")
                };
                walk(v, &path, found);
            }
        }
        Value::Array(items) => {
            if items.len() > MAX_LIST {
                *found = Some((
                    key.to_string(),
                    format!("a list of {}", items.len()),
                    format!("at most {MAX_LIST} entries"),
                ));
                return;
            }
            for item in items {
                walk(item, key, found);
            }
        }
        Value::Integer(_) | Value::Float(_) => {
            let x = match value {
                Value::Integer(i) => *i as f64,
                Value::Float(f) => *f,
                _ => f64::NAN,
            };
            let bound = BOUNDS.iter().find(|(k, _, _)| *k == key);
            let ok = match bound {
                Some((_, lo, hi)) => x >= *lo && x <= *hi,
                None => x.is_finite(),
            };
            if !ok {
                let expected = match bound {
                    Some((_, lo, hi)) => format!("a number from {lo} to {hi}"),
                    None => "a finite number".into(),
                };
                let written = match value {
                    Value::Float(f) if f.is_nan() => "nan".to_string(),
                    Value::Float(f) if f.is_infinite() => {
                        if *f > 0.0 { "inf" } else { "-inf" }.to_string()
                    }
                    Value::Float(f) if f.abs() >= 1e16 || (*f != 0.0 && f.abs() < 1e-4) => {
                        format!("{f:e}")
                    }
                    _ => value.to_string(),
                };
                *found = Some((key.to_string(), written, expected));
            }
        }
        _ => {}
    }
}
