//! Logs on stderr, as text for people or as JSON lines for collectors (`--log-format`).
//!
//! Colour only when stderr is a terminal and `NO_COLOR` is unset or empty (no escape codes in
//! files or journald). Every line names the daemon (`set_daemon`, once its id is known): text
//! lines start with it, JSON lines carry it as `daemon`, with the fields of the spans the event
//! is in (`epoch`, `frame`, …) under `span`.

use std::fmt::Write as _;
use std::io::IsTerminal;
use std::sync::OnceLock;
use tracing::field::{Field, Visit};
use tracing::{Event, Subscriber};
use tracing_subscriber::fmt::format::{DefaultFields, Format, JsonFields, Writer};
use tracing_subscriber::fmt::time::{FormatTime, SystemTime};
use tracing_subscriber::fmt::{FmtContext, FormatEvent, FormatFields, FormattedFields};
use tracing_subscriber::registry::LookupSpan;

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LogFormat {
    /// Lines for people (coloured on a terminal).
    Text,
    /// One JSON object per line: timestamp, level, target, daemon, message, fields, span.
    Json,
}

impl std::str::FromStr for LogFormat {
    type Err = String;

    /// `text` or `json` (`--log-format`, `LIGHTFOLD_LOG_FORMAT`).
    fn from_str(s: &str) -> Result<LogFormat, String> {
        match s {
            "text" => Ok(LogFormat::Text),
            "json" => Ok(LogFormat::Json),
            other => Err(format!("{other:?} is not a log format: text or json")),
        }
    }
}

static DAEMON: OnceLock<String> = OnceLock::new();
static JSON: std::sync::atomic::AtomicBool = std::sync::atomic::AtomicBool::new(false);

/// Whether logs are JSON lines: then progress lines go through the log too, as events, so
/// stderr stays one JSON object per line.
pub fn json() -> bool {
    JSON.load(std::sync::atomic::Ordering::Relaxed)
}

/// Names this process's daemon in every line logged from now on (first call wins).
pub fn set_daemon(id: &str) {
    let _ = DAEMON.set(id.to_string());
}

/// Whether escape codes may go to stderr: a terminal, and `NO_COLOR` unset or empty
/// (<https://no-color.org>).
pub fn colour(stderr_is_terminal: bool, no_color: Option<std::ffi::OsString>) -> bool {
    stderr_is_terminal && no_color.is_none_or(|v| v.is_empty())
}

/// Installs the process's logger: `default` as the filter unless `RUST_LOG` says otherwise, lines
/// on stderr in `format`.
pub fn init(default: &str, format: LogFormat) {
    let filter = tracing_subscriber::EnvFilter::try_from_default_env()
        .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new(default));
    let builder = tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_writer(std::io::stderr);
    let _ = match format {
        LogFormat::Text => {
            let ansi = colour(
                std::io::stderr().is_terminal(),
                std::env::var_os("NO_COLOR"),
            );
            builder
                .with_ansi(ansi)
                .fmt_fields(DefaultFields::new())
                .event_format(Text(Format::default().with_target(false).with_ansi(ansi)))
                .try_init()
        }
        LogFormat::Json => {
            JSON.store(true, std::sync::atomic::Ordering::Relaxed);
            builder
                .with_ansi(false)
                .fmt_fields(JsonFields::new())
                .event_format(Json)
                .try_init()
        }
    };
}

/// The usual text line, after the daemon's id.
struct Text(Format);

impl<S, N> FormatEvent<S, N> for Text
where
    S: Subscriber + for<'a> LookupSpan<'a>,
    N: for<'a> FormatFields<'a> + 'static,
{
    fn format_event(
        &self,
        ctx: &FmtContext<'_, S, N>,
        mut w: Writer<'_>,
        event: &Event<'_>,
    ) -> std::fmt::Result {
        if let Some(id) = DAEMON.get() {
            write!(w, "{id} ")?;
        }
        self.0.format_event(ctx, w, event)
    }
}

/// One JSON object per event.
struct Json;

