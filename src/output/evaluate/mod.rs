//! `evaluate`: quality figures of a decorated surface, as an
//! [`EvaluateReport`] (which `btfquilt evaluate` prints as JSON).
//!
//! - seams: colour differences across grid edges where the patch changes,
//!   against those inside patches;
//! - continuation: at seam edges, each side's sample continued one texel
//!   across the seam against the other side's colour, and the share of
//!   continuations as different as the sample's strongest edges (a feature
//!   that ends at the seam; [`super::continuation`]);
//! - zippers: mean colour difference across zipper links divided by the mean
//!   across grid links inside charts (≈ 1 means chart seams are invisible);
//! - coherence: mean and 95th percentile RGB distance from 5×5 output
//!   windows to their nearest 5×5 window of the sample (turned by the
//!   window's rotation);
//! - usage: per sample, how many covered texels use each of its pixels
//!   (through the stored sample coordinates), as a histogram and the share
//!   of the sample never used;
//! - scale: the size of the sample on the surface, measured from the stored
//!   sample coordinates against the 3D positions (mesh units);
//! - courses: for a sample whose features run in rows, courses offset or
//!   ending at seams, against the ends the field forces
//!   ([`courses`](crate::output::courses)).

use std::path::Path;

use serde::Serialize;

use crate::artifact::gim::{Gim, EMPTY};
use crate::container::MemoryBudget;
use crate::factorize::rotate_maps;
use crate::io::imageio::RgbImage;
use crate::math;
use crate::output::band::{diff, ColourBand};
use crate::output::continuation::{Continuation, ContinuationFigures};
use crate::output::courses::{CourseCount, CourseFigures};
use crate::output::ranks::{self, Ranked};
use crate::output::{open_samples, OpenSample, BAND_ROWS};
use crate::quilt::{Quilt, NO_PATCH};
use crate::Result;

/// The quality figures of a decorated surface. Serialized (serde), its
/// field names and nesting are those of `btfquilt evaluate`'s JSON.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct EvaluateReport {
    /// Covered atlas texels.
    pub texels: usize,
    /// Distinct patches in the synthesis.
    pub patches: usize,
    /// The painting measures, for a painted surface only.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub painting: Option<PaintingFigures>,
    pub seam: SeamFigures,
    /// Whether features continue across seams ([`continuation`](crate::output::continuation)).
    pub continuation: ContinuationFigures,
    pub zipper: ZipperFigures,
    pub coherence: CoherenceFigures,
    /// Per sample, how often each of its pixels appears on the surface.
    pub usage: Vec<UsageFigures>,
    pub scale: ScaleFigures,
    /// Whether courses run on across seams, when the first sample's
    /// features run in rows.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub courses: Option<CourseFigures>,
}

/// How the surface uses one sample: per sample pixel, the covered atlas
/// texels whose stored sample coordinate falls in it.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct UsageFigures {
    /// The sample's index in the quilt.
    pub sample: usize,
    /// Its pixels (the preview's width × height).
    pub pixels: usize,
    /// Share of its pixels no texel uses.
    pub never_used: f64,
    /// Pixels used 0, 1, 2–3, 4–7, 8–15, … times (powers of two).
    pub histogram: Vec<usize>,
}

/// The sample's size on the surface, measured: over grid edges inside one
/// patch of the first sample, the median of |Δ sample coordinate| (original
/// sample pixels) / |Δ position| (mesh units).
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct ScaleFigures {
    /// Grid edges measured.
    pub edges: usize,
    /// Median sample pixels per mesh unit along the surface.
    pub sample_pixels_per_unit: f64,
    /// The first sample's width in mesh units it spans on the surface
    /// (its width in pixels over the median above): a brick `p` sample
    /// pixels long is `p / sample_pixels_per_unit` units long.
    pub sample_width_units: f64,
}

/// Colour differences across grid edges inside charts where the patch
/// changes (seam edges), against those inside patches.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct SeamFigures {
    /// Seam edges.
    pub edges: usize,
    /// Seam edges / all grid edges inside charts.
    pub fraction_of_edges: f64,
    /// Mean RGB distance across seam edges.
    pub mean_colour_difference: f64,
    pub median: f64,
    pub p95: f64,
    pub max: f64,
    /// Mean RGB distance across edges inside patches.
    pub inside_patches_mean: f64,
    /// `mean_colour_difference / inside_patches_mean`.
    pub ratio_to_inside: f64,
}

/// Colour differences across zipper links (chart seams) against grid edges
/// inside charts.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct ZipperFigures {
    /// Covered zipper links.
    pub links: usize,
    pub mean_colour_difference: f64,
    pub inside_charts_mean: f64,
    /// `mean_colour_difference / inside_charts_mean` (≈ 1: chart seams are invisible).
    pub ratio: f64,
}

