//! The recording format for raw camera buffers ("dump"), version 1.
//!
//! A dump keeps every buffer exactly as the driver delivered it, with the driver's
//! sequence number and timestamp, so a dive can be reprocessed later and dropped frames
//! are visible. It is written as frames arrive, one self-checking record at a time: a
//! crash or power loss leaves a file that reads up to its last whole frame, and the
//! reader says where and why it stopped.
//!
//! All integers are little-endian.
//!
//! # File header
//! | offset | size | field |
//! |---|---|---|
//! | 0 | 8 | magic `CRSLDUMP` |
//! | 8 | 4 | format version (1) |
//! | 12 | 4 | header length `H` in bytes (the whole header, CRC included) |
//! | 16 | 4 | pixel format fourcc: `MJPG`, `YUYV` or `RGB3` |
//! | 20 | 4 | width (pixels) |
//! | 24 | 4 | height (pixels) |
//! | 28 | 4 | bytes per line (0 for compressed formats) |
//! | 32 | 4 | frame interval numerator (seconds) |
//! | 36 | 4 | frame interval denominator |
//! | 40 | 2 | length `n` of the device name |
//! | 42 | n | device name, UTF-8 (e.g. `/dev/video0`) |
//! | 42+n | 2 | length `m` of the card name |
//! | 44+n | m | card name, UTF-8 (V4L2 `QUERYCAP` card) |
//! | H−4 | 4 | CRC-32 (IEEE) of bytes `0..H−4` |
//!
//! # Records, one per buffer
//! | offset | size | field |
//! |---|---|---|
//! | 0 | 4 | magic `FRAM` |
//! | 4 | 4 | sequence number (the driver's) |
//! | 8 | 8 | timestamp, nanoseconds (the driver's clock) |
//! | 16 | 4 | V4L2 buffer flags |
//! | 20 | 4 | bytes used `b` |
//! | 24 | b | payload |
//! | 24+b | 4 | CRC-32 (IEEE) of bytes `0..24+b` of the record |

use std::fs::File;
use std::io::{BufWriter, Read, Seek, SeekFrom, Write};
use std::path::{Path, PathBuf};

use image::RgbImage;

pub const MAGIC: &[u8; 8] = b"CRSLDUMP";
pub const RECORD_MAGIC: &[u8; 4] = b"FRAM";
pub const VERSION: u32 = 1;
/// Largest payload a record may claim (a 4K RGB frame is 25 MB): a larger length is
/// taken for corruption rather than allocated.
pub const MAX_PAYLOAD: u32 = 64 << 20;
/// Largest image side a header may claim (V4L2 drivers stop well below).
pub const MAX_SIDE: u32 = 1 << 15;
/// Largest number of pixels a header may claim (an 8K frame is 33 M): the decoded RGB
/// image, `3` bytes a pixel, must stay allocatable however the header was damaged.
pub const MAX_PIXELS: u64 = 1 << 26;

/// The negotiated stream, as recorded in the header.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct DumpHeader {
    pub fourcc: [u8; 4],
    pub width: u32,
    pub height: u32,
    pub bytes_per_line: u32,
    pub interval_num: u32,
    pub interval_den: u32,
    pub device: String,
    pub card: String,
}

/// One recorded buffer.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Record {
    pub sequence: u32,
    pub timestamp_nanos: u64,
    pub flags: u32,
    pub payload: Vec<u8>,
}

#[derive(Debug, thiserror::Error)]
pub enum DumpError {
    #[error("cannot read or write dump {path}: {source}")]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("{path}: not a crossline dump (expected magic CRSLDUMP at offset 0)")]
    NotADump { path: PathBuf },
    #[error("{path}: dump format version {found}, this crossline reads version {VERSION}")]
    Version { path: PathBuf, found: u32 },
    #[error("{path}: bad header: {message}")]
    Header { path: PathBuf, message: String },
    #[error("{path}: truncated at byte {offset} inside frame record {index} (after {index} whole frames): the recording was cut off")]
    Truncated {
        path: PathBuf,
        offset: u64,
        index: usize,
    },
    #[error("{path}: corrupted frame record {index} at byte {offset}: {reason}")]
    Corrupt {
        path: PathBuf,
        offset: u64,
        index: usize,
        reason: String,
    },
    #[error("{path}: frame record {index}: cannot decode {fourcc} frame: {message}")]
    Decode {
        path: PathBuf,
        index: usize,
        fourcc: String,
        message: String,
    },
}

fn fourcc_str(f: [u8; 4]) -> String {
    String::from_utf8_lossy(&f).into_owned()
}

