//! The `[camera]` table of crossline TOML camera files.
#![no_main]
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    if let Ok(text) = std::str::from_utf8(data) {
        if let Ok(c) = crossline::camera_file::parse_toml(text, std::path::Path::new("fuzz.toml")) {
            assert!(c.fx.is_finite() && c.fy.is_finite() && c.width > 0 && c.height > 0);
        }
    }
});
