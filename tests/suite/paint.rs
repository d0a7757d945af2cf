//! Graphcut texture painting (§IV): the constraint function, the painting
//! measures on a flat square, the region inputs (mask, strokes, vertex
//! paint), verbatim copy, the paint log and its replay, and bad inputs.

use std::path::{Path, PathBuf};

use btfquilt::artifact::gim::{Gim, EMPTY};
use btfquilt::atlas::{self, AtlasConfig};
use btfquilt::container::MemoryBudget;
use btfquilt::io::imageio;
use btfquilt::paint::{self, PaintConfig, Verbatim};
use btfquilt::progress::Silent;
use btfquilt::quilt::{self, Quilt, TileConfig};

use crate::common::{self, write_mask_png, write_rgb_png};

const R: usize = 128;

/// The shared flat square as PLY with per-vertex quality 1 where x ≤ ½.
fn square_ply(dir: &Path) -> PathBuf {
    let (v, f) = common::square_grid();
    let p = dir.join("square.ply");
    let mut s = format!(
        "ply\nformat ascii 1.0\nelement vertex {}\nproperty float x\nproperty float y\nproperty float z\n\
         property float quality\nelement face {}\nproperty list uchar int vertex_indices\nend_header\n",
        v.len(),
        f.len()
    );
    for q in &v {
        s += &format!("{} {} 0 {}\n", q[0], q[1], if q[0] <= 0.5 { 1 } else { 0 });
    }
    for t in &f {
        s += &format!("3 {} {} {}\n", t[0], t[1], t[2]);
    }
    std::fs::write(&p, s).unwrap();
    p
}

/// A decorated flat square: (gim, sample, its foreground mask, base quilt).
/// The sample is a brick crop; its foreground a disk in one corner, which
/// the background tiling keeps out.
pub(crate) struct Scene {
    _dir: tempfile::TempDir,
    pub(crate) dir: PathBuf,
    gim: PathBuf,
    sample: PathBuf,
    mask: PathBuf,
    pub(crate) base: PathBuf,
}

pub(crate) fn scene() -> Scene {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path().to_path_buf();
    let g = d.join("square.gim");
    let cfg = AtlasConfig {
        resolution: R,
        ..AtlasConfig::default()
    };
    atlas::build_gim(&common::square_obj(&d), &g, &cfg, &Silent).unwrap();
    let sample = common::brick_crop(&d, 96, Some((100, 100)));
    let mask = d.join("mask.png");
    let disk = |x: usize, y: usize| (x as f32 - 22.0).powi(2) + (y as f32 - 22.0).powi(2) < 16.0f32.powi(2);
    write_mask_png(&mask, 96, 96, disk);
    let base = d.join("base.quilt");
    let tc = TileConfig {
        sample_mask: Some(mask.clone()),
        patch_radius: Some(12),
        ..TileConfig::default()
    };
    quilt::tile(&g, &sample, &base, &tc, &Silent).unwrap();
    Scene {
        _dir: dir,
        dir: d,
        gim: g,
        sample,
        mask,
        base,
    }
}

fn painting_figures(q: &Path) -> (f64, f64) {
    let report = btfquilt::output::evaluate::evaluate(q, None, None, MemoryBudget::default()).unwrap();
    let p = report.painting.expect("painting figures of a painted surface");
    (
        p.region_covered_by_foreground,
        p.foreground_outside_region_and_transition,
    )
}

fn region_array(q: &Path) -> Vec<f32> {
    let q = Quilt::open(q, MemoryBudget::default()).unwrap();
    let c = q.container();
    c.read_array(c.array("region").unwrap()).unwrap()
}

fn paint_cfg(s: &Scene) -> PaintConfig {
    PaintConfig {
        sample_mask: Some(s.mask.clone()),
        transition: 0,
        tile: TileConfig {
            patch_radius: Some(12),
            ..TileConfig::default()
        },
        ..PaintConfig::default()
    }
}