/// Checks that a header's image size and line length describe a frame that fits in a
/// record ([`MAX_PAYLOAD`]) and decodes to an image of at most [`MAX_PIXELS`], with
/// every product computed without overflow; says what is wrong otherwise.
pub fn check_frame_size(header: &DumpHeader) -> Result<(), String> {
    let (w, h) = (header.width, header.height);
    if w == 0 || h == 0 {
        return Err(format!("image size {w}x{h} is empty"));
    }
    if w > MAX_SIDE || h > MAX_SIDE || u64::from(w) * u64::from(h) > MAX_PIXELS {
        return Err(format!(
            "image size {w}x{h} is larger than crossline reads (at most {MAX_SIDE} a side, {MAX_PIXELS} pixels)"
        ));
    }
    if let Some(bpp) = packed_bytes_per_pixel(header.fourcc) {
        let row = u64::from(w) * bpp as u64;
        let stride = match header.bytes_per_line {
            0 => row,
            n => u64::from(n),
        };
        if stride < row {
            return Err(format!(
                "{stride} bytes per line is less than the {row} of a {w}-pixel {} row",
                fourcc_str(header.fourcc)
            ));
        }
        let frame = stride * (u64::from(h) - 1) + row;
        if frame > u64::from(MAX_PAYLOAD) {
            return Err(format!(
                "a {w}x{h} {} frame of {stride} bytes per line needs {frame} bytes, more than a record holds ({MAX_PAYLOAD})",
                fourcc_str(header.fourcc)
            ));
        }
    }
    Ok(())
}

/// Bytes a pixel of a packed (uncompressed) format; `None` for compressed formats.
fn packed_bytes_per_pixel(fourcc: [u8; 4]) -> Option<usize> {
    match &fourcc {
        b"YUYV" => Some(2),
        b"RGB3" => Some(3),
        _ => None,
    }
}

/// Capacity a buffer of this stream needs (a ring slot): the packed frame, or for
/// compressed formats a byte per pixel, which holds any sane MJPEG frame (larger ones
/// grow the slot). `None` when [`check_frame_size`] refuses the header.
pub fn frame_capacity(header: &DumpHeader) -> Option<usize> {
    check_frame_size(header).ok()?;
    let (w, h) = (header.width as usize, header.height as usize);
    Some(match packed_bytes_per_pixel(header.fourcc) {
        Some(bpp) => (header.bytes_per_line as usize).max(bpp * w) * h,
        None => w * h,
    })
}

impl DumpHeader {
    fn to_bytes(&self) -> Vec<u8> {
        let mut b = Vec::with_capacity(64 + self.device.len() + self.card.len());
        b.extend_from_slice(MAGIC);
        b.extend_from_slice(&VERSION.to_le_bytes());
        let len = 42 + 2 + self.device.len() + self.card.len() + 4;
        b.extend_from_slice(&(len as u32).to_le_bytes());
        b.extend_from_slice(&self.fourcc);
        for v in [
            self.width,
            self.height,
            self.bytes_per_line,
            self.interval_num,
            self.interval_den,
        ] {
            b.extend_from_slice(&v.to_le_bytes());
        }
        for s in [&self.device, &self.card] {
            b.extend_from_slice(&(s.len() as u16).to_le_bytes());
            b.extend_from_slice(s.as_bytes());
        }
        let crc = crc32fast::hash(&b);
        b.extend_from_slice(&crc.to_le_bytes());
        b
    }
}

/// Writes a dump record by record; each record goes to the file in one write.
pub struct DumpWriter {
    path: PathBuf,
    file: BufWriter<File>,
    record: Vec<u8>,
    bytes: u64,
}

impl DumpWriter {
    pub fn create(path: &Path, header: &DumpHeader) -> Result<Self, DumpError> {
        let io = |source| DumpError::Io {
            path: path.to_path_buf(),
            source,
        };
        if header.device.len() > u16::MAX as usize || header.card.len() > u16::MAX as usize {
            return Err(DumpError::Header {
                path: path.to_path_buf(),
                message: "device or card name longer than 65535 bytes".into(),
            });
        }
        let mut file = BufWriter::new(File::create(path).map_err(io)?);
        let head = header.to_bytes();
        file.write_all(&head).map_err(io)?;
        file.flush().map_err(io)?;
        Ok(Self {
            path: path.to_path_buf(),
            file,
            record: Vec::new(),
            bytes: head.len() as u64,
        })
    }

    /// Appends one buffer and hands it to the operating system, so that a crash of
    /// this process loses no whole frame.
    pub fn write_frame(
        &mut self,
        sequence: u32,
        timestamp_nanos: u64,
        flags: u32,
        payload: &[u8],
    ) -> Result<(), DumpError> {
        if payload.len() > MAX_PAYLOAD as usize {
            return Err(DumpError::Header {
                path: self.path.clone(),
                message: format!("frame of {} bytes exceeds {MAX_PAYLOAD}", payload.len()),
            });
        }
        let r = &mut self.record;
        r.clear();
        r.extend_from_slice(RECORD_MAGIC);
        r.extend_from_slice(&sequence.to_le_bytes());
        r.extend_from_slice(&timestamp_nanos.to_le_bytes());
        r.extend_from_slice(&flags.to_le_bytes());
        r.extend_from_slice(&(payload.len() as u32).to_le_bytes());
        r.extend_from_slice(payload);
        let crc = crc32fast::hash(r);
        r.extend_from_slice(&crc.to_le_bytes());
        let io = |source| DumpError::Io {
            path: self.path.clone(),
            source,
        };
        self.file.write_all(r).map_err(io)?;
        self.file.flush().map_err(io)?;
        self.bytes += r.len() as u64;
        Ok(())
    }

    /// Bytes written so far, header included.
    pub fn bytes(&self) -> u64 {
        self.bytes
    }

