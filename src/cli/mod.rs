//! The binary's command line: [`args`] parses, [`run`] calls the library.
//! (A module of `src/main.rs`, not of the library.)

/// Prints a line to stdout; a closed pipe (`btfquilt evaluate … | head`) is
/// not an error.
macro_rules! say {
    ($($t:tt)*) => {{
        use std::io::Write as _;
        let _ = writeln!(std::io::stdout(), $($t)*);
    }};
}

mod args;
mod bars;
mod run;

pub(crate) use args::Cli;
pub(crate) use run::run;
