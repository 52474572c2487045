//! A scan's files in `out_dir`: the lock that keeps one daemon per folder, the scan's
//! identity and `state/session.json` (version 1: `version`, `scan`, `input`, `width`,
//! `height`), which says whether an unfinished scan of the same input is resumed, and
//! the end of a scan: its state moved beside its cloud, its report written.

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use super::{checkpoint, ServeError, ServeOptions, ServeReport};

/// A scan's identity and where its files go.
pub(super) struct ScanFiles {
    pub id: String,
    pub state: PathBuf,
    pub cloud: PathBuf,
    pub report: PathBuf,
    pub recordings: PathBuf,
}

#[derive(Serialize, Deserialize)]
struct Session {
    version: u32,
    scan: String,
    input: String,
    width: u32,
    height: u32,
}

/// UTC time as `YYYYMMDDTHHMMSSZ` (civil-from-days, no time zone database needed).
fn utc_stamp() -> String {
    let secs = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_secs()) as i64;
    let (days, rem) = (secs.div_euclid(86_400), secs.rem_euclid(86_400));
    let z = days + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z - era * 146_097;
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let d = doy - (153 * mp + 2) / 5 + 1;
    let m = if mp < 10 { mp + 3 } else { mp - 9 };
    let y = yoe + era * 400 + i64::from(m <= 2);
    format!(
        "{y:04}{m:02}{d:02}T{:02}{:02}{:02}Z",
        rem / 3600,
        (rem / 60) % 60,
        rem % 60
    )
}

/// Finds the unfinished scan in `out_dir/state` (same input) or starts a new one.
pub(super) fn open_scan(
    opts: &ServeOptions,
    width: u32,
    height: u32,
) -> Result<(ScanFiles, bool), ServeError> {
    let io = |what, path: &Path| {
        let path = path.to_path_buf();
        move |source| ServeError::Io { what, path, source }
    };
    let state = opts.out_dir.join("state");
    std::fs::create_dir_all(&opts.out_dir).map_err(io("cannot create", &opts.out_dir))?;
    let session_path = state.join("session.json");
    let mut resumed = false;
    let mut id = None;
    if let Ok(text) = std::fs::read_to_string(&session_path) {
        match serde_json::from_str::<Session>(&text) {
            Ok(s) if s.input == opts.input_id && (s.width, s.height) == (width, height) => {
                id = Some(s.scan);
                resumed = true;
            }
            Ok(s) => {
                let aside = opts.out_dir.join(format!("{}.state", s.scan));
                tracing::warn!(
                    "{} holds an unfinished scan of another input ({}); keeping it in {}",
                    state.display(),
                    s.input,
                    aside.display()
                );
                std::fs::rename(&state, &aside).map_err(io("cannot move", &state))?;
            }
            Err(e) => {
                let aside = opts
                    .out_dir
                    .join(format!("unreadable-{}.state", utc_stamp()));
                tracing::warn!(
                    "{}: {e}; keeping that state in {}",
                    session_path.display(),
                    aside.display()
                );
                std::fs::rename(&state, &aside).map_err(io("cannot move", &state))?;
            }
        }
    }
    let id = id.unwrap_or_else(utc_stamp);
    std::fs::create_dir_all(&state).map_err(io("cannot create", &state))?;
    if !resumed {
        let s = Session {
            version: 1,
            scan: id.clone(),
            input: opts.input_id.clone(),
            width,
            height,
        };
        let text = serde_json::to_string_pretty(&s).unwrap_or_default();
        std::fs::write(&session_path, text).map_err(io("cannot write", &session_path))?;
    }
    Ok((
        ScanFiles {
            cloud: opts
                .cloud_path
                .clone()
                .unwrap_or_else(|| opts.out_dir.join(format!("{id}.ply"))),
            report: opts
                .report_path
                .clone()
                .unwrap_or_else(|| opts.out_dir.join(format!("{id}.json"))),
            recordings: opts.out_dir.join("recordings"),
            state,
            id,
        },
        resumed,
    ))
}

