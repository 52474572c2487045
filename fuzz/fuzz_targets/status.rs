//! Status socket lines as `crossline status` reads them.
#![no_main]
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let mut r = data;
    let mut line = String::new();
    while let Ok(Some(_)) = crossline::serve::status::read_line(&mut r, &mut line) {}
});
