//! Standard output for commands that print a lot (plans, tables, reports): when the reader goes
//! away (`lightfold plan | head`), the process ends quietly with status 0 instead of panicking
//! with `Broken pipe`. Rust ignores `SIGPIPE`, so a closed pipe shows up as a `BrokenPipe` write
//! error; [`Stdout`] turns that error into a quiet exit, and [`outln!`]/[`out!`] are `println!`
//! and `print!` through it.
//!
//! Use: `lightfold_telemetry::outln!("{plan}")` where `println!` was (a drop-in replacement), or `let mut
//! o = lightfold_telemetry::out::stdout();` and `writeln!(o, …)?` for many lines under one lock. An error that
//! reaches `main` with a `BrokenPipe` cause is a quiet exit too ([`is_broken_pipe`]).

use std::io::{self, Write};

/// Locked standard output that exits quietly when the reader has gone.
#[allow(missing_debug_implementations)]
pub struct Stdout {
    inner: io::StdoutLock<'static>,
}

/// Standard output, locked for the life of the value.
pub fn stdout() -> Stdout {
    Stdout {
        inner: io::stdout().lock(),
    }
}

/// Ends the process as a pipeline expects when its reader has gone: status 0, nothing on stderr.
pub fn reader_gone() -> ! {
    std::process::exit(0)
}

fn quiet<T>(r: io::Result<T>) -> io::Result<T> {
    match r {
        Err(e) if e.kind() == io::ErrorKind::BrokenPipe => reader_gone(),
        r => r,
    }
}

impl Write for Stdout {
    fn write(&mut self, buf: &[u8]) -> io::Result<usize> {
        quiet(self.inner.write(buf))
    }
    fn write_all(&mut self, buf: &[u8]) -> io::Result<()> {
        quiet(self.inner.write_all(buf))
    }
    fn flush(&mut self) -> io::Result<()> {
        quiet(self.inner.flush())
    }
}

/// Writes formatted text to standard output, as `print!` does; a closed pipe ends the process
/// quietly, any other write error panics as it does in `print!`.
pub fn print_fmt(args: std::fmt::Arguments<'_>) {
    let mut o = stdout();
    if let Err(e) = o.write_fmt(args).and_then(|()| o.flush()) {
        panic!("failed printing to stdout: {e}");
    }
}

/// Whether `e` (or any error it was caused by) is a write to a closed pipe.
pub fn is_broken_pipe(e: &anyhow::Error) -> bool {
    e.chain().any(|c| {
        c.downcast_ref::<io::Error>()
            .is_some_and(|io| io.kind() == io::ErrorKind::BrokenPipe)
    })
}

/// `println!` that ends the process quietly when standard output's reader has gone.
#[macro_export]
macro_rules! outln {
    () => {
        $crate::out::print_fmt(format_args!("\n"))
    };
    ($($arg:tt)*) => {
        $crate::out::print_fmt(format_args!("{}\n", format_args!($($arg)*)))
    };
}

/// `print!` that ends the process quietly when standard output's reader has gone.
#[macro_export]
macro_rules! out {
    ($($arg:tt)*) => {
        $crate::out::print_fmt(format_args!($($arg)*))
    };
}
