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
//! | depth_sigma | float | one standard deviation of the point's relative depth that its plane's self-calibration leaves (present for self-calibrated clouds; added in version 1) |
//!
//! A `comment crossline ply 1` line names the version; other comments carry provenance.
//! CloudCompare, MeshLab and Open3D read this layout (extra properties are kept as
//! scalar fields).
//!
//! # What crossline reads
//! [`read_ply`] accepts any PLY with a `vertex` element, not only the layout above:
//!
//! | aspect | accepted |
//! |---|---|
//! | format | `ascii`, `binary_little_endian`, `binary_big_endian` (version 1.0) |
//! | x, y, z | any scalar type (`float`, `double`, integers); required |
//! | red, green, blue | `uchar` as is; `ushort` scaled by 255/65535; `float`/`double` in 0–1 scaled by 255; optional (all three or none) |
//! | frame, laser, distance, depth_sigma | any scalar type, converted; optional |
//! | other vertex properties | skipped, also list properties |
//! | other elements | skipped before the vertex element (lists too); reading stops after it |
//!
//! ASCII bodies are read one record per line, as every common writer emits them.

use std::io::{BufRead, BufReader, BufWriter, Read, Write};
use std::path::{Path, PathBuf};

use rayon::prelude::*;

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
    /// Per point, one standard deviation of its relative depth from its plane's
    /// uncertainty (self-calibrated clouds).
    pub depth_sigmas: Option<Vec<f32>>,
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
    #[error("cannot read or write {path}")]
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

