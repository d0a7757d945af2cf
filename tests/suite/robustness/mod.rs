//! Bad input, hostile and accidental: every command that reads a damaged,
//! crafted or oversized file, or is given an output that would destroy an
//! input, fails cleanly — non-zero exit, the file named, no panic or abort,
//! no hang, nothing left at `-o`. Plus seeded mutation loops over small valid
//! artifacts (`BTFQUILT_FUZZ_CASES` raises their count).

mod containers;
mod images;
mod json;
mod meshes;
mod outputs;

use std::path::Path;
use std::process::{Command, Output, Stdio};
use std::time::{Duration, Instant};

/// How long one bad-input run may take before it counts as a hang.
pub const HANG_LIMIT: Duration = Duration::from_secs(60);

/// Runs the built binary with `args` (and `--threads 1`-free defaults),
/// killing it after [`HANG_LIMIT`]; panics on a hang.
pub fn run_bounded(args: &[&str]) -> Output {
    let mut child = Command::new(env!("CARGO_BIN_EXE_btfquilt"))
        .args(args)
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("runs");
    let start = Instant::now();
    loop {
        if child.try_wait().expect("waits").is_some() {
            return child.wait_with_output().expect("collects");
        }
        if start.elapsed() > HANG_LIMIT {
            let _ = child.kill();
            let out = child.wait_with_output().expect("collects");
            panic!(
                "btfquilt {args:?} hung for over {HANG_LIMIT:?}: {}",
                String::from_utf8_lossy(&out.stderr)
            );
        }
        std::thread::sleep(Duration::from_millis(20));
    }
}

/// Asserts that `btfquilt args` refused cleanly: a non-zero exit that is not
/// a signal (no abort, no SIGBUS/SIGSEGV), no panic message, standard error
/// naming every needle (the file, what is wrong), and — when `output` is
/// given — nothing new at that path. Returns standard error.
pub fn refuses(args: &[&str], needles: &[&str], output: Option<&Path>) -> String {
    let existed = output.map(|p| std::fs::read(p).ok());
    let out = run_bounded(args);
    let stderr = String::from_utf8_lossy(&out.stderr).into_owned();
    assert!(
        out.status.code().is_some_and(|c| c != 0),
        "btfquilt {args:?} should fail with an exit code, got {:?}: {stderr}",
        out.status
    );
    assert!(
        !stderr.contains("panicked") && !stderr.contains("RUST_BACKTRACE"),
        "btfquilt {args:?} panicked: {stderr}"
    );
    for n in needles {
        assert!(
            stderr.contains(n),
            "btfquilt {args:?}: '{n}' missing from: {stderr}"
        );
    }
    if let (Some(p), Some(before)) = (output, existed) {
        let after = std::fs::read(p).ok();
        assert_eq!(
            after,
            before,
            "btfquilt {args:?} changed or created {}",
            p.display()
        );
    }
    stderr
}

/// A seeded xorshift generator for the mutation loops (no dependency on the
/// library's own).
pub struct Rng(pub u64);

impl Rng {
    pub fn next(&mut self) -> u64 {
        let mut x = self.0;
        x ^= x << 13;
        x ^= x >> 7;
        x ^= x << 17;
        self.0 = x;
        x
    }
    pub fn below(&mut self, n: usize) -> usize {
        (self.next() % n.max(1) as u64) as usize
    }
}

/// Mutation cases per reader: `BTFQUILT_FUZZ_CASES`, else `default`.
pub fn fuzz_cases(default: usize) -> usize {
    std::env::var("BTFQUILT_FUZZ_CASES")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(default)
}

/// One mutation of `bytes`: a flipped byte, a truncation, or inserted bytes.
pub fn mutate(bytes: &[u8], rng: &mut Rng) -> Vec<u8> {
    let mut b = bytes.to_vec();
    match rng.below(3) {
        0 => {
            for _ in 0..1 + rng.below(4) {
                let i = rng.below(b.len());
                b[i] ^= 1 << rng.below(8);
            }
        }
        1 => b.truncate(rng.below(b.len())),
        _ => {
            let at = rng.below(b.len() + 1);
            let n = 1 + rng.below(16);
            let ins: Vec<u8> = (0..n).map(|_| rng.next() as u8).collect();
            b.splice(at..at, ins);
        }
    }
    b
}

/// One mutation case: runs `args` (which read the mutated `file` and write
/// `out`) and asserts the run either succeeded with its output written or
/// refused cleanly — an exit code (no signal), no panic, the file named,
/// nothing at `out`. Returns whether it succeeded.
pub fn read_or_refused(label: &str, args: &[&str], file: &Path, out: &Path) -> bool {
    let _ = std::fs::remove_file(out);
    let o = run_bounded(args);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.code().is_some(), "{label}: killed by a signal: {err}");
    assert!(!err.contains("panicked"), "{label}: {err}");
    if o.status.success() {
        assert!(out.exists(), "{label}: success without output");
        return true;
    }
    let name = file.file_name().unwrap().to_string_lossy();
    assert!(
        err.contains(&*name),
        "{label}: refusal does not name {name}: {err}"
    );
    assert!(!out.exists(), "{label}: refusal left {}", out.display());
    false
}
