//! The same inputs give the same bytes on another CPU: `factorize` (a BTF
//! and a colour photograph), `tile`, `render` and `evaluate` run natively
//! and under QEMU's user-mode emulator as the baseline x86-64 CPU (`-cpu
//! qemu64`: SSE2, no AVX or FMA), from the same BTF and geometry image.
//! Skips with a message without
//! `qemu-x86_64` (Debian's `qemu-user`; `.ci/run` installs it).

use std::path::Path;
use std::process::Command;

use crate::common::{atlas, ok, s};

/// Runs the binary with `args` under the emulator and asserts it
/// succeeded; its standard output. One allocator arena is set here, so the
/// binary does not re-execute itself outside the emulator.
fn emulated(args: &[&str]) -> String {
    let out = Command::new("qemu-x86_64")
        .args(["-cpu", "qemu64", env!("CARGO_BIN_EXE_btfquilt")])
        .args(args)
        .env("MALLOC_ARENA_MAX", "1")
        .output()
        .expect("runs");
    assert!(
        out.status.success(),
        "qemu64 btfquilt {args:?}: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8_lossy(&out.stdout).into_owned()
}

#[test]
fn factorizing_tiling_and_rendering_give_the_same_bytes_on_a_cpu_without_avx() {
    if !cfg!(target_arch = "x86_64") {
        eprintln!("skipped: the emulated CPU is x86-64's baseline");
        return;
    }
    if Command::new("qemu-x86_64").arg("--version").output().is_err() {
        eprintln!("skipped: qemu-x86_64 is not installed (Debian: apt-get install qemu-user)");
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let (btf, gim) = (d.join("b.btf"), d.join("s.gim"));
    let photo = Path::new(env!("CARGO_MANIFEST_DIR")).join("data/plaster_cracks.png");
    // the inputs, made once natively
    ok(&[
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
        s(&btf),
        "-q",
    ]);
    atlas(
        &Path::new(env!("CARGO_MANIFEST_DIR")).join("data/spot_5.8k.obj"),
        192,
        &gim,
    );
    let mut files = Vec::new();
    for (tag, run) in [("native", ok as fn(&[&str]) -> String), ("qemu64", emulated)] {
        // the same file names in a folder per run: artifacts name their inputs
        let run_dir = d.join(tag);
        std::fs::create_dir(&run_dir).unwrap();
        let [svd, photo_svd, quilt, png] =
            ["b.svd", "photo.svd", "s.quilt", "s.png"].map(|f| run_dir.join(f));
        run(&["factorize", s(&btf), "--terms", "12", "-o", s(&svd), "-q"]);
        run(&["factorize", s(&photo), "--terms", "3", "-o", s(&photo_svd), "-q"]);
        run(&[
            "tile",
            "--gim",
            s(&gim),
            "--sample",
            s(&svd),
            "--threads",
            "2",
            "-o",
            s(&quilt),
            "-q",
        ]);
        run(&[
            "render",
            s(&quilt),
            "--width",
            "160",
            "--height",
            "120",
            "-o",
            s(&png),
            "-q",
        ]);
        let json = run(&["evaluate", s(&quilt), "--windows", "500"]);
        files.push([
            std::fs::read(&svd).unwrap(),
            std::fs::read(&photo_svd).unwrap(),
            std::fs::read(&quilt).unwrap(),
            std::fs::read(&png).unwrap(),
            json.into_bytes(),
        ]);
    }
    for (k, what) in [
        "BTF's factorization",
        "photograph's factorization",
        "quilt",
        "render",
        "evaluate",
    ]
    .iter()
    .enumerate()
    {
        assert!(
            files[0][k] == files[1][k],
            "the {what} differs on the baseline CPU"
        );
    }
}
