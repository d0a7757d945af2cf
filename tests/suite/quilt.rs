//! Graphcut quilting on the dense mesh: coverage, determinism, seam quality
//! on a flat square (a 2D target), and the outputs (bake, evaluate, render).

use std::path::{Path, PathBuf};

use btfquilt::artifact::gim::{Gim, EMPTY};
use btfquilt::atlas::{self, AtlasConfig};
use btfquilt::container::MemoryBudget;
use btfquilt::io::imageio;
use btfquilt::progress::Silent;
use btfquilt::quilt::{self, Quilt, TileConfig, NO_PATCH};

use crate::common::{brick_crop, square_obj};

fn atlas(mesh: &Path, out: &Path, r: usize) {
    let cfg = AtlasConfig {
        resolution: r,
        ..AtlasConfig::default()
    };
    atlas::build_gim(mesh, out, &cfg, &Silent).unwrap();
}

/// A flat square (a 2D target) atlased at `r`² into `dir/square.gim`.
fn square_atlas(dir: &Path, r: usize) -> PathBuf {
    let g = dir.join("square.gim");
    atlas(&square_obj(dir), &g, r);
    g
}

/// The shipped Spot atlased at `r`² into `dir/spot.gim`.
fn spot_atlas(dir: &Path, r: usize) -> PathBuf {
    let g = dir.join("spot.gim");
    atlas(
        &Path::new(env!("CARGO_MANIFEST_DIR")).join("data/spot_5.8k.obj"),
        &g,
        r,
    );
    g
}

/// Tiles with `cfg` at a 1 MiB budget, which pages the atlas to scratch
/// and computes one patch at a time, into `dir/small.quilt`, and asserts
/// it pages and gives the bytes of the quilt at `want`.
fn same_quilt_when_paged(g: &Path, sample: &Path, cfg: &TileConfig, dir: &Path, want: &Path) {
    let small = dir.join("small.quilt");
    let cfg_small = TileConfig {
        memory: MemoryBudget(1 << 20),
        ..cfg.clone()
    };
    let report = quilt::tile(g, sample, &small, &cfg_small, &Silent).unwrap();
    assert!(report.scratch_bytes > 0, "{report}");
    assert!(std::fs::read(want).unwrap() == std::fs::read(&small).unwrap());
}

/// `evaluate`'s seam ratio (seam colour difference over that inside
/// patches) of the quilt at `p`.
fn seam_ratio(p: &Path) -> f64 {
    btfquilt::output::evaluate::evaluate(p, None, None, MemoryBudget::default())
        .unwrap()
        .seam
        .ratio_to_inside
}

/// Tiles with 1 and 2 worker threads into `dir/PREFIX1.quilt` and
/// `dir/PREFIX2.quilt`, checking each report.
fn tile_with_threads(
    g: &Path,
    sample: &Path,
    cfg: &TileConfig,
    dir: &Path,
    prefix: &str,
    check: impl Fn(&quilt::TileReport),
) -> Vec<PathBuf> {
    [1, 2]
        .iter()
        .map(|&t| {
            let out = dir.join(format!("{prefix}{t}.quilt"));
            let pool = rayon::ThreadPoolBuilder::new().num_threads(t).build().unwrap();
            let report = pool
                .install(|| quilt::tile(g, sample, &out, cfg, &Silent))
                .unwrap();
            check(&report);
            out
        })
        .collect()
}

#[test]
fn flat_square_is_covered_seamlessly_and_deterministically() {
    let dir = tempfile::tempdir().unwrap();
    let g = square_atlas(dir.path(), 160);
    let sample = brick_crop(dir.path(), 160, Some((100, 100)));
    let cfg = TileConfig {
        seed: 3,
        ..TileConfig::default()
    };
    let outs = tile_with_threads(&g, &sample, &cfg, dir.path(), "t", |report| {
        assert!(report.patches > 3, "{report}")
    });
    assert_eq!(std::fs::read(&outs[0]).unwrap(), std::fs::read(&outs[1]).unwrap());

    // every dense vertex got a patch and a sample coordinate on the sample
    let q = Quilt::open(&outs[0], MemoryBudget::default()).unwrap();
    let chart: Vec<u32> = Gim::open(&g, MemoryBudget::default())
        .unwrap()
        .read("chart")
        .unwrap();
    let (patches, coords) = (q.patches().unwrap(), q.coords().unwrap());
    for t in 0..chart.len() {
        assert_eq!(chart[t] != EMPTY, patches[t] != NO_PATCH, "texel {t}");
        if patches[t] != NO_PATCH {
            assert!(
                coords[t].iter().all(|&c| (0.0..=159.0).contains(&c)),
                "{:?}",
                coords[t]
            );
        }
    }
    // seams: colour steps across patch boundaries are like those inside patches
    let report = btfquilt::output::evaluate::evaluate(&outs[0], None, None, MemoryBudget::default()).unwrap();
    let ratio = report.seam.ratio_to_inside;
    eprintln!("{report:?}");
    assert!(ratio < 1.3, "seams stand out: ratio {ratio}");
    // another seed: another arrangement
    let other = dir.path().join("other.quilt");
    let cfg4 = TileConfig {
        seed: 4,
        ..TileConfig::default()
    };
    quilt::tile(&g, &sample, &other, &cfg4, &Silent).unwrap();
    assert_ne!(std::fs::read(&outs[0]).unwrap(), std::fs::read(&other).unwrap());
}

