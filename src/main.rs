//! The `btfquilt` command line: parses arguments and calls the library.

use clap::Parser;

mod cli;

use cli::{run, Cli};

fn main() {
    one_malloc_arena();
    let result = run(Cli::parse());
    for r in btfquilt::io::staging::take_removed_partials() {
        eprintln!(
            "note: removed {} ({}), a partial output left by process {} that no longer runs",
            r.path.display(),
            btfquilt::container::human_bytes(r.bytes),
            r.pid
        );
    }
    if let Err(e) = result {
        eprintln!("error: {}", error_chain(&e));
        std::process::exit(1);
    }
}

/// The C library's allocator (glibc) gives each thread that meets
/// contention an arena of its own and keeps what that thread frees there, so
/// with work patches computed on several threads the process held up to twice
/// its live heap (a 128 MiB budget peaked at 286 MB with a 140 MB heap).
/// The variable `MALLOC_ARENA_MAX` is read only when the process starts,
/// so unless the user set it the binary runs itself again in place (`exec`,
/// same process id) with one arena. Nothing else changes: outputs never
/// depend on the allocator. If the `exec` fails, it carries on as it is.
fn one_malloc_arena() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    {
        use std::os::unix::process::CommandExt;
        if std::env::var_os("MALLOC_ARENA_MAX").is_some() {
            return;
        }
        let Ok(exe) = std::env::current_exe() else {
            return;
        };
        let mut args = std::env::args_os();
        let arg0 = args.next().unwrap_or_else(|| exe.clone().into_os_string());
        // (returns only on failure)
        let _ = std::process::Command::new(&exe)
            .arg0(arg0)
            .args(args)
            .env("MALLOC_ARENA_MAX", "1")
            .exec();
    }
}

/// The error and its causes, `: `-separated, each said once (a cause whose
/// text its parent already ends with, such as an OS error the library's
/// message quotes, is not repeated).
fn error_chain(e: &anyhow::Error) -> String {
    let mut out = String::new();
    for cause in e.chain() {
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
