//! The command line: exit codes and messages a user sees.

use std::path::Path;
use std::process::Command;

use crate::common::{btfquilt, fails_clearly, s};

#[test]
fn generate_info_export_round() {
    let dir = tempfile::tempdir().unwrap();
    let btf = dir.path().join("tiny.btf");
    let out = btfquilt(&[
        "generate-btf",
        "--family",
        "pebbles",
        "--imperfection",
        "stains",
        "--size",
        "24",
        "--views",
        "4x2",
        "--lights",
        "6x2",
        "--seed",
        "5",
        "--threads",
        "1",
        "-q",
        "-o",
        s(&btf),
    ]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    assert!(dir.path().join("tiny.mask.png").exists());
    let info = btfquilt(&["info", s(&btf), "--verify"]);
    let text = String::from_utf8_lossy(&info.stdout);
    assert!(info.status.success());
    for needle in [
        "kind:      btf",
        "rgb",
        "ratio",
        "seed:      5",
        "24×24 texels, 8 views × 12 lights",
        "verify",
    ] {
        assert!(text.contains(needle), "'{needle}' missing from:\n{text}");
    }
    let png = dir.path().join("one.png");
    let out = btfquilt(&[
        "export-btf",
        s(&btf),
        "--view",
        "25,0",
        "--light",
        "75,60",
        "-o",
        s(&png),
    ]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    assert_eq!(btfquilt::io::imageio::image_size(&png).unwrap(), (24, 24));
    let out = btfquilt(&[
        "export-btf",
        s(&btf),
        "--view",
        "10,0",
        "--light",
        "45,60",
        "-o",
        s(&png),
    ]);
    fails_clearly(&out, &["tiny.btf", "no view direction"]);
}

#[test]
fn bad_inputs_exit_non_zero_with_the_file_named() {
    let dir = tempfile::tempdir().unwrap();
    let junk = dir.path().join("junk.quilt");
    std::fs::write(&junk, "junk").unwrap();
    fails_clearly(
        &btfquilt(&["info", s(&junk)]),
        &["junk.quilt", "not a btfquilt container"],
    );
    let missing = dir.path().join("missing.btf");
    fails_clearly(&btfquilt(&["info", s(&missing)]), &["missing.btf"]);
    let out = dir.path().join("x.btf");
    fails_clearly(
        &btfquilt(&["generate-btf", "--family", "marble", "-o", s(&out)]),
        &["--family", "'marble'", "bricks, weave, cracked, pebbles"],
    );
    fails_clearly(
        &btfquilt(&["generate-btf", "--views", "12by8", "-o", s(&out)]),
        &["12by8"],
    );
    fails_clearly(
        &btfquilt(&["generate-btf", "--memory", "lots", "-o", s(&out)]),
        &["--memory", "'lots'", "expected a size like 512MiB or 2GiB"],
    );
    assert!(!out.exists());
    fails_clearly(&btfquilt(&["ingest", s(&junk), "-o", s(&out)]), &["junk.quilt"]);
    assert!(!out.exists());
}

#[test]
fn factorize_reconstruct_and_their_errors() {
    let dir = tempfile::tempdir().unwrap();
    let btf = dir.path().join("s.btf");
    let ok = btfquilt(&[
        "generate-btf",
        "--size",
        "20",
        "--views",
        "4x2",
        "--lights",
        "4x2",
        "-q",
        "-o",
        s(&btf),
    ]);
    assert!(ok.status.success());
    let svd = dir.path().join("s.svd");
    let out = btfquilt(&[
        "factorize",
        s(&btf),
        "--terms",
        "8",
        "--rotations",
        "6",
        "-q",
        "-o",
        s(&svd),
    ]);
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    assert!(text.contains("relative Frobenius error"), "{text}");
    let info = String::from_utf8_lossy(&btfquilt(&["info", s(&svd)]).stdout).into_owned();
    for needle in [
        "kind:      svd",
        "geometry_maps",
        "appearance",
        "rotated_maps",
        "relative_error",
    ] {
        assert!(info.contains(needle), "'{needle}' missing from:\n{info}");
    }
    let png = dir.path().join("r.png");
    let out = btfquilt(&[
        "reconstruct",
        s(&svd),
        "--view",
        "25,90",
        "--light",
        "75,180",
        "-o",
        s(&png),
    ]);
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success() && text.contains("PSNR") && text.contains("dB"),
        "{text}"
    );
    let out = btfquilt(&[
        "factorize",
        s(&btf),
        "--terms",
        "500",
        "-o",
        s(&dir.path().join("x.svd")),
    ]);
    fails_clearly(&out, &["--terms 500", "s.btf"]);
    fails_clearly(
        &btfquilt(&["factorize", s(&svd), "-o", s(&dir.path().join("y.svd"))]),
        &["s.svd", "'svd'"],
    );
    fails_clearly(
        &btfquilt(&[
            "reconstruct",
            s(&btf),
            "--view",
            "0,0",
            "--light",
            "0,0",
            "-o",
            s(&png),
        ]),
        &["s.btf"],
    );
}

#[test]
fn a_killed_factorization_leaves_nothing_that_looks_finished() {
    let dir = tempfile::tempdir().unwrap();
    let btf = dir.path().join("k.btf");
    assert!(btfquilt(&["generate-btf", "--size", "64", "-q", "-o", s(&btf)])
        .status
        .success());
    let svd = dir.path().join("k.svd");
    for delay_ms in [50u64, 400, 1200] {
        let mut child = Command::new(env!("CARGO_BIN_EXE_btfquilt"))
            .args(["factorize", s(&btf), "-q", "-o", s(&svd)])
            .spawn()
            .unwrap();
        std::thread::sleep(std::time::Duration::from_millis(delay_ms));
        let _ = child.kill();
        let status = child.wait().unwrap();
        if status.success() || svd.exists() {
            // finished before the kill (or killed between renaming its
            // output into place and exiting): then the output must be
            // complete and valid
            btfquilt::container::Container::open(&svd, Default::default())
                .unwrap_or_else(|e| {
                    panic!(
                        "killed after {delay_ms} ms, {} is not complete: {e}",
                        svd.display()
                    )
                })
                .verify()
                .unwrap();
            std::fs::remove_file(&svd).unwrap();
            continue;
        }
        // a leftover temporary file is hidden (it may be complete when the
        // kill came between its last byte and the rename)
        for name in crate::common::listing(dir.path()) {
            if name.ends_with(".partial") {
                assert!(name.starts_with(".k.svd."), "{name}");
            }
        }
    }
    // the next run removes what the killed ones left and finishes
    assert!(btfquilt(&["factorize", s(&btf), "-q", "-o", s(&svd)])
        .status
        .success());
    btfquilt::container::Container::open(&svd, Default::default())
        .unwrap()
        .verify()
        .unwrap();
    let left: Vec<String> = crate::common::listing(dir.path())
        .into_iter()
        .filter(|n| n.ends_with(".partial"))
        .collect();
    assert!(left.is_empty(), "{left:?}");
}

/// The singularities `atlas` lists: (index, exposure) per line, and the
/// summary's count and summed exposure.
fn listed_singularities(text: &str) -> (Vec<(i32, f64)>, usize, f64) {
    let listed = text
        .lines()
        .filter_map(|l| l.trim().strip_prefix("singularity of index "))
        .map(|l| {
            let index: i32 = l.split_whitespace().next().unwrap().parse().unwrap();
            let exposure: f64 = l.rsplit("exposure ").next().unwrap().trim().parse().unwrap();
            (index, exposure)
        })
        .collect();
    let count = text.split(" field singularities").next().unwrap();
    let count: usize = count.rsplit(' ').next().unwrap().parse().unwrap();
    let summed: f64 = text
        .split("summed exposure ")
        .nth(1)
        .unwrap()
        .split(')')
        .next()
        .unwrap()
        .parse()
        .unwrap();
    (listed, count, summed)
}

#[test]
fn atlas_lists_the_singularities_and_can_move_them_out_of_sight() {
    let dir = tempfile::tempdir().unwrap();
    let spot = Path::new(env!("CARGO_MANIFEST_DIR")).join("data/spot_5.8k.obj");
    let mut seen = Vec::new();
    for exposure in ["0", "2"] {
        let gim = dir.path().join(format!("spot{exposure}.gim"));
        let text = crate::common::ok(&[
            "atlas",
            s(&spot),
            "--resolution",
            "256",
            "--field-exposure",
            exposure,
            "-q",
            "-o",
            s(&gim),
        ]);
        let (listed, count, summed) = listed_singularities(&text);
        assert_eq!(listed.len(), count, "{text}");
        // Poincaré–Hopf on a sphere, and exposures are shares
        assert_eq!(listed.iter().map(|l| l.0).sum::<i32>(), 2, "{text}");
        assert!(listed.iter().all(|l| (0.0..=1.0).contains(&l.1)), "{text}");
        let sum: f64 = listed.iter().map(|l| l.1).sum();
        assert!(
            (sum - summed).abs() < 0.01 * count as f64,
            "{sum} against {summed}"
        );
        seen.push((count, summed));
        // `show --what field` rings them: red +1, blue −1
        let png = dir.path().join(format!("field{exposure}.png"));
        crate::common::ok(&["show", s(&gim), "--what", "field", "-o", s(&png)]);
        let img = image::open(&png).unwrap().to_rgb8();
        let count_of = |c: [u8; 3]| img.pixels().filter(|p| p.0 == c).count();
        assert!(count_of([255, 26, 26]) > 0, "no red ring");
        assert_eq!(
            count_of([51, 128, 255]) > 0,
            listed.iter().any(|l| l.0 == -1),
            "blue rings and −1 singularities"
        );
    }
    // weighing turning by exposure: fewer singularities, less in sight
    assert!(seen[1].0 < seen[0].0 && seen[1].1 < seen[0].1, "{seen:?}");
}

#[test]
fn atlas_show_and_export_a_mesh() {
    let dir = tempfile::tempdir().unwrap();
    let spot = Path::new(env!("CARGO_MANIFEST_DIR")).join("data/spot_5.8k.obj");
    let gim = dir.path().join("spot.gim");
    let out = btfquilt(&["atlas", s(&spot), "--resolution", "256", "-q", "-o", s(&gim)]);
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    for needle in [
        "charts",
        "stretch L2",
        "utilization",
        "zipper links",
        "no repair needed",
    ] {
        assert!(text.contains(needle), "'{needle}' missing from {text}");
    }
    for what in ["charts", "normals", "field"] {
        let png = dir.path().join(format!("{what}.png"));
        let out = btfquilt(&["show", s(&gim), "--what", what, "-o", s(&png)]);
        assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
        assert_eq!(btfquilt::io::imageio::image_size(&png).unwrap(), (256, 256));
    }
    let export = dir.path().join("export");
    assert!(
        btfquilt(&["export", s(&gim), "--format", "obj", "-o", s(&export)])
            .status
            .success()
    );
    let (models, _) = tobj::load_obj(export.join("mesh.obj"), &tobj::LoadOptions::default()).unwrap();
    let m = &models[0].mesh;
    assert_eq!(m.indices.len(), 5856 * 3);
    assert!(!m.texcoords.is_empty() && m.texcoords.iter().all(|&t| (0.0..=1.0).contains(&t)));
    assert!(export.join("mesh.mtl").exists() && export.join("charts.png").exists());
    fails_clearly(
        &btfquilt(&[
            "show",
            s(&gim),
            "--what",
            "stars",
            "-o",
            s(&dir.path().join("x.png")),
        ]),
        &["stars"],
    );
    let bad = dir.path().join("bad.obj");
    std::fs::write(&bad, "v 0 0 0\nv 1 0 0\nv 0 1 nan\nf 1 2 3\n").unwrap();
    fails_clearly(
        &btfquilt(&["atlas", s(&bad), "-o", s(&dir.path().join("b.gim"))]),
        &["bad.obj", "vertex 3"],
    );
    fails_clearly(
        &btfquilt(&["show", s(&spot), "-o", s(&dir.path().join("y.png"))]),
        &["spot_5.8k.obj"],
    );
    for flag in ["--max-stretch", "--max-area-distortion", "--max-linf-stretch"] {
        let out = dir.path().join("limits.gim");
        fails_clearly(
            &btfquilt(&["atlas", s(&spot), flag, "0.5", "-o", s(&out)]),
            &[flag, "0.5", "≥ 1"],
        );
        assert!(!out.exists(), "nothing written for a refused {flag}");
    }
}

#[test]
fn tile_bake_evaluate_render_export_a_square() {
    let dir = tempfile::tempdir().unwrap();
    let obj = dir.path().join("square.obj");
    std::fs::write(&obj, "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nf 1 2 3\nf 1 3 4\n").unwrap();
    let gim = dir.path().join("square.gim");
    assert!(
        btfquilt(&["atlas", s(&obj), "--resolution", "96", "-q", "-o", s(&gim)])
            .status
            .success()
    );
    let brick = Path::new(env!("CARGO_MANIFEST_DIR")).join("data/brick.png");
    let quilt = dir.path().join("square.quilt");
    let out = btfquilt(&[
        "tile",
        "--gim",
        s(&gim),
        "--sample",
        s(&brick),
        "-q",
        "-o",
        s(&quilt),
    ]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let json = btfquilt(&["evaluate", s(&quilt)]);
    let doc = serde_json::from_slice::<serde_json::Value>(&json.stdout).unwrap();
    assert!(doc.get("zipper").is_some() && doc.get("coherence").is_some());
    // usage: every sample pixel in one bucket, and the buckets' bounds hold
    // the covered texels (each uses one pixel of the one sample)
    let usage = &doc["usage"][0];
    let hist: Vec<u64> = usage["histogram"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_u64().unwrap())
        .collect();
    assert_eq!(hist.iter().sum::<u64>(), usage["pixels"].as_u64().unwrap());
    let texels = doc["texels"].as_u64().unwrap();
    let low: u64 = hist.iter().enumerate().skip(1).map(|(k, n)| n << (k - 1)).sum();
    let high: u64 = hist
        .iter()
        .enumerate()
        .skip(1)
        .map(|(k, n)| n * ((1u64 << k) - 1))
        .sum();
    assert!(low <= texels && texels <= high, "{low} ≤ {texels} ≤ {high}");
    let never = usage["never_used"].as_f64().unwrap();
    assert!((never - hist[0] as f64 / usage["pixels"].as_f64().unwrap()).abs() < 1e-12);
    let c = &doc["coherence"];
    assert!(c["p95_rgb_distance_to_nearest_sample_window"].as_f64().unwrap() >= 0.0);
    // a new quilt stores Jacobians: every window has its own frame
    for key in ["mean_rgb_distance_in_own_frame", "p95_rgb_distance_in_own_frame"] {
        assert!(
            c[key].as_f64().is_some_and(|v| v.is_finite() && v >= 0.0),
            "{key}: {c}"
        );
    }
    assert_eq!(c["windows"].as_u64().unwrap(), 200);
    // more windows: the same figures but the coherence, measured on more
    let more = btfquilt(&["evaluate", s(&quilt), "--windows", "600"]);
    let mut more = serde_json::from_slice::<serde_json::Value>(&more.stdout).unwrap();
    assert_eq!(more["coherence"]["windows"].as_u64().unwrap(), 600);
    let mut same = doc.clone();
    more["coherence"] = serde_json::Value::Null;
    same["coherence"] = serde_json::Value::Null;
    assert_eq!(more, same);
    for bad in ["0", "20001"] {
        let out = btfquilt(&["evaluate", s(&quilt), "--windows", bad]);
        fails_clearly(&out, &["--windows", bad]);
    }
    let png = dir.path().join("view.png");
    assert!(btfquilt(&[
        "render",
        s(&quilt),
        "--width",
        "64",
        "--height",
        "48",
        "-o",
        s(&png)
    ])
    .status
    .success());
    let export = dir.path().join("export");
    assert!(btfquilt(&["export", s(&quilt), "-o", s(&export)])
        .status
        .success());
    assert_eq!(
        btfquilt::io::imageio::image_size(&export.join("atlas.png")).unwrap(),
        (96, 96)
    );
    let (models, _) = tobj::load_obj(export.join("mesh.obj"), &tobj::LoadOptions::default()).unwrap();
    assert_eq!(models[0].mesh.indices.len(), 6);
    fails_clearly(
        &btfquilt(&["render", s(&quilt), "--camera", "1,2,3", "-o", s(&png)]),
        &["--camera"],
    );
    // a sample that is no image, and numbers out of range (negative ones
    // too: not taken for flags), refused by name with nothing written
    for (sample, args, said) in [
        (&obj, &[][..], &["square.obj"][..]),
        (
            &brick,
            &["--occurrence-weight", "-1"],
            &["--occurrence-weight -1", "≥ 0"],
        ),
        (&brick, &["--tolerance", "-0.5"], &["--tolerance -0.5", "≥ 0"]),
        (
            &brick,
            &["--feature-align", "0.6"],
            &["--feature-align 0.6", "0 to 0.5"],
        ),
        (&brick, &["--field-turn", "37"], &["--field-turn 37", "0 to 36"]),
    ] {
        let out = dir.path().join("refused.quilt");
        let mut command = vec!["tile", "--gim", s(&gim), "--sample", s(sample), "-o", s(&out)];
        command.extend_from_slice(args);
        fails_clearly(&btfquilt(&command), said);
        assert!(!out.exists(), "nothing written for {args:?}");
    }
}

/// `compare` of a baked flat square against its sample: the figures as
/// JSON; an image against itself scores 0 both ways; an image smaller than
/// the window, and a file that is no image, are refused by name.
#[test]
fn compare_an_image_with_its_sample() {
    let dir = tempfile::tempdir().unwrap();
    let obj = crate::common::square_obj(dir.path());
    let gim = dir.path().join("square.gim");
    // a 48² crop of the brick photo as the sample
    let full = image::open(Path::new(env!("CARGO_MANIFEST_DIR")).join("data/brick.png")).unwrap();
    let brick = dir.path().join("brick48.png");
    full.crop_imm(100, 100, 48, 48).save(&brick).unwrap();
    let quilt = dir.path().join("square.quilt");
    let png = dir.path().join("square.png");
    let (atlas, tile, bake) = (
        format!("atlas {} --resolution 64 -q -o {}", s(&obj), s(&gim)),
        format!(
            "tile -q --gim {} --sample {} -o {}",
            s(&gim),
            s(&brick),
            s(&quilt)
        ),
        format!("bake {} -o {}", s(&quilt), s(&png)),
    );
    for line in [atlas, tile, bake] {
        let args: Vec<&str> = line.split(' ').collect();
        let out = btfquilt(&args);
        assert!(
            out.status.success(),
            "{args:?}: {}",
            String::from_utf8_lossy(&out.stderr)
        );
    }
    let figures = |image: &Path| {
        let out = btfquilt(&["compare", s(image), "--sample", s(&brick)]);
        assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
        serde_json::from_slice::<serde_json::Value>(&out.stdout).unwrap()
    };
    let doc = figures(&png);
    for way in ["coherence", "completeness"] {
        let mean = doc[way]["mean"].as_f64().unwrap();
        let (p95, max) = (
            doc[way]["p95"].as_f64().unwrap(),
            doc[way]["max"].as_f64().unwrap(),
        );
        assert!(
            mean.is_finite() && mean >= 0.0 && mean <= max && p95 <= max,
            "{doc}"
        );
    }
    let same = figures(&brick);
    assert_eq!(same["coherence"]["max"].as_f64(), Some(0.0));
    assert_eq!(same["completeness"]["max"].as_f64(), Some(0.0));
    let tiny = dir.path().join("tiny.png");
    image::RgbImage::new(3, 9).save(&tiny).unwrap();
    fails_clearly(
        &btfquilt(&["compare", s(&tiny), "--sample", s(&brick)]),
        &["tiny.png", "3×9"],
    );
    fails_clearly(
        &btfquilt(&["compare", s(&png), "--sample", s(&obj)]),
        &["square.obj"],
    );
}

/// The same inputs and seed give the same bytes whatever `--threads` and
/// `--memory`: the whole chain (atlas, tile of a resampled BTF, paint, bake,
/// render, glTF) at 1 thread and 1 MiB against 2 threads and 16 GiB. At
/// 1 MiB (each cache's floor) the sample's rotated copies (the sample
/// resampled to 97² six-term texels on a 160² Spot, 263 KB each) are
/// evicted and read again: three of the 24 fit.
#[test]
fn outputs_do_not_depend_on_threads_or_memory() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let spot = Path::new(env!("CARGO_MANIFEST_DIR")).join("data/spot_5.8k.obj");
    let btf = d.join("b.btf");
    let svd = d.join("b.svd");
    crate::common::ok(&[
        "generate-btf",
        "--size",
        "40",
        "--views",
        "4x2",
        "--lights",
        "4x2",
        "--imperfection",
        "cracks",
        "-q",
        "-o",
        s(&btf),
    ]);
    crate::common::ok(&[
        "factorize",
        s(&btf),
        "--terms",
        "6",
        "--rotations",
        "24",
        "-q",
        "-o",
        s(&svd),
    ]);
    let strokes = d.join("strokes.json");
    std::fs::write(&strokes, r#"[{"point": [-0.27, 0.17, 0.23], "radius": 0.2}]"#).unwrap();
    let run = |name: &str, threads: &str, memory: &str| -> Vec<(String, Vec<u8>)> {
        let o = d.join(name);
        std::fs::create_dir(&o).unwrap();
        let p = |f: &str| o.join(f).display().to_string();
        let common = ["--threads", threads, "--memory", memory];
        let with = |args: &[&str]| {
            let v: Vec<&str> = args.iter().chain(&common).copied().collect();
            crate::common::ok(&v);
        };
        let (gim, quilt, painted) = (p("spot.gim"), p("t.quilt"), p("p.quilt"));
        crate::common::ok(&[
            "atlas",
            s(&spot),
            "--resolution",
            // 16 atlas tiles: at 1 MiB the loop evicts and reads them again
            "256",
            "-q",
            "-o",
            &gim,
            "--threads",
            threads,
        ]);
        with(&[
            "tile",
            "--gim",
            &gim,
            "--sample",
            s(&svd),
            "--sample-width",
            "2.4",
            "-q",
            "-o",
            &quilt,
        ]);
        let mask = btf.with_extension("mask.png");
        with(&[
            "paint",
            &quilt,
            "--sample-mask",
            s(&mask),
            "--region",
            s(&strokes),
            "-q",
            "-o",
            &painted,
        ]);
        with(&["bake", &painted, "-o", &p("bake.png")]);
        with(&[
            "render",
            &painted,
            "--width",
            "160",
            "--height",
            "120",
            "-o",
            &p("r.png"),
        ]);
        with(&["export", &painted, "--format", "gltf", "-o", &p("gltf")]);
        let mut files = Vec::new();
        for f in crate::common::listing(&o) {
            if o.join(&f).is_dir() {
                for g in crate::common::listing(&o.join(&f)) {
                    files.push(format!("{f}/{g}"));
                }
            } else {
                files.push(f);
            }
        }
        files
            .into_iter()
            .map(|f| {
                let bytes = std::fs::read(o.join(&f)).unwrap();
                (f, bytes)
            })
            .collect()
    };
    let small = run("small", "1", "1MiB");
    let large = run("large", "2", "16GiB");
    assert!(
        small.len() >= 6,
        "{:?}",
        small.iter().map(|f| &f.0).collect::<Vec<_>>()
    );
    assert_eq!(
        small.iter().map(|f| &f.0).collect::<Vec<_>>(),
        large.iter().map(|f| &f.0).collect::<Vec<_>>()
    );
    for ((name, a), (_, b)) in small.iter().zip(&large) {
        assert!(
            a == b,
            "{name} differs between 1 thread / 1 MiB and 2 threads / 16 GiB"
        );
    }
}

/// `s.quilt` in `dir`: a 64² flat square tiled with the small brick sample
/// (for the tests that run `serve`).
#[cfg(unix)]
fn small_square_quilt(dir: &Path) -> std::path::PathBuf {
    let (gim, quilt) = (dir.join("s.gim"), dir.join("s.quilt"));
    let obj = crate::common::square_obj(dir);
    let brick = Path::new(env!("CARGO_MANIFEST_DIR")).join("data/brick.png");
    crate::common::ok(&["atlas", s(&obj), "--resolution", "64", "-q", "-o", s(&gim)]);
    let (g, b, q) = (s(&gim), s(&brick), s(&quilt));
    crate::common::ok(&["tile", "--gim", g, "--sample", b, "-q", "-o", q]);
    quilt
}

/// With glibc the binary runs with one allocator arena unless the user set
/// `MALLOC_ARENA_MAX` (it re-executes itself once): read from the
/// environment of a running `serve`.
#[cfg(all(target_os = "linux", target_env = "gnu"))]
#[test]
fn the_binary_runs_with_one_malloc_arena_unless_the_user_chose() {
    use std::io::BufRead;
    let dir = tempfile::tempdir().unwrap();
    let quilt = small_square_quilt(dir.path());
    for (set, want) in [(None, "MALLOC_ARENA_MAX=1"), (Some("3"), "MALLOC_ARENA_MAX=3")] {
        let mut cmd = Command::new(env!("CARGO_BIN_EXE_btfquilt"));
        cmd.args(["serve", s(&quilt), "--port", "0"])
            .env_remove("MALLOC_ARENA_MAX")
            .stdout(std::process::Stdio::piped())
            .stderr(std::process::Stdio::null());
        if let Some(v) = set {
            cmd.env("MALLOC_ARENA_MAX", v);
        }
        let mut child = cmd.spawn().unwrap();
        // the studio's address is printed once it listens
        let mut line = String::new();
        std::io::BufReader::new(child.stdout.take().unwrap())
            .read_line(&mut line)
            .unwrap();
        let environ = std::fs::read(format!("/proc/{}/environ", child.id())).unwrap();
        child.kill().unwrap();
        child.wait().unwrap();
        assert!(line.contains("http://127.0.0.1:"), "{line}");
        let vars: Vec<&[u8]> = environ.split(|&b| b == 0).collect();
        assert!(
            vars.contains(&want.as_bytes()),
            "{want} not in the environment of serve (MALLOC_ARENA_MAX given: {set:?})"
        );
        assert_eq!(
            vars.iter()
                .filter(|v| v.starts_with(b"MALLOC_ARENA_MAX="))
                .count(),
            1
        );
    }
}

/// Ctrl-C (SIGINT) or SIGTERM stops `serve` cleanly: it exits with
/// success and the hidden work files beside the surface (here the viewer's
/// texels, there from the start) are gone.
#[cfg(unix)]
#[test]
fn serve_stopped_by_a_signal_removes_its_work_files() {
    use std::io::BufRead;
    let dir = tempfile::tempdir().unwrap();
    let quilt = small_square_quilt(dir.path());
    let q = s(&quilt);
    let work_files = || -> Vec<String> {
        std::fs::read_dir(dir.path())
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .filter(|n| n.starts_with(".s.studio-"))
            .collect()
    };
    for signal in ["-INT", "-TERM"] {
        let mut child = Command::new(env!("CARGO_BIN_EXE_btfquilt"))
            .args(["serve", q, "--port", "0"])
            .stdout(std::process::Stdio::piped())
            .stderr(std::process::Stdio::piped())
            .spawn()
            .unwrap();
        let mut line = String::new();
        std::io::BufReader::new(child.stdout.take().unwrap())
            .read_line(&mut line)
            .unwrap();
        assert!(line.contains("http://127.0.0.1:"), "{line}");
        assert_eq!(work_files().len(), 1, "{signal}: {:?}", work_files());
        let kill = Command::new("kill")
            .args([signal, &child.id().to_string()])
            .status()
            .unwrap();
        assert!(kill.success());
        let out = child.wait_with_output().unwrap();
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(out.status.success(), "{signal}: {:?} {err}", out.status);
        assert!(err.contains("studio stopped"), "{err}");
        assert!(work_files().is_empty(), "{signal}: left {:?}", work_files());
    }
}