#[test]
fn spot_is_covered_and_baked_and_rendered() {
    let dir = tempfile::tempdir().unwrap();
    let g = spot_atlas(dir.path(), 192);
    let sample = brick_crop(dir.path(), 128, Some((100, 100)));
    let out = dir.path().join("spot.quilt");
    let unrefined = TileConfig {
        refine: None,
        ..TileConfig::default()
    };
    let report = quilt::tile(&g, &sample, &out, &unrefined, &Silent).unwrap();
    assert!(report.cross_chart_patches > 0, "{report}");
    // a small --memory (1 MiB for each cache: four of the 72 rotated copies
    // at a time on Spot's turning field, evicted and read again, and few
    // cached spectra) gives the same bytes
    let small = dir.path().join("small.quilt");
    let cfg_small = TileConfig {
        memory: MemoryBudget(4 << 20),
        ..unrefined.clone()
    };
    quilt::tile(&g, &sample, &small, &cfg_small, &Silent).unwrap();
    assert_eq!(std::fs::read(&small).unwrap(), std::fs::read(&out).unwrap());
    // seam refinement: patches placed on the worst seams, each kept only if
    // its cut costs less than the seams it replaces, so the seams' total
    // colour step goes down
    let refined = dir.path().join("refined.quilt");
    let cfg_refine = TileConfig::default();
    assert_eq!(cfg_refine.refine, Some(2.0), "refinement is on by default");
    let rr = quilt::tile(&g, &sample, &refined, &cfg_refine, &Silent).unwrap();
    assert!(rr.refined > 0, "{rr}");
    let total_step = |q: &Path| {
        let seam = btfquilt::output::evaluate::evaluate(q, None, None, MemoryBudget::default())
            .unwrap()
            .seam;
        seam.edges as f64 * seam.mean_colour_difference
    };
    let (before, after) = (total_step(&out), total_step(&refined));
    assert!(
        after < before,
        "refinement raised the seams' total step: {before} → {after}"
    );
    let refused = [
        (
            TileConfig {
                refine: Some(0.0),
                ..TileConfig::default()
            },
            "--refine",
        ),
        (
            TileConfig {
                refine_placements: 0,
                ..TileConfig::default()
            },
            "--refine-placements",
        ),
        (
            TileConfig {
                round: 0,
                ..TileConfig::default()
            },
            "--round",
        ),
    ];
    for (cfg, flag) in refused {
        let e = quilt::tile(&g, &sample, &refined, &cfg, &Silent)
            .unwrap_err()
            .to_string();
        assert!(e.contains(flag), "{e}");
    }
    // several placements per seam (the cheapest cut of three) lower them too
    let several = dir.path().join("several.quilt");
    let rs = quilt::tile(
        &g,
        &sample,
        &several,
        &TileConfig {
            refine_placements: 3,
            ..TileConfig::default()
        },
        &Silent,
    )
    .unwrap();
    assert!(rs.refined > 0 && total_step(&several) < before, "{rs}");
    // refinement where features end (on by default) leaves fewer features
    // ending at seams than seam refinement by colour step alone; with it
    // off, its passes have nothing to repeat
    let broken = |q: &Path| {
        btfquilt::output::evaluate::evaluate(q, None, None, MemoryBudget::default())
            .unwrap()
            .continuation
            .broken_per_1000_texels
    };
    let by_step = |name: &str, refine_passes: usize| {
        let out = dir.path().join(name);
        let cfg = TileConfig {
            refine_broken: 0,
            refine_passes,
            ..TileConfig::default()
        };
        quilt::tile(&g, &sample, &out, &cfg, &Silent).unwrap();
        out
    };
    let (step1, step3) = (by_step("step1.quilt", 1), by_step("step3.quilt", 3));
    assert!(std::fs::read(&step1).unwrap() == std::fs::read(&step3).unwrap());
    let (ends_default, ends_step) = (broken(&refined), broken(&step1));
    assert!(
        ends_default < 0.9 * ends_step,
        "broken per 1000 texels: {ends_default} by default, {ends_step} by colour step alone"
    );
    let q = Quilt::open(&out, MemoryBudget::default()).unwrap();
    assert!(q.patches().unwrap().iter().filter(|&&p| p != NO_PATCH).count() == report.texels);
    // the stored seams are exactly the mesh edges whose ends took different
    // patches: grid edges inside a chart, and zipper links between charts
    let (patches, seams) = (q.patches().unwrap(), q.seams().unwrap());
    let gim = btfquilt::artifact::gim::Gim::open(&g, MemoryBudget::default()).unwrap();
    let chart: Vec<u32> = gim.read("chart").unwrap();
    let r = 192;
    let mut want = vec![0u8; r * r];
    for t in 0..r * r {
        let inside = |n: usize| {
            chart[n] == chart[t] && chart[t] != btfquilt::artifact::gim::EMPTY && patches[n] != patches[t]
        };
        if t % r + 1 < r && inside(t + 1) {
            want[t] |= quilt::SEAM_X;
        }
        if t / r + 1 < r && inside(t + r) {
            want[t] |= quilt::SEAM_Y;
        }
    }
    for [a, b] in gim.zipper_links().unwrap() {
        if patches[a as usize] != patches[b as usize] {
            want[a as usize] |= quilt::SEAM_ZIPPER;
            want[b as usize] |= quilt::SEAM_ZIPPER;
        }
    }
    assert_eq!(seams, want);
    assert!(
        seams.iter().any(|&f| f & quilt::SEAM_ZIPPER != 0) && seams.iter().any(|&f| f & quilt::SEAM_X != 0)
    );
    // no visible chart seams: colour differences across zipper links are no
    // larger than across grid edges inside charts
    let report = btfquilt::output::evaluate::evaluate(&out, None, None, MemoryBudget::default()).unwrap();
    let ratio = report.zipper.ratio;
    assert!(ratio < 1.0, "zipper ratio {ratio}: chart seams show\n{report:?}");
    let png = dir.path().join("atlas.png");
    btfquilt::output::bake::bake(&out, None, &png, MemoryBudget::default()).unwrap();
    assert_eq!(imageio::image_size(&png).unwrap(), (192, 192));
    // the gutter is filled: no pixel of the baked atlas is black
    let baked = imageio::read_rgb(&png).unwrap();
    assert!(baked.data.chunks_exact(3).all(|p| p.iter().sum::<f32>() > 0.0));
    let view = dir.path().join("view.png");
    let cfg = btfquilt::output::render::RenderConfig {
        lights: vec![btfquilt::output::render::Light::directional([0.0, 1.0, 1.0])],
        width: 160,
        height: 120,
        ..Default::default()
    };
    btfquilt::output::render::render(&out, &cfg, &view, MemoryBudget::default()).unwrap();
    let img = imageio::read_rgb(&view).unwrap();
    let lit = img.data.chunks_exact(3).filter(|p| p[0] > 0.05).count();
    assert!(lit > 160 * 120 / 20, "the mesh is not in view: {lit} lit pixels");
}

