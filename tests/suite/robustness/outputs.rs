//! Outputs: never written over an input or a file an input depends on,
//! dependencies verified by content, folders staged whole, stale partial
//! files of killed runs removed, `--threads` bounded, messages said once.

use std::path::{Path, PathBuf};
use std::process::Command;

use crate::common::{brick_crop, listing, ok, s, square_obj, write_rgb_png};
use crate::robustness::{refuses, run_bounded};

/// A small decorated square: `(dir, mesh, gim, sample, quilt)`.
fn decorated(dir: &Path) -> (PathBuf, PathBuf, PathBuf, PathBuf) {
    let mesh = square_obj(dir);
    let gim = dir.join("sq.gim");
    ok(&["atlas", s(&mesh), "--resolution", "64", "-q", "-o", s(&gim)]);
    let sample = brick_crop(dir, 32, None);
    let quilt = dir.join("sq.quilt");
    crate::common::tile(&gim, &sample, &quilt);
    (mesh, gim, sample, quilt)
}

#[test]
fn an_output_equal_to_an_input_is_refused_and_the_input_kept() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let (mesh, gim, sample, quilt) = decorated(d);
    let strokes = d.join("strokes.json");
    std::fs::write(&strokes, "[{\"point\": [0.5, 0.5, 0.0], \"radius\": 0.2}]").unwrap();
    let mask = d.join("mask.png");
    crate::common::write_mask_png(&mask, 32, 32, |x, _| x < 4);
    let sq = |p: &Path| s(p).to_string();
    let cases: Vec<(Vec<String>, PathBuf)> = vec![
        (
            vec!["atlas".into(), sq(&mesh), "-o".into(), sq(&mesh)],
            mesh.clone(),
        ),
        (
            vec!["factorize".into(), sq(&sample), "-o".into(), sq(&sample)],
            sample.clone(),
        ),
        (vec!["show".into(), sq(&gim), "-o".into(), sq(&gim)], gim.clone()),
        (
            vec![
                "tile".into(),
                "--gim".into(),
                sq(&gim),
                "--sample".into(),
                sq(&sample),
                "-o".into(),
                sq(&gim),
            ],
            gim.clone(),
        ),
        (
            vec![
                "tile".into(),
                "--gim".into(),
                sq(&gim),
                "--sample".into(),
                sq(&sample),
                "-o".into(),
                sq(&sample),
            ],
            sample.clone(),
        ),
        (
            vec!["bake".into(), sq(&quilt), "-o".into(), sq(&sample)],
            sample.clone(),
        ),
        (
            vec!["render".into(), sq(&quilt), "-o".into(), sq(&sample)],
            sample.clone(),
        ),
        (
            vec![
                "paint".into(),
                sq(&quilt),
                "--region".into(),
                sq(&strokes),
                "--sample-mask".into(),
                sq(&mask),
                "-o".into(),
                sq(&quilt),
            ],
            quilt.clone(),
        ),
        (
            vec![
                "paint".into(),
                sq(&quilt),
                "--region".into(),
                sq(&strokes),
                "--sample-mask".into(),
                sq(&mask),
                "-o".into(),
                sq(&gim),
            ],
            gim.clone(),
        ),
    ];
    for (args, victim) in &cases {
        let args: Vec<&str> = args.iter().map(String::as_str).collect();
        let name = victim.file_name().unwrap().to_str().unwrap();
        refuses(&args, &[name, "would destroy"], Some(victim));
    }
    // the same file through a symbolic link
    #[cfg(unix)]
    {
        let link = d.join("link.obj");
        std::os::unix::fs::symlink(&mesh, &link).unwrap();
        refuses(
            &["atlas", s(&mesh), "-o", s(&link)],
            &["link.obj", "would destroy"],
            Some(&mesh),
        );
    }
    // ingest: a manifest as its own output
    let btf = d.join("t.btf");
    ok(&[
        "generate-btf",
        "--size",
        "8",
        "--views",
        "2x2",
        "--lights",
        "2x2",
        "-q",
        "-o",
        s(&btf),
    ]);
    let folder = d.join("pairs");
    ok(&["export-btf", s(&btf), "--all", s(&folder), "-q"]);
    let manifest = folder.join("manifest.csv");
    refuses(
        &["ingest", s(&manifest), "-o", s(&manifest)],
        &["manifest.csv", "would destroy"],
        Some(&manifest),
    );
    // export: a folder output whose file would land on an input
    let clash = d.join("clash");
    std::fs::create_dir(&clash).unwrap();
    let img = clash.join("atlas.png");
    std::fs::copy(&sample, &img).unwrap();
    let q2 = clash.join("q.quilt");
    crate::common::tile(&gim, &img, &q2);
    refuses(
        &["export", s(&q2), "-o", s(&clash)],
        &["atlas.png", "would destroy"],
        Some(&img),
    );
}