    pub fn finish(mut self) -> Result<(), DumpError> {
        self.file.flush().map_err(|source| DumpError::Io {
            path: self.path.clone(),
            source,
        })
    }
}

/// Reads a dump record by record.
pub struct DumpReader {
    path: PathBuf,
    file: std::io::BufReader<File>,
    header: DumpHeader,
    offset: u64,
    index: usize,
}

fn read_exact_or_eof(r: &mut impl Read, buf: &mut [u8]) -> std::io::Result<usize> {
    let mut got = 0;
    while got < buf.len() {
        match r.read(&mut buf[got..]) {
            Ok(0) => break,
            Ok(n) => got += n,
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
            Err(e) => return Err(e),
        }
    }
    Ok(got)
}

impl DumpReader {
    pub fn open(path: &Path) -> Result<Self, DumpError> {
        let mut file =
            std::io::BufReader::new(File::open(path).map_err(|source| DumpError::Io {
                path: path.to_path_buf(),
                source,
            })?);
        let (header, header_len) = read_header(&mut file, path)?;
        Ok(Self {
            path: path.to_path_buf(),
            file,
            header,
            offset: header_len as u64,
            index: 0,
        })
    }

    pub fn header(&self) -> &DumpHeader {
        &self.header
    }

    /// Byte offset of the next record.
    pub fn offset(&self) -> u64 {
        self.offset
    }

    /// The next record; `Ok(None)` at a clean end of file. A cut-off last record is
    /// [`DumpError::Truncated`]; a record that fails its checks is
    /// [`DumpError::Corrupt`]. Both say where; the records before them are whole.
    pub fn next_record(&mut self) -> Result<Option<Record>, DumpError> {
        let record = read_record(&mut self.file, &self.path, self.offset, self.index)?;
        if let Some(r) = &record {
            self.offset += 24 + r.payload.len() as u64 + 4;
            self.index += 1;
        }
        Ok(record)
    }

    /// Byte offsets of every whole record, and how the scan ended (`None` for a clean
    /// end, or the error that stopped it).
    pub fn index(path: &Path) -> Result<(DumpHeader, Vec<u64>, Option<DumpError>), DumpError> {
        let mut reader = Self::open(path)?;
        let mut offsets = Vec::new();
        loop {
            let at = reader.offset;
            match reader.next_record() {
                Ok(Some(_)) => offsets.push(at),
                Ok(None) => return Ok((reader.header, offsets, None)),
                Err(e @ (DumpError::Truncated { .. } | DumpError::Corrupt { .. })) => {
                    return Ok((reader.header, offsets, Some(e)))
                }
                Err(e) => return Err(e),
            }
        }
    }

    /// Reads the record at `offset` (from [`DumpReader::index`]), numbered `index`
    /// in errors.
    pub fn read_at(path: &Path, offset: u64, index: usize) -> Result<Record, DumpError> {
        let io = |source| DumpError::Io {
            path: path.to_path_buf(),
            source,
        };
        let mut file = File::open(path).map_err(io)?;
        file.seek(SeekFrom::Start(offset)).map_err(io)?;
        read_record(&mut std::io::BufReader::new(file), path, offset, index)?.ok_or(
            DumpError::Truncated {
                path: path.to_path_buf(),
                offset,
                index,
            },
        )
    }
}

fn read_header(file: &mut impl Read, path: &Path) -> Result<(DumpHeader, usize), DumpError> {
    let io = |source| DumpError::Io {
        path: path.to_path_buf(),
        source,
    };
    let bad = |message: String| DumpError::Header {
        path: path.to_path_buf(),
        message,
    };
    let mut fixed = [0u8; 42];
    let got = read_exact_or_eof(file, &mut fixed).map_err(io)?;
    if got < 8 || &fixed[..8] != MAGIC {
        return Err(DumpError::NotADump {
            path: path.to_path_buf(),
        });
    }
    if got < fixed.len() {
        return Err(bad(format!("file ends at byte {got}, inside the header")));
    }
    let u32_at =
        |o: usize| u32::from_le_bytes([fixed[o], fixed[o + 1], fixed[o + 2], fixed[o + 3]]);
    let version = u32_at(8);
    if version != VERSION {
        return Err(DumpError::Version {
            path: path.to_path_buf(),
            found: version,
        });
    }
    let header_len = u32_at(12) as usize;
    if !(48..=42 + 4 + 2 * 65535 + 4).contains(&header_len) {
        return Err(bad(format!("header length {header_len} is impossible")));
    }
    let mut rest = vec![0u8; header_len - 42];
    let got = read_exact_or_eof(file, &mut rest).map_err(io)?;
    if got < rest.len() {
        return Err(bad(format!(
            "file ends at byte {}, inside the {header_len}-byte header",
            42 + got
        )));
    }
    let mut all = fixed.to_vec();
    all.extend_from_slice(&rest);
    let stored = u32::from_le_bytes([
        all[header_len - 4],
        all[header_len - 3],
        all[header_len - 2],
        all[header_len - 1],
    ]);
    if crc32fast::hash(&all[..header_len - 4]) != stored {
        return Err(bad("header checksum mismatch".into()));
    }
    let mut pos = 40;
    let mut string = |what: &str| -> Result<String, DumpError> {
        if pos + 2 > header_len - 4 {
            return Err(bad(format!("{what} length runs past the header")));
        }
        let n = u16::from_le_bytes([all[pos], all[pos + 1]]) as usize;
        let (a, b) = (pos + 2, pos + 2 + n);
        if b > header_len - 4 {
            return Err(bad(format!("{what} runs past the header")));
        }
        pos = b;
        String::from_utf8(all[a..b].to_vec()).map_err(|_| bad(format!("{what} is not UTF-8")))
    };
    let device = string("device name")?;
    let card = string("card name")?;
    let header = DumpHeader {
        fourcc: [fixed[16], fixed[17], fixed[18], fixed[19]],
        width: u32_at(20),
        height: u32_at(24),
        bytes_per_line: u32_at(28),
        interval_num: u32_at(32),
        interval_den: u32_at(36),
        device,
        card,
    };
    check_frame_size(&header).map_err(bad)?;
    Ok((header, header_len))
}

