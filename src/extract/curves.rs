//! One frame's laser curves, and the curves file that `crossline extract` writes
//! ([`CurvesFile::load`] reads it back).
//!
//! # Curves file (JSON, version 1)
//! | key | type | meaning |
//! |---|---|---|
//! | `format` | string | always `"crossline-curves"` |
//! | `version` | integer | `1` |
//! | `width`, `height` | integer | image size in pixels |
//! | `lasers` | array of strings | laser names; a curve's `laser` indexes it |
//! | `curves` | array | one object per curve, fields below |
//! | `curves[].laser` | integer | 0 or 1 |
//! | `curves[].points_px` | array of `[x, y]` | sub-pixel points in distorted pixels (pixel centres at integers), in order along the curve |
//! | `curves[].points` | array of `[x, y]` | the same points, undistorted normalised coordinates |
//! | `curves[].strength` | array of numbers | ridge strength of each point, grey levels |
//! | `curves[].polyline` | array of `[x, y]` | Douglas–Peucker simplification of `points` |
//!
//! `points_px`, `points` and `strength` are parallel; points whose undistortion fails are
//! dropped from all three.

use std::path::Path;

use serde::{Deserialize, Serialize};

use super::{link, ExtractError, LaserColour};

/// Version of the curves file written by [`CurvesFile::to_json`].
pub const CURVES_FILE_VERSION: u32 = 1;
const CURVES_FILE_FORMAT: &str = "crossline-curves";

/// One laser curve of one frame.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Curve {
    /// Index into [`super::ExtractParams::lasers`].
    pub laser: u8,
    /// Dense sub-pixel points in distorted pixels, in order along the curve.
    pub points_px: Vec<[f32; 2]>,
    /// The same points in undistorted normalised coordinates.
    pub points: Vec<[f64; 2]>,
    /// Ridge strength of each point, grey levels of stripe contrast.
    pub strength: Vec<f32>,
    /// Douglas–Peucker simplification of `points`, normalised coordinates.
    pub polyline: Vec<[f64; 2]>,
}

impl Curve {
    /// Length along `points_px`, pixels.
    pub fn length_px(&self) -> f64 {
        self.points_px
            .windows(2)
            .map(|w| {
                let (dx, dy) = ((w[1][0] - w[0][0]) as f64, (w[1][1] - w[0][1]) as f64);
                dx.hypot(dy)
            })
            .sum()
    }

    /// Length of the linked ridge (pixels): the length without the gaps the linker
    /// jumped ([`link::MAX_GAP_PX`]), which no ridge point vouches for.
    pub fn linked_length_px(&self) -> f64 {
        link::linked_length_px(self.points_px.iter().copied())
    }
}

/// The curves of one frame as written to disk (see the module doc for the format).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CurvesFile {
    pub format: String,
    pub version: u32,
    pub width: u32,
    pub height: u32,
    pub lasers: Vec<String>,
    pub curves: Vec<Curve>,
}

impl CurvesFile {
    pub fn new(width: u32, height: u32, lasers: &[LaserColour], curves: Vec<Curve>) -> Self {
        Self {
            format: CURVES_FILE_FORMAT.into(),
            version: CURVES_FILE_VERSION,
            width,
            height,
            lasers: lasers.iter().map(|l| l.name.clone()).collect(),
            curves,
        }
    }

    pub fn to_json(&self) -> String {
        // Serialising plain numbers and strings cannot fail.
        serde_json::to_string(self).unwrap_or_default()
    }

    /// Parses a curves file; `path` only names the source in errors.
    pub fn parse(text: &str, path: &Path) -> Result<Self, ExtractError> {
        let err = |message: String| ExtractError::CurvesFile {
            path: path.to_path_buf(),
            message,
        };
        let file: Self = serde_json::from_str(text).map_err(|e| err(e.to_string()))?;
        if file.format != CURVES_FILE_FORMAT {
            return Err(err(format!(
                "format is {:?}, expected {CURVES_FILE_FORMAT:?}",
                file.format
            )));
        }
        if file.version != CURVES_FILE_VERSION {
            return Err(err(format!(
                "version {} is not supported (expected {CURVES_FILE_VERSION})",
                file.version
            )));
        }
        Ok(file)
    }

    pub fn load(path: &Path) -> Result<Self, ExtractError> {
        let text = std::fs::read_to_string(path).map_err(|source| ExtractError::Io {
            path: path.to_path_buf(),
            source,
        })?;
        Self::parse(&text, path)
    }
}