/// How closely 5×5 output windows resemble the sample.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct CoherenceFigures {
    /// Windows measured.
    pub windows: usize,
    pub mean_rgb_distance_to_nearest_sample_window: f64,
    /// 95th percentile (nearest rank) of the same distances.
    pub p95_rgb_distance_to_nearest_sample_window: f64,
    /// The same windows against the sample read in each window's own frame
    /// (the rotation, scale and sub-pixel position of its centre texel,
    /// moved by whole sample pixels; [`framed_distance`]): resampling at
    /// another phase or scale no longer counts, seams, bends and content
    /// do. `None` for a quilt that stores no Jacobians.
    pub mean_rgb_distance_in_own_frame: Option<f64>,
    /// 95th percentile (nearest rank) of the same distances.
    pub p95_rgb_distance_in_own_frame: Option<f64>,
}

/// The painting measures of a painted surface (§IV).
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct PaintingFigures {
    /// Texels of F (m0 = 1).
    pub region_texels: usize,
    /// Fraction of F covered by foreground texels.
    pub region_covered_by_foreground: f64,
    /// Texels of the painted sample with m_σ ≥ ½.
    pub foreground_texels: usize,
    /// Fraction of the foreground texels outside F and its transition zone (m0 = 0).
    pub foreground_outside_region_and_transition: f64,
}

/// How `evaluate` measures.
#[derive(Clone, Debug)]
pub struct EvaluateConfig {
    /// Memory for decoded tiles.
    pub memory: MemoryBudget,
    /// Output windows the coherence measures at most (seeded places, the
    /// same for every quilt of one resolution). Each costs an exact search
    /// over its sample; its 95th percentile steadies with more.
    pub windows: usize,
    /// Also count the course ends of the smoothest stripe pattern along
    /// the field at the sample's course period
    /// ([`crate::field::forced_ends`]): a stripe solve on the subdivided
    /// mesh, about a second and 140 MB on Spot.
    pub forced_ends: bool,
}

impl Default for EvaluateConfig {
    fn default() -> Self {
        EvaluateConfig {
            memory: MemoryBudget::default(),
            windows: 200,
            forced_ends: false,
        }
    }
}

impl EvaluateConfig {
    /// Refuses a setting that cannot measure anything.
    pub fn validate(&self) -> Result<()> {
        if self.windows == 0 || self.windows > MAX_WINDOWS {
            return Err(crate::Error::Config(format!(
                "--windows {}: measure 1 to {MAX_WINDOWS} windows",
                self.windows
            )));
        }
        Ok(())
    }
}

/// [`evaluate_with`] with the default windows.
pub fn evaluate(
    quilt_path: &Path,
    gim_path: Option<&Path>,
    sample: Option<&Path>,
    budget: MemoryBudget,
) -> Result<EvaluateReport> {
    let cfg = EvaluateConfig {
        memory: budget,
        ..EvaluateConfig::default()
    };
    evaluate_with(quilt_path, gim_path, sample, &cfg)
}

