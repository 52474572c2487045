//! The daemon's checkpoint log (`curves.log`) as a resume reads it.
#![no_main]
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let path = std::path::Path::new("curves.log");
    if let Ok(log) = crossline::serve::checkpoint::read_log(data, path, 640, 480) {
        assert!(log.whole_bytes <= data.len());
    }
});
