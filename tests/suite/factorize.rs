//! The out-of-core randomized SVD against faer's exact SVD, the colour-image
//! path, thread-count independence, rotated copies, and bad input.

use std::path::{Path, PathBuf};

use btfquilt::artifact::btf::{self, Angles, Btf, BtfLayout, BtfWriter};
use btfquilt::artifact::svd::SvdArtifact;
use btfquilt::container::MemoryBudget;
use btfquilt::factorize::{self, FactorizeConfig};
use btfquilt::generate::{self, Family, GenerateConfig, Imperfection};
use btfquilt::io::imageio;
use btfquilt::progress::Silent;
use faer::Mat;

use crate::common::{listing, write_rgb_png};
use half::f16;

/// A small generated BTF: 24×20 texels (ragged tiles), 8 views × 12 lights.
fn small_btf(dir: &Path, family: Family) -> PathBuf {
    let path = dir.join(format!("{}.btf", family.name()));
    let cfg = GenerateConfig {
        family,
        imperfection: Imperfection::Cracks,
        width: 24,
        height: 20,
        views: btf::grid(4, 2, 60.0),
        lights: btf::grid(6, 2, 70.0),
        seed: 5,
        ..GenerateConfig::default()
    };
    generate::generate_btf(&cfg, &path, &Silent).unwrap();
    path
}

/// The BTF as a dense matrix: row = texel (image order), column = pair·3 + c.
fn dense(path: &Path) -> Mat<f64> {
    let b = Btf::open(path, MemoryBudget::default()).unwrap();
    let l = b.layout();
    let (m, pairs) = (l.width * l.height, l.pairs());
    let images = b.read_pair_images(0..pairs).unwrap(); // [pair][texel][c]
    Mat::from_fn(m, pairs * 3, |r, col| {
        images[((col / 3) * m + r) * 3 + col % 3] as f64
    })
}

fn frob(m: &Mat<f64>) -> f64 {
    let mut s = 0.0;
    for j in 0..m.ncols() {
        for i in 0..m.nrows() {
            s += m[(i, j)] * m[(i, j)];
        }
    }
    s.sqrt()
}

fn run(input: &Path, out: &Path, cfg: &FactorizeConfig) -> factorize::FactorizeReport {
    factorize::factorize(input, out, cfg, &Silent).unwrap()
}

#[test]
fn randomized_svd_matches_the_exact_truncation() {
    let dir = tempfile::tempdir().unwrap();
    for family in [Family::Bricks, Family::Weave] {
        let src = small_btf(dir.path(), family);
        let a = dense(&src);
        let exact = a.thin_svd().unwrap();
        let s = exact.S().column_vector();
        let norm = frob(&a);
        for terms in [4usize, 12] {
            let out = dir.path().join(format!("{}-{terms}.svd", family.name()));
            let cfg = FactorizeConfig {
                terms: Some(terms),
                rotations: 4,
                ..FactorizeConfig::default()
            };
            let report = run(&src, &out, &cfg);
            let tail: f64 = (terms..s.nrows()).map(|i| s[i] * s[i]).sum::<f64>().sqrt();
            let exact_err = tail / norm;
            let rel = (report.relative_error - exact_err).abs() / exact_err;
            assert!(
                rel < 0.01,
                "{family:?} n={terms}: randomized {} vs exact {exact_err}",
                report.relative_error
            );
            for i in 0..terms {
                assert!((report.singular_values[i] - s[i]).abs() < 1e-3 * s[0], "σ_{i}");
            }
            // G Pᵀ reproduces the exact rank-n approximation U_n Σ_n V_nᵀ
            let svd = SvdArtifact::open(&out, MemoryBudget::default()).unwrap();
            let (g, p) = (svd.geometry_maps().unwrap(), svd.appearance().unwrap());
            let (m, n) = (a.nrows(), a.ncols());
            let approx = Mat::from_fn(m, n, |r, c| {
                (0..terms)
                    .map(|i| g[r * terms + i] as f64 * p[c * terms + i] as f64)
                    .sum::<f64>()
            });
            let (u, v) = (exact.U(), exact.V());
            let best = Mat::from_fn(m, n, |r, c| {
                (0..terms).map(|i| u[(r, i)] * s[i] * v[(c, i)]).sum::<f64>()
            });
            let diff = frob(&(&approx - &best)) / frob(&best);
            assert!(diff < 5e-3, "{family:?} n={terms}: ‖GPᵀ − A_n‖/‖A_n‖ = {diff}");
            // appearance functions are orthonormal
            for i in 0..terms {
                for j in 0..terms {
                    let dot: f64 = (0..n)
                        .map(|c| p[c * terms + i] as f64 * p[c * terms + j] as f64)
                        .sum();
                    let want = if i == j { 1.0 } else { 0.0 };
                    assert!((dot - want).abs() < 1e-4, "p_{i}·p_{j} = {dot}");
                }
            }
        }
    }
}

