//! Meshes and points: damaged or extreme meshes through `atlas` (refused
//! naming the file, or made into a valid atlas in the user's units), user
//! points far from or off the surface through `paint`, and non-finite float
//! flags refused naming the flag. See `mod.rs`.

use crate::common::{self, s};
use crate::robustness::{fuzz_cases, mutate, refuses, run_bounded, Rng};
use btfquilt::artifact::gim::{Gim, EMPTY};
use btfquilt::container::MemoryBudget;
use std::path::{Path, PathBuf};

/// The square grid as OBJ text, its copies offset by `dx` along x and
/// scaled by `scale` (vertices of all copies first, then faces).
fn squares_obj(copies: &[(f64, f64)]) -> String {
    let (v, f) = common::square_grid();
    let mut text = String::new();
    for &(dx, scale) in copies {
        for q in &v {
            text += &format!("v {:e} {:e} 0\n", q[0] as f64 * scale + dx, q[1] as f64 * scale);
        }
    }
    for k in 0..copies.len() {
        for t in &f {
            let o = k * v.len() + 1;
            text += &format!("f {} {} {}\n", t[0] + o, t[1] + o, t[2] + o);
        }
    }
    text
}

/// The square grid as an ASCII PLY.
fn square_ply() -> String {
    let (v, f) = common::square_grid();
    let mut text = format!(
        "ply\nformat ascii 1.0\nelement vertex {}\nproperty float x\nproperty float y\n\
         property float z\nelement face {}\nproperty list uchar int vertex_indices\nend_header\n",
        v.len(),
        f.len()
    );
    for q in &v {
        text += &format!("{} {} 0\n", q[0], q[1]);
    }
    for t in &f {
        text += &format!("3 {} {} {}\n", t[0], t[1], t[2]);
    }
    text
}

fn write(dir: &Path, name: &str, text: &str) -> PathBuf {
    let p = dir.join(name);
    std::fs::write(&p, text).unwrap();
    p
}

/// Runs `atlas mesh -o out --resolution r`, asserting success; returns stdout.
fn atlas_ok(mesh: &Path, out: &Path, r: &str) -> String {
    let o = run_bounded(&["atlas", s(mesh), "-o", s(out), "--resolution", r, "-q"]);
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "atlas {}: {stderr}", mesh.display());
    String::from_utf8_lossy(&o.stdout).into_owned()
}

#[test]
fn mesh_far_apart_copies_keep_all_their_faces() {
    let dir = tempfile::tempdir().unwrap();
    let faces = common::square_grid().1.len();
    let obj = write(dir.path(), "two.obj", &squares_obj(&[(0.0, 1.0), (3e5, 1.0)]));
    let gim = dir.path().join("two.gim");
    let report = atlas_ok(&obj, &gim, "64");
    assert!(
        report.contains(&format!("{} faces, 2 components", 2 * faces)) && report.contains("no repair needed"),
        "both copies whole: {report}"
    );
    let g = Gim::open(&gim, MemoryBudget::default()).unwrap();
    let mesh = g.mesh().unwrap();
    assert_eq!(mesh.triangles.len(), 2 * faces);
    // dense vertices on both copies
    let chart: Vec<u32> = g.read("chart").unwrap();
    let pos: Vec<f32> = g.read("position").unwrap();
    let xs: Vec<f32> = (0..chart.len())
        .filter(|&t| chart[t] != EMPTY)
        .map(|t| pos[3 * t])
        .collect();
    assert!(
        xs.iter().any(|&x| x < 2.0) && xs.iter().any(|&x| x > 2e5),
        "both copies rasterized"
    );
}

