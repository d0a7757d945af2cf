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

use crate::artifact::gim::EMPTY;
use crate::io::imageio::{self, RgbImage};
use crate::math;
use crate::output::band::{diff, rgb_distance, ColourBand};
use crate::output::ranks::{self, Ranked};
use crate::quilt::NO_PATCH;

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
    /// The same, each broken continuation counted by the exposure (0..=1,
    /// [`crate::mesh::exposure`]) of the face it lands on: a feature that
    /// ends in a crease or under the chin, where the surface is seen from
    /// few directions, counts little. Where the field's singularities sit
    /// out of sight (`atlas --field-exposure`), courses end out of sight.
    pub broken_seen_per_1000_texels: f64,
}

/// The continuation of features across seams, gathered band by band
/// ([`Continuation::gather`]) in [`super::evaluate`]'s pass over the atlas.
pub(super) struct Continuation {
    /// Each continuation across a seam edge (for its 95th percentile).
    pub(super) seam: Ranked,
    /// The sample's edge strength ([`ContinuationFigures::sample_edge`]).
    sample_edge: f64,
    /// Continuations across seam edges beyond `sample_edge`, and the
    /// exposure of the faces they land on summed in their order.
    broken: usize,
    broken_seen: f64,
    /// Continuations inside patches, summed in the order a list would sum them.
    inner_sum: f64,
    inner_count: usize,
}

impl Continuation {
    /// Keeps at most `seam_bytes` of continuations across seams
    /// ([`Ranked`]); `previews` give the sample's edge strength.
    pub(super) fn new(previews: &[RgbImage], seam_bytes: u64) -> Continuation {
        Continuation {
            seam: Ranked::within(seam_bytes),
            sample_edge: previews.first().map_or(0.0, edge_strength),
            broken: 0,
            broken_seen: 0.0,
            inner_sum: 0.0,
            inner_count: 0,
        }
    }

    /// The continuations of the band's own rows ([`each`]); `exposure` is
    /// per mesh face.
    pub(super) fn gather(&mut self, b: &ColourBand, previews: &[RgbImage], exposure: &[f32], r: usize) {
        each(b, previews, r, |across, e, to| {
            if across {
                self.seam.push(e);
                if e > self.sample_edge {
                    self.broken += 1;
                    self.broken_seen += exposure.get(b.face[to] as usize).copied().unwrap_or(1.0) as f64;
                }
            } else {
                self.inner_sum += e;
                self.inner_count += 1;
            }
        });
    }

    /// The figures, over `texels` covered texels; `p95` is the 95th
    /// percentile (nearest rank, [`super::ranks::nearest_rank_index`]) of
    /// the continuations across seams.
    pub(super) fn figures(&self, p95: f64, texels: usize) -> ContinuationFigures {
        let n = self.seam.len();
        ContinuationFigures {
            continuations: n,
            mean: self.seam.mean(),
            p95,
            inside_patches_mean: self.inner_sum / self.inner_count.max(1) as f64,
            sample_edge: self.sample_edge,
            broken: self.broken as f64 / n.max(1) as f64,
            broken_per_1000_texels: 1000.0 * self.broken as f64 / texels.max(1) as f64,
            broken_seen_per_1000_texels: 1000.0 * self.broken_seen / texels.max(1) as f64,
        }
    }
}

/// Calls `f(across a seam, distance, texel continued into)` for each
/// continuation of the band's own rows: each grid edge from an own texel
/// to its right and lower neighbours, each way (the band holds one row
/// above its own and two below), in atlas order.
pub(super) fn each(b: &ColourBand, previews: &[RgbImage], r: usize, mut f: impl FnMut(bool, f64, usize)) {
    let rows = b.covered.len() / r;
    for s in b.own_texels() {
        let (x, ys) = (s % r, s / r);
        for (dx, dy) in [(1usize, 0usize), (0, 1)] {
            let (xt, yt) = (x + dx, ys + dy);
            if xt >= r || yt >= rows {
                continue;
            }
            let t = yt * r + xt;
            let d = dx + dy * r;
            if !same_surface(b, s, t) {
                continue;
            }
            let behind_s = (x >= dx && ys >= dy).then(|| s - d);
            let beyond_t = (xt + dx < r && yt + dy < rows).then(|| t + d);
            for (from, behind, to) in [(s, behind_s, t), (t, beyond_t, s)] {
                if let Some(e) = behind.and_then(|k| continued(b, previews, from, k, to)) {
                    f(b.patch[s] != b.patch[t], e, to);
                }
            }
        }
    }
}

/// Both texels covered, in one chart, from one sample.
fn same_surface(band: &ColourBand, a: usize, b: usize) -> bool {
    band.covered[a]
        && band.covered[b]
        && band.chart[a] != EMPTY
        && band.chart[a] == band.chart[b]
        && band.index[a] == band.index[b]
}

/// The RGB distance between `to`'s colour and the colour `from`'s patch
/// would show at `to`: its sample coordinate continued by the step from
/// `behind` (same patch and chart) to `from`. `None` where `behind` is not
/// in `from`'s patch or the step is not a continuation.
fn continued(band: &ColourBand, previews: &[RgbImage], from: usize, behind: usize, to: usize) -> Option<f64> {
    if !same_surface(band, from, behind)
        || band.patch[behind] != band.patch[from]
        || band.patch[from] == NO_PATCH
    {
        return None;
    }
    let ([u, v], [ub, vb]) = (band.coords[from], band.coords[behind]);
    let (du, dv) = (u - ub, v - vb);
    if !(du.is_finite() && dv.is_finite()) || math::hypot(du, dv) > MAX_STEP {
        return None;
    }
    let c = imageio::bilinear(&previews[band.index[from] as usize], u + du, v + dv);
    Some(rgb_distance(&c, &band.colour[to * 3..to * 3 + 3]))
}

/// The 95th percentile (nearest rank) of an image's RGB differences
/// between 4-neighbours, holding at most [`ranks::COLLECT`] of them.
fn edge_strength(img: &RgbImage) -> f64 {
    let (w, h) = (img.width, img.height);
    let steps = |f: &mut dyn FnMut(f64)| {
        for y in 0..h {
            for x in 0..w {
                let i = y * w + x;
                if x + 1 < w {
                    f(diff(&img.data, i, i + 1));
                }
                if y + 1 < h {
                    f(diff(&img.data, i, i + w));
                }
            }
        }
        Ok(())
    };
    ranks::rank_of(steps, |n| ranks::nearest_rank_index(n, 0.95)).map_or(0.0, |(_, v)| v)
}
