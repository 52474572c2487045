//! The cloud stream as a client reads it (`crossline tail`'s follower).
#![no_main]
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let mut follower = crossline::serve::stream::Follower::default();
    let mut r = data;
    while let Ok(Some(_)) = follower.step(&mut r) {}
    assert!(follower.points.len() <= data.len());
});
