//! Integration tests: the real `crossline` binary on real files.

mod util;