#[test]
fn bad_tiling_inputs_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let g = square_atlas(dir.path(), 64);
    let out = dir.path().join("o.quilt");
    let missing = dir.path().join("nope.png");
    let e = quilt::tile(&g, &missing, &out, &TileConfig::default(), &Silent)
        .err()
        .unwrap()
        .to_string();
    assert!(e.contains("nope.png"), "{e}");
    let e = quilt::tile(
        &missing.with_extension("gim"),
        &g,
        &out,
        &TileConfig::default(),
        &Silent,
    )
    .err()
    .unwrap()
    .to_string();
    assert!(e.contains("nope.gim"), "{e}");
    // a .gim given as the sample is the wrong kind
    let e = quilt::tile(&g, &g, &out, &TileConfig::default(), &Silent)
        .err()
        .unwrap()
        .to_string();
    assert!(e.contains("square.gim") && e.contains("'gim'"), "{e}");
    assert!(!out.exists());
}

/// The sample's size in the world: with `sample_width` the sample spans the same mesh
/// units at any atlas resolution (measured from the stored coordinates by
/// `evaluate`), and a bad width is refused with the figures it implies.
#[test]
fn sample_width_is_the_same_on_the_surface_at_any_resolution() {
    let dir = tempfile::tempdir().unwrap();
    let sample = brick_crop(dir.path(), 64, None);
    let measured = |r: usize, width: Option<f64>| {
        let g = dir.path().join(format!("square{r}.gim"));
        if !g.exists() {
            atlas(&square_obj(dir.path()), &g, r);
        }
        let out = dir.path().join(format!("s{r}-{width:?}.quilt"));
        let cfg = TileConfig {
            sample_width: width,
            ..TileConfig::default()
        };
        let report = quilt::tile(&g, &sample, &out, &cfg, &Silent).unwrap();
        let eval = btfquilt::output::evaluate::evaluate(&out, None, None, MemoryBudget::default()).unwrap();
        eprintln!("R {r} width {width:?}: {report} measured {:?}", eval.scale);
        assert!(eval.scale.edges > 1000, "{:?}", eval.scale);
        // the report's width (implied or asked) is the one on the surface
        let w = eval.scale.sample_width_units;
        assert!(
            (w / report.sample_width - 1.0).abs() < 0.05,
            "{w} vs {}",
            report.sample_width
        );
        w
    };
    // by default one sample pixel per texel: the width halves at twice the resolution
    let (d96, d192) = (measured(96, None), measured(192, None));
    assert!((d96 / d192 - 2.0).abs() < 0.15, "{d96} {d192}");
    // with a width: the same size in the world
    for r in [96, 192] {
        let w = measured(r, Some(0.4));
        assert!((w / 0.4 - 1.0).abs() < 0.05, "R {r}: {w}");
    }
    // too small for the atlas: refused, naming the flag
    let g = dir.path().join("square96.gim");
    let cfg = TileConfig {
        sample_width: Some(0.01),
        ..TileConfig::default()
    };
    let out = dir.path().join("tiny.quilt");
    let e = quilt::tile(&g, &sample, &out, &cfg, &Silent)
        .err()
        .unwrap()
        .to_string();
    assert!(e.contains("--sample-width") && e.contains("texels"), "{e}");
    assert!(!out.exists());
}

