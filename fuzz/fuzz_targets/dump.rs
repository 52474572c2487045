//! The dump reader (header and records) on arbitrary bytes: no panic, no allocation
//! beyond what the bytes hold (libFuzzer's -rss_limit_mb and -malloc_limit_mb).
#![no_main]
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    if let Ok((header, records, _)) = crossline::capture::dump::parse(data) {
        // Whatever opens must also decode (or refuse) without panicking.
        for r in records.iter().take(4) {
            let _ = crossline::capture::dump::decode_rgb(&header, &r.payload);
        }
    }
});