/// A whole dump held in memory, read as [`DumpReader`] reads a file: the header, the
/// whole records, and the error that ended the records early (if any).
pub fn parse(bytes: &[u8]) -> Result<(DumpHeader, Vec<Record>, Option<DumpError>), DumpError> {
    let path = Path::new("<memory>");
    let mut cursor = std::io::Cursor::new(bytes);
    let (header, header_len) = read_header(&mut cursor, path)?;
    let (mut offset, mut records) = (header_len as u64, Vec::new());
    loop {
        match read_record(&mut cursor, path, offset, records.len()) {
            Ok(Some(r)) => {
                offset += 24 + r.payload.len() as u64 + 4;
                records.push(r);
            }
            Ok(None) => return Ok((header, records, None)),
            Err(e) => return Ok((header, records, Some(e))),
        }
    }
}

/// One record from `file` positioned at `offset`; `Ok(None)` at a clean end of file.
fn read_record(
    file: &mut impl Read,
    path: &Path,
    offset: u64,
    index: usize,
) -> Result<Option<Record>, DumpError> {
    let mut head = [0u8; 24];
    let io = |source| DumpError::Io {
        path: path.to_path_buf(),
        source,
    };
    let got = read_exact_or_eof(file, &mut head).map_err(io)?;
    if got == 0 {
        return Ok(None);
    }
    let truncated = || DumpError::Truncated {
        path: path.to_path_buf(),
        offset,
        index,
    };
    if got < head.len() {
        return Err(truncated());
    }
    let corrupt = |reason: String| DumpError::Corrupt {
        path: path.to_path_buf(),
        offset,
        index,
        reason,
    };
    if &head[..4] != RECORD_MAGIC {
        return Err(corrupt("no FRAM marker".into()));
    }
    let u32_at = |o: usize| u32::from_le_bytes([head[o], head[o + 1], head[o + 2], head[o + 3]]);
    let used = u32_at(20);
    if used > MAX_PAYLOAD {
        return Err(corrupt(format!("impossible payload length {used}")));
    }
    // Grown as the bytes arrive: a cut-off file costs what it holds, not the length
    // its last record claims.
    let want = used as usize + 4;
    let mut body = Vec::with_capacity(want.min(1 << 20));
    file.take(want as u64).read_to_end(&mut body).map_err(io)?;
    if body.len() < want {
        return Err(truncated());
    }
    let crc_at = used as usize;
    let stored = u32::from_le_bytes([
        body[crc_at],
        body[crc_at + 1],
        body[crc_at + 2],
        body[crc_at + 3],
    ]);
    let mut hasher = crc32fast::Hasher::new();
    hasher.update(&head);
    hasher.update(&body[..crc_at]);
    if hasher.finalize() != stored {
        return Err(corrupt("checksum mismatch".into()));
    }
    body.truncate(crc_at);
    Ok(Some(Record {
        sequence: u32_at(4),
        timestamp_nanos: u64::from_le_bytes([
            head[8], head[9], head[10], head[11], head[12], head[13], head[14], head[15],
        ]),
        flags: u32_at(16),
        payload: body,
    }))
}

/// JPEG markers that stand alone, without a length.
fn standalone_marker(m: u8) -> bool {
    m == 0x01 || (0xD0..=0xD8).contains(&m)
}

/// A marker segment before the first scan: its marker byte and its bytes
/// `[start, end)`.
type Segment = (u8, usize, usize);

/// The marker segments before the first scan, and the offset of the SOS marker.
/// `None` if the data is not a well-formed JPEG header.
pub(crate) fn jpeg_segments(jpeg: &[u8]) -> Option<(Vec<Segment>, usize)> {
    if jpeg.get(..2)? != [0xFF, 0xD8] {
        return None;
    }
    let mut segments = Vec::new();
    let mut i = 2;
    loop {
        if *jpeg.get(i)? != 0xFF {
            return None;
        }
        let mut j = i + 1;
        while *jpeg.get(j)? == 0xFF {
            j += 1;
        }
        let m = jpeg[j];
        if m == 0xDA {
            return Some((segments, i));
        }
        if standalone_marker(m) {
            i = j + 1;
            continue;
        }
        let len = u16::from_be_bytes([*jpeg.get(j + 1)?, *jpeg.get(j + 2)?]) as usize;
        let end = j + 1 + len;
        if len < 2 || end > jpeg.len() {
            return None;
        }
        segments.push((m, i, end));
        i = end;
    }
}

