//! Log lines that fit the host: levels from `RUST_LOG` (default `warn`), one line per event
//! on stderr; colours only on a terminal; under systemd's journal (stderr is the stream
//! `JOURNAL_STREAM` names) each line starts with its syslog priority (`<3>` error, `<4>`
//! warning, `<6>` info, `<7>` debug) and has no timestamp, so `journalctl -p warning`
//! filters them and the journal's own time is the only one.

use std::io::IsTerminal as _;

use tracing::{Event, Level, Subscriber};
use tracing_subscriber::fmt::format::Writer;
use tracing_subscriber::fmt::{FmtContext, FormatEvent, FormatFields};
use tracing_subscriber::registry::LookupSpan;
use tracing_subscriber::EnvFilter;

/// The journal's line format.
struct Journal;

impl<S, N> FormatEvent<S, N> for Journal
where
    S: Subscriber + for<'a> LookupSpan<'a>,
    N: for<'a> FormatFields<'a> + 'static,
{
    fn format_event(&self, ctx: &FmtContext<'_, S, N>, mut writer: Writer<'_>, event: &Event<'_>) -> std::fmt::Result {
        let priority = match *event.metadata().level() {
            Level::ERROR => 3,
            Level::WARN => 4,
            Level::INFO => 6,
            Level::DEBUG | Level::TRACE => 7,
        };
        write!(writer, "<{priority}>{}: ", event.metadata().target())?;
        ctx.field_format().format_fields(writer.by_ref(), event)?;
        writeln!(writer)
    }
}

/// Whether stderr is the journal stream systemd connected (`JOURNAL_STREAM=dev:inode`).
fn stderr_is_journal() -> bool {
    let Some(stream) = std::env::var_os("JOURNAL_STREAM") else { return false };
    let Ok(stat) = rustix::fs::fstat(std::io::stderr()) else { return false };
    stream.to_string_lossy() == format!("{}:{}", stat.st_dev, stat.st_ino)
}

pub fn init() {
    // The DDS library's own warnings narrate discovery (peers without locators, resends):
    // errors only, unless RUST_LOG asks for more. The Foxglove server's are about its
    // clients (one that resets its connection mid-handshake is logged as an error): off,
    // unless RUST_LOG asks for them.
    let filter = EnvFilter::try_from_default_env()
        .unwrap_or_else(|_| EnvFilter::new("warn,rustdds=error,ros2_client=error,foxglove::websocket::server=off"));
    let fmt = tracing_subscriber::fmt().with_env_filter(filter).with_writer(std::io::stderr);
    if stderr_is_journal() {
        fmt.event_format(Journal).init();
    } else {
        fmt.with_ansi(std::io::stderr().is_terminal()).init();
    }
}