#[test]
fn dependencies_are_checked_by_content_and_found_from_anywhere() {
    let dir = tempfile::tempdir().unwrap();
    let work = dir.path().join("work");
    std::fs::create_dir(&work).unwrap();
    let (_, gim, sample, quilt) = decorated(&work);
    // the whole folder moves; the quilt is read by absolute path from elsewhere
    let moved = dir.path().join("moved");
    std::fs::rename(&work, &moved).unwrap();
    let quilt = moved.join(quilt.file_name().unwrap());
    let elsewhere = tempfile::tempdir().unwrap();
    let out = Command::new(env!("CARGO_BIN_EXE_btfquilt"))
        .current_dir(elsewhere.path())
        .args(["bake", s(&quilt), "-o", "baked.png"])
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    assert!(elsewhere.path().join("baked.png").exists());
    let gim = moved.join(gim.file_name().unwrap());
    let sample = moved.join(sample.file_name().unwrap());

    // another image of the same size at the sample's path
    let original = std::fs::read(&sample).unwrap();
    write_rgb_png(&sample, 32, 32, |x, y| [x as f32 / 32.0, y as f32 / 32.0, 0.5]);
    let o = moved.join("o.png");
    for args in [
        vec!["bake", s(&quilt), "-o", s(&o)],
        vec![
            "render",
            s(&quilt),
            "--width",
            "32",
            "--height",
            "24",
            "-o",
            s(&o),
        ],
        vec!["evaluate", s(&quilt)],
    ] {
        refuses(&args, &["brick32.png", "is not the sample", "sq.quilt"], Some(&o));
    }
    let ex = moved.join("ex");
    refuses(
        &["export", s(&quilt), "--btf", s(&ex)],
        &["brick32.png", "sq.quilt"],
        None,
    );
    assert!(!ex.exists());
    std::fs::write(&sample, &original).unwrap();
    ok(&["bake", s(&quilt), "-o", s(&o)]);

    // another atlas at the geometry image's path
    let mesh = moved.join("square.obj");
    let other = moved.join("other.gim");
    ok(&[
        "atlas",
        s(&mesh),
        "--resolution",
        "64",
        "--gutter",
        "3",
        "-q",
        "-o",
        s(&other),
    ]);
    let saved = moved.join("saved.gim");
    std::fs::rename(&gim, &saved).unwrap();
    std::fs::copy(&other, &gim).unwrap();
    let o2 = moved.join("o2.png");
    for args in [
        vec![
            "render",
            s(&quilt),
            "--width",
            "32",
            "--height",
            "24",
            "-o",
            s(&o2),
        ],
        vec!["evaluate", s(&quilt)],
        vec!["export", s(&quilt), "-o", s(&moved.join("mesh"))],
    ] {
        refuses(
            &args,
            &["sq.gim", "is not the geometry image", "sq.quilt"],
            Some(&o2),
        );
    }
    // gone altogether
    std::fs::remove_file(&gim).unwrap();
    refuses(&["evaluate", s(&quilt)], &["sq.gim", "is gone"], None);
    // given in its place: checked the same way
    refuses(
        &["evaluate", s(&quilt), "--gim", s(&other)],
        &["other.gim", "is not the geometry image"],
        None,
    );
    ok(&["evaluate", s(&quilt), "--gim", s(&saved)]);
}