/// The standard Huffman tables of ITU-T T.81 Annex K.3 as DHT segments, taken once
/// from a JPEG that the `image` encoder writes (it always uses those tables).
fn standard_dht() -> &'static [u8] {
    static DHT: std::sync::OnceLock<Vec<u8>> = std::sync::OnceLock::new();
    DHT.get_or_init(|| {
        let mut jpeg = Vec::new();
        let tiny = RgbImage::from_pixel(8, 8, image::Rgb([128, 64, 32]));
        if image::codecs::jpeg::JpegEncoder::new_with_quality(&mut jpeg, 90)
            .encode_image(&tiny)
            .is_err()
        {
            return Vec::new();
        }
        let mut dht = Vec::new();
        if let Some((segments, _)) = jpeg_segments(&jpeg) {
            for (m, a, b) in segments {
                if m == 0xC4 {
                    dht.extend_from_slice(&jpeg[a..b]);
                }
            }
        }
        dht
    })
}

/// Many USB webcams send MJPEG frames without Huffman tables (the "AVI1" motion-JPEG
/// convention: the decoder is to assume the standard ones); decoders then fail with
/// "no DC table". This returns the frame with the standard tables inserted before the
/// scan when it has none, and the frame unchanged otherwise.
pub fn with_huffman_tables(jpeg: &[u8]) -> std::borrow::Cow<'_, [u8]> {
    match jpeg_segments(jpeg) {
        Some((segments, sos)) if !segments.iter().any(|(m, _, _)| *m == 0xC4) => {
            let dht = standard_dht();
            let mut out = Vec::with_capacity(jpeg.len() + dht.len());
            out.extend_from_slice(&jpeg[..sos]);
            out.extend_from_slice(dht);
            out.extend_from_slice(&jpeg[sos..]);
            std::borrow::Cow::Owned(out)
        }
        _ => std::borrow::Cow::Borrowed(jpeg),
    }
}

/// True when a JPEG's scan ends with the end-of-image marker. The decoder fills a
/// cut-off scan with grey without a word; the marker cannot occur inside the scan
/// (a data byte 0xFF is always followed by 0x00 or a restart marker there), so its
/// absence after the first scan means the frame was cut off.
pub fn jpeg_is_complete(jpeg: &[u8]) -> bool {
    let Some((_, sos)) = jpeg_segments(jpeg) else {
        return false;
    };
    jpeg[sos..].windows(2).any(|w| w == [0xFF, 0xD9])
}

/// Bytes per line of a packed format of `bytes_per_pixel` (the header's, or the packed
/// width when it says 0), checked against the payload's length.
fn packed_stride(header: &DumpHeader, bytes_per_pixel: usize, len: usize) -> Result<usize, String> {
    check_frame_size(header)?;
    let (w, h) = (header.width as usize, header.height as usize);
    let row = bytes_per_pixel * w;
    let stride = match header.bytes_per_line {
        0 => row,
        n => n as usize,
    };
    if len < stride * (h - 1) + row {
        return Err(format!(
            "{len} bytes is too short for {w}x{h} {} with {stride} bytes per line",
            fourcc_str(header.fourcc)
        ));
    }
    Ok(stride)
}

/// One row of YUYV (BT.601, limited range) to RGB, in 8-bit fixed point (the
/// coefficients ×256: 1.164 → 298, 1.596 → 409, 0.392 → 100, 0.813 → 208, 2.017 →
/// 516): a 1080p frame in a few milliseconds where the per-sample float version took
/// 26 (`cargo bench --bench decode`). Within one grey level of the float formula.
pub fn yuyv_row_to_rgb(src: &[u8], dst: &mut [u8]) {
    let clamp = |v: i32| (v >> 8).clamp(0, 255) as u8;
    for (quad, px) in src.chunks_exact(4).zip(dst.chunks_exact_mut(6)) {
        let (d, e) = (i32::from(quad[1]) - 128, i32::from(quad[3]) - 128);
        let (rv, gv, bv) = (409 * e + 128, -100 * d - 208 * e + 128, 516 * d + 128);
        for (k, luma) in [quad[0], quad[2]].into_iter().enumerate() {
            let c = 298 * (i32::from(luma) - 16);
            px[3 * k] = clamp(c + rv);
            px[3 * k + 1] = clamp(c + gv);
            px[3 * k + 2] = clamp(c + bv);
        }
    }
}