/// Computes the figures, reading the atlas in bands of 64 rows
/// (and the row below each), so memory follows the band, the seam edges and
/// the zipper links, not the atlas.
pub fn evaluate_with(
    quilt_path: &Path,
    gim_path: Option<&Path>,
    sample: Option<&Path>,
    cfg: &EvaluateConfig,
) -> Result<EvaluateReport> {
    cfg.validate()?;
    let budget = cfg.memory;
    // decoded chunks of the quilt, the geometry image and the samples; the
    // rest for the seam steps, zipper links, bands and the stripe solve
    let [quilt_budget, gim_budget, sample_budget, work] =
        budget.less(crate::output::PROGRAM_BYTES).split([2, 2, 1, 3]);
    let quilt = Quilt::open(quilt_path, quilt_budget)?;
    let gim = quilt.open_gim(gim_path, gim_budget)?;
    let samples = open_samples(&quilt, sample, [sample_budget, budget])?;
    let previews = samples
        .iter()
        .map(|s| s.svd.preview())
        .collect::<Result<Vec<_>>>()?;
    let r = quilt.resolution;
    let links = gim.zipper_links()?;
    let mut zipper = ZipperEnds::new(&links);
    let mut windows = Windows::new(r, cfg.windows);
    let mut usage: Vec<Vec<u32>> = previews.iter().map(|p| vec![0; p.width * p.height]).collect();
    let mut painting = Painting::open(&quilt, &samples)?;
    let mut patch_ids = std::collections::HashSet::new();
    let mut texels = 0usize;
    // seam steps and continuations are kept as far as the work share
    // leaves room (their percentiles are reported; past it the bands are
    // read again, [`ranks`]); steps inside patches only summed, in the
    // order a list would sum them
    let lists = work.0.saturating_sub(windows.bytes() + zipper.bytes()) / 2;
    let mut seam = Ranked::within(lists);
    let (mut inner_sum, mut inner_count) = (0f64, 0usize);
    let mut continuation = Continuation::new(&previews, lists);
    // mesh units one pixel of each sample spans
    let span = |k: usize| match quilt.sample_span(k) {
        Some(units) => units / previews[k].width as f64,
        None => gim.texel_size,
    };
    let courses = crate::output::courses::sample_courses(&previews, span);
    let mut course_count = CourseCount::default();
    let mesh = gim.mesh()?;
    let exposure = crate::mesh::exposure::face_exposure(&mesh);
    let band = |y0: usize| {
        let y1 = (y0 + BAND_ROWS).min(r);
        // one row above and two below the band's own: a vertical seam edge
        // from the band's first row continues from the row above, one
        // from its last row two rows down
        ColourBand::read(
            &quilt,
            &gim,
            &previews,
            y0.saturating_sub(1),
            y0,
            y1,
            (y1 + 2).min(r),
        )
    };
    for y0 in (0..r).step_by(BAND_ROWS) {
        let b = band(y0)?;
        for t in b.own_texels() {
            texels += b.covered[t] as usize;
            if b.patch[t] != NO_PATCH {
                patch_ids.insert(b.patch[t]);
            }
        }
        grid_steps(&b, r, |across, d| {
            if across {
                seam.push(d);
            } else {
                inner_sum += d;
                inner_count += 1;
            }
        });
        zipper.gather(&b, r);
        windows.gather(&b, r);
        continuation.gather(&b, &previews, &exposure, r);
        if let Some(c) = &courses {
            course_count.gather(&b, c, r);
        }
        count_usage(&mut usage, &previews, &b);
        if let Some(p) = painting.as_mut() {
            p.count(&quilt, &b, r)?;
        }
    }
    // the seam steps summed after the steps inside patches, in their order
    // (read again with the bands if they were not all kept)
    let mut inside_sum = seam.kept().map(|k| k.iter().fold(inner_sum, |a, &d| a + d));
    let (edges, seam_mean) = (seam.len(), seam.mean());
    let q = |p: f64| ((edges as f64 - 1.0) * p).round() as usize;
    let wanted = [
        (0, q(0.5)),
        (0, q(0.95)),
        (0, q(1.0)),
        (1, ranks::nearest_rank_index(continuation.seam.len(), 0.95)),
    ];
    let found = ranks::at_ranks(&mut [&mut seam, &mut continuation.seam], &wanted, |f| {
        let mut sum = inner_sum;
        for y0 in (0..r).step_by(BAND_ROWS) {
            let b = band(y0)?;
            grid_steps(&b, r, |across, d| {
                if across {
                    sum += d;
                    f(0, d);
                }
            });
            crate::output::continuation::each(&b, &previews, r, |across, e, _| {
                if across {
                    f(1, e)
                }
            });
        }
        inside_sum.get_or_insert(sum);
        Ok(())
    })?;
    let inside_mean = inside_sum.unwrap_or(inner_sum) / (inner_count + edges).max(1) as f64;
    let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len().max(1) as f64;
    let zip = zipper.differences(&links);
    let inner_mean = inner_sum / inner_count.max(1) as f64;
    let zipper_ratio = mean(&zip) / inside_mean.max(1e-12) + 0.0;
    let steps = match quilt.container().metadata().param("rotations") {
        Some(crate::container::Param::Int(v)) if *v > 0 => *v as usize,
        _ => 72,
    };
    let (mut coherence, mut framed) = windows.coherence(&previews, steps);
    coherence.sort_by(f64::total_cmp);
    framed.sort_by(f64::total_cmp);
    let p95 = super::compare::nearest_rank(&coherence, 0.95);
    // (none for a quilt that stores no Jacobians)
    let framed_figures =
        (!framed.is_empty()).then(|| (mean(&framed), super::compare::nearest_rank(&framed, 0.95)));
    let seams_fraction = edges as f64 / (edges + inner_count).max(1) as f64;
    let width = previews.first().map_or(0, |p| p.width);
    let scale = scale(&quilt, &gim, width)?;
    let continuation = continuation.figures(found[3], texels);
    let courses = match courses.as_ref().and_then(|c| c[0].as_ref()) {
        Some(c) if cfg.forced_ends && scale.sample_pixels_per_unit > 0.0 => {
            let field = gim.face_field()?;
            let period = c.period() / scale.sample_pixels_per_unit;
            let forced = crate::field::forced_ends(&mesh, &field, period, work.0, budget.0)?;
            Some(course_count.figures(&c, Some(forced.ends)))
        }
        Some(c) => Some(course_count.figures(&c, None)),
        None => None,
    };
    Ok(EvaluateReport {
        texels,
        patches: patch_ids.len(),
        painting: painting.map(|p| p.figures()),
        seam: SeamFigures {
            edges,
            fraction_of_edges: seams_fraction,
            mean_colour_difference: seam_mean,
            median: found[0],
            p95: found[1],
            max: found[2],
            inside_patches_mean: inner_mean,
            ratio_to_inside: seam_mean / inner_mean.max(1e-12),
        },
        continuation,
        zipper: ZipperFigures {
            links: zip.len(),
            mean_colour_difference: mean(&zip),
            inside_charts_mean: inside_mean,
            ratio: zipper_ratio,
        },
        coherence: CoherenceFigures {
            windows: coherence.len(),
            mean_rgb_distance_to_nearest_sample_window: mean(&coherence),
            p95_rgb_distance_to_nearest_sample_window: p95,
            mean_rgb_distance_in_own_frame: framed_figures.map(|f| f.0),
            p95_rgb_distance_in_own_frame: framed_figures.map(|f| f.1),
        },
        usage: usage
            .iter()
            .enumerate()
            .map(|(sample, counts)| usage_figures(sample, counts))
            .collect(),
        scale,
        courses,
    })
}

