//! Portable Float Map (PFM) reading and writing, for depth maps such as the simulator's
//! `depth.pfm`.
//!
//! # Format (as crossline writes it)
//! | part | content |
//! |---|---|
//! | line 1 | `Pf` (one channel, greyscale); `PF` (three channels) is rejected |
//! | line 2 | `<width> <height>` in decimal |
//! | line 3 | scale: negative means little-endian samples (we write `-1.0`) |
//! | data | `width * height` IEEE-754 `f32`, rows **bottom-to-top**, left to right |
//!
//! In memory, [`Pfm::data`] is row-major **top-to-bottom** like every other image in
//! the crate; the row flip happens here and nowhere else. NaN marks "no value".
//! The reader accepts big-endian files (positive scale) too; the magnitude of the scale
//! is ignored.

use std::io::{BufReader, BufWriter, Read, Write};
use std::path::{Path, PathBuf};

/// A one-channel float image, row-major, top row first.
#[derive(Clone, Debug, PartialEq)]
pub struct Pfm {
    pub width: u32,
    pub height: u32,
    pub data: Vec<f32>,
}

#[derive(Debug, thiserror::Error)]
pub enum PfmError {
    #[error("cannot read or write {path}: {source}")]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("not a greyscale PFM file: {message}")]
    Format { message: String },
    #[error("{path}: {message}")]
    InFile { path: PathBuf, message: String },
}

/// Writes `data` (row-major, top row first, `width * height` samples) as little-endian PFM.
pub fn write_pfm_to<W: Write>(
    mut w: W,
    width: u32,
    height: u32,
    data: &[f32],
) -> Result<(), PfmError> {
    let (wu, hu) = (width as usize, height as usize);
    if data.len() != wu * hu {
        return Err(PfmError::Format {
            message: format!("{} samples given for a {width}x{height} image", data.len()),
        });
    }
    let io = |source| PfmError::Io {
        path: PathBuf::from("<stream>"),
        source,
    };
    w.write_all(format!("Pf\n{width} {height}\n-1.0\n").as_bytes())
        .map_err(io)?;
    let mut row = Vec::with_capacity(wu * 4);
    for y in (0..hu).rev() {
        row.clear();
        for v in &data[y * wu..(y + 1) * wu] {
            row.extend_from_slice(&v.to_le_bytes());
        }
        w.write_all(&row).map_err(io)?;
    }
    w.flush().map_err(io)?;
    Ok(())
}

