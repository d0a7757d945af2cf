//! `compare`: how faithfully an image reproduces its sample, in both
//! directions, from exact nearest 5×5 windows.
//!
//! - coherence: every output window's distance to its nearest sample
//!   window (low: nothing in the output that the sample does not have);
//! - completeness: every sample window's distance to its nearest output
//!   window (low: the output shows all of the sample — the completeness
//!   term of Simakov et al. 2008, "Summarizing visual data using
//!   bidirectional similarity").
//!
//! A distance is the RMS over the window's 25 texels of the RGB distance
//! (linear RGB in [0, 1]): `sqrt(SSD / 25)`. Windows are compared as they
//! stand, unrotated, so the figures suit flat (2D) outputs and outputs of
//! other tools alike. Nearest neighbours are exact: all pairs are scored
//! through one matrix product `‖o‖² + ‖s‖² − 2 o·s` (single precision,
//! blocks of output rows against blocks of sample windows, the sample's
//! windows held once), and each winner's distance is recomputed in double
//! precision from the pixels. Blocks are reduced with `min`, so the figures
//! do not depend on the thread count.

use std::path::Path;

use rayon::prelude::*;
use serde::Serialize;

use crate::container::MemoryBudget;
use crate::dense;
use crate::io::imageio::{self, RgbImage};
use crate::{Error, Result};

/// Window side (texels).
pub const WINDOW: usize = 5;
const DIM: usize = WINDOW * WINDOW * 3;
/// Output windows scored together (rows of one product).
const OUTPUT_BLOCK: usize = 256;
/// Sample windows scored together (columns of one product).
const SAMPLE_BLOCK: usize = 2048;

/// The two figures of [`compare`]. Serialized (serde), its field names are
/// those of `btfquilt compare`'s JSON.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct CompareReport {
    /// Output windows → nearest sample window.
    pub coherence: Distances,
    /// Sample windows → nearest output window.
    pub completeness: Distances,
}

/// Nearest-window distances of one direction.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Distances {
    /// Windows measured (every window position of the image).
    pub windows: usize,
    pub mean: f64,
    /// 95th percentile (nearest rank).
    pub p95: f64,
    pub max: f64,
}

/// The value at quantile `q` of ascending `sorted` by nearest rank (the
/// ⌈q·n⌉-th), 0 when it is empty.
pub(crate) fn nearest_rank(sorted: &[f64], q: f64) -> f64 {
    let n = sorted.len();
    if n == 0 {
        return 0.0;
    }
    sorted[((q * n as f64).ceil() as usize).clamp(1, n) - 1]
}

impl Distances {
    fn of(mut d: Vec<f64>) -> Distances {
        let windows = d.len();
        let mean = d.iter().sum::<f64>() / windows.max(1) as f64;
        d.sort_by(f64::total_cmp);
        Distances {
            windows,
            mean,
            p95: nearest_rank(&d, 0.95),
            max: nearest_rank(&d, 1.0),
        }
    }
}

/// Why `img` (the `what` image) cannot be compared: smaller than a window.
fn too_small(what: &str, img: &RgbImage) -> Option<String> {
    (img.width < WINDOW || img.height < WINDOW).then(|| {
        format!(
            "the {what} image is {}×{}: smaller than the {WINDOW}×{WINDOW} window",
            img.width, img.height
        )
    })
}

/// The windows of `img` as the rows of a row-major `count × DIM` matrix
/// (window texels, R G B each), or as its columns (`DIM × count`, with
/// `as_columns`), and their squared norms.
fn windows(img: &RgbImage, rows: std::ops::Range<usize>, as_columns: bool) -> (Vec<f32>, Vec<f32>) {
    let cols = img.width + 1 - WINDOW;
    let n = rows.len() * cols;
    let mut m = vec![0f32; n * DIM];
    let mut norms = vec![0f32; n];
    for (i, y) in rows.enumerate() {
        for x in 0..cols {
            let r = i * cols + x;
            let mut k = 0;
            for dy in 0..WINDOW {
                let row = &img.data[((y + dy) * img.width + x) * 3..][..WINDOW * 3];
                for &v in row {
                    m[if as_columns { k * n + r } else { r * DIM + k }] = v;
                    norms[r] += v * v;
                    k += 1;
                }
            }
        }
    }
    (m, norms)
}