/// Calls `f(across a seam, colour step)` for each grid edge from an own
/// texel of the band to its right and lower neighbour inside one chart,
/// both covered, in atlas order.
fn grid_steps(b: &ColourBand, r: usize, mut f: impl FnMut(bool, f64)) {
    for t in b.own_texels() {
        let (x, y) = (t % r, b.y0 + t / r);
        if b.chart[t] == EMPTY || !b.covered[t] {
            continue;
        }
        for n in [(x + 1 < r).then(|| t + 1), (y + 1 < r).then(|| t + r)]
            .into_iter()
            .flatten()
        {
            if b.chart[n] == b.chart[t] && b.covered[n] {
                f(b.patch[n] != b.patch[t], diff(&b.colour, t, n));
            }
        }
    }
}

/// Adds the band's covered texels to the use counts of the sample pixels
/// their stored coordinates fall in (wrapped into the sample).
fn count_usage(usage: &mut [Vec<u32>], previews: &[RgbImage], b: &ColourBand) {
    for t in b.own_texels() {
        let i = b.index[t] as usize;
        if !b.covered[t] || b.patch[t] == NO_PATCH || i >= usage.len() {
            continue;
        }
        let (w, h) = (previews[i].width as i64, previews[i].height as i64);
        let [u, v] = b.coords[t];
        if !(u.is_finite() && v.is_finite()) {
            continue;
        }
        let (x, y) = ((u.floor() as i64).rem_euclid(w), (v.floor() as i64).rem_euclid(h));
        usage[i][(y * w + x) as usize] += 1;
    }
}

/// The figures of one sample's use counts.
fn usage_figures(sample: usize, counts: &[u32]) -> UsageFigures {
    let mut histogram = vec![0usize];
    for &c in counts {
        let bucket = if c == 0 { 0 } else { 1 + c.ilog2() as usize };
        if histogram.len() <= bucket {
            histogram.resize(bucket + 1, 0);
        }
        histogram[bucket] += 1;
    }
    UsageFigures {
        sample,
        pixels: counts.len(),
        never_used: histogram[0] as f64 / counts.len().max(1) as f64,
        histogram,
    }
}

/// The colour and coverage of every zipper link's two texels, gathered band
/// by band (links cross charts, so their ends lie anywhere in the atlas).
struct ZipperEnds {
    /// Texels at an end of a link, ascending.
    texels: Vec<u32>,
    colour: Vec<f32>,
    covered: Vec<bool>,
}

impl ZipperEnds {
    fn new(links: &[[u32; 2]]) -> ZipperEnds {
        let mut texels: Vec<u32> = links.iter().flatten().copied().collect();
        texels.sort_unstable();
        texels.dedup();
        ZipperEnds {
            colour: vec![0.0; texels.len() * 3],
            covered: vec![false; texels.len()],
            texels,
        }
    }

    /// What the link ends hold.
    fn bytes(&self) -> u64 {
        (self.texels.len() * (4 + 12 + 1)) as u64
    }

    fn gather(&mut self, b: &ColourBand, r: usize) {
        let (lo, hi) = ((b.first * r) as u64, (b.first * r + b.own) as u64);
        let first = self.texels.partition_point(|&t| (t as u64) < lo);
        let last = self.texels.partition_point(|&t| (t as u64) < hi);
        for i in first..last {
            let t = self.texels[i] as usize - b.y0 * r;
            self.covered[i] = b.covered[t];
            self.colour[i * 3..i * 3 + 3].copy_from_slice(&b.colour[t * 3..t * 3 + 3]);
        }
    }