#[test]
fn mesh_extreme_scales_give_an_atlas_in_the_users_units() {
    let dir = tempfile::tempdir().unwrap();
    let unit = dir.path().join("unit.gim");
    atlas_ok(
        &write(dir.path(), "unit.obj", &squares_obj(&[(0.0, 1.0)])),
        &unit,
        "64",
    );
    let sample = crate::common::brick_crop(dir.path(), 32, None);
    let unit_quilt = dir.path().join("unit.quilt");
    crate::common::tile(&unit, &sample, &unit_quilt);
    let unit_png = dir.path().join("unit.png");
    crate::common::ok(&[
        "render",
        s(&unit_quilt),
        "--width",
        "48",
        "--height",
        "36",
        "-o",
        s(&unit_png),
    ]);
    let unit_render = btfquilt::io::imageio::read_rgb(&unit_png).unwrap();
    let unit = Gim::open(&unit, MemoryBudget::default()).unwrap().mesh().unwrap();
    for scale in [1e30, 1e-30] {
        let obj = write(dir.path(), "scaled.obj", &squares_obj(&[(0.0, scale)]));
        let gim = dir.path().join("scaled.gim");
        let report = atlas_ok(&obj, &gim, "64");
        assert!(!report.contains("NaN"), "scale {scale}: {report}");
        let g = Gim::open(&gim, MemoryBudget::default()).unwrap();
        // the same mesh as the unit square's, in the user's units
        let mesh = g.mesh().unwrap();
        assert_eq!(mesh.triangles, unit.triangles, "scale {scale}");
        for (p, q) in mesh.positions.iter().zip(&unit.positions) {
            for k in 0..3 {
                assert_eq!(p[k], (q[k] as f64 * scale) as f32, "scale {scale}");
            }
        }
        // dense positions in the user's units, and plenty of them
        let chart: Vec<u32> = g.read("chart").unwrap();
        let pos: Vec<f32> = g.read("position").unwrap();
        let covered: Vec<usize> = (0..chart.len()).filter(|&t| chart[t] != EMPTY).collect();
        assert!(
            covered.len() > 64 * 64 / 4,
            "scale {scale}: {} dense vertices",
            covered.len()
        );
        let max = covered
            .iter()
            .map(|&t| pos[3 * t].abs().max(pos[3 * t + 1].abs()) as f64)
            .fold(0.0, f64::max);
        assert!(
            max > 0.9 * scale && max < 1.1 * scale,
            "scale {scale}: largest dense coordinate {max}"
        );
        assert!(covered
            .iter()
            .all(|&t| pos[3 * t..3 * t + 3].iter().all(|c| c.is_finite())));
        // decorated and rendered, it looks as the unit square does (no
        // blank image from f32 overflow in the renderer)
        let quilt = dir.path().join("scaled.quilt");
        crate::common::tile(&gim, &sample, &quilt);
        let png = dir.path().join("scaled.png");
        crate::common::ok(&[
            "render",
            s(&quilt),
            "--width",
            "48",
            "--height",
            "36",
            "-o",
            s(&png),
        ]);
        let img = btfquilt::io::imageio::read_rgb(&png).unwrap();
        // the same silhouette as the unit square's, shaded (the tiling
        // itself may differ in the last bits of its f32 frames)
        let bg = |d: &[f32], k: usize| d[3 * k..3 * k + 3] == d[0..3];
        let pixels = img.data.len() / 3;
        let same = (0..pixels)
            .filter(|&k| bg(&img.data, k) == bg(&unit_render.data, k))
            .count();
        let drawn = (0..pixels).filter(|&k| !bg(&img.data, k)).count();
        assert!(
            drawn > pixels / 10,
            "scale {scale}: a blank render ({drawn} pixels drawn)"
        );
        assert!(
            same * 100 >= pixels * 97,
            "scale {scale}: silhouette differs on {} of {pixels} pixels",
            pixels - same
        );
        assert!(img.data.iter().all(|v| v.is_finite()));
    }
}

#[test]
fn mesh_non_finite_coordinates_refused_naming_the_file() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("x.gim");
    for (name, coord) in [("nan.obj", "nan"), ("inf.obj", "inf"), ("huge.obj", "1e39")] {
        let obj = write(
            dir.path(),
            name,
            &format!("v 0 0 0\nv 1 0 0\nv 0 1 {coord}\nf 1 2 3\n"),
        );
        refuses(
            &["atlas", s(&obj), "-o", s(&out)],
            &[name, "vertex 3", "non-finite"],
            Some(&out),
        );
    }
    let ply = square_ply().replacen("\n0 0 0\n", "\n0 1e39 0\n", 1);
    let p = write(dir.path(), "huge.ply", &ply);
    refuses(
        &["atlas", s(&p), "-o", s(&out)],
        &["huge.ply", "vertex 0", "non-finite"],
        Some(&out),
    );
}

#[test]
fn mesh_ply_face_count_must_match_the_data() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("x.gim");
    let faces = common::square_grid().1.len();
    let under = square_ply().replace(&format!("element face {faces}"), "element face 10");
    let p = write(dir.path(), "under.ply", &under);
    refuses(
        &["atlas", s(&p), "-o", s(&out)],
        &["under.ply", "the header declares 10 faces but more data follows"],
        Some(&out),
    );
    let over = square_ply().replace(
        &format!("element face {faces}"),
        &format!("element face {}", faces + 5),
    );
    let p = write(dir.path(), "over.ply", &over);
    refuses(
        &["atlas", s(&p), "-o", s(&out)],
        &["over.ply", "face"],
        Some(&out),
    );
    // trailing blank lines are no data
    let p = write(dir.path(), "blank.ply", &(square_ply() + "\n\n  \n"));
    atlas_ok(&p, &out, "32");
}

