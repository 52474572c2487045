//! PLY point clouds (ASCII and binary, either endianness).
#![no_main]
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    if let Ok(cloud) = crossline::ply::read_ply_from(data, "fuzz.ply") {
        assert!(cloud.len() <= data.len());
    }
});