#[test]
fn a_budget_that_forces_eviction_changes_no_byte() {
    // 256² = 16 atlas tiles; 1 MiB leaves the loop a few of them resident
    let dir = tempfile::tempdir().unwrap();
    let g = square_atlas(dir.path(), 256);
    let sample = brick_crop(dir.path(), 64, None);
    let run = |memory: u64, threads: usize| {
        let out = dir.path().join(format!("m{memory}-t{threads}.quilt"));
        let cfg = TileConfig {
            memory: MemoryBudget(memory),
            seed: 5,
            ..TileConfig::default()
        };
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        let report = pool
            .install(|| quilt::tile(&g, &sample, &out, &cfg, &Silent))
            .unwrap();
        eprintln!("{memory} B, {threads} threads: {report}");
        (std::fs::read(&out).unwrap(), report)
    };
    let (small, paged) = run(1 << 20, 1);
    let (large, held) = run(16 << 30, 2);
    assert_eq!(paged.atlas_tiles, 16);
    // every tile read once per pager when all fit; evicted ones again
    assert_eq!(held.tiles_read, 2 * 16, "{held}");
    assert_eq!(held.scratch_bytes, 0);
    assert!(paged.tiles_read > 2 * 16 + 16, "{paged}");
    assert!(paged.scratch_bytes > 0, "{paged}");
    // work patches were computed in rounds, on 1 thread and on 2
    assert!(
        paged.concurrent_patches > 0 && held.concurrent_patches > 0,
        "{paged}"
    );
    assert_eq!(paged.concurrent_patches, held.concurrent_patches);
    assert!(small == large, "the quilt depends on the budget");
    // the scratch store went with the run
    let left: Vec<String> = crate::common::listing(dir.path())
        .into_iter()
        .filter(|f| f.ends_with(".scratch"))
        .collect();
    assert!(left.is_empty(), "{left:?}");
}

/// Matching coarse to fine (a sample longer than `coarse_above` a side):
/// the same bytes on 1 and 2 threads and with a budget that forces
/// eviction, another quilt than matching at full
/// resolution, and seams as good (evaluate's seam ratio within 10 %).
#[test]
fn coarse_to_fine_matching_is_deterministic_and_as_seamless() {
    let dir = tempfile::tempdir().unwrap();
    let g = square_atlas(dir.path(), 256);
    let sample = brick_crop(dir.path(), 96, None);
    let cfg = TileConfig {
        coarse_above: 40,
        ..TileConfig::default()
    };
    let outs = tile_with_threads(&g, &sample, &cfg, dir.path(), "c", |r| {
        assert_eq!(r.coarse_factor, 3, "{r}");
        assert!(r.to_string().contains("coarse to fine at 1/3"), "{r}");
    });
    assert!(std::fs::read(&outs[0]).unwrap() == std::fs::read(&outs[1]).unwrap());
    same_quilt_when_paged(&g, &sample, &cfg, dir.path(), &outs[0]);
    let exact = dir.path().join("exact.quilt");
    let cfg = TileConfig {
        coarse_above: 0,
        ..TileConfig::default()
    };
    let report = quilt::tile(&g, &sample, &exact, &cfg, &Silent).unwrap();
    assert_eq!(report.coarse_factor, 1);
    assert!(std::fs::read(&outs[0]).unwrap() != std::fs::read(&exact).unwrap());
    let (coarse, full) = (seam_ratio(&outs[0]), seam_ratio(&exact));
    eprintln!("seam ratio: coarse to fine {coarse:.3}, full resolution {full:.3}");
    assert!(coarse <= 1.1 * full, "{coarse} vs {full}");
}

/// Matching on a BTF's leading terms (`--match-terms`): the same bytes on
/// 1 and 2 threads, with a budget that pages the atlas, and from the
/// command line; another quilt than matching on every term, and seams
/// about as good (evaluate's seam ratio within 15 %).
#[test]
fn matching_on_the_leading_terms_is_deterministic_and_as_seamless() {
    let dir = tempfile::tempdir().unwrap();
    let g = square_atlas(dir.path(), 192);
    let sample = crate::common::btf_sample(dir.path(), "bricks", btfquilt::generate::Family::Bricks, 2, 8, 4);
    let cfg = TileConfig {
        match_terms: 3,
        ..TileConfig::default()
    };
    let outs = tile_with_threads(&g, &sample, &cfg, dir.path(), "m", |_| ());
    let bytes = |p: &Path| std::fs::read(p).unwrap();
    assert!(bytes(&outs[0]) == bytes(&outs[1]));
    same_quilt_when_paged(&g, &sample, &cfg, dir.path(), &outs[0]);
    let cli = dir.path().join("cli.quilt");
    let s = crate::common::s;
    crate::common::ok(&[
        "tile",
        "--gim",
        s(&g),
        "--sample",
        s(&sample),
        "--match-terms",
        "3",
        "-q",
        "-o",
        s(&cli),
    ]);
    assert!(bytes(&outs[0]) == bytes(&cli), "the flag reaches the config");
    let every = dir.path().join("every.quilt");
    quilt::tile(&g, &sample, &every, &TileConfig::default(), &Silent).unwrap();
    assert!(bytes(&outs[0]) != bytes(&every));
    let (lead, all) = (seam_ratio(&outs[0]), seam_ratio(&every));
    eprintln!("seam ratio: 3 of 8 terms {lead:.3}, every term {all:.3}");
    assert!(lead <= 1.15 * all, "{lead} vs {all}");
}