/// Writes a PFM file; see [`write_pfm_to`].
pub fn write_pfm(path: &Path, width: u32, height: u32, data: &[f32]) -> Result<(), PfmError> {
    let file = std::fs::File::create(path).map_err(|source| PfmError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    write_pfm_to(BufWriter::new(file), width, height, data).map_err(|e| with_path(e, path))
}

/// Reads a greyscale PFM stream into a top-row-first image.
pub fn read_pfm_from<R: Read>(r: R) -> Result<Pfm, PfmError> {
    let mut bytes = Vec::new();
    BufReader::new(r)
        .read_to_end(&mut bytes)
        .map_err(|source| PfmError::Io {
            path: PathBuf::from("<stream>"),
            source,
        })?;
    let fmt = |message: String| PfmError::Format { message };
    // Header: three whitespace-separated tokens after the magic, then exactly one
    // whitespace byte before the samples.
    let mut pos = 0;
    let mut token = |what: &str| -> Result<String, PfmError> {
        while pos < bytes.len() && bytes[pos].is_ascii_whitespace() {
            pos += 1;
        }
        let start = pos;
        while pos < bytes.len() && !bytes[pos].is_ascii_whitespace() {
            pos += 1;
        }
        if start == pos {
            return Err(fmt(format!("header ends before the {what}")));
        }
        Ok(String::from_utf8_lossy(&bytes[start..pos]).into_owned())
    };
    let magic = token("magic")?;
    if magic != "Pf" {
        return Err(fmt(format!(
            "magic is {magic:?}, expected \"Pf\" (one channel)"
        )));
    }
    let width: u32 = token("width")?
        .parse()
        .map_err(|_| fmt("width is not a whole number".into()))?;
    let height: u32 = token("height")?
        .parse()
        .map_err(|_| fmt("height is not a whole number".into()))?;
    let scale: f64 = token("scale")?
        .parse()
        .map_err(|_| fmt("scale is not a number".into()))?;
    let data_start = pos + 1;
    let (wu, hu) = (width as usize, height as usize);
    let need = wu * hu * 4;
    if bytes.len() < data_start + need {
        return Err(fmt(format!(
            "{width}x{height} needs {need} bytes of samples, file has {}",
            bytes.len().saturating_sub(data_start)
        )));
    }
    let little = scale < 0.0;
    let mut data = vec![0.0f32; wu * hu];
    for (file_row, chunk) in bytes[data_start..data_start + need]
        .chunks_exact(wu * 4)
        .enumerate()
    {
        let y = hu - 1 - file_row;
        for (x, b) in chunk.chunks_exact(4).enumerate() {
            let b = [b[0], b[1], b[2], b[3]];
            data[y * wu + x] = if little {
                f32::from_le_bytes(b)
            } else {
                f32::from_be_bytes(b)
            };
        }
    }
    Ok(Pfm {
        width,
        height,
        data,
    })
}

/// Reads a PFM file; see [`read_pfm_from`].
pub fn read_pfm(path: &Path) -> Result<Pfm, PfmError> {
    let file = std::fs::File::open(path).map_err(|source| PfmError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    read_pfm_from(file).map_err(|e| with_path(e, path))
}

fn with_path(e: PfmError, path: &Path) -> PfmError {
    match e {
        PfmError::Io { source, .. } => PfmError::Io {
            path: path.to_path_buf(),
            source,
        },
        PfmError::Format { message } => PfmError::InFile {
            path: path.to_path_buf(),
            message,
        },
        other => other,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trip_keeps_values_nan_and_row_order() {
        let (w, h) = (5u32, 3u32);
        let data: Vec<f32> = (0..15)
            .map(|i| {
                if i == 7 {
                    f32::NAN
                } else {
                    i as f32 * 0.5 - 1.0
                }
            })
            .collect();
        let mut buf = Vec::new();
        write_pfm_to(&mut buf, w, h, &data).expect("write");
        // The first sample in the file is the bottom-left pixel (row 2, column 0).
        let header = b"Pf\n5 3\n-1.0\n";
        assert_eq!(&buf[..header.len()], header);
        let first = f32::from_le_bytes([
            buf[header.len()],
            buf[header.len() + 1],
            buf[header.len() + 2],
            buf[header.len() + 3],
        ]);
        assert_eq!(first, 10.0 * 0.5 - 1.0);
        let back = read_pfm_from(buf.as_slice()).expect("read");
        assert_eq!((back.width, back.height), (w, h));
        for (a, b) in data.iter().zip(&back.data) {
            assert!(a == b || (a.is_nan() && b.is_nan()));
        }
    }

    #[test]
    fn big_endian_files_are_read() {
        let mut buf = b"Pf\n2 1\n1.0\n".to_vec();
        buf.extend_from_slice(&1.5f32.to_be_bytes());
        buf.extend_from_slice(&(-2.0f32).to_be_bytes());
        let p = read_pfm_from(buf.as_slice()).expect("read");
        assert_eq!(p.data, vec![1.5, -2.0]);
    }

    #[test]
    fn bad_files_are_rejected() {
        assert!(read_pfm_from(&b"PF\n1 1\n-1.0\n\0\0\0\0"[..]).is_err());
        assert!(read_pfm_from(&b"Pf\n2 2\n-1.0\n\0\0\0\0"[..]).is_err());
        assert!(read_pfm_from(&b"Pf\nx 2\n-1.0\n"[..]).is_err());
        assert!(write_pfm_to(Vec::new(), 2, 2, &[0.0; 3]).is_err());
    }
}