/// Reads a PLY point cloud; see the module doc for what is accepted.
pub fn read_ply(path: &Path) -> Result<Cloud, PlyError> {
    let file = std::fs::File::open(path).map_err(|source| PlyError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    read_ply_from(
        BufReader::with_capacity(1 << 20, file),
        &path.to_string_lossy(),
    )
}

/// Reads a PLY point cloud from `reader`; `name` (usually the path) labels errors.
pub fn read_ply_from<R: BufRead>(mut reader: R, name: &str) -> Result<Cloud, PlyError> {
    let path = PathBuf::from(name);
    let header = read_header(&mut reader, &path)?;
    let fail = |message: String| PlyError::Format {
        path: path.clone(),
        message,
    };
    let io = |source| PlyError::Io {
        path: path.clone(),
        source,
    };
    let Some(vertex_at) = header.elements.iter().position(|e| e.name == "vertex") else {
        return Err(fail("header has no `element vertex`".into()));
    };
    let mut line_no = header.lines;
    // Elements before the vertex element must be read past; those after it are never read.
    for element in &header.elements[..vertex_at] {
        match header.format {
            Format::Ascii => {
                let mut line = Vec::new();
                for i in 0..element.count {
                    line.clear();
                    if reader.read_until(b'\n', &mut line).map_err(io)? == 0 {
                        return Err(fail(format!(
                            "truncated body: read {i} of {} `{}` records",
                            element.count, element.name
                        )));
                    }
                    line_no += 1;
                }
            }
            Format::Binary { big_endian } => {
                let mut scratch = [0u8; 8];
                for i in 0..element.count {
                    for prop in &element.properties {
                        skip_binary(&mut reader, prop, big_endian, &mut scratch).map_err(|e| {
                            truncated_or_io(e, &path, i, element.count, &element.name)
                        })?;
                    }
                }
            }
        }
    }
    let vertex = &header.elements[vertex_at];
    read_vertices(&mut reader, header.format, vertex, &path, line_no)
}

fn truncated_or_io(
    e: std::io::Error,
    path: &Path,
    read: usize,
    count: usize,
    element: &str,
) -> PlyError {
    if e.kind() == std::io::ErrorKind::UnexpectedEof {
        let what = if element == "vertex" {
            "vertices".to_string()
        } else {
            format!("`{element}` records")
        };
        PlyError::Format {
            path: path.to_path_buf(),
            message: format!("truncated body: read {read} of {count} {what}"),
        }
    } else {
        PlyError::Io {
            path: path.to_path_buf(),
            source: e,
        }
    }
}

#[derive(Clone, Copy, Debug, PartialEq)]
enum Format {
    Ascii,
    Binary { big_endian: bool },
}

#[derive(Clone, Copy, Debug, PartialEq)]
enum Scalar {
    I8,
    U8,
    I16,
    U16,
    I32,
    U32,
    F32,
    F64,
}

impl Scalar {
    fn parse(name: &str) -> Option<Self> {
        Some(match name {
            "char" | "int8" => Self::I8,
            "uchar" | "uint8" => Self::U8,
            "short" | "int16" => Self::I16,
            "ushort" | "uint16" => Self::U16,
            "int" | "int32" => Self::I32,
            "uint" | "uint32" => Self::U32,
            "float" | "float32" => Self::F32,
            "double" | "float64" => Self::F64,
            _ => return None,
        })
    }

    fn size(self) -> usize {
        match self {
            Self::I8 | Self::U8 => 1,
            Self::I16 | Self::U16 => 2,
            Self::I32 | Self::U32 | Self::F32 => 4,
            Self::F64 => 8,
        }
    }

    fn decode(self, b: &[u8], big_endian: bool) -> f64 {
        macro_rules! num {
            ($t:ty, $n:expr) => {{
                let mut a = [0u8; $n];
                a.copy_from_slice(&b[..$n]);
                if big_endian {
                    <$t>::from_be_bytes(a) as f64
                } else {
                    <$t>::from_le_bytes(a) as f64
                }
            }};
        }
        match self {
            Self::I8 => b[0] as i8 as f64,
            Self::U8 => b[0] as f64,
            Self::I16 => num!(i16, 2),
            Self::U16 => num!(u16, 2),
            Self::I32 => num!(i32, 4),
            Self::U32 => num!(u32, 4),
            Self::F32 => num!(f32, 4),
            Self::F64 => num!(f64, 8),
        }
    }
}

#[derive(Clone, Copy, Debug, PartialEq)]
enum Field {
    X,
    Y,
    Z,
    Red,
    Green,
    Blue,
    Frame,
    Laser,
    Distance,
    DepthSigma,
    Ignored,
}

#[derive(Clone, Debug)]
enum Property {
    Scalar { ty: Scalar, field: Field },
    List { count: Scalar, item: Scalar },
}

#[derive(Clone, Debug)]
struct Element {
    name: String,
    count: usize,
    properties: Vec<Property>,
}

struct Header {
    format: Format,
    elements: Vec<Element>,
    /// Number of header lines, `end_header` included.
    lines: usize,
}

fn read_header<R: BufRead>(reader: &mut R, path: &Path) -> Result<Header, PlyError> {
    let mut line_no = 0usize;
    let mut format = None;
    let mut elements: Vec<Element> = Vec::new();
    let mut buf = Vec::new();
    loop {
        buf.clear();
        let n = reader
            .by_ref()
            .take(4096)
            .read_until(b'\n', &mut buf)
            .map_err(|source| PlyError::Io {
                path: path.to_path_buf(),
                source,
            })?;
        line_no += 1;
        let fail = |what: &str| PlyError::Format {
            path: path.to_path_buf(),
            message: format!("header line {line_no}: {what}"),
        };
        if n == 0 {
            return Err(fail("file ends before `end_header`"));
        }
        if !buf.ends_with(b"\n") && n == 4096 {
            return Err(fail("line longer than 4096 bytes (is this a PLY file?)"));
        }
        let line = std::str::from_utf8(&buf)
            .map_err(|_| fail("not text (is this a PLY file?)"))?
            .trim_end_matches(['\n', '\r']);
        let words: Vec<&str> = line.split_whitespace().collect();
        if line_no == 1 {
            if line.trim() != "ply" {
                return Err(fail("expected `ply` (the PLY magic number)"));
            }
            continue;
        }
        match words.first().copied() {
            None | Some("comment") | Some("obj_info") => {}
            Some("format") => {
                let f = match words.get(1).copied() {
                    Some("ascii") => Format::Ascii,
                    Some("binary_little_endian") => Format::Binary { big_endian: false },
                    Some("binary_big_endian") => Format::Binary { big_endian: true },
                    _ => {
                        return Err(fail(
                            "expected `format ascii|binary_little_endian|binary_big_endian 1.0`",
                        ))
                    }
                };
                if words.get(2).copied() != Some("1.0") {
                    return Err(fail("expected PLY version `1.0` after the format"));
                }
                format = Some(f);
            }
            Some("element") => {
                let (Some(name), Some(count), None) = (words.get(1), words.get(2), words.get(3))
                else {
                    return Err(fail("expected `element NAME COUNT`"));
                };
                let count = count
                    .parse::<usize>()
                    .map_err(|_| fail("expected a non-negative integer element count"))?;
                elements.push(Element {
                    name: (*name).to_string(),
                    count,
                    properties: Vec::new(),
                });
            }
            Some("property") => {
                let Some(element) = elements.last_mut() else {
                    return Err(fail("`property` before any `element`"));
                };
                let property = match words[1..] {
                    ["list", count, item, _name] => {
                        let (Some(count), Some(item)) = (Scalar::parse(count), Scalar::parse(item))
                        else {
                            return Err(fail("expected `property list COUNT_TYPE ITEM_TYPE NAME` with PLY scalar types"));
                        };
                        if matches!(count, Scalar::F32 | Scalar::F64) {
                            return Err(fail("list count type must be an integer type"));
                        }
                        Property::List { count, item }
                    }
                    [ty, name] => {
                        let Some(ty) = Scalar::parse(ty) else {
                            return Err(fail(
                                "expected a PLY scalar type (char uchar short ushort int uint float double)",
                            ));
                        };
                        let field = if element.name == "vertex" {
                            match name {
                                "x" => Field::X,
                                "y" => Field::Y,
                                "z" => Field::Z,
                                "red" | "r" | "diffuse_red" => Field::Red,
                                "green" | "g" | "diffuse_green" => Field::Green,
                                "blue" | "b" | "diffuse_blue" => Field::Blue,
                                "frame" => Field::Frame,
                                "laser" => Field::Laser,
                                "distance" => Field::Distance,
                                "depth_sigma" => Field::DepthSigma,
                                _ => Field::Ignored,
                            }
                        } else {
                            Field::Ignored
                        };
                        Property::Scalar { ty, field }
                    }
                    _ => return Err(fail("expected `property TYPE NAME` or `property list COUNT_TYPE ITEM_TYPE NAME`")),
                };
                element.properties.push(property);
            }
            Some("end_header") => break,
            Some(other) => {
                return Err(fail(&format!(
                    "unknown keyword `{other}`; expected format, element, property, comment or end_header"
                )))
            }
        }
    }
    let Some(format) = format else {
        return Err(PlyError::Format {
            path: path.to_path_buf(),
            message: "header has no `format` line".into(),
        });
    };
    if let Some(v) = elements.iter().find(|e| e.name == "vertex") {
        let has = |f: Field| {
            v.properties
                .iter()
                .any(|p| matches!(p, Property::Scalar { field, .. } if *field == f))
        };
        for (f, n) in [(Field::X, "x"), (Field::Y, "y"), (Field::Z, "z")] {
            if !has(f) {
                return Err(PlyError::Format {
                    path: path.to_path_buf(),
                    message: format!("vertex element has no `{n}` property"),
                });
            }
        }
        let colours = [Field::Red, Field::Green, Field::Blue].map(has);
        if colours.iter().any(|&c| c) && !colours.iter().all(|&c| c) {
            return Err(PlyError::Format {
                path: path.to_path_buf(),
                message: "vertex element has some but not all of red, green, blue".into(),
            });
        }
    }
    Ok(Header {
        format,
        elements,
        lines: line_no,
    })
}

fn skip_binary<R: Read>(
    reader: &mut R,
    prop: &Property,
    big_endian: bool,
    scratch: &mut [u8; 8],
) -> std::io::Result<()> {
    match *prop {
        Property::Scalar { ty, .. } => reader.read_exact(&mut scratch[..ty.size()]),
        Property::List { count, item } => {
            reader.read_exact(&mut scratch[..count.size()])?;
            let n = count.decode(&scratch[..], big_endian);
            if !(0.0..=1e9).contains(&n) {
                return Err(std::io::Error::new(
                    std::io::ErrorKind::InvalidData,
                    format!("list length {n} out of range"),
                ));
            }
            let bytes = n as u64 * item.size() as u64;
            let skipped = std::io::copy(&mut reader.take(bytes), &mut std::io::sink())?;
            if skipped < bytes {
                return Err(std::io::ErrorKind::UnexpectedEof.into());
            }
            Ok(())
        }
    }
}

/// One decoded vertex record, before conversion into the cloud's types.
#[derive(Default)]
struct Record {
    xyz: [f64; 3],
    rgb: [f64; 3],
    frame: f64,
    laser: f64,
    distance: f64,
    depth_sigma: f64,
}

impl Record {
    fn set(&mut self, field: Field, ty: Scalar, value: f64) {
        let colour = |v: f64| match ty {
            Scalar::F32 | Scalar::F64 => v * 255.0,
            Scalar::U16 => v * (255.0 / 65535.0),
            _ => v,
        };
        match field {
            Field::X => self.xyz[0] = value,
            Field::Y => self.xyz[1] = value,
            Field::Z => self.xyz[2] = value,
            Field::Red => self.rgb[0] = colour(value),
            Field::Green => self.rgb[1] = colour(value),
            Field::Blue => self.rgb[2] = colour(value),
            Field::Frame => self.frame = value,
            Field::Laser => self.laser = value,
            Field::Distance => self.distance = value,
            Field::DepthSigma => self.depth_sigma = value,
            Field::Ignored => {}
        }
    }
}

fn read_vertices<R: BufRead>(
    reader: &mut R,
    format: Format,
    vertex: &Element,
    path: &Path,
    mut line_no: usize,
) -> Result<Cloud, PlyError> {
    let n = vertex.count;
    let has = |f: Field| {
        vertex
            .properties
            .iter()
            .any(|p| matches!(p, Property::Scalar { field, .. } if *field == f))
    };
    // Cap the up-front reservation so that a lying header cannot exhaust memory.
    let reserve = n.min(1 << 24);
    let mut cloud = Cloud {
        points: Vec::with_capacity(reserve),
        colors: has(Field::Red).then(|| Vec::with_capacity(reserve)),
        frames: has(Field::Frame).then(|| Vec::with_capacity(reserve)),
        lasers: has(Field::Laser).then(|| Vec::with_capacity(reserve)),
        distances: has(Field::Distance).then(|| Vec::with_capacity(reserve)),
        depth_sigmas: has(Field::DepthSigma).then(|| Vec::with_capacity(reserve)),
    };
    let mut rec = Record::default();
    let push = |rec: &Record, cloud: &mut Cloud| {
        cloud.points.push(rec.xyz.map(|c| c as f32));
        if let Some(c) = cloud.colors.as_mut() {
            c.push(rec.rgb.map(|v| v.round().clamp(0.0, 255.0) as u8));
        }
        if let Some(f) = cloud.frames.as_mut() {
            f.push(rec.frame.max(0.0) as u32);
        }
        if let Some(l) = cloud.lasers.as_mut() {
            l.push(rec.laser.clamp(0.0, 255.0) as u8);
        }
        if let Some(d) = cloud.distances.as_mut() {
            d.push(rec.distance as f32);
        }
        if let Some(d) = cloud.depth_sigmas.as_mut() {
            d.push(rec.depth_sigma as f32);
        }
    };
    match format {
        Format::Binary { big_endian } => {
            let fixed: Option<usize> = vertex
                .properties
                .iter()
                .map(|p| match p {
                    Property::Scalar { ty, .. } => Some(ty.size()),
                    Property::List { .. } => None,
                })
                .sum();
            let mut buf = vec![0u8; fixed.unwrap_or(8)];
            for i in 0..n {
                if fixed.is_some() {
                    reader
                        .read_exact(&mut buf)
                        .map_err(|e| truncated_or_io(e, path, i, n, "vertex"))?;
                    let mut at = 0;
                    for p in &vertex.properties {
                        if let Property::Scalar { ty, field } = *p {
                            if field != Field::Ignored {
                                rec.set(field, ty, ty.decode(&buf[at..], big_endian));
                            }
                            at += ty.size();
                        }
                    }
                } else {
                    let mut scratch = [0u8; 8];
                    for p in &vertex.properties {
                        let r = match *p {
                            Property::Scalar { ty, field } => reader
                                .read_exact(&mut scratch[..ty.size()])
                                .map(|()| rec.set(field, ty, ty.decode(&scratch, big_endian))),
                            Property::List { .. } => {
                                skip_binary(reader, p, big_endian, &mut scratch)
                            }
                        };
                        r.map_err(|e| truncated_or_io(e, path, i, n, "vertex"))?;
                    }
                }
                push(&rec, &mut cloud);
            }
        }
        Format::Ascii => {
            let mut line = String::new();
            for i in 0..n {
                line.clear();
                let got = reader.read_line(&mut line).map_err(|source| {
                    // Bytes that are not UTF-8 are a damaged file, not a failing disk.
                    if source.kind() == std::io::ErrorKind::InvalidData {
                        PlyError::Format {
                            path: path.to_path_buf(),
                            message: format!(
                                "line {}: vertex {i} of {n} is not text (binary data in an ASCII PLY?)",
                                line_no + 1
                            ),
                        }
                    } else {
                        PlyError::Io {
                            path: path.to_path_buf(),
                            source,
                        }
                    }
                })?;
                line_no += 1;
                if got == 0 {
                    let eof = std::io::ErrorKind::UnexpectedEof.into();
                    return Err(truncated_or_io(eof, path, i, n, "vertex"));
                }
                let bad = |what: String| PlyError::Format {
                    path: path.to_path_buf(),
                    message: format!("line {line_no} (vertex {i}): {what}"),
                };
                let mut tokens = line.split_ascii_whitespace();
                let mut next = |what: &str| -> Result<f64, PlyError> {
                    let t = tokens.next().ok_or_else(|| {
                        bad(format!("expected {what}, found the end of the line"))
                    })?;
                    t.parse::<f64>()
                        .map_err(|_| bad(format!("expected {what}, found `{t}`")))
                };
                for p in &vertex.properties {
                    match *p {
                        Property::Scalar { ty, field } => {
                            let v = next("a number")?;
                            rec.set(field, ty, v);
                        }
                        Property::List { .. } => {
                            let k = next("a list length")?;
                            if !(0.0..=1e9).contains(&k) || k.fract() != 0.0 {
                                return Err(bad(format!("list length {k} is not a count")));
                            }
                            for _ in 0..k as usize {
                                next("a list item")?;
                            }
                        }
                    }
                }
                push(&rec, &mut cloud);
            }
        }
    }
    Ok(cloud)
}

/// [`write_ply`] to a temporary file beside `path`, then renamed over it: readers of
/// `path` (a viewer reloading a growing scan) only ever see a whole cloud, and a crash
/// leaves the previous one.
pub fn write_ply_atomic(path: &Path, cloud: &Cloud, comments: &[String]) -> Result<(), PlyError> {
    let tmp = path.with_extension("ply.tmp");
    write_ply(&tmp, cloud, comments)?;
    std::fs::rename(&tmp, path).map_err(|source| PlyError::Io {
        path: path.to_path_buf(),
        source,
    })
}

/// Points encoded at a time by [`write_ply`], and blocks encoded side by side before
/// they are written (at most about 25 MB held at once).
const WRITE_BLOCK: usize = 1 << 15;
const WRITE_BATCH: usize = 32;

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
        ("depth_sigmas", cloud.depth_sigmas.as_ref().map(Vec::len)),
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
    if cloud.depth_sigmas.is_some() {
        header.push_str("property float depth_sigma\n");
    }
    header.push_str("end_header\n");
    w.write_all(header.as_bytes()).map_err(io)?;
    // The records are encoded a block of points at a time, the blocks of a batch side
    // by side, and written in order: the same bytes as one point at a time, which took
    // 0.5 s of the 9 M-point dive's final cloud on one core after its solve.
    let encode = |from: usize| -> Vec<u8> {
        let to = (from + WRITE_BLOCK).min(n);
        let mut rec = Vec::with_capacity((to - from) * 32);
        for i in from..to {
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
            if let Some(d) = &cloud.depth_sigmas {
                rec.extend_from_slice(&d[i].to_le_bytes());
            }
        }
        rec
    };
    let starts: Vec<usize> = (0..n).step_by(WRITE_BLOCK).collect();
    for batch in starts.chunks(WRITE_BATCH) {
        let blocks: Vec<Vec<u8>> = batch.par_iter().map(|&from| encode(from)).collect();
        for block in &blocks {
            w.write_all(block).map_err(io)?;
        }
    }
    w.flush().map_err(io)?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn read(bytes: &[u8]) -> Result<Cloud, PlyError> {
        read_ply_from(bytes, "test.ply")
    }

    fn message(r: Result<Cloud, PlyError>) -> String {
        match r {
            Ok(c) => panic!("expected an error, read {} points", c.len()),
            Err(e) => e.to_string(),
        }
    }

    #[test]
    fn bytes_that_are_not_text_in_an_ascii_body_are_a_format_error() {
        let mut bytes = b"ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\n\
            property float y\nproperty float z\nend_header\n1 2 3\n"
            .to_vec();
        bytes.extend_from_slice(&[0xFF, 0xFE, b' ', b'1', b'\n']);
        let err = read(&bytes).expect_err("not text");
        assert!(matches!(err, PlyError::Format { .. }), "{err:?}");
        assert!(err.to_string().contains("vertex 1 of 2"), "{err}");
    }

    #[test]
    fn round_trip_with_write_ply() {
        let cloud = Cloud {
            points: vec![[1.0, -2.5, 3.25], [0.0, 1e-3, 7.0], [-4.0, 5.0, 6.5]],
            colors: Some(vec![[255, 0, 7], [1, 2, 3], [9, 8, 128]]),
            frames: Some(vec![0, 17, 4_000_000]),
            lasers: Some(vec![0, 1, 1]),
            distances: Some(vec![0.5, 0.0, 2.0e-4]),
            depth_sigmas: Some(vec![1e-4, 0.003, 0.25]),
        };
        let dir = tempfile::tempdir().expect("temp dir");
        let path = dir.path().join("c.ply");
        write_ply(&path, &cloud, &["made by a test".into()]).expect("write");
        assert_eq!(read_ply(&path).expect("read"), cloud);
        let bare = Cloud {
            points: cloud.points.clone(),
            ..Default::default()
        };
        write_ply(&path, &bare, &[]).expect("write");
        assert_eq!(read_ply(&path).expect("read"), bare);
    }

    /// A cloud of several blocks and batches of [`write_ply`]'s encoding, the last
    /// ones short, comes back point for point in order.
    #[test]
    fn a_cloud_of_many_blocks_round_trips_in_order() {
        let n = WRITE_BLOCK * (WRITE_BATCH + 3) + 17;
        let cloud = Cloud {
            points: (0..n).map(|i| [i as f32, -(i as f32), 0.5]).collect(),
            colors: Some((0..n).map(|i| [i as u8, (i >> 8) as u8, 3]).collect()),
            frames: Some((0..n as u32).collect()),
            lasers: Some((0..n).map(|i| (i % 2) as u8).collect()),
            distances: None,
            depth_sigmas: Some((0..n).map(|i| i as f32 * 1e-6).collect()),
        };
        let dir = tempfile::tempdir().expect("temp dir");
        let path = dir.path().join("many.ply");
        write_ply(&path, &cloud, &[]).expect("write");
        assert_eq!(read_ply(&path).expect("read"), cloud);
    }

    #[test]
    fn ascii_with_extra_properties_and_faces_after() {
        let text = "ply\r\nformat ascii 1.0\ncomment hi\nelement vertex 2\n\
            property double x\nproperty double y\nproperty double z\n\
            property float nx\nproperty list uchar int idx\n\
            property uchar red\nproperty uchar green\nproperty uchar blue\n\
            element face 1\nproperty list uchar int vertex_indices\nend_header\n\
            1.5 2 3 0.1 2 7 8 10 20 30\n-1 -2 -3e-1 0 0 255 0 1\n3 0 1 1\n";
        let c = read(text.as_bytes()).expect("read");
        assert_eq!(c.points, vec![[1.5, 2.0, 3.0], [-1.0, -2.0, -0.3]]);
        assert_eq!(c.colors, Some(vec![[10, 20, 30], [255, 0, 1]]));
        assert!(c.frames.is_none() && c.distances.is_none());
    }

    #[test]
    fn ascii_float_colours_are_scaled() {
        let text = "ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\n\
            property float y\nproperty float z\nproperty float red\nproperty float green\n\
            property float blue\nend_header\n0 0 1 1.0 0.5 0\n";
        let c = read(text.as_bytes()).expect("read");
        assert_eq!(c.colors, Some(vec![[255, 128, 0]]));
    }

    /// A binary file with a face element (with lists) *before* the vertices, double
    /// coordinates, ushort colours, an ignored int property and a vertex list property.
    fn binary(big_endian: bool, vertices_written: usize) -> Vec<u8> {
        let fmt = if big_endian {
            "binary_big_endian"
        } else {
            "binary_little_endian"
        };
        let mut out = format!(
            "ply\nformat {fmt} 1.0\nelement face 2\nproperty list uchar uint vertex_indices\n\
             property short flag\nelement vertex 3\nproperty double x\nproperty double y\n\
             property double z\nproperty int ignored\nproperty ushort red\n\
             property ushort green\nproperty ushort blue\nproperty list ushort float normals\n\
             property uint frame\nproperty uchar laser\nproperty double distance\nend_header\n"
        )
        .into_bytes();
        macro_rules! put {
            ($v:expr) => {
                if big_endian {
                    out.extend_from_slice(&$v.to_be_bytes())
                } else {
                    out.extend_from_slice(&$v.to_le_bytes())
                }
            };
        }
        for k in [3u8, 4] {
            put!(k);
            for j in 0..k {
                put!(j as u32);
            }
            put!(-5i16);
        }
        for i in 0..vertices_written {
            let f = i as f64;
            put!(f + 0.25);
            put!(-f);
            put!(2.0 * f + 1.0);
            put!(77i32);
            put!(65535u16);
            put!(0u16);
            put!(257u16 * i as u16);
            put!(i as u16);
            for _ in 0..i {
                put!(1.5f32);
            }
            put!(10 * i as u32);
            put!(i as u8);
            put!(0.125 * f);
        }
        out
    }

    #[test]
    fn binary_both_endians_doubles_lists_and_skipped_elements() {
        for big_endian in [false, true] {
            let c = read(&binary(big_endian, 3)).expect("read");
            assert_eq!(
                c.points,
                vec![[0.25, 0.0, 1.0], [1.25, -1.0, 3.0], [2.25, -2.0, 5.0]]
            );
            assert_eq!(c.colors, Some(vec![[255, 0, 0], [255, 0, 1], [255, 0, 2]]));
            assert_eq!(c.frames, Some(vec![0, 10, 20]));
            assert_eq!(c.lasers, Some(vec![0, 1, 2]));
            assert_eq!(c.distances, Some(vec![0.0, 0.125, 0.25]));
        }
    }

    #[test]
    fn truncated_bodies_say_how_many_were_read() {
        let mut bytes = binary(false, 2);
        bytes.extend_from_slice(&[0, 0, 0]);
        let m = message(read(&bytes));
        assert!(m.contains("read 2 of 3 vertices"), "{m}");
        let text = "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\n\
            property float y\nproperty float z\nend_header\n1 2 3\n4 5 6\n";
        let m = message(read(text.as_bytes()));
        assert!(m.contains("read 2 of 3 vertices"), "{m}");
        let text = "ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\n\
            property float y\nproperty float z\nend_header\n1 2 3\n4 5\n";
        let m = message(read(text.as_bytes()));
        assert!(m.contains("line 9 (vertex 1)"), "{m}");
        assert!(m.contains("end of the line"), "{m}");
    }

    #[test]
    fn bad_headers_name_the_line_and_the_expectation() {
        let cases: [(&str, &str); 7] = [
            ("plx\n", "line 1: expected `ply`"),
            ("ply\nformat binary 1.0\nend_header\n", "line 2: expected `format ascii"),
            ("ply\nformat ascii 1.0\nelement vertex many\n", "line 3: expected a non-negative"),
            ("ply\nformat ascii 1.0\nelement vertex 1\nproperty half x\n", "line 4: expected a PLY scalar type"),
            ("ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\n", "line 5: file ends before `end_header`"),
            ("ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\nend_header\n", "no `z` property"),
            ("ply\nformat ascii 1.0\nelement face 0\nend_header\n", "no `element vertex`"),
        ];
        for (text, expected) in cases {
            let m = message(read(text.as_bytes()));
            assert!(m.contains(expected), "{text:?}: {m}");
            assert!(m.contains("test.ply"), "{m}");
        }
    }
}