#[test]
fn bake_and_evaluate_in_bands_equal_the_whole_atlas() {
    // Spot at 256²: 4 bands of 64 rows whose borders cross charts, gutter,
    // and empty atlas farther than the dilation reaches
    let dir = tempfile::tempdir().unwrap();
    let g = spot_atlas(dir.path(), 256);
    let sample = brick_crop(dir.path(), 48, None);
    let out = dir.path().join("s.quilt");
    let cfg = TileConfig {
        seed: 2,
        ..TileConfig::default()
    };
    quilt::tile(&g, &sample, &out, &cfg, &Silent).unwrap();
    // the oracle: the whole atlas's colour, dilated as one image
    let q = Quilt::open(&out, MemoryBudget::default()).unwrap();
    let samples = btfquilt::output::open_samples(&q, None, [MemoryBudget::default(); 2]).unwrap();
    let previews: Vec<_> = samples.iter().map(|s| s.svd.preview().unwrap()).collect();
    let (mut whole, covered) = btfquilt::output::atlas_colour(&q, &previews).unwrap();
    assert!(covered.iter().any(|&c| !c), "no gutter to dilate");
    imageio::dilate(&mut whole, &covered, 16);
    for ext in ["png", "exr"] {
        let want = dir.path().join(format!("want.{ext}"));
        imageio::write_rgb(&want, &whole).unwrap();
        for memory in [1 << 20, 16 << 30] {
            let got = dir.path().join(format!("got{memory}.{ext}"));
            btfquilt::output::bake::bake(&out, None, &got, MemoryBudget(memory)).unwrap();
            let (a, b) = (
                imageio::read_rgb(&want).unwrap(),
                imageio::read_rgb(&got).unwrap(),
            );
            assert_eq!((a.width, a.height), (256, 256));
            let same = a
                .data
                .iter()
                .zip(&b.data)
                .all(|(x, y)| x.to_bits() == y.to_bits());
            assert!(same, "{ext} at {memory} B differs from the whole image");
        }
    }
    // evaluate reads the same atlas in bands: its counts equal the whole
    // atlas's, and a budget that cannot hold a band's chunks changes nothing
    let gim = Gim::open(&g, MemoryBudget::default()).unwrap();
    let (chart, patch): (Vec<u32>, Vec<u32>) = (gim.read("chart").unwrap(), q.patches().unwrap());
    let position: Vec<f32> = gim.read("position").unwrap();
    let r = 256;
    let (mut seam_edges, mut scale_edges) = (0, 0);
    let rgb = |a: usize, b: usize| {
        (0..3)
            .map(|k| ((whole.data[a * 3 + k] - whole.data[b * 3 + k]) as f64).powi(2))
            .sum::<f64>()
            .sqrt()
    };
    let mut seam_steps = Vec::new();
    for t in 0..r * r {
        for n in [(t % r + 1 < r).then(|| t + 1), (t / r + 1 < r).then(|| t + r)]
            .into_iter()
            .flatten()
        {
            if chart[t] != EMPTY && chart[n] == chart[t] && covered[t] && covered[n] {
                seam_edges += (patch[n] != patch[t]) as usize;
                if patch[n] != patch[t] {
                    seam_steps.push(rgb(t, n));
                }
                let apart = (0..3).any(|k| position[t * 3 + k] != position[n * 3 + k]);
                scale_edges += (patch[n] == patch[t] && apart) as usize;
            }
        }
    }
    let links = gim
        .zipper_links()
        .unwrap()
        .iter()
        .filter(|l| covered[l[0] as usize] && covered[l[1] as usize])
        .count();
    let mut ids: Vec<u32> = patch.iter().copied().filter(|&p| p != NO_PATCH).collect();
    ids.sort_unstable();
    ids.dedup();
    let small = btfquilt::output::evaluate::evaluate(&out, None, None, MemoryBudget(1 << 20)).unwrap();
    let large = btfquilt::output::evaluate::evaluate(&out, None, None, MemoryBudget(16 << 30)).unwrap();
    assert_eq!(small, large);
    assert_eq!(small.texels, covered.iter().filter(|&&c| c).count());
    assert_eq!(small.patches, ids.len());
    assert_eq!(small.seam.edges, seam_edges);
    assert_eq!(small.zipper.links, links);
    assert!(links > 0 && seam_edges > 0);
    assert_eq!(small.scale.edges, scale_edges);
    assert_eq!(small.coherence.windows, 200);
    // percentiles of the seam steps: at 1 MiB the report keeps none of
    // them and selects by reading the bands again; the same values
    seam_steps.sort_by(f64::total_cmp);
    let at = |p: f64| seam_steps[((seam_steps.len() as f64 - 1.0) * p).round() as usize];
    assert_eq!(
        (small.seam.median, small.seam.p95, small.seam.max),
        (at(0.5), at(0.95), at(1.0))
    );
    // continuation, the oracle over the whole atlas: at each seam edge,
    // each side whose patch holds the texel behind it, that patch's sample
    // continued one texel across against the other side's colour
    let coords = q.coord_region(0, 0, r, r).unwrap();
    let colour = |t: usize| &whole.data[t * 3..t * 3 + 3];
    let continued = |from: usize, behind: usize, to: usize| -> Option<f64> {
        let same = chart[behind] == chart[from] && covered[behind] && patch[behind] == patch[from];
        let (du, dv) = (
            coords[from][0] - coords[behind][0],
            coords[from][1] - coords[behind][1],
        );
        (same && du.hypot(dv) <= 4.0).then(|| {
            let c = imageio::bilinear(&previews[0], coords[from][0] + du, coords[from][1] + dv);
            (0..3)
                .map(|k| ((c[k] - colour(to)[k]) as f64).powi(2))
                .sum::<f64>()
                .sqrt()
        })
    };
    let (mut seam_continuations, mut inside) = (Vec::new(), Vec::new());
    for t in 0..r * r {
        let (x, y) = (t % r, t / r);
        for (d, ahead, back, beyond) in [
            (1, x + 1 < r, x >= 1, x + 2 < r),
            (r, y + 1 < r, y >= 1, y + 2 < r),
        ] {
            let n = t + d;
            if !ahead || chart[t] == EMPTY || chart[n] != chart[t] || !covered[t] || !covered[n] {
                continue;
            }
            let sides = [back.then(|| (t, t - d, n)), beyond.then(|| (n, n + d, t))];
            for e in sides
                .into_iter()
                .flatten()
                .filter_map(|(f, b, to)| continued(f, b, to))
            {
                if patch[t] != patch[n] {
                    seam_continuations.push(e);
                } else {
                    inside.push(e);
                }
            }
        }
    }
    let c = &small.continuation;
    assert_eq!(c.continuations, seam_continuations.len());
    let mut sorted = seam_continuations.clone();
    sorted.sort_by(f64::total_cmp);
    assert_eq!(c.p95, sorted[(0.95 * sorted.len() as f64).ceil() as usize - 1]);
    let mean = seam_continuations.iter().sum::<f64>() / seam_continuations.len() as f64;
    assert!((c.mean - mean).abs() < 1e-9, "{} vs {mean}", c.mean);
    let inside_mean = inside.iter().sum::<f64>() / inside.len() as f64;
    assert!((c.inside_patches_mean - inside_mean).abs() < 1e-9);
    let broken = seam_continuations.iter().filter(|&&e| e > c.sample_edge).count();
    assert!(broken > 0 && c.sample_edge > 0.0);
    assert!((c.broken - broken as f64 / seam_continuations.len() as f64).abs() < 1e-12);
    // inside a patch the continuation is the resampling error alone, far
    // under what a seam continues
    assert!(c.inside_patches_mean < 0.15 * c.mean, "{c:?}");
    // render looks the dilated texture up in tiles: a budget that evicts
    // them draws the same pixels
    let cfg = btfquilt::output::render::RenderConfig {
        width: 96,
        height: 72,
        ..Default::default()
    };
    let frames: Vec<_> = [1 << 20, 16 << 30]
        .iter()
        .map(|&m| {
            let scene = btfquilt::output::render::Scene::open(&out, MemoryBudget(m)).unwrap();
            scene.render_image(&cfg).unwrap()
        })
        .collect();
    assert!(frames[0].data.iter().any(|&v| v > 0.05));
    assert!(
        frames[0].data == frames[1].data,
        "the render depends on the budget"
    );
}