#[test]
fn export_btf_folders_are_staged_whole_and_ingest_refuses_mixed_folders() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let btf = d.join("t.btf");
    ok(&[
        "generate-btf",
        "--size",
        "8",
        "--views",
        "2x2",
        "--lights",
        "2x2",
        "-q",
        "-o",
        s(&btf),
    ]);
    let folder = d.join("pairs");
    ok(&["export-btf", s(&btf), "--all", s(&folder), "-q"]);
    let exr = listing(&folder);
    assert_eq!(exr.len(), 17, "{exr:?}");
    // a second export replaces the first whole: no old image stays beside the new manifest
    ok(&[
        "export-btf",
        s(&btf),
        "--all",
        s(&folder),
        "--format",
        "png",
        "-q",
    ]);
    let png = listing(&folder);
    assert_eq!(png.len(), 17, "{png:?}");
    assert!(
        png.iter().all(|n| n == "manifest.csv" || n.ends_with(".png")),
        "{png:?}"
    );
    assert_eq!(
        listing(d).iter().filter(|n| n.starts_with('.')).count(),
        0,
        "{:?}",
        listing(d)
    );
    // a folder holding the user's own files is refused, and kept as it was
    let mine = d.join("mine");
    std::fs::create_dir(&mine).unwrap();
    std::fs::write(mine.join("notes.txt"), b"mine").unwrap();
    refuses(
        &["export-btf", s(&btf), "--all", s(&mine), "-q"],
        &["mine", "other files"],
        None,
    );
    assert_eq!(listing(&mine), vec!["notes.txt".to_string()]);
    // two exports mixed in one folder are not one BTF
    let mixed = d.join("mixed");
    std::fs::create_dir(&mixed).unwrap();
    ok(&["export-btf", s(&btf), "--all", s(&d.join("a")), "-q"]);
    for f in listing(&d.join("a")) {
        if f.ends_with(".exr") {
            std::fs::copy(d.join("a").join(&f), mixed.join(&f)).unwrap();
        }
    }
    let first_png = png.iter().find(|n| n.ends_with(".png")).unwrap();
    let renamed = first_png.replace("btf_", "zzz_");
    std::fs::copy(folder.join(first_png), mixed.join(renamed)).unwrap();
    let out = d.join("mixed.btf");
    refuses(
        &["ingest", s(&mixed), "-o", s(&out)],
        &["mixed", "more than one format"],
        Some(&out),
    );
}

#[test]
fn partial_files_of_killed_runs_are_removed_and_reported() {
    if !Path::new("/proc/self").exists() {
        eprintln!("no /proc: process liveness is unknown and no partial is removed; skipped");
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let mesh = square_obj(d);
    // a pid above the kernel's largest (2^22) has no process
    let dead = d.join(".sq.gim.4294967.AbCdEfGh.partial");
    std::fs::write(&dead, vec![0u8; 4096]).unwrap();
    // a partial of a running process (this test) stays
    let live = d.join(format!(".sq.gim.{}.AbCdEfGh.partial", std::process::id()));
    std::fs::write(&live, b"live").unwrap();
    let out = run_bounded(&[
        "atlas",
        s(&mesh),
        "--resolution",
        "32",
        "-q",
        "-o",
        s(&d.join("sq.gim")),
    ]);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{stderr}");
    assert!(!dead.exists(), "the dead writer's partial is still there");
    assert!(live.exists(), "a live writer's partial was removed");
    assert!(
        stderr.contains("removed")
            && stderr.contains(".sq.gim.4294967.AbCdEfGh.partial")
            && stderr.contains("4294967"),
        "{stderr}"
    );
    // a run that fails leaves nothing behind either
    let bad = d.join("bad.obj");
    std::fs::write(&bad, "v 0 0 0\nv 1 0 0\nf 1 2\n").unwrap();
    let before = listing(d);
    refuses(
        &["atlas", s(&bad), "-q", "-o", s(&d.join("bad.gim"))],
        &["bad.obj"],
        Some(&d.join("bad.gim")),
    );
    assert_eq!(listing(d), before);
}

#[test]
fn threads_are_capped_and_messages_said_once() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let sample = brick_crop(d, 16, None);
    let svd = d.join("s.svd");
    let out = run_bounded(&[
        "factorize",
        s(&sample),
        "--rotations",
        "4",
        "--threads",
        "100000",
        "-q",
        "-o",
        s(&svd),
    ]);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{stderr}");
    assert!(stderr.contains("--threads 100000 capped at"), "{stderr}");
    // an OS error is printed once
    let e = refuses(&["info", s(d)], &["Is a directory"], None);
    assert_eq!(e.matches("Is a directory").count(), 1, "{e}");
    // a --sample that does not exist is named as given, not asked for
    let (_, _, _, quilt) = decorated(d);
    let missing = d.join("missing.svd");
    let e = refuses(
        &[
            "bake",
            s(&quilt),
            "--sample",
            s(&missing),
            "-o",
            s(&d.join("b.png")),
        ],
        &["missing.svd"],
        None,
    );
    assert!(!e.contains("give --sample"), "{e}");
}