/// The exact SSD between window `(x, y)` of `a` and window `(u, v)` of `b`.
fn ssd(a: &RgbImage, (x, y): (usize, usize), b: &RgbImage, (u, v): (usize, usize)) -> f64 {
    let mut s = 0f64;
    for dy in 0..WINDOW {
        let p = &a.data[((y + dy) * a.width + x) * 3..][..WINDOW * 3];
        let q = &b.data[((v + dy) * b.width + u) * 3..][..WINDOW * 3];
        s += p
            .iter()
            .zip(q)
            .map(|(&p, &q)| ((p - q) as f64).powi(2))
            .sum::<f64>();
    }
    s
}

/// Coherence and completeness of `output` against `sample` (see the module
/// documentation). The sample's windows are held as one matrix; it must fit
/// `budget` together with one product block per worker.
pub fn compare_images(output: &RgbImage, sample: &RgbImage, budget: MemoryBudget) -> Result<CompareReport> {
    for (what, img) in [("output", output), ("sample", sample)] {
        if let Some(reason) = too_small(what, img) {
            return Err(Error::Config(reason));
        }
    }
    let (s_cols, s_rows) = (sample.width + 1 - WINDOW, sample.height + 1 - WINDOW);
    let (o_cols, o_rows) = (output.width + 1 - WINDOW, output.height + 1 - WINDOW);
    let ns = s_cols * s_rows;
    let block_rows = (OUTPUT_BLOCK / o_cols).max(1);
    let need = (ns * (DIM + 1) * 4) as u64
        + rayon::current_num_threads() as u64
            * ((block_rows * o_cols * (DIM + 1) + block_rows * o_cols * SAMPLE_BLOCK + ns * 2) * 4) as u64;
    if need > budget.0 {
        return Err(Error::Config(format!(
            "comparing {}×{} windows against {ns} sample windows needs about {} MiB; \
             --memory is {} MiB",
            o_cols,
            o_rows,
            need >> 20,
            budget.0 >> 20
        )));
    }
    // the sample's windows as columns (DIM × ns), so a block of them is
    // the right-hand side of one product
    let (s_win, s_norm) = windows(sample, 0..s_rows, true);
    // per band of output rows: each output window's best (score, sample
    // window), and each sample window's best (score, output window)
    let bands: Vec<(usize, usize)> = (0..o_rows)
        .step_by(block_rows)
        .map(|y| (y, (y + block_rows).min(o_rows)))
        .collect();
    type Best = (f32, u32);
    let parts: Vec<(Vec<Best>, Vec<Best>)> = bands
        .par_iter()
        .map(|&(y0, y1)| {
            let (o_win, o_norm) = windows(output, y0..y1, false);
            let no = o_norm.len();
            let mut out_best = vec![(f32::INFINITY, 0u32); no];
            let mut sam_best = vec![(f32::INFINITY, 0u32); ns];
            let mut dot = Vec::with_capacity(no * SAMPLE_BLOCK);
            for s0 in (0..ns).step_by(SAMPLE_BLOCK) {
                let s1 = (s0 + SAMPLE_BLOCK).min(ns);
                let nb = s1 - s0;
                // o·s for every pair of the block, each a fixed-order sum
                dot.clear();
                dot.resize(no * nb, 0.0);
                let sample_block = (&s_win[s0..], ns);
                dense::mul_add(&mut dot, nb, (&o_win, DIM), sample_block, (no, DIM, nb));
                for (i, row) in dot.chunks_exact(nb).enumerate() {
                    let o = (y0 * o_cols + i) as u32;
                    for (j, &d) in row.iter().enumerate() {
                        let s = s0 + j;
                        let score = o_norm[i] + s_norm[s] - 2.0 * d;
                        if (score, s as u32) < out_best[i] {
                            out_best[i] = (score, s as u32);
                        }
                        if (score, o) < sam_best[s] {
                            sam_best[s] = (score, o);
                        }
                    }
                }
            }
            (out_best, sam_best)
        })
        .collect();
    let mut out_best: Vec<Best> = Vec::with_capacity(o_cols * o_rows);
    let mut sam_best = vec![(f32::INFINITY, 0u32); ns];
    for (o, s) in parts {
        out_best.extend(o);
        for (b, c) in sam_best.iter_mut().zip(s) {
            if c < *b {
                *b = c;
            }
        }
    }
    let at = |w: u32, cols: usize| (w as usize % cols, w as usize / cols);
    let n = (WINDOW * WINDOW) as f64;
    let coherence: Vec<f64> = out_best
        .par_iter()
        .enumerate()
        .map(|(o, &(_, s))| (ssd(output, at(o as u32, o_cols), sample, at(s, s_cols)) / n).sqrt())
        .collect();
    let completeness: Vec<f64> = sam_best
        .par_iter()
        .enumerate()
        .map(|(s, &(_, o))| (ssd(sample, at(s as u32, s_cols), output, at(o, o_cols)) / n).sqrt())
        .collect();
    Ok(CompareReport {
        coherence: Distances::of(coherence),
        completeness: Distances::of(completeness),
    })
}