/// A sample with sparse features: a plain ground with a few dark spots. Without the
/// occurrence penalty the choice among near-minimal placements keeps
/// returning to the ground that matches what is already there; with it more
/// of the sample shows on the surface.
#[test]
fn the_occurrence_penalty_spreads_use_over_a_sparse_feature_sample() {
    let dir = tempfile::tempdir().unwrap();
    let g = square_atlas(dir.path(), 200);
    let sample = dir.path().join("spots.png");
    let spots = [
        (20.0, 24.0),
        (70.0, 16.0),
        (48.0, 60.0),
        (80.0, 78.0),
        (14.0, 82.0),
    ];
    crate::common::write_rgb_png(&sample, 96, 96, |x, y| {
        // a faint deterministic grain on a light ground
        let h = ((x * 7919 + y * 104_729) % 97) as f32 / 97.0;
        let v = 0.7 + 0.04 * h;
        let dark = spots
            .iter()
            .any(|&(cx, cy)| (x as f32 - cx).powi(2) + (y as f32 - cy).powi(2) < 16.0);
        if dark {
            [0.08, 0.06, 0.05]
        } else {
            [v, 0.97 * v, 0.9 * v]
        }
    });
    let never_used = |weight: f64| {
        let out = dir.path().join(format!("w{weight}.quilt"));
        let cfg = TileConfig {
            occurrence_weight: weight,
            ..TileConfig::default()
        };
        quilt::tile(&g, &sample, &out, &cfg, &Silent).unwrap();
        btfquilt::output::evaluate::evaluate(&out, None, None, MemoryBudget::default())
            .unwrap()
            .usage[0]
            .never_used
    };
    let (off, on) = (
        never_used(0.0),
        never_used(TileConfig::default().occurrence_weight),
    );
    assert!(
        on < 0.8 * off,
        "sample never used: {off:.3} without the penalty, {on:.3} with it"
    );
}

