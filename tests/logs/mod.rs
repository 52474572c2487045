//! What the binary writes to stderr when stderr is not a terminal (journald, a file,
//! a pipe): plain log lines, no ANSI colour codes.

use crate::daemon::{dump, serve_on};
use crate::util::run_ok;

#[test]
fn logs_to_a_pipe_carry_no_colour_codes() {
    let tmp = tempfile::tempdir().expect("tempdir");
    // The live view on a free port: serve logs its address at INFO level.
    let out = run_ok(&mut serve_on(tmp.path(), &dump(), "max", "127.0.0.1:0"));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("INFO") && err.contains("live view at http://127.0.0.1:"),
        "expected log lines on stderr:\n{err}"
    );
    assert!(
        !err.contains('\x1b'),
        "colour codes in piped logs:\n{err:?}"
    );
}