/// A whole JPEG of `w × h` to RGB: zune-jpeg (the decoder the `image` crate wraps)
/// called straight. Its size is checked against the header's before the pixels are
/// allocated, so that a damaged frame that claims 65535x65535 costs nothing. Through
/// `image` each frame was copied once more, its headers read twice and its pixels
/// decoded into a buffer of `image`'s: 0.7-1.4 ms more a 1080p frame (of about 11),
/// the same pixels.
fn decode_jpeg(jpeg: &[u8], w: usize, h: usize) -> Result<RgbImage, String> {
    use zune_jpeg::zune_core::{bytestream::ZCursor, colorspace::ColorSpace, options};
    let options = options::DecoderOptions::default()
        .set_strict_mode(false)
        .set_max_width(usize::MAX)
        .set_max_height(usize::MAX)
        .jpeg_set_out_colorspace(ColorSpace::RGB);
    let mut decoder = zune_jpeg::JpegDecoder::new_with_options(ZCursor::new(jpeg), options);
    decoder.decode_headers().map_err(|e| e.to_string())?;
    let (jw, jh) = decoder.dimensions().unwrap_or((0, 0));
    if (jw, jh) != (w, h) {
        return Err(format!("JPEG is {jw}x{jh}, the header says {w}x{h}"));
    }
    let mut out = vec![0u8; 3 * w * h];
    decoder.decode_into(&mut out).map_err(|e| e.to_string())?;
    RgbImage::from_raw(w as u32, h as u32, out).ok_or_else(|| "size".to_string())
}