/// The structure channel joins the features of the loop only: the result is
/// still independent of the thread count, the quilt records the sample's
/// own term count, and the texture comes out whole.
#[test]
fn the_structure_channel_keeps_results_deterministic_and_the_quilt_plain() {
    use btfquilt::container::Param;
    let dir = tempfile::tempdir().unwrap();
    let g = square_atlas(dir.path(), 128);
    let sample = brick_crop(dir.path(), 96, Some((40, 40)));
    let cfg = TileConfig {
        structure_weight: 1.0,
        ..TileConfig::default()
    };
    let outs = tile_with_threads(&g, &sample, &cfg, dir.path(), "s", |_| ());
    assert_eq!(std::fs::read(&outs[0]).unwrap(), std::fs::read(&outs[1]).unwrap());
    let plain = dir.path().join("plain.quilt");
    quilt::tile(&g, &sample, &plain, &TileConfig::default(), &Silent).unwrap();
    assert_ne!(std::fs::read(&outs[0]).unwrap(), std::fs::read(&plain).unwrap());
    let terms = |p: &Path| {
        Quilt::open(p, MemoryBudget::default())
            .unwrap()
            .container()
            .metadata()
            .param("terms")
            .cloned()
    };
    assert!(matches!(terms(&outs[0]), Some(Param::Int(t)) if t > 0));
    assert_eq!(terms(&outs[0]), terms(&plain));
    let q = Quilt::open(&outs[0], MemoryBudget::default()).unwrap();
    assert!(q.patches().unwrap().iter().any(|&p| p != NO_PATCH));
    let e = btfquilt::output::evaluate::evaluate(&outs[0], None, None, MemoryBudget::default()).unwrap();
    assert_eq!(e.usage.len(), 1);
}

/// Turning the sample off the field's mean direction is allowed only as far
/// as the field turns inside a work patch: on a flat square (a constant
/// field) it changes nothing; on Spot, whose field turns, it does.
#[test]
fn the_field_turn_acts_only_where_the_field_turns() {
    let dir = tempfile::tempdir().unwrap();
    let tile = |g: &Path, sample: &Path, turn: usize, name: &str| {
        let out = dir.path().join(name);
        let cfg = TileConfig {
            field_turn: turn,
            ..TileConfig::default()
        };
        quilt::tile(g, sample, &out, &cfg, &Silent).unwrap();
        std::fs::read(out).unwrap()
    };
    let g = square_atlas(dir.path(), 128);
    let sample = brick_crop(dir.path(), 96, Some((40, 40)));
    assert_eq!(tile(&g, &sample, 0, "f0.quilt"), tile(&g, &sample, 2, "f2.quilt"));
    let spot = spot_atlas(dir.path(), 256);
    assert_ne!(
        tile(&spot, &sample, 0, "s0.quilt"),
        tile(&spot, &sample, 1, "s1.quilt")
    );
}

/// A budget that holds only some of a round's work patches in flight: the
/// views of the others are made when a thread takes them, from the pagers
/// the round's traversals borrow too; the same bytes as with the views
/// made at once (a roomy budget and a thread per patch of a round, whose
/// patches' share then holds nearly all).
#[test]
fn views_made_when_a_thread_takes_the_patch_change_no_byte() {
    let dir = tempfile::tempdir().unwrap();
    let g = square_atlas(dir.path(), 256);
    let sample = brick_crop(dir.path(), 64, None);
    let run = |memory: u64, threads: usize| {
        let out = dir.path().join(format!("v{memory}.quilt"));
        let cfg = TileConfig {
            memory: MemoryBudget(memory),
            seed: 3,
            ..TileConfig::default()
        };
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        let report = pool
            .install(|| quilt::tile(&g, &sample, &out, &cfg, &Silent))
            .unwrap();
        eprintln!("{memory} B: {report:?}");
        (std::fs::read(&out).unwrap(), report)
    };
    let (tight, late) = run(8 << 20, 2);
    let (roomy, early) = run(16 << 30, TileConfig::default().round);
    assert!(
        late.late_views > 0 && late.concurrent_patches > late.late_views,
        "{late:?}"
    );
    // the roomy budget is sized for a patch per thread, traversals half
    // again as large as the first: only a round with larger ones makes a
    // few views late
    assert!(early.late_views * 10 < late.late_views, "{early:?}");
    assert!(tight == roomy, "the quilt depends on when views are made");
}

