//! Helpers shared by the integration tests.

#![allow(dead_code)]

use std::path::PathBuf;
use std::process::Command;

/// The `crossline` binary Cargo built for these tests.
pub fn crossline() -> Command {
    Command::new(env!("CARGO_BIN_EXE_crossline"))
}

/// The project's `fixtures/` folder.
pub fn fixtures() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("fixtures")
}

/// Runs a command that must succeed; on failure, panics with its output.
pub fn run_ok(cmd: &mut Command) -> std::process::Output {
    let out = cmd.output().expect("spawn crossline");
    assert!(
        out.status.success(),
        "{cmd:?} failed ({}):\n{}\n{}",
        out.status,
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    out
}

/// Runs a command that must fail cleanly (exit code 1, not a panic) and returns its
/// standard error.
pub fn stderr_of_failure(cmd: &mut Command) -> String {
    let out = cmd.output().expect("spawn crossline");
    let err = String::from_utf8_lossy(&out.stderr).into_owned();
    assert_eq!(
        out.status.code(),
        Some(1),
        "{cmd:?}: expected a clean failure:\n{err}"
    );
    assert!(!err.contains("panicked"), "{cmd:?} panicked:\n{err}");
    err
}

/// `crossline reconstruct --input INPUT --camera CAMERA --out OUT`; add more arguments
/// to the returned command.
pub fn reconstruct(
    input: &std::path::Path,
    camera: &std::path::Path,
    out: &std::path::Path,
) -> Command {
    let mut cmd = crossline();
    cmd.args(["reconstruct", "--input"])
        .arg(input)
        .arg("--camera")
        .arg(camera)
        .arg("--out")
        .arg(out);
    cmd
}

/// A TCP port free on loopback a moment ago (for a child process to bind).
pub fn free_port() -> u16 {
    std::net::TcpListener::bind("127.0.0.1:0")
        .and_then(|l| l.local_addr())
        .expect("a free port")
        .port()
}