/// Decodes a recorded buffer to RGB: MJPEG (with or without Huffman tables), YUYV
/// (BT.601, limited range) or packed RGB.
pub fn decode_rgb(header: &DumpHeader, payload: &[u8]) -> Result<RgbImage, String> {
    let (w, h) = (header.width as usize, header.height as usize);
    match &header.fourcc {
        b"MJPG" | b"JPEG" => {
            check_frame_size(header)?;
            if !jpeg_is_complete(payload) {
                return Err(format!(
                    "the JPEG of {} bytes is not whole (no end-of-image marker after its scan: cut off?)",
                    payload.len()
                ));
            }
            decode_jpeg(&with_huffman_tables(payload), w, h)
        }
        b"YUYV" => {
            let stride = packed_stride(header, 2, payload.len())?;
            let mut out = vec![0u8; w * h * 3];
            for (row, dst) in payload.chunks(stride).zip(out.chunks_exact_mut(3 * w)) {
                yuyv_row_to_rgb(&row[..2 * w], dst);
            }
            RgbImage::from_raw(w as u32, h as u32, out).ok_or_else(|| "size".to_string())
        }
        b"RGB3" => {
            let stride = packed_stride(header, 3, payload.len())?;
            let mut out = Vec::with_capacity(w * h * 3);
            for y in 0..h {
                out.extend_from_slice(&payload[y * stride..y * stride + 3 * w]);
            }
            RgbImage::from_raw(w as u32, h as u32, out).ok_or_else(|| "size".to_string())
        }
        other => Err(format!("unsupported pixel format {}", fourcc_str(*other))),
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;

    /// A 320x240 image textured so that its JPEG's scan is most of the file (a third of
    /// the file ends inside the scan, which a decoder fills with grey unasked).
    pub(crate) fn textured_image() -> RgbImage {
        RgbImage::from_fn(320, 240, |x, y| {
            image::Rgb([
                (x * 7 % 256) as u8,
                (y * 5 % 256) as u8,
                ((x ^ y) % 256) as u8,
            ])
        })
    }

    pub(crate) fn header() -> DumpHeader {
        DumpHeader {
            fourcc: *b"RGB3",
            width: 4,
            height: 2,
            bytes_per_line: 12,
            interval_num: 1,
            interval_den: 30,
            device: "/dev/video0".into(),
            card: "Test camera".into(),
        }
    }

    fn write(path: &Path, frames: u32) {
        let mut w = DumpWriter::create(path, &header()).expect("create");
        for i in 0..frames {
            let payload: Vec<u8> = (0..24).map(|k| (k as u32 * 7 + i) as u8).collect();
            w.write_frame(100 + i, 1_000_000 * i as u64, 1, &payload)
                .expect("write");
        }
        w.finish().expect("finish");
    }

    #[test]
    fn yuyv_fixed_point_matches_the_float_formula() {
        let mut worst = 0i32;
        for y in (0..=255u8).step_by(3) {
            for u in (0..=255u8).step_by(5) {
                for v in (0..=255u8).step_by(5) {
                    let mut rgb = [0u8; 6];
                    yuyv_row_to_rgb(&[y, u, y, v], &mut rgb);
                    let c = 1.164 * (f32::from(y) - 16.0);
                    let (u, v) = (f32::from(u) - 128.0, f32::from(v) - 128.0);
                    let want = [c + 1.596 * v, c - 0.392 * u - 0.813 * v, c + 2.017 * u];
                    for k in 0..3 {
                        let w = want[k].round().clamp(0.0, 255.0) as i32;
                        worst = worst.max((i32::from(rgb[k]) - w).abs());
                        assert_eq!(rgb[k], rgb[k + 3], "both pixels of a pair share chroma");
                    }
                }
            }
        }
        assert!(worst <= 1, "fixed point off by {worst} grey levels");
    }

    #[test]
    fn round_trip_keeps_header_and_every_record() {
        let dir = tempfile::tempdir().expect("tempdir");
        let p = dir.path().join("a.dump");
        write(&p, 3);
        let mut r = DumpReader::open(&p).expect("open");
        assert_eq!(r.header(), &header());
        for i in 0..3u32 {
            let rec = r.next_record().expect("ok").expect("record");
            assert_eq!(rec.sequence, 100 + i);
            assert_eq!(rec.timestamp_nanos, 1_000_000 * i as u64);
            assert_eq!(rec.payload[1], (7 + i) as u8);
            let img = decode_rgb(r.header(), &rec.payload).expect("decode");
            assert_eq!(
                img.get_pixel(1, 0).0,
                [(21 + i) as u8, (28 + i) as u8, (35 + i) as u8]
            );
        }
        assert!(r.next_record().expect("clean end").is_none());
    }

    #[test]
    fn a_cut_off_dump_reads_to_its_last_whole_frame_and_says_where() {
        let dir = tempfile::tempdir().expect("tempdir");
        let p = dir.path().join("a.dump");
        write(&p, 3);
        let bytes = std::fs::read(&p).expect("read");
        std::fs::write(&p, &bytes[..bytes.len() - 10]).expect("cut");
        let (_, offsets, end) = DumpReader::index(&p).expect("index");
        assert_eq!(offsets.len(), 2);
        let err = end.expect("stopped early");
        assert!(
            matches!(err, DumpError::Truncated { index: 2, .. }),
            "{err}"
        );
        assert!(err.to_string().contains("after 2 whole frames"), "{err}");
    }

    #[test]
    fn a_corrupted_record_is_detected_not_decoded() {
        let dir = tempfile::tempdir().expect("tempdir");
        let p = dir.path().join("a.dump");
        write(&p, 3);
        let mut bytes = std::fs::read(&p).expect("read");
        let header_len = header().to_bytes().len();
        let second = header_len + 24 + 24 + 4;
        bytes[second + 30] ^= 0x55; // a payload byte of record 1
        std::fs::write(&p, &bytes).expect("write");
        let (_, offsets, end) = DumpReader::index(&p).expect("index");
        assert_eq!(offsets.len(), 1);
        let err = end.expect("stopped");
        assert!(
            matches!(&err, DumpError::Corrupt { index: 1, offset, .. } if *offset == second as u64),
            "{err}"
        );
        // Garbage instead of a header.
        std::fs::write(
            &p,
            b"PK\x03\x04 not a dump at all....................................",
        )
        .expect("write");
        assert!(matches!(
            DumpReader::open(&p),
            Err(DumpError::NotADump { .. })
        ));
        // A damaged header.
        let mut head = header().to_bytes();
        head[21] ^= 1;
        std::fs::write(&p, &head).expect("write");
        let err = DumpReader::open(&p).err().expect("bad header");
        assert!(err.to_string().contains("checksum"), "{err}");
    }

    #[test]
    fn mjpeg_without_huffman_tables_decodes_with_the_standard_ones() {
        let img = RgbImage::from_fn(64, 48, |x, y| {
            image::Rgb([(x * 4) as u8, (y * 5) as u8, ((x + y) * 2) as u8])
        });
        let mut jpeg = Vec::new();
        image::codecs::jpeg::JpegEncoder::new_with_quality(&mut jpeg, 85)
            .encode_image(&img)
            .expect("encode");
        // Strip every DHT segment, as table-less webcams send them.
        let (segments, _) = jpeg_segments(&jpeg).expect("parses");
        let mut stripped = jpeg.clone();
        for (m, a, b) in segments.iter().rev() {
            if *m == 0xC4 {
                stripped.drain(*a..*b);
            }
        }
        assert!(stripped.len() < jpeg.len());
        assert!(
            image::load_from_memory_with_format(&stripped, image::ImageFormat::Jpeg).is_err(),
            "a frame without tables should not decode as it is"
        );
        let header = DumpHeader {
            fourcc: *b"MJPG",
            width: 64,
            height: 48,
            bytes_per_line: 0,
            ..header()
        };
        let want = decode_rgb(&header, &jpeg).expect("original");
        let got = decode_rgb(&header, &stripped).expect("tables inserted");
        assert_eq!(got, want);
        // A frame that has its tables is passed through untouched.
        assert!(matches!(
            with_huffman_tables(&jpeg),
            std::borrow::Cow::Borrowed(_)
        ));
    }

    /// The straight decoder gives the very pixels the `image` crate's JPEG decoder
    /// gives, for colour (4:2:0, as MJPEG cameras send) and grey frames, and a frame of
    /// another size than the header's is refused with both sizes named.
    #[test]
    fn jpeg_decodes_as_the_image_crate_does() {
        let (w, h) = (67u32, 45u32);
        let colour = RgbImage::from_fn(w, h, |x, y| {
            image::Rgb([(x * 3) as u8, (y * 5 + x) as u8, (200 - x - y) as u8])
        });
        let grey = image::GrayImage::from_fn(w, h, |x, y| image::Luma([(x * 2 + y) as u8]));
        let mut jpegs = Vec::new();
        for img in [image::DynamicImage::from(colour), grey.into()] {
            let mut jpeg = Vec::new();
            image::codecs::jpeg::JpegEncoder::new_with_quality(&mut jpeg, 80)
                .encode_image(&img)
                .expect("encode");
            jpegs.push(jpeg);
        }
        let header = DumpHeader {
            fourcc: *b"MJPG",
            width: w,
            height: h,
            bytes_per_line: 0,
            ..header()
        };
        for jpeg in &jpegs {
            let want = image::load_from_memory_with_format(jpeg, image::ImageFormat::Jpeg)
                .expect("image decodes")
                .into_rgb8();
            assert_eq!(decode_rgb(&header, jpeg).expect("decodes"), want);
        }
        let wider = DumpHeader {
            width: w + 1,
            ..header
        };
        let err = decode_rgb(&wider, &jpegs[0]).expect_err("another size");
        assert!(err.contains("67x45") && err.contains("68x45"), "{err}");
    }

    #[test]
    fn yuyv_decodes_grey_and_colour() {
        let h = DumpHeader {
            fourcc: *b"YUYV",
            width: 2,
            height: 1,
            bytes_per_line: 4,
            ..header()
        };
        // Mid grey (Y=126, U=V=128) and, in the same pair, the same chroma.
        let img = decode_rgb(&h, &[126, 128, 126, 128]).expect("decode");
        assert_eq!(img.get_pixel(0, 0).0, [128, 128, 128]);
        // Pure-ish red: Y=81, U=90, V=240 (BT.601 limited range).
        let img = decode_rgb(&h, &[81, 90, 81, 240]).expect("decode");
        let p = img.get_pixel(0, 0).0;
        assert!(p[0] > 240 && p[1] < 15 && p[2] < 15, "{p:?}");
        assert!(decode_rgb(&h, &[1, 2]).is_err());
    }

    fn header_bytes(h: &DumpHeader) -> Vec<u8> {
        h.to_bytes()
    }

    #[test]
    fn a_header_whose_frame_size_overflows_is_refused_with_a_message() {
        let dir = tempfile::tempdir().expect("tempdir");
        let p = dir.path().join("a.dump");
        for (fourcc, w, h, bpl) in [
            (*b"YUYV", 4_294_901_823, 2_147_516_385, 0),
            (*b"RGB3", 4_294_901_823, 1_431_677_590, 0),
            (*b"MJPG", 65_535, 65_535, 0),
            (*b"RGB3", 640, 480, u32::MAX),
            (*b"YUYV", 640, 480, 100),
        ] {
            let h = DumpHeader {
                fourcc,
                width: w,
                height: h,
                bytes_per_line: bpl,
                ..header()
            };
            std::fs::write(&p, header_bytes(&h)).expect("write");
            let err = DumpReader::open(&p).err().expect("refused");
            assert!(matches!(err, DumpError::Header { .. }), "{err}");
            assert!(err.to_string().contains(&w.to_string()), "{err}");
            // decode_rgb is refused too, for headers from elsewhere (a device).
            assert!(decode_rgb(&h, &[0; 64]).is_err());
            assert_eq!(frame_capacity(&h), None);
        }
        // A sane 4K RGB header passes, and its ring slot is what a frame needs.
        let h = DumpHeader {
            fourcc: *b"RGB3",
            width: 3840,
            height: 2160,
            bytes_per_line: 0,
            ..header()
        };
        assert_eq!(frame_capacity(&h), Some(3840 * 2160 * 3));
    }

    #[test]
    fn a_cut_off_jpeg_is_not_decoded_as_a_grey_frame() {
        let img = textured_image();
        let mut jpeg = Vec::new();
        image::codecs::jpeg::JpegEncoder::new_with_quality(&mut jpeg, 85)
            .encode_image(&img)
            .expect("encode");
        let header = DumpHeader {
            fourcc: *b"MJPG",
            width: 320,
            height: 240,
            bytes_per_line: 0,
            ..header()
        };
        assert!(jpeg_is_complete(&jpeg));
        decode_rgb(&header, &jpeg).expect("whole");
        let third = &jpeg[..jpeg.len() / 3];
        // Cut inside the scan, where the decoder fills the rest with grey unasked.
        let scan = jpeg_segments(&jpeg).expect("segments").1;
        assert!(scan < third.len(), "scan at {scan} of {}", third.len());
        assert!(!jpeg_is_complete(third));
        let err = decode_rgb(&header, third).expect_err("cut off");
        assert!(err.contains("end-of-image"), "{err}");
    }

    #[test]
    fn parse_reads_a_dump_from_memory_like_the_file_reader() {
        let dir = tempfile::tempdir().expect("tempdir");
        let p = dir.path().join("a.dump");
        write(&p, 3);
        let bytes = std::fs::read(&p).expect("read");
        let (h, records, end) = parse(&bytes).expect("parse");
        assert_eq!(h, header());
        assert_eq!(records.len(), 3);
        assert!(end.is_none());
        // A record claiming 64 MiB in a short file is cut off, not allocated.
        let mut cut = bytes[..header().to_bytes().len()].to_vec();
        cut.extend_from_slice(b"FRAM");
        cut.extend_from_slice(&[0; 16]);
        cut.extend_from_slice(&MAX_PAYLOAD.to_le_bytes());
        let (_, records, end) = parse(&cut).expect("parse");
        assert!(records.is_empty());
        assert!(matches!(end, Some(DumpError::Truncated { .. })), "{end:?}");
    }
}