#[test]
fn mesh_without_polygons_says_what_is_wrong() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("x.gim");
    let obj = write(
        dir.path(),
        "lines.obj",
        "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2\nf 2 3\n",
    );
    refuses(
        &["atlas", s(&obj), "-o", s(&out)],
        &["lines.obj", "fewer than 3 vertices"],
        Some(&out),
    );
    let ply = "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n\
               property float z\nelement face 2\nproperty list uchar int vertex_indices\nend_header\n\
               0 0 0\n1 0 0\n0 1 0\n2 0 1\n2 1 2\n";
    let p = write(dir.path(), "lines.ply", ply);
    refuses(
        &["atlas", s(&p), "-o", s(&out)],
        &["lines.ply", "fewer than 3 vertices"],
        Some(&out),
    );
    let obj = write(dir.path(), "points.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\n");
    refuses(
        &["atlas", s(&obj), "-o", s(&out)],
        &["points.obj", "3 vertices but no faces"],
        Some(&out),
    );
    let obj = write(dir.path(), "line.obj", "v 0 0 0\nv 1 0 0\nv 2 0 0\nf 1 2 3\n");
    refuses(
        &["atlas", s(&obj), "-o", s(&out)],
        &["line.obj", "degenerate"],
        Some(&out),
    );
}

#[test]
fn mesh_float_flags_must_be_finite() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let obj = common::square_obj(d);
    let gim = d.join("square.gim");
    atlas_ok(&obj, &gim, "32");
    let sample = common::brick_crop(d, 64, None);
    let out = d.join("x.gim");
    for (flag, value) in [
        ("--weld", "inf"),
        ("--weld", "NaN"),
        ("--max-stretch", "NaN"),
        ("--max-area-distortion", "inf"),
        ("--max-linf-stretch", "NaN"),
        ("--field-exposure", "NaN"),
        ("--field-exposure", "-1"),
        ("--field-exposure", "9"),
    ] {
        let arg = format!("{flag}={value}");
        refuses(
            &["atlas", s(&obj), &arg, "-o", s(&out)],
            &[flag, value],
            Some(&out),
        );
    }
    let quilt = d.join("x.quilt");
    for (flag, value) in [
        ("--seam-threshold", "NaN"),
        ("--refine", "NaN"),
        ("--seam-threshold", "-1"),
        ("--occurrence-weight", "-0.5"),
        ("--occurrence-weight", "inf"),
        ("--tolerance", "-0.1"),
        ("--tolerance", "NaN"),
        ("--structure-weight", "-1"),
        ("--feature-align", "NaN"),
        ("--feature-align", "-0.1"),
        ("--feature-align", "0.6"),
        ("--field-turn", "-1"),
        ("--refine-passes", "0"),
    ] {
        let arg = format!("{flag}={value}");
        refuses(
            &[
                "tile",
                "--gim",
                s(&gim),
                "--sample",
                s(&sample),
                &arg,
                "-o",
                s(&quilt),
            ],
            &[flag, value],
            Some(&quilt),
        );
    }
    let png = d.join("x.png");
    refuses(
        &["render", s(&gim), "--exposure", "NaN", "-o", s(&png)],
        &["--exposure", "NaN"],
        Some(&png),
    );
    refuses(
        &[
            "render",
            s(&gim),
            "--camera",
            "0,0,NaN,0,0,0,0,1,0,45",
            "-o",
            s(&png),
        ],
        &["--camera", "NaN", "finite"],
        Some(&png),
    );
}