    /// The colour difference across each link whose two texels are covered,
    /// in link order.
    fn differences(&self, links: &[[u32; 2]]) -> Vec<f64> {
        let at = |t: u32| self.texels.binary_search(&t).ok();
        links
            .iter()
            .filter_map(|l| Some((at(l[0])?, at(l[1])?)))
            .filter(|&(a, b)| self.covered[a] && self.covered[b])
            .map(|(a, b)| diff(&self.colour, a, b))
            .collect()
    }
}

/// Candidate 5×5 output windows for the coherence figure, at seeded places
/// (the same sequence at any band size), gathered band by band.
struct Windows {
    /// Each candidate's centre texel, in the seeded order.
    centres: Vec<usize>,
    /// Per candidate and window texel (row-major 5×5): colour.
    colour: Vec<f32>,
    /// Per candidate: the chart and sample index of the first texel
    /// gathered, and whether every texel so far is covered and in that
    /// chart and sample (a window inside one chart and one sample).
    chart: Vec<u32>,
    index: Vec<u8>,
    inside: Vec<bool>,
    /// The centre's rotation.
    rotation: Vec<u8>,
    /// The centre's stored sample coordinate and Jacobian (its frame), if
    /// the quilt stores Jacobians.
    frame: Vec<Option<Frame>>,
    /// Atlas row, candidate and window row, packed by [`row_key`], ascending.
    rows: Vec<u64>,
    next_row: usize,
    /// Windows measured at most.
    windows: usize,
}

/// How many seeded places the coherence figure tries: at least this many,
/// and [`TRIES_PER_WINDOW`] for each window it measures at most (most
/// places are inside a chart; the windows measured are the first that are,
/// so a larger count measures the same windows and more).
const MIN_TRIES: usize = 20_000;
const TRIES_PER_WINDOW: usize = 4;

/// The most windows `--windows` takes: each place tried holds about 390
/// bytes of [`Windows`] (its 5×5 colours, its centre, chart, sample,
/// frame and five rows), 31 MB for the 80 000 places of the most windows.
const MAX_WINDOWS: usize = 20_000;

/// `(atlas row, candidate, window row)` as one key in the same order (a
/// candidate below 2^24 (`MAX_WINDOWS × TRIES_PER_WINDOW`), rows below 2^32).
fn row_key(y: usize, c: usize, dy: usize) -> u64 {
    (y as u64) << 32 | (c as u64) << 8 | dy as u64
}

impl Windows {
    fn new(r: usize, windows: usize) -> Windows {
        let centres: Vec<usize> = (1..=(windows * TRIES_PER_WINDOW).max(MIN_TRIES) as u64)
            .map(|k| (crate::rng::mix64(k) % (r * r) as u64) as usize)
            .filter(|&t| {
                let (x, y) = (t % r, t / r);
                !(x < 2 || y < 2 || x + 2 >= r || y + 2 >= r)
            })
            .collect();
        let mut rows: Vec<u64> = centres
            .iter()
            .enumerate()
            .flat_map(|(c, &t)| (0..5).map(move |dy| row_key(t / r + dy - 2, c, dy)))
            .collect();
        rows.sort_unstable();
        let n = centres.len();
        Windows {
            colour: vec![0.0; n * 75],
            chart: vec![EMPTY; n],
            index: vec![0; n],
            inside: vec![true; n],
            rotation: vec![0; n],
            frame: vec![None; n],
            centres,
            rows,
            next_row: 0,
            windows,
        }
    }

    /// What the candidates hold.
    fn bytes(&self) -> u64 {
        (self.centres.len() * (8 + 75 * 4 + 4 + 1 + 1 + 1 + std::mem::size_of::<Option<Frame>>())
            + self.rows.len() * 8) as u64
    }

    fn gather(&mut self, b: &ColourBand, r: usize) {
        let end = b.first + b.own / r;
        while let Some(&key) = self.rows.get(self.next_row) {
            let (y, c, dy) = (
                (key >> 32) as usize,
                (key >> 8 & 0xff_ffff) as usize,
                (key & 0xff) as usize,
            );
            if y >= end {
                break;
            }
            self.next_row += 1;
            let x = self.centres[c] % r;
            for dx in 0..5 {
                let (t, w) = ((y - b.y0) * r + x + dx - 2, c * 25 + dy * 5 + dx);
                self.colour[w * 3..w * 3 + 3].copy_from_slice(&b.colour[t * 3..t * 3 + 3]);
                if dy == 0 && dx == 0 {
                    (self.chart[c], self.index[c]) = (b.chart[t], b.index[t]);
                }
                self.inside[c] &= b.covered[t] && b.chart[t] == self.chart[c] && b.index[t] == self.index[c];
            }
            if dy == 2 {
                let t = (y - b.y0) * r + x;
                self.rotation[c] = b.rotation[t];
                self.frame[c] = b.jacobian.as_ref().map(|j| Frame {
                    centre: b.coords[t],
                    jacobian: j[t],
                });
            }
        }
    }

