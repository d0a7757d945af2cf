//! Structure across seams, for [`super::evaluate`]: at a seam edge, the
//! colour each side's patch would have shown one texel further on (its
//! sample continued across the seam, from the step between the seam texel
//! and the texel behind it in the same patch) against the colour the other
//! patch shows there. A cut through bland texture costs little; a mortar
//! line or a strand that ends at the seam, or a course offset by part of a
//! course, shows as a continuation as different as the sample's strongest
//! edges. Colour steps across the seam (`seam` in the report) cannot tell
//! the two apart: a seam along a mortar line has a strong step too.

use serde::Serialize;

use crate::artifact::gim::{Gim, EMPTY};
use crate::io::imageio::{self, RgbImage};
use crate::output::{colour_rows, BAND_ROWS};
use crate::quilt::{Quilt, NO_PATCH};
use crate::Result;

/// A sample step longer than this (sample pixels) between two grid
/// neighbours is not a continuation (a wrapped coordinate).
const MAX_STEP: f32 = 4.0;

/// How features continue across seam edges.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct ContinuationFigures {
    /// Continuations measured: per seam edge inside a chart, each side
    /// whose patch also holds the texel behind it.
    pub continuations: usize,
    /// Mean RGB distance between a side's continued sample colour and the
    /// colour the other patch shows.
    pub mean: f64,
    /// 95th percentile (nearest rank) of the same distances.
    pub p95: f64,
    /// The same mean over grid edges inside patches (the resampling error
    /// alone, the floor of `mean`).
    pub inside_patches_mean: f64,
    /// The sample's edge strength: the 95th percentile (nearest rank) of
    /// its RGB neighbour differences (the first sample's preview).
    pub sample_edge: f64,
    /// Share of continuations differing by more than `sample_edge`: a
    /// feature ends at the seam.
    pub broken: f64,
    /// Broken continuations per 1000 covered texels.
    pub broken_per_1000_texels: f64,
}

/// Bands of atlas rows with one row above and two below (a vertical seam
/// edge from the band's last row continues two rows down).
struct Band {
    /// First row held (one above the band's own rows, except at the top).
    lo: usize,
    colour: Vec<f32>,
    covered: Vec<bool>,
    patch: Vec<u32>,
    index: Vec<u8>,
    chart: Vec<u32>,
    coords: Vec<[f32; 2]>,
}

/// Measures the continuation of features across the seams of `quilt`,
/// reading the atlas in bands of [`BAND_ROWS`] rows.
pub(super) fn continuation(quilt: &Quilt, gim: &Gim, previews: &[RgbImage]) -> Result<ContinuationFigures> {
    let r = quilt.resolution;
    let mut seam = Vec::new();
    let (mut inner_sum, mut inner_count, mut texels) = (0f64, 0usize, 0usize);
    for y0 in (0..r).step_by(BAND_ROWS) {
        let y1 = (y0 + BAND_ROWS).min(r);
        let (lo, hi) = (y0.saturating_sub(1), (y1 + 2).min(r));
        let (colour, covered) = colour_rows(quilt, previews, lo, hi)?;
        let b = Band {
            lo,
            colour,
            covered,
            patch: quilt.patch_region(0, lo, r, hi - lo)?,
            index: quilt.sample_region(0, lo, r, hi - lo)?,
            chart: gim.chart_face_region(0, lo, r, hi - lo)?.0,
            coords: quilt.coord_region(0, lo, r, hi - lo)?,
        };
        let rows = hi - lo;
        for y in y0..y1 {
            for x in 0..r {
                let s = (y - b.lo) * r + x;
                texels += b.covered[s] as usize;
                // (x, y) and its right and lower neighbours, each edge once
                for (dx, dy) in [(1usize, 0usize), (0, 1)] {
                    let (xt, yt) = (x + dx, y - b.lo + dy);
                    if xt >= r || yt >= rows {
                        continue;
                    }
                    let t = yt * r + xt;
                    let d = dx + dy * r;
                    if !b.same_surface(s, t) {
                        continue;
                    }
                    let behind_s = (x >= dx && y - b.lo >= dy).then(|| s - d);
                    let beyond_t = (xt + dx < r && yt + dy < rows).then(|| t + d);
                    for (from, behind, to) in [(s, behind_s, t), (t, beyond_t, s)] {
                        let Some(e) = behind.and_then(|k| b.continued(previews, from, k, to)) else {
                            continue;
                        };
                        if b.patch[s] != b.patch[t] {
                            seam.push(e);
                        } else {
                            inner_sum += e;
                            inner_count += 1;
                        }
                    }
                }
            }
        }
    }
    let sample_edge = previews.first().map_or(0.0, edge_strength);
    let broken = seam.iter().filter(|&&e| e > sample_edge).count();
    let mean = seam.iter().sum::<f64>() / seam.len().max(1) as f64;
    seam.sort_by(f64::total_cmp);
    Ok(ContinuationFigures {
        continuations: seam.len(),
        mean,
        p95: super::compare::nearest_rank(&seam, 0.95),
        inside_patches_mean: inner_sum / inner_count.max(1) as f64,
        sample_edge,
        broken: broken as f64 / seam.len().max(1) as f64,
        broken_per_1000_texels: 1000.0 * broken as f64 / texels.max(1) as f64,
    })
}

impl Band {
    /// Both texels covered, in one chart, from one sample.
    fn same_surface(&self, a: usize, b: usize) -> bool {
        self.covered[a]
            && self.covered[b]
            && self.chart[a] != EMPTY
            && self.chart[a] == self.chart[b]
            && self.index[a] == self.index[b]
    }

    /// The RGB distance between `to`'s colour and the colour `from`'s patch
    /// would show at `to`: its sample coordinate continued by the step from
    /// `behind` (same patch and chart) to `from`. `None` where `behind` is
    /// not in `from`'s patch or the step is not a continuation.
    fn continued(&self, previews: &[RgbImage], from: usize, behind: usize, to: usize) -> Option<f64> {
        if !self.same_surface(from, behind)
            || self.patch[behind] != self.patch[from]
            || self.patch[from] == NO_PATCH
        {
            return None;
        }
        let ([u, v], [ub, vb]) = (self.coords[from], self.coords[behind]);
        let (du, dv) = (u - ub, v - vb);
        if !(du.is_finite() && dv.is_finite()) || du.hypot(dv) > MAX_STEP {
            return None;
        }
        let c = imageio::bilinear(&previews[self.index[from] as usize], u + du, v + dv);
        let o = &self.colour[to * 3..to * 3 + 3];
        Some((0..3).map(|k| ((c[k] - o[k]) as f64).powi(2)).sum::<f64>().sqrt())
    }
}

/// The 95th percentile (nearest rank) of an image's RGB differences
/// between 4-neighbours.
fn edge_strength(img: &RgbImage) -> f64 {
    let (w, h) = (img.width, img.height);
    let px = |x: usize, y: usize| &img.data[(y * w + x) * 3..(y * w + x) * 3 + 3];
    let d = |a: &[f32], b: &[f32]| (0..3).map(|k| ((a[k] - b[k]) as f64).powi(2)).sum::<f64>().sqrt();
    let mut steps = Vec::with_capacity(2 * w * h);
    for y in 0..h {
        for x in 0..w {
            if x + 1 < w {
                steps.push(d(px(x, y), px(x + 1, y)));
            }
            if y + 1 < h {
                steps.push(d(px(x, y), px(x, y + 1)));
            }
        }
    }
    steps.sort_by(f64::total_cmp);
    super::compare::nearest_rank(&steps, 0.95)
}