#[test]
fn painting_a_region_fills_it_merges_it_and_replays() {
    let s = scene();
    let gim = Gim::open(&s.gim, MemoryBudget::default()).unwrap();
    let chart: Vec<u32> = gim.read("chart").unwrap();
    // F: a disk of radius 14 texels in the atlas, inside the chart
    let covered: Vec<usize> = (0..R * R).filter(|&t| chart[t] != EMPTY).collect();
    let (cx, cy) = (
        covered.iter().map(|t| t % R).sum::<usize>() as f32 / covered.len() as f32,
        covered.iter().map(|t| t / R).sum::<usize>() as f32 / covered.len() as f32,
    );
    let in_f =
        |t: usize| chart[t] != EMPTY && ((t % R) as f32 - cx).powi(2) + ((t / R) as f32 - cy).powi(2) < 196.0;
    let region = s.dir.join("region.png");
    write_rgb_png(
        &region,
        R,
        R,
        |x, y| if in_f(y * R + x) { [1.0; 3] } else { [0.0; 3] },
    );
    let base_bytes = std::fs::read(&s.base).unwrap();
    let out = s.dir.join("painted.quilt");
    let cfg = PaintConfig {
        region: Some(region.clone()),
        transition: 5,
        ..paint_cfg(&s)
    };
    let report = paint::paint(&s.base, &out, &cfg, &Silent).unwrap();
    assert!(report.region_texels > 500 && report.repainted > 0, "{report}");
    // the base stays as it was: undo is free
    assert_eq!(std::fs::read(&s.base).unwrap(), base_bytes);

    // m0: 1 on F, 1 − d/(T+1) at d hops outside (a 4-neighbour BFS on the
    // single chart), 0 beyond
    let m0 = region_array(&out);
    let mut hops = vec![u32::MAX; R * R];
    let mut queue: std::collections::VecDeque<usize> = (0..R * R).filter(|&t| in_f(t)).collect();
    for &t in &queue {
        hops[t] = 0;
    }
    while let Some(t) = queue.pop_front() {
        let (x, y) = (t % R, t / R);
        for n in [
            (x > 0).then(|| t - 1),
            (x + 1 < R).then(|| t + 1),
            (y > 0).then(|| t - R),
            (y + 1 < R).then(|| t + R),
        ]
        .into_iter()
        .flatten()
        {
            if chart[n] != EMPTY && hops[n] == u32::MAX {
                hops[n] = hops[t] + 1;
                queue.push_back(n);
            }
        }
    }
    for t in 0..R * R {
        let want = match hops[t] {
            u32::MAX => 0.0,
            d => (1.0 - d as f32 / 6.0).max(0.0),
        };
        assert!(
            (m0[t] - want).abs() < 1e-6,
            "m0 at texel {t}: {} vs {want}",
            m0[t]
        );
    }

    // the measures of §IV: F filled with foreground, none spilled outside
    let (coverage, spill) = painting_figures(&out);
    assert!(coverage >= 0.95, "F covered by foreground: {coverage}");
    assert!(
        spill <= 0.05,
        "foreground outside F and the transition zone: {spill}"
    );

    // the log replays to the same bytes, on one thread within 24 MiB and
    // on two
    let again = s.dir.join("replayed.quilt");
    rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .unwrap()
        .install(|| paint::replay(&out, &again, MemoryBudget(24 << 20), &Silent))
        .unwrap();
    assert_eq!(std::fs::read(&again).unwrap(), std::fs::read(&out).unwrap());
    let two = s.dir.join("two.quilt");
    rayon::ThreadPoolBuilder::new()
        .num_threads(2)
        .build()
        .unwrap()
        .install(|| paint::paint(&s.base, &two, &cfg, &Silent))
        .unwrap();
    assert_eq!(std::fs::read(&two).unwrap(), std::fs::read(&out).unwrap());
    // painting a painted surface appends to its log, and replays too
    let twice = s.dir.join("twice.quilt");
    let strokes = s.dir.join("s.json");
    std::fs::write(&strokes, r#"[{"point": [0.2, 0.2, 0.0], "radius": 0.1}]"#).unwrap();
    let cfg2 = PaintConfig {
        region: Some(strokes),
        ..cfg.clone()
    };
    paint::paint(&out, &twice, &cfg2, &Silent).unwrap();
    let again2 = s.dir.join("replayed2.quilt");
    paint::replay(&twice, &again2, Default::default(), &Silent).unwrap();
    assert_eq!(std::fs::read(&again2).unwrap(), std::fs::read(&twice).unwrap());
}

#[test]
fn strokes_are_geodesic_disks_and_vertex_paint_is_interpolated() {
    let s = scene();
    let gim = Gim::open(&s.gim, MemoryBudget::default()).unwrap();
    let chart: Vec<u32> = gim.read("chart").unwrap();
    let pos: Vec<f32> = gim.read("position").unwrap();
    let strokes = s.dir.join("strokes.json");
    std::fs::write(&strokes, r#"[{"point": [0.5, 0.5, 0.02], "radius": 0.2}]"#).unwrap();
    let out = s.dir.join("a.quilt");
    let cfg = PaintConfig {
        region: Some(strokes),
        transition: 0,
        ..paint_cfg(&s)
    };
    paint::paint(&s.base, &out, &cfg, &Silent).unwrap();
    let m0 = region_array(&out);
    for t in (0..R * R).filter(|&t| chart[t] != EMPTY) {
        let d = ((pos[t * 3] - 0.5).powi(2) + (pos[t * 3 + 1] - 0.5).powi(2)).sqrt();
        // 8-neighbour paths are at most 8.24 % longer than straight ones;
        // the source texel is within a texel (1/120) of the point
        if d + 0.01 < 0.2 / 1.0824 {
            assert_eq!(m0[t], 1.0, "texel {t} at distance {d} should be in the disk");
        }
        if d > 0.2 + 0.01 {
            assert_eq!(m0[t], 0.0, "texel {t} at distance {d} should be outside the disk");
        }
    }
    // vertex paint: quality 1 on vertices with x ≤ ½, 0 from x = 5/8: the
    // interpolated weight is ≥ ½ for x ≤ 9/16
    region_is_left_of(&s, square_ply(&s.dir), 0.555, 0.57);
}

/// Paints the scene with a vertex-paint region and checks F by the texels'
/// x: in F left of `inside`, out of it right of `outside`.
fn region_is_left_of(s: &Scene, region: PathBuf, inside: f32, outside: f32) {
    let gim = Gim::open(&s.gim, MemoryBudget::default()).unwrap();
    let chart: Vec<u32> = gim.read("chart").unwrap();
    let pos: Vec<f32> = gim.read("position").unwrap();
    let out = s.dir.join("vertex-paint.quilt");
    let cfg = PaintConfig {
        region: Some(region),
        transition: 0,
        ..paint_cfg(s)
    };
    paint::paint(&s.base, &out, &cfg, &Silent).unwrap();
    let m0 = region_array(&out);
    for t in (0..R * R).filter(|&t| chart[t] != EMPTY) {
        let x = pos[t * 3];
        if x < inside {
            assert_eq!(m0[t], 1.0, "texel {t} at x = {x}");
        }
        if x > outside {
            assert_eq!(m0[t], 0.0, "texel {t} at x = {x}");
        }
    }
}

#[test]
fn obj_vertex_colours_mark_the_region_against_the_dominant_colour() {
    let s = scene();
    // the square as OBJ with vertex colours: red where x ≤ ¼ (27 vertices),
    // white elsewhere (54, the dominant, unpainted colour)
    let obj = std::fs::read_to_string(common::square_obj(&s.dir)).unwrap();
    let painted: String = obj
        .lines()
        .map(|l| {
            if let Some(rest) = l.strip_prefix("v ") {
                let x: f32 = rest.split_whitespace().next().unwrap().parse().unwrap();
                let c = if x <= 0.25 { "1 0 0" } else { "1 1 1" };
                format!("v {rest} {c}\n")
            } else {
                format!("{l}\n")
            }
        })
        .collect();
    let path = s.dir.join("painted.obj");
    std::fs::write(&path, painted).unwrap();
    // weight 1 up to x = ¼, falling to 0 at ⅜: ≥ ½ up to x = 5/16
    region_is_left_of(&s, path, 0.305, 0.32);
}

#[test]
fn verbatim_copy_places_the_whole_foreground() {
    let s = scene();
    let preview = s.dir.join("preview.png");
    let v = Verbatim {
        at: [0.5, 0.5, 0.0],
        angle: 30.0,
    };
    let cfg = PaintConfig {
        verbatim: Some(v),
        preview: Some(preview.clone()),
        ..paint_cfg(&s)
    };
    let out = s.dir.join("v.quilt");
    let e = paint::paint(&s.base, &out, &cfg, &Silent)
        .unwrap_err()
        .to_string();
    assert!(e.contains("--preview"), "{e}");
    assert!(!out.exists() && !preview.exists());
    let report = paint::preview(&s.base, &cfg, &Silent).unwrap();
    let first = std::fs::read(&preview).unwrap();
    assert!(imageio::read_rgb(&preview).unwrap().width > 20);
    assert!(report.region_texels > 600, "{report}");
    assert!(!out.exists(), "a preview writes no quilt");
    // a session opens the artifacts once: the same preview, then others
    let mut session = paint::PreviewSession::open(&s.base, &cfg, &Silent).unwrap();
    let again = s.dir.join("again.png");
    assert_eq!(session.preview(v, &again, &Silent).unwrap(), report.region_texels);
    assert_eq!(std::fs::read(&again).unwrap(), first);
    let turned = s.dir.join("turned.png");
    session
        .preview(Verbatim { angle: 75.0, ..v }, &turned, &Silent)
        .unwrap();
    assert_ne!(
        std::fs::read(&turned).unwrap(),
        first,
        "another angle, another picture"
    );
    let cfg = PaintConfig { preview: None, ..cfg };
    let report = paint::paint(&s.base, &out, &cfg, &Silent).unwrap();
    // the disk has ~800 pixels; every placed foreground texel took the copy
    assert!(report.region_texels > 600, "{report}");
    let (coverage, _) = painting_figures(&out);
    assert!(
        coverage >= 0.99,
        "verbatim copy left {coverage} of the foreground"
    );
}

#[test]
fn bad_paint_inputs_are_refused_and_write_nothing() {
    let s = scene();
    let out = s.dir.join("never.quilt");
    let err = |cfg: PaintConfig| -> String {
        let e = paint::paint(&s.base, &out, &cfg, &Silent)
            .err()
            .expect("should fail")
            .to_string();
        assert!(!out.exists(), "{e}: output written");
        e
    };
    let small = s.dir.join("small.png");
    write_rgb_png(&small, 10, 10, |_, _| [1.0; 3]);
    let e = err(PaintConfig {
        region: Some(small.clone()),
        ..paint_cfg(&s)
    });
    assert!(e.contains("small.png") && e.contains("atlas size"), "{e}");
    let e = err(PaintConfig {
        region: Some(s.sample.clone()),
        sample_mask: Some(small.clone()),
        ..paint_cfg(&s)
    });
    assert!(e.contains("small.png") && e.contains("sample's size"), "{e}");
    let txt = s.dir.join("region.txt");
    std::fs::write(&txt, "x").unwrap();
    let e = err(PaintConfig {
        region: Some(txt),
        ..paint_cfg(&s)
    });
    assert!(e.contains("region.txt") && e.contains("not a region"), "{e}");
    let bad = s.dir.join("bad.json");
    std::fs::write(&bad, r#"[{"point": [0, 0]}]"#).unwrap();
    let e = err(PaintConfig {
        region: Some(bad),
        ..paint_cfg(&s)
    });
    assert!(e.contains("bad.json") && e.contains("point"), "{e}");
    let other = s.dir.join("other.png");
    std::fs::copy(&s.sample, &other).unwrap();
    let e = err(PaintConfig {
        sample: Some(other.clone()),
        sample_mask: None,
        region: Some(s.mask.clone()),
        ..paint_cfg(&s)
    });
    assert!(e.contains("--sample-mask") && e.contains("other.png"), "{e}");
    let e = err(PaintConfig {
        sample: Some(s.dir.join("gone.png")),
        region: Some(s.mask.clone()),
        ..paint_cfg(&s)
    });
    assert!(e.contains("gone.png") && e.contains("does not exist"), "{e}");
    let e = err(paint_cfg(&s));
    assert!(e.contains("--region"), "{e}");
    let empty = s.dir.join("empty.png");
    write_rgb_png(&empty, R, R, |_, _| [0.0; 3]);
    let e = err(PaintConfig {
        region: Some(empty),
        ..paint_cfg(&s)
    });
    assert!(e.contains("empty.png") && e.contains("no texel"), "{e}");
}

#[test]
fn paint_cli_fails_clearly_with_a_non_zero_exit() {
    let s = scene();
    let small = s.dir.join("tiny.png");
    write_rgb_png(&small, 10, 10, |_, _| [1.0; 3]);
    let out = s.dir.join("cli.quilt");
    let run = |args: &[&str]| {
        std::process::Command::new(env!("CARGO_BIN_EXE_btfquilt"))
            .args(args)
            .output()
            .unwrap()
    };
    let base = s.base.to_str().unwrap();
    let o = run(&[
        "paint",
        base,
        "--sample-mask",
        s.mask.to_str().unwrap(),
        "--region",
        small.to_str().unwrap(),
        "-o",
        out.to_str().unwrap(),
    ]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        !o.status.success() && err.contains("tiny.png") && err.contains("atlas size"),
        "{err}"
    );
    assert!(!out.exists());
    let o = run(&[
        "paint",
        base,
        "--verbatim",
        "--at",
        "0.5,0.5",
        "-o",
        out.to_str().unwrap(),
    ]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success() && err.contains("x,y,z"), "{err}");
    let o = run(&["paint", base, "--region", small.to_str().unwrap()]);
    assert!(!o.status.success() && String::from_utf8_lossy(&o.stderr).contains("-o"));
    // a good stroke through the CLI, then its replay: the same bytes
    let strokes = s.dir.join("s.json");
    std::fs::write(&strokes, r#"[{"point": [0.5, 0.5, 0.0], "radius": 0.15}]"#).unwrap();
    let o = run(&[
        "paint",
        base,
        "--sample-mask",
        s.mask.to_str().unwrap(),
        "--region",
        strokes.to_str().unwrap(),
        "--patch-radius",
        "12",
        "-o",
        out.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let again = s.dir.join("again.quilt");
    let o = run(&["replay", out.to_str().unwrap(), "-o", again.to_str().unwrap()]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert_eq!(std::fs::read(&again).unwrap(), std::fs::read(&out).unwrap());
}

/// A stain sample: green-grey noise with a striped blue disk (its
/// foreground) in the middle; returns (sample, mask).
fn stain_sample(dir: &Path) -> (PathBuf, PathBuf) {
    let disk = |x: usize, y: usize| (x as f32 - 48.0).powi(2) + (y as f32 - 48.0).powi(2) < 22.0f32.powi(2);
    let noise = |x: usize, y: usize| ((x * 7919 + y * 104_729) % 1000) as f32 / 1000.0;
    let sample = dir.join("stain.png");
    write_rgb_png(&sample, 96, 96, |x, y| {
        if disk(x, y) {
            let stripe = if (x + y) % 6 < 3 { 0.25 } else { 0.05 };
            [stripe, stripe, 0.7 + 0.2 * noise(x, y)]
        } else {
            let v = 0.3 + 0.2 * noise(x, y);
            [v, v + 0.1, v]
        }
    });
    let mask = dir.join("stain_mask.png");
    write_mask_png(&mask, 96, 96, disk);
    (sample, mask)
}

#[test]
fn painting_with_another_sample_adds_it_to_the_surface() {
    let s = scene();
    let (stain, stain_mask) = stain_sample(&s.dir);
    let region = s.dir.join("strokes.json");
    std::fs::write(&region, r#"[{"point": [0.5, 0.5, 0.0], "radius": 0.12}]"#).unwrap();
    let out = s.dir.join("stained.quilt");
    let cfg = PaintConfig {
        sample: Some(stain.clone()),
        sample_mask: Some(stain_mask.clone()),
        region: Some(region.clone()),
        transition: 4,
        ..paint_cfg(&s)
    };
    let report = paint::paint(&s.base, &out, &cfg, &Silent).unwrap();
    assert!(report.region_texels > 300, "{report}");
    let q = Quilt::open(&out, MemoryBudget::default()).unwrap();
    assert_eq!(q.samples, vec![s.sample.clone(), stain.clone()]);
    assert_eq!(q.mask_sample(), 1);
    let index = q.sample_index().unwrap();
    let m0 = region_array(&out);
    let from_stain = index.iter().filter(|&&k| k == 1).count();
    assert!(
        from_stain >= report.region_texels,
        "{from_stain} texels from the stain"
    );
    for t in 0..R * R {
        assert!(
            index[t] == 0 || m0[t] > 0.0,
            "texel {t} took the stain outside the zone"
        );
    }
    // §IV measures count the stain's foreground: F filled, nothing spilled
    let (coverage, spill) = painting_figures(&out);
    assert!(
        coverage >= 0.95,
        "F covered by the stain's foreground: {coverage}"
    );
    assert!(
        spill <= 0.05,
        "stain foreground outside F and the transition zone: {spill}"
    );

    // the baked colours: blue in F, the base's bricks outside the zone
    let bake = |q: &Path, png: &str| {
        let p = s.dir.join(png);
        btfquilt::output::bake::bake(q, None, &p, MemoryBudget::default()).unwrap();
        imageio::read_rgb(&p).unwrap()
    };
    let (before, after) = (bake(&s.base, "before.png"), bake(&out, "after.png"));
    let (mut blue, mut in_f, mut changed_outside) = (0, 0, 0);
    for t in 0..R * R {
        let px = &after.data[t * 3..t * 3 + 3];
        if m0[t] >= 1.0 {
            in_f += 1;
            blue += (px[2] > px[0] + 0.2) as usize;
        } else if m0[t] <= 0.0 && before.data[t * 3..t * 3 + 3] != *px {
            changed_outside += 1;
        }
    }
    assert!(
        blue as f64 >= 0.95 * in_f as f64,
        "{blue} of {in_f} texels of F are blue"
    );
    assert_eq!(changed_outside, 0, "texels outside the zone changed colour");

    // the log records the stain: replay gives the same bytes
    let again = s.dir.join("again.quilt");
    paint::replay(&out, &again, Default::default(), &Silent).unwrap();
    assert_eq!(std::fs::read(&again).unwrap(), std::fs::read(&out).unwrap());

    // painting the tiling's sample again keeps both samples, and leaves the
    // stain where the new zone does not reach
    let corner = s.dir.join("corner.json");
    std::fs::write(&corner, r#"[{"point": [0.15, 0.15, 0.0], "radius": 0.08}]"#).unwrap();
    let twice = s.dir.join("twice.quilt");
    let cfg2 = PaintConfig {
        sample: Some(s.sample.clone()),
        sample_mask: Some(s.mask.clone()),
        region: Some(corner),
        ..paint_cfg(&s)
    };
    paint::paint(&out, &twice, &cfg2, &Silent).unwrap();
    let q2 = Quilt::open(&twice, MemoryBudget::default()).unwrap();
    assert_eq!(q2.samples.len(), 2);
    assert_eq!(q2.mask_sample(), 0);
    let (index2, m2) = (q2.sample_index().unwrap(), region_array(&twice));
    for t in 0..R * R {
        if m2[t] <= 0.0 {
            assert_eq!(index2[t], index[t], "texel {t} outside the second zone");
        }
    }
    let again2 = s.dir.join("again2.quilt");
    paint::replay(&twice, &again2, Default::default(), &Silent).unwrap();
    assert_eq!(std::fs::read(&again2).unwrap(), std::fs::read(&twice).unwrap());
}

/// A surface tiled with a size on the surface (`sample_pixel`) is painted at
/// that size: the stroke keeps the recorded width, a stroke's own size is
/// recorded in the log, and both replay to the same bytes.
#[test]
fn painting_keeps_the_sample_size_on_the_surface() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let g = d.join("square.gim");
    let acfg = AtlasConfig {
        resolution: 96,
        ..AtlasConfig::default()
    };
    atlas::build_gim(&common::square_obj(d), &g, &acfg, &Silent).unwrap();
    let sample = common::brick_crop(d, 64, Some((100, 100)));
    let mask = d.join("mask.png");
    write_mask_png(&mask, 64, 64, |x, y| {
        (x as f32 - 20.0).hypot(y as f32 - 20.0) < 10.0
    });
    let base = d.join("base.quilt");
    let tc = TileConfig {
        sample_mask: Some(mask.clone()),
        sample_pixel: Some(0.008),
        ..TileConfig::default()
    };
    quilt::tile(&g, &sample, &base, &tc, &Silent).unwrap();
    let width = |q: &Path| {
        btfquilt::output::evaluate::evaluate(q, None, None, MemoryBudget::default())
            .unwrap()
            .scale
            .sample_width_units
    };
    let want = 64.0 * 0.008;
    assert!(
        (width(&base) / want - 1.0).abs() < 0.05,
        "{} vs {want}",
        width(&base)
    );
    let strokes = d.join("s.json");
    std::fs::write(&strokes, r#"[{"point": [0.5, 0.5, 0.0], "radius": 0.25}]"#).unwrap();
    for (name, tile) in [
        ("kept", TileConfig::default()),
        (
            "own",
            TileConfig {
                sample_width: Some(want),
                ..TileConfig::default()
            },
        ),
    ] {
        let out = d.join(format!("{name}.quilt"));
        let cfg = PaintConfig {
            sample_mask: Some(mask.clone()),
            region: Some(strokes.clone()),
            tile,
            ..PaintConfig::default()
        };
        let report = paint::paint(&base, &out, &cfg, &Silent).unwrap();
        assert!(report.repainted > 0, "{report}");
        let w = painted_width(&base, &out, &g, 64);
        assert!((w / want - 1.0).abs() < 0.05, "{name}: {w} vs {want}");
        let again = d.join(format!("{name}-replayed.quilt"));
        paint::replay(&out, &again, Default::default(), &Silent).unwrap();
        assert_eq!(
            std::fs::read(&again).unwrap(),
            std::fs::read(&out).unwrap(),
            "{name}"
        );
    }
    // both sizes at once are refused, naming the flags
    let cfg = PaintConfig {
        sample_mask: Some(mask),
        region: Some(strokes),
        tile: TileConfig {
            sample_width: Some(0.5),
            sample_pixel: Some(0.01),
            ..TileConfig::default()
        },
        ..PaintConfig::default()
    };
    let out = d.join("both.quilt");
    let e = paint::paint(&base, &out, &cfg, &Silent).unwrap_err().to_string();
    assert!(
        e.contains("--sample-width") && e.contains("--sample-pixel"),
        "{e}"
    );
    assert!(!out.exists());
}

/// The sample width (mesh units) measured over the patches of `painted`
/// that are not in `base`: the median |Δ sample coordinate| / |Δ position|
/// over grid edges inside one new patch.
fn painted_width(base: &Path, painted: &Path, gim: &Path, sample_px: usize) -> f64 {
    let (b, q) = (
        Quilt::open(base, MemoryBudget::default()).unwrap(),
        Quilt::open(painted, MemoryBudget::default()).unwrap(),
    );
    let old: std::collections::BTreeSet<u32> = b.patches().unwrap().into_iter().collect();
    let (patches, coords) = (q.patches().unwrap(), q.coords().unwrap());
    let position: Vec<f32> = Gim::open(gim, MemoryBudget::default())
        .unwrap()
        .read("position")
        .unwrap();
    let r = q.resolution;
    let mut ratios = Vec::new();
    for t in 0..r * r {
        for n in [t + 1, t + r] {
            if n >= r * r || patches[t] != patches[n] || old.contains(&patches[t]) {
                continue;
            }
            let d = (0..3)
                .map(|k| (position[t * 3 + k] - position[n * 3 + k]).powi(2))
                .sum::<f32>();
            let c = (coords[t][0] - coords[n][0]).hypot(coords[t][1] - coords[n][1]);
            if d > 0.0 {
                ratios.push((c / d.sqrt()) as f64);
            }
        }
    }
    assert!(ratios.len() > 100, "{} edges in new patches", ratios.len());
    ratios.sort_by(f64::total_cmp);
    sample_px as f64 / ratios[ratios.len() / 2]
}