    /// The distance from each window (inside one chart, drawn from one
    /// sample) to the nearest 5×5 window of that sample's preview turned by
    /// the window's rotation (`steps` rotations a turn), in window order:
    /// the first `windows` such windows whose turned preview holds a whole
    /// 5×5 window. The windows are measured grouped by sample and rotation,
    /// one turned preview held per thread at a time (not every rotation at
    /// once: a large sample's 72 turned previews would not fit `--memory`).
    /// Second, the same windows' distances in their own frames
    /// ([`framed_distance`]), for those that have one.
    fn coherence(&self, previews: &[RgbImage], steps: usize) -> (Vec<f64>, Vec<f64>) {
        use rayon::prelude::*;
        let turned = |index: u8, rot: u8| {
            let p = &previews[index as usize];
            rotate_maps(
                &p.data,
                p.width,
                p.height,
                3,
                rot as f64 * 360.0 / steps as f64,
                false,
            )
        };
        // each window inside one chart and one sample, with its (sample, rotation)
        let candidates: Vec<(usize, (u8, u8))> = (0..self.centres.len())
            .filter(|&c| self.inside[c])
            .map(|c| (c, (self.index[c], self.rotation[c])))
            .collect();
        let mut keys: Vec<(u8, u8)> = candidates.iter().map(|&(_, k)| k).collect();
        keys.sort_unstable();
        keys.dedup();
        // a turned preview without a whole window measures none of its
        // windows (which pixels are valid depends on the turn alone: no
        // colour is turned here)
        let whole: std::collections::BTreeSet<(u8, u8)> = keys
            .par_iter()
            .filter(|&&(index, rot)| {
                let p = &previews[index as usize];
                let degrees = rot as f64 * 360.0 / steps as f64;
                let (_, valid) = rotate_maps(&[], p.width, p.height, 0, degrees, false);
                (2..p.height.saturating_sub(2)).any(|sy| {
                    (2..p.width.saturating_sub(2))
                        .any(|sx| (0..25).all(|i| valid[(sy + i / 5 - 2) * p.width + sx + i % 5 - 2] != 0))
                })
            })
            .copied()
            .collect();
        let mut groups: std::collections::BTreeMap<(u8, u8), Vec<usize>> = Default::default();
        for &(c, key) in candidates
            .iter()
            .filter(|(_, k)| whole.contains(k))
            .take(self.windows)
        {
            groups.entry(key).or_default().push(c);
        }
        let mut measured: Vec<(usize, f64, Option<f64>)> = groups
            .into_par_iter()
            .flat_map_iter(|((index, rot), windows)| {
                let p = &previews[index as usize];
                let (sw, sh) = (p.width, p.height);
                let (maps, valid) = turned(index, rot);
                windows
                    .into_iter()
                    .map(|c| {
                        let window = &self.colour[c * 75..c * 75 + 75];
                        let mut best = f64::INFINITY;
                        for sy in 2..sh.saturating_sub(2) {
                            for sx in 2..sw.saturating_sub(2) {
                                let mut ssd = 0f64;
                                let mut ok = true;
                                for i in 0..25 {
                                    let s = (sy + i / 5 - 2) * sw + sx + i % 5 - 2;
                                    if valid[s] == 0 {
                                        ok = false;
                                        break;
                                    }
                                    for k in 0..3 {
                                        ssd += ((maps[s * 3 + k] - window[i * 3 + k]) as f64).powi(2);
                                    }
                                    if ssd >= best {
                                        break;
                                    }
                                }
                                if ok && ssd < best {
                                    best = ssd;
                                }
                            }
                        }
                        let framed = self.frame[c].and_then(|f| framed_distance(p, window, f));
                        (c, (best / 25.0).sqrt(), framed)
                    })
                    .collect::<Vec<_>>()
            })
            .collect();
        measured.sort_unstable_by_key(|&(c, _, _)| c);
        (
            measured.iter().map(|&(_, d, _)| d).collect(),
            measured.iter().filter_map(|&(_, _, f)| f).collect(),
        )
    }
}

/// A window centre's stored sample coordinate and Jacobian (sample offset
/// per atlas step, as [`Quilt::jacobians`]).
#[derive(Clone, Copy, Debug)]
struct Frame {
    centre: [f32; 2],
    jacobian: [f32; 4],
}