/// A texel's frame (its stored Jacobian) is the central difference of the
/// stored sample coordinates of its atlas neighbours where all four belong
/// to its patch and chart: a bent patch's frames turn with the bend.
fn frames_follow_the_stored_coordinates(gim: &Path, quilt: &Path, r: usize) {
    let budget = MemoryBudget::default();
    let chart: Vec<u32> = Gim::open(gim, budget).unwrap().read("chart").unwrap();
    let q = Quilt::open(quilt, budget).unwrap();
    let (coords, jac, patch) = (q.coords().unwrap(), q.jacobians().unwrap(), q.patches().unwrap());
    let (mut checked, mut turned) = (0, 0);
    for y in 1..r - 1 {
        for x in 1..r - 1 {
            let t = y * r + x;
            let around = [t - 1, t + 1, t - r, t + r];
            if patch[t] == NO_PATCH
                || around
                    .iter()
                    .any(|&n| patch[n] != patch[t] || chart[n] != chart[t])
            {
                continue;
            }
            let half = |a: usize, b: usize| {
                [
                    (coords[a][0] - coords[b][0]) / 2.0,
                    (coords[a][1] - coords[b][1]) / 2.0,
                ]
            };
            let (ax, ay) = (half(t + 1, t - 1), half(t + r, t - r));
            let want = [ax[0], ax[1], ay[0], ay[1]];
            for (j, w) in jac[t].iter().zip(want) {
                assert!(
                    (j - w).abs() < 1e-3,
                    "texel {t}: frame {:?}, coordinates say {want:?}",
                    jac[t]
                );
            }
            // (and the frame differs from its right neighbour's: turned)
            turned += (jac[t] != jac[t + 1]) as usize;
            checked += 1;
        }
    }
    assert!(
        checked > 10_000 && turned > 0,
        "{checked} texels checked, {turned} turned"
    );
}

#[test]
fn feature_alignment_ends_fewer_courses_at_seams_and_leaves_a_flat_square_alone() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let wall = Path::new(env!("CARGO_MANIFEST_DIR")).join("data/brick_wall.png");
    let g = spot_atlas(d, 512);
    let broken = |q: &Path| {
        let report = btfquilt::output::evaluate::evaluate(q, None, None, MemoryBudget::default()).unwrap();
        let c = report.continuation;
        // Spot's legs, udder and chin hide some faces: counted by their
        // exposure, fewer features end in sight than end at all
        assert!(
            c.broken_seen_per_1000_texels < 0.97 * c.broken_per_1000_texels
                && c.broken_seen_per_1000_texels > 0.5 * c.broken_per_1000_texels,
            "{c:?}"
        );
        c.broken_per_1000_texels
    };
    let (mut rigid, mut aligned) = (0.0, 0.0);
    for seed in [1, 2] {
        // bent patches are the default; what they do alone, without the
        // refinement where features end that mends rigid ones' too, at the
        // occurrence weight of 1 their gain was measured at (at 0.5 it is
        // 14 % on these two seeds)
        let cfg = TileConfig {
            seed,
            sample_width: Some(1.07),
            refine_broken: 0,
            occurrence_weight: 1.0,
            ..TileConfig::default()
        };
        assert!(cfg.feature_align > 0.0);
        let base = TileConfig {
            feature_align: 0.0,
            ..cfg.clone()
        };
        let out = d.join(format!("rigid{seed}.quilt"));
        quilt::tile(&g, &wall, &out, &base, &Silent).unwrap();
        rigid += broken(&out);
        // bent patches are computed in rounds like rigid ones: the same
        // quilt for any thread count, and (seed 1) for a budget that pages
        // atlas tiles out to scratch
        let outs = tile_with_threads(&g, &wall, &cfg, d, &format!("aligned{seed}-"), |_| {});
        assert_eq!(std::fs::read(&outs[0]).unwrap(), std::fs::read(&outs[1]).unwrap());
        if seed == 1 {
            let tight = TileConfig {
                memory: MemoryBudget(2 << 20),
                ..cfg.clone()
            };
            let out = d.join("aligned-tight.quilt");
            let report = quilt::tile(&g, &wall, &out, &tight, &Silent).unwrap();
            assert!(report.scratch_bytes > 0, "{report}");
            assert!(std::fs::read(&out).unwrap() == std::fs::read(&outs[0]).unwrap());
            frames_follow_the_stored_coordinates(&g, &outs[0], 512);
        }
        aligned += broken(&outs[0]);
    }
    // courses (and mortar lines) that end at a seam: markedly fewer
    eprintln!("broken per 1000 texels: rigid {rigid}, aligned {aligned}");
    assert!(
        aligned < 0.8 * rigid,
        "aligned {aligned} against rigid {rigid} broken per 1000 texels"
    );
    // on a flat square the field is constant: nothing to align, the same bytes
    let square = square_atlas(d, 96);
    let sample = brick_crop(d, 64, None);
    let (a, b) = (d.join("sq0.quilt"), d.join("sq1.quilt"));
    quilt::tile(&square, &sample, &a, &TileConfig::default(), &Silent).unwrap();
    let cfg = TileConfig {
        feature_align: 0.0,
        ..TileConfig::default()
    };
    quilt::tile(&square, &sample, &b, &cfg, &Silent).unwrap();
    assert_eq!(std::fs::read(&a).unwrap(), std::fs::read(&b).unwrap());
    // an open plane is seen from (nearly) its whole hemisphere: features
    // that end at its seams count (nearly) in full
    let c = btfquilt::output::evaluate::evaluate(&a, None, None, MemoryBudget::default())
        .unwrap()
        .continuation;
    assert!(
        c.broken_per_1000_texels > 0.0
            && c.broken_seen_per_1000_texels <= c.broken_per_1000_texels
            && c.broken_seen_per_1000_texels > 0.9 * c.broken_per_1000_texels,
        "{c:?}"
    );
}