#[test]
fn mesh_paint_points_far_or_not_finite() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let obj = common::square_obj(d);
    let gim = d.join("square.gim");
    atlas_ok(&obj, &gim, "64");
    let sample = common::brick_crop(d, 64, None);
    let mask = d.join("mask.png");
    common::write_mask_png(&mask, 64, 64, |x, y| {
        (x as f32 - 32.0).powi(2) + (y as f32 - 32.0).powi(2) < 100.0
    });
    let quilt = d.join("base.quilt");
    let o = run_bounded(&[
        "tile",
        "--gim",
        s(&gim),
        "--sample",
        s(&sample),
        "--sample-mask",
        s(&mask),
        "--patch-radius",
        "8",
        "--refine",
        "0",
        "-q",
        "-o",
        s(&quilt),
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let out = d.join("painted.quilt");
    let preview = d.join("preview.png");
    // strokes: infinite point, far point, infinite and negative radius
    for (name, stroke, needle) in [
        (
            "inf.json",
            r#"[{"point": [1e999, 0, 0], "radius": 0.1}]"#,
            "number out of range",
        ),
        (
            "far.json",
            r#"[{"point": [1e30, 0, 0], "radius": 0.1}]"#,
            "from the surface",
        ),
        (
            "radius.json",
            r#"[{"point": [0.5, 0.5, 0], "radius": 1e999}]"#,
            "number out of range",
        ),
        (
            "negative.json",
            r#"[{"point": [0.5, 0.5, 0], "radius": -1}]"#,
            "has no positive \"radius\"",
        ),
    ] {
        let strokes = write(d, name, stroke);
        refuses(
            &["paint", s(&quilt), "--region", s(&strokes), "-o", s(&out)],
            &[name, needle],
            Some(&out),
        );
    }
    for at in ["1e30,0,0", "0,-1e30,0"] {
        refuses(
            &[
                "paint",
                s(&quilt),
                "--verbatim",
                "--at",
                at,
                "--preview",
                s(&preview),
            ],
            &["--at", "from the surface"],
            Some(&preview),
        );
    }
    refuses(
        &[
            "paint",
            s(&quilt),
            "--verbatim",
            "--at",
            "1e999,0,0",
            "--preview",
            s(&preview),
        ],
        &["--at", "finite"],
        Some(&preview),
    );
    for (flag, value) in [("--angle", "NaN"), ("--constraint-weight", "NaN")] {
        refuses(
            &[
                "paint",
                s(&quilt),
                "--verbatim",
                "--at",
                "0.5,0.5,0",
                flag,
                value,
                "-o",
                s(&out),
            ],
            &[flag, value],
            Some(&out),
        );
    }
    // a point near (not on) the surface is still fine
    let o = run_bounded(&[
        "paint",
        s(&quilt),
        "--verbatim",
        "--at",
        "0.5,0.5,0.3",
        "--preview",
        s(&preview),
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(preview.exists());
}

/// Mutations of a small OBJ and ASCII PLY through `atlas`: success, or a
/// clean refusal naming the file; never a panic or a signal.
#[test]
fn mesh_mutations_load_or_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let cases = fuzz_cases(40);
    let mut rng = Rng(0x6d65_7368_2021);
    let out = dir.path().join("m.gim");
    let mut ran = 0;
    for (name, text) in [("m.obj", squares_obj(&[(0.0, 1.0)])), ("m.ply", square_ply())] {
        let path = dir.path().join(name);
        for _ in 0..cases {
            std::fs::write(&path, mutate(text.as_bytes(), &mut rng)).unwrap();
            let _ = std::fs::remove_file(&out);
            let o = run_bounded(&["atlas", s(&path), "-o", s(&out), "--resolution", "64", "-q"]);
            let stderr = String::from_utf8_lossy(&o.stderr);
            assert!(
                !stderr.contains("panicked") && o.status.code().is_some(),
                "{name}: {:?} {stderr}",
                o.status
            );
            if !o.status.success() {
                assert!(stderr.contains(name), "{name}: refusal names the file: {stderr}");
                assert!(!out.exists(), "{name}: nothing written on refusal");
            }
            ran += 1;
        }
    }
    eprintln!("mesh mutations: {ran} cases");
}

#[test]
fn factorize_and_generate_counts_are_checked() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let sample = common::brick_crop(d, 32, None);
    let svd = d.join("x.svd");
    for (flag, value, needle) in [
        ("--terms", "0", "at least 1"),
        ("--rotations", "257", "at most 256"),
        ("--power-iterations", "33", "at most 32"),
    ] {
        refuses(
            &["factorize", s(&sample), flag, value, "-o", s(&svd)],
            &[flag, value, needle],
            Some(&svd),
        );
    }
    let btf = d.join("x.btf");
    refuses(
        &["generate-btf", "--size", "0", "-o", s(&btf)],
        &["0×0", "texels per side"],
        Some(&btf),
    );
    refuses(
        &["generate-btf", "--size", "70000", "-o", s(&btf)],
        &["70000×70000", "65536"],
        Some(&btf),
    );
    // what the command line cannot express, the library still refuses
    let none = btfquilt::generate::GenerateConfig {
        views: Vec::new(),
        ..Default::default()
    };
    let e = none.validate().unwrap_err().to_string();
    assert!(e.contains("0 view"), "{e}");
    let level = btfquilt::quilt::TileConfig {
        level: 0,
        ..Default::default()
    };
    let e = level.validate().unwrap_err().to_string();
    assert!(e.contains("zstd level 0"), "{e}");
}