/// The RGB distance from a 5×5 output `window` (row-major, 3 values a
/// texel) to the nearest window of the preview `p` read in the window's own
/// frame: texel (dx, dy) of the window at `centre + S·(dx, dy) + t`, with
/// S the similarity nearest the centre's Jacobian (its rotation, or
/// reflection, and its scale √|det|) and t any whole-pixel move that keeps
/// every read inside the preview. A window copied from one rigid patch is
/// at distance 0 whatever its rotation, scale or sub-pixel position, so
/// what remains is seams, bends (stretch that S does not follow) and
/// content. `None` for a degenerate Jacobian or a frame larger than the
/// preview.
fn framed_distance(p: &RgbImage, window: &[f32], frame: Frame) -> Option<f64> {
    let [a, b, c, d] = frame.jacobian.map(f64::from);
    let det = a * d - b * c;
    if !(det.abs() > 1e-12) || !frame.centre.iter().all(|v| v.is_finite()) {
        return None;
    }
    let scale = det.abs().sqrt();
    // the columns of S: the sample offset of one atlas step along +X and +Y
    let (x_step, y_step) = if det > 0.0 {
        let (sin, cos) = math::sin_cos(math::atan2(b - c, a + d));
        ([cos, sin], [-sin, cos])
    } else {
        let (sin, cos) = math::sin_cos(math::atan2(b + c, a - d));
        ([cos, sin], [sin, -cos])
    };
    // each window texel's pixel and bilinear fractions (the same for every
    // whole-pixel move)
    let mut base = [[0i64; 2]; 25];
    let mut frac = [[0f32; 2]; 25];
    for i in 0..25 {
        let (dx, dy) = ((i % 5) as f64 - 2.0, (i / 5) as f64 - 2.0);
        for k in 0..2 {
            let v = frame.centre[k] as f64 + scale * (x_step[k] * dx + y_step[k] * dy);
            let f = v.floor();
            base[i][k] = f as i64;
            frac[i][k] = (v - f) as f32;
        }
    }
    let (w, h) = (p.width as i64, p.height as i64);
    let lo = |k: usize| base.iter().map(|q| q[k]).min().unwrap_or(0);
    let hi = |k: usize| base.iter().map(|q| q[k]).max().unwrap_or(0);
    // t keeps every read (pixel and pixel + 1) inside the preview
    let (tx0, tx1, ty0, ty1) = (-lo(0), w - 2 - hi(0), -lo(1), h - 2 - hi(1));
    if tx0 > tx1 || ty0 > ty1 {
        return None;
    }
    let px = |x: i64, y: i64| &p.data[(y * w + x) as usize * 3..(y * w + x) as usize * 3 + 3];
    // the squared distance at move t, given up (any value ≥ `best`) once
    // it reaches `best`
    let ssd_at = |tx: i64, ty: i64, best: f64| {
        let mut ssd = 0f64;
        for i in 0..25 {
            let (x, y) = (base[i][0] + tx, base[i][1] + ty);
            let (fx, fy) = (frac[i][0], frac[i][1]);
            let (p00, p10, p01, p11) = (px(x, y), px(x + 1, y), px(x, y + 1), px(x + 1, y + 1));
            for k in 0..3 {
                let top = p00[k] + (p10[k] - p00[k]) * fx;
                let bottom = p01[k] + (p11[k] - p01[k]) * fx;
                ssd += ((top + (bottom - top) * fy - window[i * 3 + k]) as f64).powi(2);
            }
            if ssd >= best {
                break;
            }
        }
        ssd
    };
    // the window's own place first (no move): a window from one patch is
    // near 0 there, and every other move is then given up early; the
    // minimum is the same in any order
    let mut best = f64::INFINITY;
    if (tx0..=tx1).contains(&0) && (ty0..=ty1).contains(&0) {
        best = ssd_at(0, 0, best);
    }
    for ty in ty0..=ty1 {
        for tx in tx0..=tx1 {
            best = best.min(ssd_at(tx, ty, best));
        }
    }
    Some((best / 25.0).sqrt())
}

/// The painting measures of a painted surface (§IV), counted band by band:
/// the fraction of F (m0 = 1) covered by foreground texels (texels of the
/// painted sample with m_σ ≥ ½), and the fraction of foreground texels
/// outside F and its transition zone (m0 = 0).
struct Painting {
    mask: Vec<f32>,
    mask_size: (usize, usize),
    /// The sample the mask belongs to.
    painted: usize,
    tileable: bool,
    f: usize,
    f_covered: usize,
    fg: usize,
    fg_outside: usize,
}

