//! The `crossline` command line. Each subcommand lives in `src/bin/crossline/<name>.rs`
//! with its clap arguments and its `run`; library errors become `anyhow` errors with
//! context here and nowhere else.

use std::io::IsTerminal;
use std::process::ExitCode;

use clap::{Parser, Subcommand};

/// `println!` that returns an error instead of panicking when stdout is closed (a
/// pipe into `head`); `main` ends quietly with success on a broken pipe.
#[macro_export]
macro_rules! outln {
    ($($arg:tt)*) => {{
        use std::io::Write as _;
        anyhow::Context::context(
            writeln!(std::io::stdout().lock(), $($arg)*),
            "writing to standard output",
        )?;
    }};
}

mod compare;
mod demo;
mod device;
mod extract;
#[cfg(target_os = "linux")]
mod feed;
mod inspect;
mod reconstruct;
#[cfg(target_os = "linux")]
mod record;
mod serve;
mod simulate;
mod status;
mod tail;

/// Turn a fixed camera and a hand-held cross line laser into a 3D scanner, with no
/// calibration of the laser.
///
/// Try it without a camera: `crossline demo` simulates, reconstructs and checks a
/// scan of a built-in scene. By hand:
///
///   crossline simulate --scene room --frames 200 --out sim
///   crossline reconstruct --input sim --camera sim/camera.yml --out cloud.ply
///   crossline compare cloud.ply --truth sim
///
/// With a camera (Linux, V4L2):
///
///   crossline record --device /dev/video0 --out dive.dump --seconds 60
///   crossline feed --device /dev/video10 --input dive.dump --loop
#[derive(Parser)]
#[command(name = "crossline", version, about, long_about, verbatim_doc_comment)]
struct Cli {
    /// More log output (-v debug, -vv trace); RUST_LOG overrides.
    #[arg(short, long, global = true, action = clap::ArgAction::Count)]
    verbose: u8,
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    Demo(demo::Args),
    Simulate(simulate::Args),
    Compare(compare::Args),
    Extract(extract::Args),
    Reconstruct(reconstruct::Args),
    Serve(serve::Args),
    Status(status::Args),
    Tail(tail::Args),
    Inspect(inspect::Args),
    #[cfg(target_os = "linux")]
    Record(record::Args),
    #[cfg(target_os = "linux")]
    Feed(feed::Args),
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    faer::set_global_parallelism(faer::Par::Seq);
    init_logging(cli.verbose);
    let result = match cli.command {
        Command::Demo(args) => demo::run(args),
        Command::Simulate(args) => simulate::run(args),
        Command::Compare(args) => compare::run(args),
        Command::Extract(args) => extract::run(args),
        Command::Reconstruct(args) => reconstruct::run(args),
        Command::Serve(args) => serve::run(args),
        Command::Status(args) => status::run(args),
        Command::Tail(args) => tail::run(args),
        Command::Inspect(args) => inspect::run(args),
        #[cfg(target_os = "linux")]
        Command::Record(args) => record::run(args),
        #[cfg(target_os = "linux")]
        Command::Feed(args) => feed::run(args),
    };
    match result {
        Ok(code) => code,
        // The reader of our output went away (`| head`): nothing is wrong.
        Err(err) if is_broken_pipe(&err) => ExitCode::SUCCESS,
        Err(err) => {
            eprintln!("crossline: error: {}", error_chain(&err));
            ExitCode::FAILURE
        }
    }
}

fn is_broken_pipe(err: &anyhow::Error) -> bool {
    err.chain().any(|c| {
        c.downcast_ref::<std::io::Error>()
            .is_some_and(|e| e.kind() == std::io::ErrorKind::BrokenPipe)
    })
}

/// `{err:#}` without repeats: the library's errors put their cause in their message
/// and also return it as `source()`, which `{:#}` would print a second time.
fn error_chain(err: &anyhow::Error) -> String {
    let mut out = String::new();
    for cause in err.chain() {
        let text = cause.to_string();
        if out.ends_with(&text) {
            continue;
        }
        if !out.is_empty() {
            out.push_str(": ");
        }
        out.push_str(&text);
    }
    out
}

/// A flag that SIGINT and SIGTERM raise, for loops that stop cleanly between frames.
#[cfg(target_os = "linux")]
fn stop_on_signals() -> anyhow::Result<std::sync::Arc<std::sync::atomic::AtomicBool>> {
    use anyhow::Context;
    let stop = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
    for signal in [signal_hook::consts::SIGINT, signal_hook::consts::SIGTERM] {
        // A second signal, while the first is still being honoured, ends the process
        // (exit code 1), in case it is stuck in a blocking call.
        signal_hook::flag::register_conditional_shutdown(signal, 1, std::sync::Arc::clone(&stop))
            .context("installing the SIGINT/SIGTERM handler")?;
        signal_hook::flag::register(signal, std::sync::Arc::clone(&stop))
            .context("installing the SIGINT/SIGTERM handler")?;
    }
    Ok(stop)
}

fn init_logging(verbose: u8) {
    let default = match verbose {
        0 => "info",
        1 => "debug",
        _ => "trace",
    };
    let filter = tracing_subscriber::EnvFilter::try_from_default_env()
        .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new(default));
    tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_writer(std::io::stderr)
        // Colour codes only for a person at a terminal: journald, files and pipes
        // would keep them as `\x1b[2m` noise.
        .with_ansi(std::io::stderr().is_terminal())
        .with_target(false)
        .init();
}