impl<S, N> FormatEvent<S, N> for Json
where
    S: Subscriber + for<'a> LookupSpan<'a>,
    N: for<'a> FormatFields<'a> + 'static,
{
    fn format_event(
        &self,
        ctx: &FmtContext<'_, S, N>,
        mut w: Writer<'_>,
        event: &Event<'_>,
    ) -> std::fmt::Result {
        let mut ts = String::new();
        SystemTime.format_time(&mut Writer::new(&mut ts))?;
        let meta = event.metadata();
        let mut line = serde_json::Map::new();
        line.insert("timestamp".into(), ts.into());
        line.insert("level".into(), meta.level().as_str().into());
        line.insert("target".into(), meta.target().into());
        if let Some(id) = DAEMON.get() {
            line.insert("daemon".into(), id.as_str().into());
        }
        let mut fields = Fields(serde_json::Map::new());
        event.record(&mut fields);
        let mut fields = fields.0;
        if let Some(m) = fields.remove("message") {
            line.insert("message".into(), m);
        }
        if !fields.is_empty() {
            line.insert("fields".into(), fields.into());
        }
        // The fields of every span the event is in, outermost first (inner ones win).
        let mut span = serde_json::Map::new();
        if let Some(scope) = ctx.event_scope() {
            for s in scope.from_root() {
                span.insert("name".into(), s.name().into());
                let ext = s.extensions();
                let Some(f) = ext.get::<FormattedFields<N>>() else {
                    continue;
                };
                if let Ok(serde_json::Value::Object(m)) = serde_json::from_str(f.as_str()) {
                    span.extend(m);
                }
            }
        }
        if !span.is_empty() {
            line.insert("span".into(), span.into());
        }
        let text = serde_json::to_string(&line).map_err(|_| std::fmt::Error)?;
        writeln!(w, "{text}")
    }
}

/// An event's fields as JSON values.
struct Fields(serde_json::Map<String, serde_json::Value>);

impl Visit for Fields {
    fn record_debug(&mut self, field: &Field, value: &dyn std::fmt::Debug) {
        let mut s = String::new();
        let _ = write!(s, "{value:?}");
        self.0.insert(field.name().into(), s.into());
    }
    fn record_str(&mut self, field: &Field, value: &str) {
        self.0.insert(field.name().into(), value.into());
    }
    fn record_u64(&mut self, field: &Field, value: u64) {
        self.0.insert(field.name().into(), value.into());
    }
    fn record_i64(&mut self, field: &Field, value: i64) {
        self.0.insert(field.name().into(), value.into());
    }
    fn record_f64(&mut self, field: &Field, value: f64) {
        self.0.insert(field.name().into(), value.into());
    }
    fn record_bool(&mut self, field: &Field, value: bool) {
        self.0.insert(field.name().into(), value.into());
    }
    fn record_error(&mut self, field: &Field, value: &(dyn std::error::Error + 'static)) {
        self.0.insert(field.name().into(), value.to_string().into());
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn colour_only_on_a_terminal_without_no_color() {
        assert!(colour(true, None));
        assert!(colour(true, Some("".into())));
        assert!(!colour(true, Some("1".into())));
        assert!(!colour(false, None));
    }

    #[test]
    fn json_lines_carry_the_daemon_fields_and_spans() {
        use std::sync::{Arc, Mutex};
        #[derive(Clone, Default)]
        struct Buf(Arc<Mutex<Vec<u8>>>);
        impl std::io::Write for Buf {
            fn write(&mut self, b: &[u8]) -> std::io::Result<usize> {
                self.0.lock().unwrap().extend_from_slice(b);
                Ok(b.len())
            }
            fn flush(&mut self) -> std::io::Result<()> {
                Ok(())
            }
        }
        let buf = Buf::default();
        let out = buf.clone();
        let subscriber = tracing_subscriber::fmt()
            .with_writer(move || out.clone())
            .with_ansi(false)
            .fmt_fields(JsonFields::new())
            .event_format(Json)
            .finish();
        set_daemon("node-7");
        tracing::subscriber::with_default(subscriber, || {
            let span = tracing::info_span!("frame", epoch = 3u64, frame = 12u64);
            let _g = span.enter();
            tracing::warn!(bytes = 42u64, peer = "comp-1", "band \"late\"");
        });
        let text = String::from_utf8(buf.0.lock().unwrap().clone()).unwrap();
        let line: serde_json::Value = serde_json::from_str(text.trim()).unwrap();
        assert_eq!(line["level"], "WARN");
        assert_eq!(line["message"], "band \"late\"");
        assert_eq!(line["daemon"], "node-7");
        assert_eq!(line["fields"]["bytes"], 42);
        assert_eq!(line["fields"]["peer"], "comp-1");
        assert_eq!(line["span"]["epoch"], 3);
        assert_eq!(line["span"]["frame"], 12);
        assert_eq!(line["span"]["name"], "frame");
        assert!(line["timestamp"].as_str().unwrap().starts_with("20"));
    }
}