impl Painting {
    /// `None` for a surface that was not painted.
    fn open(quilt: &Quilt, samples: &[OpenSample]) -> Result<Option<Painting>> {
        let (Ok(_), Some(mask_path)) = (quilt.container().array("region"), &quilt.sample_mask) else {
            return Ok(None);
        };
        quilt.verify("sample_mask", mask_path)?;
        let (mw, mh) = crate::io::imageio::image_size(mask_path)?;
        let painted = quilt.mask_sample();
        Ok(Some(Painting {
            mask: crate::io::imageio::read_sized_mask(mask_path, mw, mh, "")?,
            mask_size: (mw, mh),
            painted,
            // a generated BTF may be tileable; the synthesis then wraps its mask
            tileable: samples.get(painted).is_some_and(|s| s.svd.tileable()),
            f: 0,
            f_covered: 0,
            fg: 0,
            fg_outside: 0,
        }))
    }

    fn count(&mut self, quilt: &Quilt, b: &ColourBand, r: usize) -> Result<()> {
        let rows = b.own / r;
        let Some(m0) = quilt.constraint_region(0, b.first, r, rows)? else {
            return Ok(());
        };
        let (mw, mh) = self.mask_size;
        for (t, k) in b.own_texels().enumerate() {
            if b.chart[k] == EMPTY {
                continue;
            }
            let foreground = b.index[k] as usize == self.painted
                && crate::io::imageio::mask_bilinear(
                    &self.mask,
                    mw,
                    mh,
                    b.coords[k].map(f64::from),
                    self.tileable,
                ) >= 0.5;
            if m0[t] >= 1.0 {
                self.f += 1;
                self.f_covered += foreground as usize;
            }
            if foreground {
                self.fg += 1;
                self.fg_outside += (m0[t] <= 0.0) as usize;
            }
        }
        Ok(())
    }

    fn figures(&self) -> PaintingFigures {
        PaintingFigures {
            region_texels: self.f,
            region_covered_by_foreground: self.f_covered as f64 / self.f.max(1) as f64,
            foreground_texels: self.fg,
            foreground_outside_region_and_transition: self.fg_outside as f64 / self.fg.max(1) as f64,
        }
    }
}

/// [`ScaleFigures`] of the first sample, `width` pixels wide.
fn scale(quilt: &Quilt, gim: &Gim, width: usize) -> Result<ScaleFigures> {
    let (edges, median) = median_of(|f| scale_ratios(quilt, gim, f))?;
    Ok(ScaleFigures {
        edges,
        sample_pixels_per_unit: median,
        sample_width_units: if median > 0.0 { width as f64 / median } else { 0.0 },
    })
}

/// Calls `f` with |Δ sample coordinate| / |Δ position| over every grid edge
/// inside one patch of the first sample, in atlas order, band by band.
fn scale_ratios(quilt: &Quilt, gim: &Gim, f: &mut dyn FnMut(f64)) -> Result<()> {
    let r = quilt.resolution;
    for y0 in (0..r).step_by(BAND_ROWS) {
        let (y1, hi) = ((y0 + BAND_ROWS).min(r), (y0 + BAND_ROWS + 1).min(r));
        let coords = quilt.coord_region(0, y0, r, hi - y0)?;
        let patches = quilt.patch_region(0, y0, r, hi - y0)?;
        let index = quilt.sample_region(0, y0, r, hi - y0)?;
        let chart = gim.chart_face_region(0, y0, r, hi - y0)?.0;
        let position = gim.position_region(0, y0, r, hi - y0)?;
        let p = |t: usize| glam::Vec3::from_slice(&position[t * 3..t * 3 + 3]);
        for t in 0..(y1 - y0) * r {
            let (x, y) = (t % r, y0 + t / r);
            if chart[t] == EMPTY || patches[t] == NO_PATCH || index[t] != 0 {
                continue;
            }
            for n in [(x + 1 < r).then(|| t + 1), (y + 1 < r).then(|| t + r)]
                .into_iter()
                .flatten()
            {
                if chart[n] != chart[t] || patches[n] != patches[t] || index[n] != 0 {
                    continue;
                }
                let units = p(t).distance(p(n)) as f64;
                let (a, b) = (coords[t], coords[n]);
                let pixels = math::hypot((a[0] - b[0]) as f64, (a[1] - b[1]) as f64);
                if units > 0.0 && pixels.is_finite() {
                    f(pixels / units);
                }
            }
        }
    }
    Ok(())
}

/// How many values `stream` yields (it yields the same ones on every
/// call), and the one at rank `len / 2` in `f64::total_cmp` order (0 when
/// there are none), holding at most [`ranks::COLLECT`] of them
/// ([`ranks::at_ranks`]).
fn median_of(stream: impl FnMut(&mut dyn FnMut(f64)) -> Result<()>) -> Result<(usize, f64)> {
    ranks::rank_of(stream, |n| n / 2)
}

#[cfg(test)]
mod tests;
