//! The `flowgate` command line: one module a subcommand, each parsing its flags with clap
//! and calling the library (probe-rs's split: the library does the work, the CLI says it).

#[cfg(feature = "lab")]
pub mod bench;
pub mod calibrate;
pub mod check;
pub mod ctl;
#[cfg(feature = "lab")]
pub mod demo;
pub mod logging;
#[cfg(feature = "lab")]
pub mod null_gateway;
#[cfg(feature = "lab")]
pub mod plan;
pub mod record;
pub mod replay;
pub mod run;

/// Print a line to standard output (`say!` as `println!`, `say_raw!` as `print!`). A closed
/// stdout (`| head`, `| true`) ends the command at once with the status of a writer whose
/// reader went away (141, as SIGPIPE gives a shell), never a panic; any other write error
/// ends it with a message.
macro_rules! say {
    () => { $crate::cli::write_out(format_args!("\n")) };
    ($($arg:tt)*) => { $crate::cli::write_out(format_args!("{}\n", format_args!($($arg)*))) };
}
macro_rules! say_raw {
    ($($arg:tt)*) => { $crate::cli::write_out(format_args!($($arg)*)) };
}
pub(crate) use {say, say_raw};

/// The exit status of a command whose standard output was closed under it.
pub const CLOSED_STDOUT: i32 = 141;

pub fn write_out(args: std::fmt::Arguments<'_>) {
    use std::io::Write as _;
    let mut out = std::io::stdout().lock();
    if let Err(e) = out.write_fmt(args).and_then(|()| out.flush()) {
        if e.kind() == std::io::ErrorKind::BrokenPipe {
            std::process::exit(CLOSED_STDOUT);
        }
        let _ = writeln!(std::io::stderr(), "Error: writing to standard output: {e}");
        std::process::exit(1);
    }
}