#[test]
fn factorization_is_identical_with_one_or_two_threads() {
    let dir = tempfile::tempdir().unwrap();
    let src = small_btf(dir.path(), Family::Pebbles);
    let cfg = FactorizeConfig {
        terms: Some(10),
        rotations: 8,
        ..FactorizeConfig::default()
    };
    let outs: Vec<PathBuf> = [1, 2]
        .iter()
        .map(|&t| {
            let out = dir.path().join(format!("t{t}.svd"));
            let pool = rayon::ThreadPoolBuilder::new().num_threads(t).build().unwrap();
            pool.install(|| run(&src, &out, &cfg));
            out
        })
        .collect();
    assert_eq!(std::fs::read(&outs[0]).unwrap(), std::fs::read(&outs[1]).unwrap());
}

/// Budgets below the sketch's QR (1920 × 20 values, 12 bytes each, with
/// `--terms 10`) keep the sketch and its Q in a scratch file beside the
/// output: at 16 KiB a tile's rows at a time, the QR streaming its
/// columns in pieces of rows (Aᵀ Q's 288 × 20 in panels of two columns),
/// at 600 KiB blocks of one and two tiles and panels of 16 columns; the
/// geometry maps then go to the `.svd` a row of chunks at a time, and the
/// rotated copies read windows of them. The same bytes as in memory with
/// two threads, on a tileable sample too, and no scratch file left beside
/// the output.
#[test]
fn a_factorization_through_scratch_columns_gives_the_same_bytes() {
    let dir = tempfile::tempdir().unwrap();
    let src = dir.path().join("wide.btf");
    let cfg = GenerateConfig {
        family: Family::Pebbles,
        imperfection: Imperfection::Cracks,
        width: 48,
        height: 40,
        views: btf::grid(4, 2, 60.0),
        lights: btf::grid(6, 2, 70.0),
        seed: 5,
        ..GenerateConfig::default()
    };
    generate::generate_btf(&cfg, &src, &Silent).unwrap();
    let runs = [
        (1, MemoryBudget(16 << 10)),
        (1, MemoryBudget(600 << 10)),
        (2, MemoryBudget::default()),
    ];
    for tileable in [false, true] {
        let outs: Vec<Vec<u8>> = runs
            .iter()
            .enumerate()
            .map(|(i, &(t, memory))| {
                let out = dir.path().join(format!("run{i}.svd"));
                let cfg = FactorizeConfig {
                    terms: Some(10),
                    rotations: 8,
                    tileable,
                    memory,
                    ..FactorizeConfig::default()
                };
                let pool = rayon::ThreadPoolBuilder::new().num_threads(t).build().unwrap();
                pool.install(|| run(&src, &out, &cfg));
                std::fs::read(&out).unwrap()
            })
            .collect();
        assert!(outs[0] == outs[2], "16 KiB, tileable {tileable}");
        assert!(outs[1] == outs[2], "600 KiB, tileable {tileable}");
        assert_eq!(
            listing(dir.path()),
            ["run0.svd", "run1.svd", "run2.svd", "wide.btf", "wide.mask.png"]
        );
    }
}

#[test]
fn a_colour_image_is_a_one_pair_btf_factorized_exactly() {
    let dir = tempfile::tempdir().unwrap();
    let png = dir.path().join("sample.png");
    let (w, h) = (37, 29);
    // value i of the image's interleaved data
    let value = |i: usize| (((i * 7919) % 251) as f32 / 250.0).powf(2.2);
    write_rgb_png(&png, w, h, |x, y| [0, 1, 2].map(|c| value((y * w + x) * 3 + c)));
    let out = dir.path().join("sample.svd");
    let report = run(&png, &out, &FactorizeConfig::default());
    assert_eq!((report.columns, report.terms), (3, 3));
    assert!(report.relative_error < 1e-3, "{}", report.relative_error);
    let svd = SvdArtifact::open(&out, MemoryBudget::default()).unwrap();
    let rec = svd.reconstruct_pair(0).unwrap();
    let orig = imageio::read_rgb(&png).unwrap();
    assert!(
        factorize::psnr(&orig, &rec) > 55.0,
        "{}",
        factorize::psnr(&orig, &rec)
    );
    assert_eq!(svd.preview().unwrap().data.len(), w * h * 3);
    // the three geometry maps are the colour, up to an orthogonal transform:
    // their norms carry all the energy
    let sigma = svd.singular_values().unwrap();
    assert!(sigma[0] > sigma[1] && sigma[1] >= sigma[2]);
}

