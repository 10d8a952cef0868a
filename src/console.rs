//! The user's console lines: writes to standard output and error that never panic.
//!
//! `println!` panics when standard output is closed or full (`palpate run … | head -1`,
//! `> /dev/full`), which would stop a run before it writes its files. These write what they
//! can and carry on: a closed pipe (the reader stopped reading) is silent, and any other
//! failure to write standard output is kept, for the command to report as its one-line
//! error once its work is done ([`stdout_failure`]).

use std::fmt;
use std::io::{self, Write};
use std::sync::OnceLock;

/// The first failure to write standard output other than a closed pipe.
static STDOUT_FAILURE: OnceLock<String> = OnceLock::new();

/// Write `args` and a newline to standard output (see the module docs).
pub fn out_line(args: fmt::Arguments) {
    write_out(format_args!("{args}\n"));
}

/// Write `args` to standard output as they are (see the module docs).
pub fn write_out(args: fmt::Arguments) {
    let mut out = io::stdout().lock();
    if let Err(e) = out.write_fmt(args).and_then(|()| out.flush()) {
        if e.kind() != io::ErrorKind::BrokenPipe {
            let _ = STDOUT_FAILURE.set(e.to_string());
        }
    }
}

/// Write `args` and a newline to standard error, ignoring a failure (there is nowhere left
/// to report it).
pub fn err_line(args: fmt::Arguments) {
    let _ = writeln!(io::stderr().lock(), "{args}");
}

/// The first failure to write standard output other than a closed pipe, as its OS message.
pub fn stdout_failure() -> Option<&'static str> {
    STDOUT_FAILURE.get().map(|s| s.as_str())
}

/// `println!` that never panics: [`out_line`].
#[macro_export]
macro_rules! say {
    () => {
        $crate::console::out_line(format_args!(""))
    };
    ($($arg:tt)*) => {
        $crate::console::out_line(format_args!($($arg)*))
    };
}

/// `eprintln!` that never panics: [`err_line`].
#[macro_export]
macro_rules! say_err {
    () => {
        $crate::console::err_line(format_args!(""))
    };
    ($($arg:tt)*) => {
        $crate::console::err_line(format_args!($($arg)*))
    };
}