/// A resumed scan's checkpoint (nothing for a new scan), its state said in the log.
pub(super) fn resume_scan(
    scan: &ScanFiles,
    resumed: bool,
    width: u32,
    height: u32,
) -> Result<checkpoint::Resumed, ServeError> {
    if !resumed {
        return Ok(checkpoint::Resumed {
            background: None,
            frames: Vec::new(),
            stopped: None,
        });
    }
    let r = checkpoint::resume(&scan.state, width, height)?;
    if let Some(why) = &r.stopped {
        tracing::warn!("checkpoint ended early ({why}); those frames are processed again");
    }
    tracing::info!(
        scan = %scan.id,
        frames = r.frames.len(),
        "resuming the unfinished scan from its checkpoint"
    );
    Ok(r)
}

/// Open files kept only to be closed when they are needed (see [`RESERVED_FDS`]).
pub(super) struct FdReserve(Vec<std::fs::File>);

impl FdReserve {
    pub(super) fn new(n: usize) -> Self {
        Self(
            (0..n)
                .filter_map(|_| std::fs::File::open("/dev/null").ok())
                .collect(),
        )
    }

    pub(super) fn release(&mut self) {
        self.0.clear();
    }
}

/// Takes the exclusive lock of `out_dir` (`out_dir/lock`, holding the owner's pid),
/// for as long as the returned file lives.
pub(super) fn lock_out_dir(out_dir: &Path) -> Result<std::fs::File, ServeError> {
    use std::io::{Read, Seek, Write};
    let path = out_dir.join("lock");
    let io = |what| {
        let path = path.clone();
        move |source| ServeError::Io { what, path, source }
    };
    std::fs::create_dir_all(out_dir).map_err(io("cannot create the directory of"))?;
    let mut file = std::fs::OpenOptions::new()
        .read(true)
        .write(true)
        .create(true)
        .truncate(false)
        .open(&path)
        .map_err(io("cannot open"))?;
    match file.try_lock() {
        Ok(()) => {}
        Err(std::fs::TryLockError::WouldBlock) => {
            let mut pid = String::new();
            let _ = file.read_to_string(&mut pid);
            let pid = crate::truncate_echo(pid.trim());
            return Err(ServeError::Busy {
                path: out_dir.to_path_buf(),
                pid: if pid.is_empty() {
                    "unknown".into()
                } else {
                    pid
                },
            });
        }
        Err(std::fs::TryLockError::Error(e)) => return Err(io("cannot lock")(e)),
    }
    file.set_len(0).map_err(io("cannot write"))?;
    file.rewind().map_err(io("cannot write"))?;
    writeln!(file, "{}", std::process::id()).map_err(io("cannot write"))?;
    Ok(file)
}

pub(super) fn write_atomic(path: &Path, bytes: &[u8]) -> Result<(), ServeError> {
    let tmp = path.with_extension("tmp");
    let io = |what| {
        move |source| ServeError::Io {
            what,
            path: path.to_path_buf(),
            source,
        }
    };
    if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).map_err(io("cannot create the folder of"))?;
    }
    std::fs::write(&tmp, bytes).map_err(io("cannot write"))?;
    std::fs::rename(&tmp, path).map_err(io("cannot write"))
}

/// Ends a finished scan: its state moves beside its cloud (`<scan>.state`), and the
/// report is written atomically to its path.
pub(super) fn close(
    scan: &ScanFiles,
    out_dir: &Path,
    report: &ServeReport,
) -> Result<(), ServeError> {
    let done_state = out_dir.join(format!("{}.state", scan.id));
    let _ = std::fs::remove_dir_all(&done_state);
    if let Err(e) = std::fs::rename(&scan.state, &done_state) {
        tracing::warn!("cannot move {} aside: {e}", scan.state.display());
    }
    if report.decode_errors > 0 {
        tracing::warn!(
            "{} of {} frames could not be decoded and were skipped",
            report.decode_errors,
            report.frames_in
        );
    }
    let text = serde_json::to_string_pretty(report).unwrap_or_default();
    write_atomic(&scan.report, text.as_bytes())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_second_daemon_on_the_same_out_dir_is_refused_naming_the_first() {
        let dir = tempfile::tempdir().expect("tempdir");
        let held = lock_out_dir(dir.path()).expect("first");
        let err = lock_out_dir(dir.path()).expect_err("second");
        let msg = err.to_string();
        assert!(
            msg.contains(&format!("pid {}", std::process::id())),
            "{msg}"
        );
        drop(held);
        lock_out_dir(dir.path()).expect("free again once the first is gone");
    }
}
