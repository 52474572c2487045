//! `crossline.toml`: parsing and the range checks of every key.
#![no_main]
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    if let Ok(text) = std::str::from_utf8(data) {
        if let Ok(c) = crossline::config::parse(text, std::path::Path::new("fuzz.toml")) {
            // Accepted numbers are within their bounds: durations convert.
            assert!(c.serve.checkpoint_interval_s.is_finite());
            assert!(c.serve.drain_timeout_s.is_finite());
            let _ = std::time::Duration::from_secs_f64(c.serve.checkpoint_interval_s);
            let _ = std::time::Duration::from_secs_f64(c.serve.drain_timeout_s);
        }
    }
});
