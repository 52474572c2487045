//! `decode_rgb` for MJPG, YUYV and RGB3 buffers under arbitrary small headers.
#![no_main]
use crossline::capture::dump::{decode_rgb, DumpHeader};
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    if data.len() < 7 {
        return;
    }
    let fourcc = match data[0] % 3 {
        0 => *b"MJPG",
        1 => *b"YUYV",
        _ => *b"RGB3",
    };
    let header = DumpHeader {
        fourcc,
        width: u32::from(u16::from_le_bytes([data[1], data[2]])),
        height: u32::from(u16::from_le_bytes([data[3], data[4]])),
        bytes_per_line: u32::from(u16::from_le_bytes([data[5], data[6]])),
        interval_num: 1,
        interval_den: 30,
        device: String::new(),
        card: String::new(),
    };
    if let Ok(img) = decode_rgb(&header, &data[7..]) {
        assert_eq!(img.dimensions(), (header.width, header.height));
    }
});
