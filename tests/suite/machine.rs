//! The same inputs give the same bytes on another CPU: `tile`, `render`
//! and `evaluate` run natively and under QEMU's user-mode emulator as the
//! baseline x86-64 CPU (`-cpu qemu64`: SSE2, no AVX or FMA), from the same
//! geometry image and factorization. Skips with a message without
//! `qemu-x86_64` (Debian's `qemu-user`; `.ci/run` installs it).

use std::path::Path;
use std::process::Command;

/// Runs the binary with `args` in `dir`, natively or under the emulator;
/// one allocator arena set here so the binary does not re-execute itself
/// (natively) outside the emulator.
fn btfquilt(dir: &Path, emulated: bool, args: &[&str]) -> Vec<u8> {
    let bin = env!("CARGO_BIN_EXE_btfquilt");
    let mut cmd = if emulated {
        let mut c = Command::new("qemu-x86_64");
        c.args(["-cpu", "qemu64", bin]);
        c
    } else {
        Command::new(bin)
    };
    let out = cmd
        .args(args)
        .current_dir(dir)
        .env("MALLOC_ARENA_MAX", "1")
        .output()
        .expect("runs");
    assert!(
        out.status.success(),
        "{args:?} (emulated: {emulated}): {}",
        String::from_utf8_lossy(&out.stderr)
    );
    out.stdout
}

#[test]
fn tiling_and_rendering_give_the_same_bytes_on_a_cpu_without_avx() {
    if !cfg!(target_arch = "x86_64") {
        eprintln!("skipped: the emulated CPU is x86-64's baseline");
        return;
    }
    if Command::new("qemu-x86_64").arg("--version").output().is_err() {
        eprintln!("skipped: qemu-x86_64 is not installed (Debian: apt-get install qemu-user)");
        return;
    }
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let dir = tempfile::tempdir().unwrap();
    let spot = root.join("data/spot_5.8k.obj");
    let spot = spot.to_str().unwrap();
    let d = dir.path();
    // the inputs, made once natively
    btfquilt(
        d,
        false,
        &[
            "generate-btf",
            "--family",
            "bricks",
            "--size",
            "48",
            "--views",
            "4x2",
            "--lights",
            "4x2",
            "-o",
            "b.btf",
            "-q",
        ],
    );
    btfquilt(
        d,
        false,
        &["factorize", "b.btf", "--terms", "12", "-o", "b.svd", "-q"],
    );
    btfquilt(
        d,
        false,
        &["atlas", spot, "--resolution", "192", "-o", "s.gim", "-q"],
    );
    let mut files = Vec::new();
    for (emulated, tag) in [(false, "native"), (true, "qemu64")] {
        let quilt = format!("{tag}.quilt");
        let png = format!("{tag}.png");
        btfquilt(
            d,
            emulated,
            &[
                "tile",
                "--gim",
                "s.gim",
                "--sample",
                "b.svd",
                "--threads",
                "2",
                "-o",
                &quilt,
                "-q",
            ],
        );
        btfquilt(
            d,
            emulated,
            &[
                "render", &quilt, "--width", "160", "--height", "120", "-o", &png, "-q",
            ],
        );
        let json = btfquilt(d, emulated, &["evaluate", &quilt, "--windows", "500"]);
        files.push([
            std::fs::read(d.join(&quilt)).unwrap(),
            std::fs::read(d.join(&png)).unwrap(),
            json,
        ]);
    }
    for (k, what) in ["quilt", "render", "evaluate"].iter().enumerate() {
        assert!(
            files[0][k] == files[1][k],
            "the {what} differs on the baseline CPU"
        );
    }
}