/// A colour image of several 64² chunks: the same bytes with one thread at
/// 256 KiB (the image read by rows, its factors stored, rotated copies made
/// a chunk at a time from windows of the maps) as with two threads and the
/// default budget (a rotation's chunks at once from the whole maps),
/// tileable or not, and the preview,
/// written chunk by chunk, is the image as the BTF stores it (f16).
#[test]
fn factorizing_an_image_gives_the_same_bytes_for_any_budget() {
    let dir = tempfile::tempdir().unwrap();
    let png = dir.path().join("wide.png");
    let (w, h) = (150, 70);
    let value = |i: usize| (((i * 7919) % 251) as f32 / 250.0).powf(2.2);
    write_rgb_png(&png, w, h, |x, y| [0, 1, 2].map(|c| value((y * w + x) * 3 + c)));
    let runs = [(1, MemoryBudget(256 << 10)), (2, MemoryBudget::default())];
    let factorize = |tileable: bool| -> Vec<PathBuf> {
        runs.iter()
            .enumerate()
            .map(|(i, &(t, memory))| {
                let out = dir.path().join(format!("run{i}.svd"));
                let cfg = FactorizeConfig {
                    rotations: 12,
                    tileable,
                    memory,
                    ..FactorizeConfig::default()
                };
                let pool = rayon::ThreadPoolBuilder::new().num_threads(t).build().unwrap();
                pool.install(|| run(&png, &out, &cfg));
                out
            })
            .collect()
    };
    // at 256 KiB the sketch, Q and the geometry maps are stored beside the
    // output, and each turned chunk reads a window of the maps' chunks
    let mut outs = Vec::new();
    for tileable in [true, false] {
        outs = factorize(tileable);
        let same = std::fs::read(&outs[0]).unwrap() == std::fs::read(&outs[1]).unwrap();
        assert!(same, "tileable {tileable}");
    }
    let preview = SvdArtifact::open(&outs[0], MemoryBudget::default())
        .unwrap()
        .preview()
        .unwrap();
    let orig = imageio::read_rgb(&png).unwrap();
    assert_eq!((preview.width, preview.height), (w, h));
    for (i, (&p, &o)) in preview.data.iter().zip(&orig.data).enumerate() {
        assert_eq!(p, f16::from_f32(o).to_f32(), "value {i}");
    }
}

/// The preview's row means, read 64 rows at a time, are those of the whole
/// preview, over a last band of fewer rows too.
#[test]
fn preview_row_means_read_in_bands_equal_the_whole_preview() {
    let dir = tempfile::tempdir().unwrap();
    let png = dir.path().join("rows.png");
    let (w, h) = (23, 150);
    let value = |i: usize| ((i * 31 + i / (3 * w)) % 97) as f32 / 96.0;
    write_rgb_png(&png, w, h, |x, y| [0, 1, 2].map(|c| value((y * w + x) * 3 + c)));
    let out = dir.path().join("rows.svd");
    run(&png, &out, &FactorizeConfig::default());
    let svd = SvdArtifact::open(&out, MemoryBudget::default()).unwrap();
    let whole: Vec<f64> = svd
        .preview()
        .unwrap()
        .data
        .chunks_exact(3 * w)
        .map(imageio::row_luminance)
        .collect();
    let banded = svd.preview_row_means().unwrap();
    assert_eq!(banded.len(), h);
    assert_eq!(banded, whole);
    assert!(whole.windows(2).any(|p| p[0] != p[1]), "rows that differ");
}