/// [`compare_images`] on two image files (PNG, JPEG, EXR, …); an error
/// names the file it is about.
pub fn compare(output: &Path, sample: &Path, budget: MemoryBudget) -> Result<CompareReport> {
    let mut images = Vec::with_capacity(2);
    for (what, path) in [("output", output), ("sample", sample)] {
        let img = imageio::read_rgb_within(path, budget.0)?;
        if let Some(reason) = too_small(what, &img) {
            return Err(Error::Input {
                path: path.to_path_buf(),
                reason,
            });
        }
        images.push(img);
    }
    compare_images(&images[0], &images[1], budget)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn noise(w: usize, h: usize, seed: u64) -> RgbImage {
        let data = (0..w * h * 3)
            .map(|i| (crate::rng::mix64(seed * 1_000_003 + i as u64) % 1000) as f32 / 1000.0)
            .collect();
        RgbImage {
            width: w,
            height: h,
            data,
        }
    }

    /// Nearest windows by brute force in double precision.
    fn brute(a: &RgbImage, b: &RgbImage) -> Vec<f64> {
        let mut d = Vec::new();
        for y in 0..=a.height - WINDOW {
            for x in 0..=a.width - WINDOW {
                let mut best = f64::INFINITY;
                for v in 0..=b.height - WINDOW {
                    for u in 0..=b.width - WINDOW {
                        best = best.min(ssd(a, (x, y), b, (u, v)));
                    }
                }
                d.push((best / 25.0).sqrt());
            }
        }
        d
    }

    #[test]
    fn nearest_windows_match_brute_force() {
        let out = noise(23, 17, 1);
        let sam = noise(14, 19, 2);
        let r = compare_images(&out, &sam, MemoryBudget::default()).unwrap();
        let want = (Distances::of(brute(&out, &sam)), Distances::of(brute(&sam, &out)));
        for (got, want) in [(&r.coherence, &want.0), (&r.completeness, &want.1)] {
            assert_eq!(got.windows, want.windows);
            for (g, w) in [(got.mean, want.mean), (got.p95, want.p95), (got.max, want.max)] {
                assert!((g - w).abs() < 1e-9, "{got:?} vs {want:?}");
            }
        }
    }

    #[test]
    fn a_crop_is_coherent_but_incomplete() {
        let sam = noise(24, 24, 3);
        // the top-left 12×12 of the sample
        let mut crop = RgbImage::new(12, 12);
        for y in 0..12 {
            crop.data[y * 36..y * 36 + 36].copy_from_slice(&sam.data[y * 72..y * 72 + 36]);
        }
        let r = compare_images(&crop, &sam, MemoryBudget::default()).unwrap();
        assert_eq!(r.coherence.max, 0.0, "{r:?}");
        assert!(r.completeness.mean > 0.1, "{r:?}");
        let same = compare_images(&sam, &sam, MemoryBudget::default()).unwrap();
        assert_eq!((same.coherence.max, same.completeness.max), (0.0, 0.0));
    }

    #[test]
    fn figures_do_not_depend_on_the_thread_count() {
        let out = noise(300, 9, 4);
        let sam = noise(64, 40, 5);
        let run = |threads: usize| {
            rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap()
                .install(|| compare_images(&out, &sam, MemoryBudget::default()).unwrap())
        };
        assert_eq!(run(1), run(3));
    }

    #[test]
    fn too_small_or_too_large_is_refused() {
        let small = noise(4, 30, 6);
        let e = compare_images(&small, &noise(10, 10, 7), MemoryBudget::default()).unwrap_err();
        assert!(e.to_string().contains("output image is 4×30"), "{e}");
        let e = compare_images(&noise(10, 10, 7), &noise(64, 64, 8), MemoryBudget(1 << 16)).unwrap_err();
        assert!(e.to_string().contains("--memory"), "{e}");
    }
}