#[test]
fn a_painted_surface_moves_with_its_inputs_and_replays_from_anywhere() {
    let dir = tempfile::tempdir().unwrap();
    let work = dir.path().join("work");
    std::fs::create_dir(&work).unwrap();
    let (_, _, _, quilt) = decorated(&work);
    let mask = work.join("mask.png");
    crate::common::write_mask_png(&mask, 32, 32, |x, y| (x / 4 + y / 4) % 3 == 0);
    let strokes = work.join("strokes.json");
    std::fs::write(&strokes, r#"[{"point": [0.5, 0.5, 0.0], "radius": 0.2}]"#).unwrap();
    let painted = work.join("painted.quilt");
    ok(&[
        "paint",
        s(&quilt),
        "--sample-mask",
        s(&mask),
        "--region",
        s(&strokes),
        "--patch-radius",
        "8",
        "-q",
        "-o",
        s(&painted),
    ]);
    let moved = dir.path().join("moved");
    std::fs::rename(&work, &moved).unwrap();
    let painted = moved.join("painted.quilt");
    let elsewhere = tempfile::tempdir().unwrap();
    let out = Command::new(env!("CARGO_BIN_EXE_btfquilt"))
        .current_dir(elsewhere.path())
        .args(["replay", s(&painted), "-q", "-o", "again.quilt"])
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    // the same strokes on the same base: the same surface, its log naming
    // the same files from its own folder
    let again = elsewhere.path().join("again.quilt");
    let a = btfquilt::quilt::Quilt::open(&painted, Default::default()).unwrap();
    let b = btfquilt::quilt::Quilt::open(&again, Default::default()).unwrap();
    assert_eq!(a.patches().unwrap(), b.patches().unwrap());
    assert_eq!(a.coords().unwrap(), b.coords().unwrap());
    ok(&["evaluate", s(&again)]);
}

#[test]
fn painting_a_surface_whose_samples_are_gone_or_changed_names_them() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let (_, _, sample, quilt) = decorated(d);
    // another sample to paint with (a copy), then the tiling's is removed
    let other = d.join("other.png");
    std::fs::copy(&sample, &other).unwrap();
    std::fs::remove_file(&sample).unwrap();
    let mask = d.join("mask.png");
    crate::common::write_mask_png(&mask, 32, 32, |x, _| x < 8);
    let strokes = d.join("strokes.json");
    std::fs::write(&strokes, r#"[{"point": [0.5, 0.5, 0.0], "radius": 0.2}]"#).unwrap();
    let out = d.join("painted.quilt");
    #[rustfmt::skip]
    let run = crate::common::btfquilt(&["paint", s(&quilt), "--sample", s(&other), "--sample-mask", s(&mask),
                         "--region", s(&strokes), "-q", "-o", s(&out)]);
    let name = |p: &Path| p.file_name().unwrap().to_str().unwrap().to_string();
    crate::common::fails_clearly(&run, &[&name(&quilt), &name(&sample), "is gone"]);
    assert!(!out.exists());
    // put back changed: refused as not the one the surface was made from
    std::fs::copy(&other, &sample).unwrap();
    let mut bytes = std::fs::read(&sample).unwrap();
    let last = bytes.len() - 1;
    bytes.truncate(last);
    std::fs::write(&sample, &bytes).unwrap();
    #[rustfmt::skip]
    let run = crate::common::btfquilt(&["paint", s(&quilt), "--sample", s(&other), "--sample-mask", s(&mask),
                                        "--region", s(&strokes), "-q", "-o", s(&out)]);
    crate::common::fails_clearly(&run, &[&name(&quilt), &name(&sample), "is not the sample"]);
    assert!(!out.exists());
}