#[test]
fn rotated_copies_rotate_the_geometry_maps() {
    let (w, h, c) = (9usize, 9usize, 2usize);
    let maps: Vec<f32> = (0..w * h * c).map(|i| (i as f32 * 0.37).sin()).collect();
    let texel = |m: &[f32], x: usize, y: usize| m[(y * w + x) * c..(y * w + x + 1) * c].to_vec();
    // 0°: identity, valid everywhere
    let (r0, v0) = factorize::rotate_maps(&maps, w, h, c, 0.0, false);
    assert_eq!(r0, maps);
    assert!(v0.iter().all(|&v| v == 1));
    // 90° on a square sample: an exact pixel permutation
    let (r90, v90) = factorize::rotate_maps(&maps, w, h, c, 90.0, false);
    assert!(v90.iter().all(|&v| v == 1));
    for y in 0..h {
        for x in 0..w {
            // out(x, y) = in(R(−90°)(x − c) + c) = in(y, w − 1 − x)
            let want = texel(&maps, y, w - 1 - x);
            let got = texel(&r90, x, y);
            for k in 0..c {
                assert!((want[k] - got[k]).abs() < 1e-5, "({x},{y})");
            }
        }
    }
    // 45°: the corners come from outside the sample, the centre is valid
    let (_, v45) = factorize::rotate_maps(&maps, w, h, c, 45.0, false);
    assert_eq!(v45[0], 0);
    assert_eq!(v45[(h / 2) * w + w / 2], 1);
    let (_, vt) = factorize::rotate_maps(&maps, w, h, c, 45.0, true);
    assert!(vt.iter().all(|&v| v == 1), "tileable samples wrap");
}

#[test]
fn stored_rotations_match_rotating_the_stored_maps() {
    let dir = tempfile::tempdir().unwrap();
    let src = small_btf(dir.path(), Family::Bricks);
    let out = dir.path().join("r.svd");
    let cfg = FactorizeConfig {
        terms: Some(6),
        ..FactorizeConfig::default()
    };
    run(&src, &out, &cfg);
    let svd = SvdArtifact::open(&out, MemoryBudget::default()).unwrap();
    assert_eq!(svd.rotations, 72);
    let g = svd.geometry_maps().unwrap();
    for r in [0usize, 7, 18, 55] {
        let (want, want_valid) = factorize::rotate_maps(&g, svd.width, svd.height, 6, r as f64 * 5.0, false);
        let (got, valid) = svd.rotated(r).unwrap();
        assert_eq!(valid, want_valid);
        // stored a chunk at a time, each texel as the whole copy's in f16
        for (a, b) in want.iter().zip(&got) {
            assert_eq!(f16::from_f32(*a), *b, "rotation {r}");
        }
    }
}

#[test]
fn too_many_terms_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let src = small_btf(dir.path(), Family::Weave);
    let out = dir.path().join("x.svd");
    let cfg = FactorizeConfig {
        terms: Some(300),
        ..FactorizeConfig::default()
    };
    let err = factorize::factorize(&src, &out, &cfg, &Silent)
        .err()
        .unwrap()
        .to_string();
    assert!(err.contains("--terms 300") && err.contains("480 × 288"), "{err}");
    assert!(!out.exists());
}

#[test]
fn non_finite_values_are_refused_without_output() {
    let dir = tempfile::tempdir().unwrap();
    let src = dir.path().join("nan.btf");
    let head_on = Angles { theta: 0.0, phi: 0.0 };
    let grazing = Angles {
        theta: 60.0,
        phi: 0.0,
    };
    let layout = BtfLayout::new(20, 18, vec![head_on, grazing], vec![head_on]);
    let mut w = BtfWriter::create(&src, layout.clone()).unwrap();
    let (ntx, nty) = layout.tiles();
    for ty in 0..nty {
        for tx in 0..ntx {
            for band in 0..layout.bands() {
                let tw = 16.min(20 - tx * 16);
                let th = 16.min(18 - ty * 16);
                let mut v = vec![f16::from_f32(0.5); tw * th * layout.band * 3];
                // one light: each band is one view; texel (18, 17), grazing view, green
                assert_eq!(layout.band, 1);
                if (tx, ty, band) == (1, 1, 1) {
                    v[(tw + 2) * 3 + 1] = f16::INFINITY;
                }
                w.write_tile_band(tx, ty, band, &v).unwrap();
            }
        }
    }
    w.finish().unwrap();
    let out = dir.path().join("nan.svd");
    let err = factorize::factorize(&src, &out, &FactorizeConfig::default(), &Silent)
        .err()
        .unwrap()
        .to_string();
    assert!(
        err.contains("nan.btf") && err.contains("non-finite") && err.contains("(18, 17)"),
        "{err}"
    );
    assert!(err.contains("θ 60"), "{err}");
    assert!(!out.exists());
    let leftovers = std::fs::read_dir(dir.path()).unwrap().filter(|e| {
        e.as_ref()
            .unwrap()
            .file_name()
            .to_string_lossy()
            .contains("partial")
    });
    assert_eq!(leftovers.count(), 0);
}
