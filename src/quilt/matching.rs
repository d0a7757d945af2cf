//! `matching`: entire-patch matching of a sample against a work image
//! (Kwatra et al. 2003, "Graphcut Textures", §3.2; used by Zhou et al. on the
//! work image of surface synthesis).
//!
//! A placement t = (dx, dy) puts sample pixel p − t on work pixel p. Its cost
//! is the SSD over the overlap, normalised by the overlap's weight:
//!
//! ```text
//! C(t) = Σ_p M(p) V(p−t) (‖I(p) − S(p−t)‖² + w ‖m0(p) − mP(p−t)‖²) / Σ_p M(p) V(p−t)
//! ```
//!
//! with M the work image's `known` weights, V the sample's validity (0 outside
//! a rotated copy), I/S the feature channels and m0/mP optional constraint
//! channels weighted by w. Expanding the square, every term is a correlation
//! `corr(B, A)(t) = Σ_p B(p) A(p − t)` of a work-side "lane" B with a
//! sample-side lane A:
//!
//! ```text
//! lane  work side B                 sample side A
//! c<n   −2 M I_c                    V S_c
//! n     M (‖I‖² + w‖m0‖²)           V
//! n+1   M                           V ‖S‖²
//! n+2   w M                         V ‖mP‖²          (constraint only)
//! n+3+k −2 w M m0_k                 V mP_k           (constraint only)
//! ```
//!
//! so SSD(t) = Σ_lanes corr(B, A) and overlap(t) = corr(M, V). All of them are
//! computed with 2D FFTs in f64: lanes are packed two by two into complex
//! signals (b₁ + i b₂ against a₁ + i a₂), whose cross-spectra are summed;
//! the Hermitian part of the sum transforms back to Σ corr(b, a), the
//! cross-talk lands in the anti-Hermitian part and is dropped. The overlap
//! spectrum F(M)·conj F(V) rides in the imaginary part of the same, single
//! inverse FFT. Per match: ⌈lanes/2⌉ forward 2D FFTs of the work image and one
//! inverse; the sample's spectra depend only on the sample and the FFT size
//! and are cached by [`Matcher`] under the caller's `key`.
//!
//! FFT size: for [`Span::Contained`] (one image inside the other, as in the
//! paper) no index ever wraps for a wanted placement once the transform is at
//! least max(W_S, W_I) long, so that (rounded up to 2^a·3^b·5^c) is used; for
//! [`Span::Overlapping`] (every placement with any overlap) the linear size
//! W_S + W_I − 1 is needed. The forward transform skips the all-zero padding
//! rows and the inverse computes only the rows holding placements. All
//! parallel steps are element- or row-wise independent, so results do not
//! depend on the thread count.

use std::sync::{Arc, Mutex};

use half::slice::HalfFloatSliceExt;
use rayon::prelude::*;
use rustfft::num_complex::Complex;
use rustfft::{Fft, FftPlanner};

use crate::artifact::svd::SvdArtifact;
use crate::container::{BoundedCache, MemoryBudget};
use crate::{Error, Result};

type C64 = Complex<f64>;

const ZERO: C64 = C64 { re: 0.0, im: 0.0 };

/// Complex values per parallel task in the row-wise FFT stages.
const TASK_ELEMS: usize = 1 << 13;

/// Default budget of the sample-spectrum cache.
pub const DEFAULT_CACHE_BYTES: usize = 256 << 20;

/// A borrowed multi-channel image, `[y][x][c]` row-major.
#[derive(Clone, Copy, Debug)]
pub struct Image<'a> {
    pub width: usize,
    pub height: usize,
    pub channels: usize,
    pub data: &'a [f32],
}

impl<'a> Image<'a> {
    /// Checks that `data` holds width × height × channels values.
    pub fn new(width: usize, height: usize, channels: usize, data: &'a [f32]) -> Result<Image<'a>> {
        let img = Image {
            width,
            height,
            channels,
            data,
        };
        img.check("image")?;
        Ok(img)
    }

    fn pixels(&self) -> usize {
        self.width * self.height
    }

    fn check(&self, what: &str) -> Result<()> {
        if self.width == 0 || self.height == 0 {
            return Err(Error::Config(format!(
                "{what}: empty ({}×{})",
                self.width, self.height
            )));
        }
        if self.data.len() != self.pixels() * self.channels {
            return Err(Error::Config(format!(
                "{what}: {} values for {}×{}×{}",
                self.data.len(),
                self.width,
                self.height,
                self.channels
            )));
        }
        Ok(())
    }
}

/// The work image: feature channels, `known` weights (1 where synthesized,
/// 0 elsewhere, or any non-negative weight), optional constraint channels
/// (same size as `image`).
#[derive(Clone, Copy, Debug)]
pub struct Work<'a> {
    pub image: Image<'a>,
    pub known: &'a [f32],
    pub constraint: Option<Image<'a>>,
}

/// The sample (typically one rotated copy): feature channels, validity
/// (1 inside the rotated sample, 0 outside, `[y][x]`), optional constraint
/// channels, and `key`, which must identify (image, valid, constraint): the
/// [`Matcher`] caches the sample's spectra under it and never looks at the
/// data again while the entry lives. Using one key for different data gives
/// wrong costs.
#[derive(Clone, Copy, Debug)]
pub struct Sample<'a> {
    pub image: Image<'a>,
    pub valid: &'a [f32],
    pub constraint: Option<Image<'a>>,
    pub key: u64,
}

/// Which placements are considered, per axis.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Span {
    /// One image lies inside the other: the work image inside the sample
    /// (dx ∈ [W_I − W_S, 0]) where the sample is at least as large, the
    /// sample inside the work image (dx ∈ [0, W_I − W_S]) where it is smaller
    /// (partial coverage, bounded by `min_overlap`). The paper's choice.
    #[default]
    Contained,
    /// Every placement with a non-empty overlap: dx ∈ [−(W_S − 1), W_I − 1].
    Overlapping,
}

/// Options of a match.
#[derive(Clone, Copy, Debug)]
pub struct MatchConfig {
    /// Minimum overlap weight Σ M V (e.g. 0.1 × Σ known) for a placement to
    /// count.
    pub min_overlap: f64,
    /// Keep at most this many best placements (0 = no limit).
    pub candidates: usize,
    /// Keep only near-minimal placements: cost ≤ (1 + tolerance) · best.
    pub tolerance: f64,
    /// Weight w of the constraint term (used only when both sides have
    /// constraint channels).
    pub constraint_weight: f64,
    pub span: Span,
}

impl Default for MatchConfig {
    fn default() -> Self {
        MatchConfig {
            min_overlap: 1.0,
            candidates: 8,
            tolerance: 0.1,
            constraint_weight: 0.0,
            span: Span::Contained,
        }
    }
}

/// A placement: sample pixel (x − dx, y − dy) lands on work pixel (x, y).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Placement {
    pub dx: i32,
    pub dy: i32,
    /// SSD / overlap (features + w · constraint).
    pub cost: f64,
    /// Σ M V over the overlap.
    pub overlap: f64,
}

impl Placement {
    /// Deterministic order: cost, then dy, then dx.
    fn order(&self, other: &Placement) -> std::cmp::Ordering {
        self.cost
            .total_cmp(&other.cost)
            .then(self.dy.cmp(&other.dy))
            .then(self.dx.cmp(&other.dx))
    }
}

/// Cost and overlap of every placement, `[dy − dy0][dx − dx0]`. The cost is
/// +∞ where the overlap is below the minimum.
#[derive(Clone, Debug, PartialEq)]
pub struct CostMap {
    pub dx0: i32,
    pub dy0: i32,
    /// Number of dx values.
    pub columns: usize,
    /// Number of dy values.
    pub rows: usize,
    pub cost: Vec<f64>,
    pub overlap: Vec<f64>,
}

impl CostMap {
    /// (cost, overlap) of placement (dx, dy), if it is in the map.
    pub fn get(&self, dx: i32, dy: i32) -> Option<(f64, f64)> {
        let (c, r) = (dx - self.dx0, dy - self.dy0);
        if c < 0 || r < 0 || c as usize >= self.columns || r as usize >= self.rows {
            return None;
        }
        let i = r as usize * self.columns + c as usize;
        Some((self.cost[i], self.overlap[i]))
    }

    /// The map over the bounding box of `placements`, +∞ (overlap 0) where
    /// none is given; empty without placements.
    pub fn from_placements(placements: &[Placement]) -> CostMap {
        if placements.is_empty() {
            return CostMap {
                dx0: 0,
                dy0: 0,
                columns: 0,
                rows: 0,
                cost: Vec::new(),
                overlap: Vec::new(),
            };
        }
        let (x0, x1) = placements
            .iter()
            .fold((i32::MAX, i32::MIN), |a, p| (a.0.min(p.dx), a.1.max(p.dx)));
        let (y0, y1) = placements
            .iter()
            .fold((i32::MAX, i32::MIN), |a, p| (a.0.min(p.dy), a.1.max(p.dy)));
        let (columns, rows) = ((x1 - x0 + 1) as usize, (y1 - y0 + 1) as usize);
        let mut map = CostMap {
            dx0: x0,
            dy0: y0,
            columns,
            rows,
            cost: vec![f64::INFINITY; columns * rows],
            overlap: vec![0.0; columns * rows],
        };
        for p in placements {
            let i = (p.dy - y0) as usize * columns + (p.dx - x0) as usize;
            map.cost[i] = p.cost;
            map.overlap[i] = p.overlap;
        }
        map
    }

    /// All placements with a finite cost, unordered.
    pub fn placements(&self) -> impl Iterator<Item = Placement> + '_ {
        (0..self.rows * self.columns)
            .filter(|&i| self.cost[i].is_finite())
            .map(|i| Placement {
                dx: self.dx0 + (i % self.columns) as i32,
                dy: self.dy0 + (i / self.columns) as i32,
                cost: self.cost[i],
                overlap: self.overlap[i],
            })
    }

    /// The best placements in (cost, dy, dx) order: at most `candidates`
    /// (0 = all) of those with cost ≤ (1 + tolerance) · best.
    pub fn best(&self, candidates: usize, tolerance: f64) -> Vec<Placement> {
        let mut all: Vec<Placement> = self.placements().collect();
        if candidates > 0 && candidates < all.len() {
            all.select_nth_unstable_by(candidates - 1, Placement::order);
            all.truncate(candidates);
        }
        all.sort_unstable_by(Placement::order);
        if let Some(best) = all.first().map(|p| p.cost) {
            let limit = near_limit(best, tolerance);
            all.retain(|p| p.cost <= limit);
        }
        all
    }
}

/// The near-minimal bound: cost ≤ best + tolerance · |best| (all when the
/// tolerance is infinite).
pub(super) fn near_limit(best: f64, tolerance: f64) -> f64 {
    if tolerance == f64::INFINITY {
        f64::INFINITY
    } else {
        best + tolerance.max(0.0) * best.abs()
    }
}

/// Seeded choice among near-minimal placements (Kwatra et al.: a random pick
/// among good matches avoids visible repetition): uniform among the entries
/// of `placements` with cost ≤ (1 + tolerance) · min cost, in slice order,
/// indexed by a hash of (seed, counter). A pure function; `None` if no
/// placement has a finite cost.
pub fn choose(placements: &[Placement], tolerance: f64, seed: u64, counter: u64) -> Option<Placement> {
    let best = placements
        .iter()
        .map(|p| p.cost)
        .filter(|c| c.is_finite())
        .min_by(f64::total_cmp)?;
    let limit = near_limit(best, tolerance);
    let near = |p: &&Placement| p.cost.is_finite() && p.cost <= limit;
    let count = placements.iter().filter(near).count() as u64;
    let h = crate::rng::mix64(crate::rng::derive(seed, counter));
    let pick = ((h as u128 * count as u128) >> 64) as usize;
    placements.iter().filter(near).nth(pick).copied()
}

/// Everything a match needs to know about the shapes involved.
#[derive(Clone, Copy, Debug)]
struct Layout {
    n: usize,
    nc: usize,
    lanes: usize,
    pairs: usize,
    nx: usize,
    ny: usize,
    dx: (i32, i32),
    dy: (i32, i32),
    key: CacheKey,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
struct CacheKey {
    key: u64,
    width: usize,
    height: usize,
    channels: usize,
    constraint: Option<usize>,
    nx: usize,
    ny: usize,
}

/// Lane of M (work side) and of V (sample side), see the module table.
fn m_lane(n: usize) -> usize {
    n + 1
}
fn v_lane(n: usize) -> usize {
    n
}

/// Placement range and minimal transform length along one axis.
fn axis(work: usize, sample: usize, span: Span) -> ((i32, i32), usize) {
    let (w, s) = (work as i32, sample as i32);
    match span {
        Span::Contained => (((w - s).min(0), (w - s).max(0)), work.max(sample)),
        Span::Overlapping => ((-(s - 1), w - 1), work + sample - 1),
    }
}

/// Smallest 2^a·3^b·5^c ≥ n.
pub fn fast_size(n: usize) -> usize {
    let mut best = n.max(1).next_power_of_two();
    let mut p5 = 1;
    while p5 < best {
        let mut p35 = p5;
        while p35 < best {
            let mut v = p35;
            while v < n {
                v *= 2;
            }
            best = best.min(v);
            p35 *= 3;
        }
        p5 *= 5;
    }
    best
}

impl Layout {
    fn new(work: &Work, sample: &Sample, cfg: &MatchConfig) -> Result<Layout> {
        let (wi, si) = (&work.image, &sample.image);
        wi.check("work image")?;
        si.check("sample")?;
        if wi.channels != si.channels {
            return Err(Error::Config(format!(
                "work image has {} channels, sample {}",
                wi.channels, si.channels
            )));
        }
        if work.known.len() != wi.pixels() {
            return Err(Error::Config(format!(
                "known mask: {} values for {}×{}",
                work.known.len(),
                wi.width,
                wi.height
            )));
        }
        if sample.valid.len() != si.pixels() {
            return Err(Error::Config(format!(
                "sample validity: {} values for {}×{}",
                sample.valid.len(),
                si.width,
                si.height
            )));
        }
        let nc = match (&work.constraint, &sample.constraint) {
            (None, None) => None,
            (Some(a), Some(b)) => {
                a.check("work constraint")?;
                b.check("sample constraint")?;
                if (a.width, a.height) != (wi.width, wi.height)
                    || (b.width, b.height) != (si.width, si.height)
                {
                    return Err(Error::Config(
                        "constraint channels differ in size from their images".into(),
                    ));
                }
                if a.channels != b.channels {
                    return Err(Error::Config(format!(
                        "work constraint has {} channels, sample constraint {}",
                        a.channels, b.channels
                    )));
                }
                Some(a.channels)
            }
            _ => {
                return Err(Error::Config(
                    "constraint channels given for only one of work image and sample".into(),
                ))
            }
        };
        if !(cfg.min_overlap.is_finite() && cfg.constraint_weight.is_finite()) || cfg.tolerance.is_nan() {
            return Err(Error::Config(
                "match config: non-finite min_overlap, weight or tolerance".into(),
            ));
        }
        let n = wi.channels;
        let lanes = n + 2 + nc.map_or(0, |c| c + 1);
        let (dx, lx) = axis(wi.width, si.width, cfg.span);
        let (dy, ly) = axis(wi.height, si.height, cfg.span);
        let (nx, ny) = (fast_size(lx), fast_size(ly));
        Ok(Layout {
            n,
            nc: nc.unwrap_or(0),
            lanes,
            pairs: lanes.div_ceil(2),
            nx,
            ny,
            dx,
            dy,
            key: CacheKey {
                key: sample.key,
                width: si.width,
                height: si.height,
                channels: n,
                constraint: nc,
                nx,
                ny,
            },
        })
    }
}

/// Value of work-side lane `c` at pixel `i` (see the module table);
/// `energy[i]` = M(‖I‖² + w‖m0‖²).
#[inline]
fn work_lane(work: &Work, lay: &Layout, w: f64, energy: &[f64], c: usize, i: usize) -> f64 {
    let n = lay.n;
    let m = work.known[i] as f64;
    if c < n {
        -2.0 * m * work.image.data[i * n + c] as f64
    } else if c == n {
        energy[i]
    } else if c == n + 1 {
        m
    } else if c == n + 2 {
        w * m
    } else {
        let k = c - n - 3;
        -2.0 * w * m * work.constraint.unwrap().data[i * lay.nc + k] as f64
    }
}

/// Value of sample-side lane `c` at pixel `i`; `energy[i]` = V‖S‖²,
/// `cenergy[i]` = V‖mP‖².
#[inline]
fn sample_lane(sample: &Sample, lay: &Layout, energy: &[f64], cenergy: &[f64], c: usize, i: usize) -> f64 {
    let n = lay.n;
    let v = sample.valid[i] as f64;
    if c < n {
        v * sample.image.data[i * n + c] as f64
    } else if c == n {
        v
    } else if c == n + 1 {
        energy[i]
    } else if c == n + 2 {
        cenergy[i]
    } else {
        let k = c - n - 3;
        v * sample.constraint.unwrap().data[i * lay.nc + k] as f64
    }
}

fn sq_norm(v: &[f32]) -> f64 {
    v.iter().map(|&x| x as f64 * x as f64).sum()
}

/// Packs lanes (2j, 2j+1) of a `width`×`height` image into the first
/// `height` rows (of length `nx`) of `rows`, zero-padded.
fn pack_pair(
    rows: &mut [C64],
    nx: usize,
    width: usize,
    height: usize,
    lanes: usize,
    j: usize,
    lane: impl Fn(usize, usize) -> f64,
) {
    let (a, b) = (2 * j, 2 * j + 1);
    for (y, row) in rows[..height * nx].chunks_exact_mut(nx).enumerate() {
        for (x, v) in row[..width].iter_mut().enumerate() {
            let i = y * width + x;
            *v = C64::new(lane(a, i), if b < lanes { lane(b, i) } else { 0.0 });
        }
        row[width..].fill(ZERO);
    }
}

/// FFT plans of one transform size.
struct Plans {
    nx: usize,
    ny: usize,
    fx: Arc<dyn Fft<f64>>,
    fy: Arc<dyn Fft<f64>>,
    ix: Arc<dyn Fft<f64>>,
    iy: Arc<dyn Fft<f64>>,
}

/// In-place FFTs of consecutive length-`len` rows of `buf`, in parallel.
fn fft_rows(fft: &Arc<dyn Fft<f64>>, len: usize, buf: &mut [C64]) {
    let per = (TASK_ELEMS / len).max(1) * len;
    let scratch = fft.get_inplace_scratch_len();
    buf.par_chunks_mut(per).for_each_init(
        || vec![ZERO; scratch],
        |s, chunk| fft.process_with_scratch(chunk, s),
    );
}

/// Columns `kx0..` of the row-transformed `rows` (`h` rows of `nx`) into the
/// spectrum chunk `out` (`[kx][ky]`, columns of `ny`), zero-padded and
/// transformed along y.
fn column_stage(p: &Plans, rows: &[C64], h: usize, kx0: usize, out: &mut [C64], scratch: &mut [C64]) {
    let (nx, ny) = (p.nx, p.ny);
    let cols = out.len() / ny;
    for y in 0..h {
        let src = &rows[y * nx + kx0..y * nx + kx0 + cols];
        for (j, v) in src.iter().enumerate() {
            out[j * ny + y] = *v;
        }
    }
    for col in out.chunks_exact_mut(ny) {
        col[h..].fill(ZERO);
    }
    p.fy.process_with_scratch(out, scratch);
}

/// Columns per parallel task of the column stage.
fn cols_per_task(ny: usize) -> usize {
    (TASK_ELEMS / ny).max(1)
}

/// 2D forward FFT of `h` packed rows into `spec` (`[kx][ky]`); then, if
/// `acc` is given, `acc += spec · conj(ys)`.
fn forward_2d(p: &Plans, rows: &mut [C64], h: usize, spec: &mut [C64], acc: Option<(&mut [C64], &[C64])>) {
    let (nx, ny) = (p.nx, p.ny);
    fft_rows(&p.fx, nx, &mut rows[..h * nx]);
    let rows: &[C64] = rows;
    let per = cols_per_task(ny);
    let scratch = p.fy.get_inplace_scratch_len();
    let spec = &mut spec[..nx * ny];
    match acc {
        None => spec.par_chunks_mut(per * ny).enumerate().for_each_init(
            || vec![ZERO; scratch],
            |s, (ci, out)| column_stage(p, rows, h, ci * per, out, s),
        ),
        Some((acc, ys)) => spec
            .par_chunks_mut(per * ny)
            .zip(acc[..nx * ny].par_chunks_mut(per * ny))
            .zip(ys[..nx * ny].par_chunks(per * ny))
            .enumerate()
            .for_each_init(
                || vec![ZERO; scratch],
                |s, (ci, ((out, acc), ys))| {
                    column_stage(p, rows, h, ci * per, out, s);
                    accumulate(acc, out, ys);
                },
            ),
    }
}

/// `acc += zs · conj(ys)`, element by element.
#[inline]
fn accumulate(acc: &mut [C64], zs: &[C64], ys: &[C64]) {
    for ((a, z), y) in acc.iter_mut().zip(zs).zip(ys) {
        *a += z * y.conj();
    }
}

/// Index of the spectrum entry at −k.
#[inline]
fn neg_index(nx: usize, ny: usize, i: usize) -> usize {
    let (kx, ky) = (i / ny, i % ny);
    ((nx - kx) % nx) * ny + (ny - ky) % ny
}

/// The spectrum of the real (`part` 0) or imaginary (`part` 1) lane of a
/// packed spectrum z: (z(k) + conj z(−k))/2 or (z(k) − conj z(−k))/(2i).
fn unpack_lane(nx: usize, ny: usize, z: &[C64], part: usize, out: &mut [C64]) {
    let per = cols_per_task(ny) * ny;
    out[..nx * ny]
        .par_chunks_mut(per)
        .enumerate()
        .for_each(|(ci, chunk)| {
            for (o, v) in chunk.iter_mut().enumerate() {
                let i = ci * per + o;
                let (a, b) = (z[i], z[neg_index(nx, ny, i)].conj());
                *v = if part == 0 {
                    (a + b) * 0.5
                } else {
                    (a - b) * C64::new(0.0, -0.5)
                };
            }
        });
}

/// The sample side of one (key, transform size): packed lane spectra and
/// F(V).
struct SampleSpectra {
    pairs: Vec<C64>,
    fv: Vec<C64>,
    max_valid: f64,
}

impl SampleSpectra {
    fn bytes(&self) -> usize {
        (self.pairs.len() + self.fv.len()) * std::mem::size_of::<C64>()
    }
}

/// What the kept work spectra were computed for: the caller's key and the
/// transform layout.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct WorkTag {
    key: u64,
    nx: usize,
    ny: usize,
    /// Feature channels and all lanes (features, constraint, energy, mask).
    n: usize,
    lanes: usize,
    /// The constraint weight's bits (it scales the work's lanes).
    weight: u64,
}

/// A matcher's cache of sample spectra, shared between matchers.
#[derive(Clone)]
pub struct SpectraCache(Arc<Mutex<BoundedCache<CacheKey, Arc<SampleSpectra>>>>);

/// Entire-patch matcher: owns the FFT planner, reusable buffers and a cache
/// of sample spectra (least recently used entries are dropped beyond the
/// budget; the newest entry is always kept).
pub struct Matcher {
    planner: FftPlanner<f64>,
    rows: Vec<C64>,
    spec: Vec<C64>,
    zm: Vec<C64>,
    acc: Vec<C64>,
    out: Vec<C64>,
    energy: Vec<f64>,
    /// The spectra Z_j of the last keyed work image ([`Matcher::cost_map_for`]).
    work_spectra: Vec<C64>,
    work_tag: Option<WorkTag>,
    /// Shared with the matchers of [`Matcher::sibling`].
    cache: Arc<Mutex<BoundedCache<CacheKey, Arc<SampleSpectra>>>>,
    computed: u64,
    reused: u64,
}

impl Default for Matcher {
    fn default() -> Self {
        Matcher::new()
    }
}

impl Matcher {
    /// A matcher whose spectrum cache holds up to [`DEFAULT_CACHE_BYTES`].
    pub fn new() -> Matcher {
        Matcher::with_cache_budget(DEFAULT_CACHE_BYTES)
    }

    /// A matcher whose spectrum cache holds up to `bytes` (at least one
    /// entry is always kept).
    pub fn with_cache_budget(bytes: usize) -> Matcher {
        Matcher {
            planner: FftPlanner::new(),
            rows: Vec::new(),
            spec: Vec::new(),
            zm: Vec::new(),
            acc: Vec::new(),
            out: Vec::new(),
            energy: Vec::new(),
            work_spectra: Vec::new(),
            work_tag: None,
            cache: Arc::new(Mutex::new(BoundedCache::new(MemoryBudget(bytes as u64)))),
            computed: 0,
            reused: 0,
        }
    }

    /// Bytes of this matcher's buffers (sized by the largest match so far).
    pub fn buffer_bytes(&self) -> usize {
        let complex = [
            &self.rows,
            &self.spec,
            &self.zm,
            &self.acc,
            &self.out,
            &self.work_spectra,
        ];
        complex.iter().map(|b| b.capacity()).sum::<usize>() * std::mem::size_of::<C64>()
            + self.energy.capacity() * 8
    }

    /// This matcher's spectrum cache, to share with [`Matcher::sharing`].
    pub fn spectra_cache(&self) -> SpectraCache {
        SpectraCache(Arc::clone(&self.cache))
    }

    /// A matcher of its own (planner and buffers) sharing a spectrum cache,
    /// for a work patch computed on another thread (two matchers may
    /// compute the same spectra; they are equal).
    pub fn sharing(cache: SpectraCache) -> Matcher {
        Matcher {
            cache: cache.0,
            ..Matcher::with_cache_budget(0)
        }
    }

    /// How many times sample spectra were computed (cache misses).
    pub fn spectra_computed(&self) -> u64 {
        self.computed
    }

    /// How many matches reused cached sample spectra.
    pub fn spectra_reused(&self) -> u64 {
        self.reused
    }

    /// Bytes held by the spectrum cache.
    pub fn cache_bytes(&self) -> usize {
        crate::lock(&self.cache).bytes() as usize
    }

    /// Drops every cached sample spectrum.
    pub fn clear_cache(&mut self) {
        crate::lock(&self.cache).clear();
    }

    /// The k best near-minimal placements, in (cost, dy, dx) order (see
    /// [`CostMap::best`]).
    pub fn match_patch(&mut self, work: &Work, sample: &Sample, cfg: &MatchConfig) -> Result<Vec<Placement>> {
        Ok(self
            .cost_map(work, sample, cfg)?
            .best(cfg.candidates, cfg.tolerance))
    }

    /// Cost and overlap of every placement.
    pub fn cost_map(&mut self, work: &Work, sample: &Sample, cfg: &MatchConfig) -> Result<CostMap> {
        self.cost_map_for(work, None, sample, cfg)
    }

    /// [`Matcher::cost_map`], keeping the work image's spectra under
    /// `work_key`: a following match of the same work image (the same key)
    /// against another sample of the same size (another rotated copy)
    /// reuses them instead of transforming the work image again, with
    /// bit-identical costs. `work_key` must identify the work image's data
    /// (features, known weights, constraint) as [`Sample::key`] does the
    /// sample's; `None` keeps nothing.
    pub fn cost_map_for(
        &mut self,
        work: &Work,
        work_key: Option<u64>,
        sample: &Sample,
        cfg: &MatchConfig,
    ) -> Result<CostMap> {
        let lay = Layout::new(work, sample, cfg)?;
        let (nx, ny, nn) = (lay.nx, lay.ny, lay.nx * lay.ny);
        let plans = Plans {
            nx,
            ny,
            fx: self.planner.plan_fft_forward(nx),
            fy: self.planner.plan_fft_forward(ny),
            ix: self.planner.plan_fft_inverse(nx),
            iy: self.planner.plan_fft_inverse(ny),
        };
        let (wi, si) = (&work.image, &sample.image);
        let rows_len = wi.height.max(si.height) * nx;
        for (buf, len) in [
            (&mut self.rows, rows_len),
            (&mut self.spec, nn),
            (&mut self.zm, nn),
            (&mut self.acc, nn),
        ] {
            buf.resize(len, ZERO);
        }
        let cached = crate::lock(&self.cache).get(&lay.key).cloned();
        let entry = match cached {
            Some(e) => {
                self.reused += 1;
                e
            }
            None => {
                let e = Arc::new(self.sample_spectra(&plans, sample, &lay));
                let bytes = e.bytes() as u64;
                crate::lock(&self.cache).insert(lay.key, Arc::clone(&e), bytes);
                e
            }
        };

        // work side: Σ_j Z_j conj(Y_j), keeping the pair that holds M
        let w = if work.constraint.is_some() {
            cfg.constraint_weight
        } else {
            0.0
        };
        let m_pair = m_lane(lay.n) / 2;
        let tag = work_key.map(|key| WorkTag {
            key,
            nx,
            ny,
            n: lay.n,
            lanes: lay.lanes,
            weight: w.to_bits(),
        });
        if tag.is_some() && tag == self.work_tag {
            // Z_j kept from the last match of this work image
            self.acc.fill(ZERO);
            for j in 0..lay.pairs {
                let (zs, ys) = (
                    &self.work_spectra[j * nn..(j + 1) * nn],
                    &entry.pairs[j * nn..(j + 1) * nn],
                );
                self.acc
                    .par_chunks_mut(TASK_ELEMS)
                    .zip(zs.par_chunks(TASK_ELEMS))
                    .zip(ys.par_chunks(TASK_ELEMS))
                    .for_each(|((acc, zs), ys)| accumulate(acc, zs, ys));
            }
        } else {
            self.work_tag = None;
            if tag.is_some() {
                self.work_spectra.resize(lay.pairs * nn, ZERO);
            }
            self.energy.clear();
            self.energy.extend((0..wi.pixels()).map(|i| {
                let m = work.known[i] as f64;
                let mut e = sq_norm(&wi.data[i * lay.n..(i + 1) * lay.n]);
                if let Some(c) = &work.constraint {
                    e += w * sq_norm(&c.data[i * lay.nc..(i + 1) * lay.nc]);
                }
                m * e
            }));
            let energy = &self.energy;
            self.acc.fill(ZERO);
            for j in 0..lay.pairs {
                pack_pair(&mut self.rows, nx, wi.width, wi.height, lay.lanes, j, |c, i| {
                    work_lane(work, &lay, w, energy, c, i)
                });
                let target = if tag.is_some() {
                    &mut self.work_spectra[j * nn..(j + 1) * nn]
                } else if j == m_pair {
                    &mut self.zm
                } else {
                    &mut self.spec
                };
                let ys = &entry.pairs[j * nn..(j + 1) * nn];
                forward_2d(
                    &plans,
                    &mut self.rows,
                    wi.height,
                    target,
                    Some((&mut self.acc, ys)),
                );
            }
        }
        if tag.is_some() {
            // F(M) of the kept spectra, where the unkept path transforms it
            self.zm[..nn].copy_from_slice(&self.work_spectra[m_pair * nn..(m_pair + 1) * nn]);
            self.work_tag = tag;
        }

        // Hermitian part of the sum (→ SSD) + i F(M) conj F(V) (→ overlap)
        let (acc, zm, fv) = (&self.acc, &self.zm, &entry.fv);
        let m_part = m_lane(lay.n) % 2;
        let per = cols_per_task(ny) * ny;
        self.spec.par_chunks_mut(per).enumerate().for_each(|(ci, chunk)| {
            for (o, q) in chunk.iter_mut().enumerate() {
                let i = ci * per + o;
                let ni = neg_index(nx, ny, i);
                let herm = (acc[i] + acc[ni].conj()) * 0.5;
                let (a, b) = (zm[i], zm[ni].conj());
                let fm = if m_part == 0 {
                    (a + b) * 0.5
                } else {
                    (a - b) * C64::new(0.0, -0.5)
                };
                *q = herm + C64::new(0.0, 1.0) * fm * fv[i].conj();
            }
        });

        // inverse: along y for every kx, then along x only for placement rows
        fft_rows(&plans.iy, ny, &mut self.spec);
        let (dx0, dy0) = (lay.dx.0, lay.dy.0);
        let columns = (lay.dx.1 - dx0 + 1) as usize;
        let prow = (lay.dy.1 - dy0 + 1) as usize;
        self.out.resize(prow * nx, ZERO);
        let spec = &self.spec;
        self.out.par_chunks_mut(nx).enumerate().for_each(|(r, row)| {
            let ty = (dy0 + r as i32).rem_euclid(ny as i32) as usize;
            for (kx, v) in row.iter_mut().enumerate() {
                *v = spec[kx * ny + ty];
            }
        });
        fft_rows(&plans.ix, nx, &mut self.out);

        let mass: f64 = work.known.iter().map(|&m| m as f64).sum();
        let tol = 1e-9 * mass * entry.max_valid;
        let scale = 1.0 / nn as f64;
        let mut cost = vec![f64::INFINITY; prow * columns];
        let mut overlap = vec![0.0; prow * columns];
        for r in 0..prow {
            for c in 0..columns {
                let tx = (dx0 + c as i32).rem_euclid(nx as i32) as usize;
                let v = self.out[r * nx + tx] * scale;
                let i = r * columns + c;
                overlap[i] = v.im;
                if accept(v.im, cfg.min_overlap, tol) {
                    cost[i] = v.re.max(0.0) / v.im;
                }
            }
        }
        Ok(CostMap {
            dx0,
            dy0,
            columns,
            rows: prow,
            cost,
            overlap,
        })
    }

    /// The packed lane spectra of the sample and F(V).
    fn sample_spectra(&mut self, plans: &Plans, sample: &Sample, lay: &Layout) -> SampleSpectra {
        self.computed += 1;
        let (nx, ny, nn) = (lay.nx, lay.ny, lay.nx * lay.ny);
        let si = &sample.image;
        let energy: Vec<f64> = (0..si.pixels())
            .map(|i| sample.valid[i] as f64 * sq_norm(&si.data[i * lay.n..(i + 1) * lay.n]))
            .collect();
        let cenergy: Vec<f64> = match &sample.constraint {
            Some(c) => (0..si.pixels())
                .map(|i| sample.valid[i] as f64 * sq_norm(&c.data[i * lay.nc..(i + 1) * lay.nc]))
                .collect(),
            None => Vec::new(),
        };
        let mut pairs = vec![ZERO; lay.pairs * nn];
        for (j, spec) in pairs.chunks_exact_mut(nn).enumerate() {
            pack_pair(&mut self.rows, nx, si.width, si.height, lay.lanes, j, |c, i| {
                sample_lane(sample, lay, &energy, &cenergy, c, i)
            });
            forward_2d(plans, &mut self.rows, si.height, spec, None);
        }
        let mut fv = vec![ZERO; nn];
        let vl = v_lane(lay.n);
        unpack_lane(nx, ny, &pairs[vl / 2 * nn..(vl / 2 + 1) * nn], vl % 2, &mut fv);
        let max_valid = sample.valid.iter().fold(0.0f64, |a, &v| a.max(v as f64));
        SampleSpectra { pairs, fv, max_valid }
    }
}

/// Whether an overlap weight counts: above the numerical noise floor `tol`
/// and at least the minimum (up to `tol`).
fn accept(overlap: f64, min_overlap: f64, tol: f64) -> bool {
    overlap > tol && overlap >= min_overlap - tol && overlap > 0.0
}

/// Brute-force reference: the cost of one placement by direct sums, with the
/// same acceptance rule as [`Matcher::cost_map`] (cost +∞ if rejected).
pub fn brute_force_cost(
    work: &Work,
    sample: &Sample,
    cfg: &MatchConfig,
    dx: i32,
    dy: i32,
) -> Result<Placement> {
    let lay = Layout::new(work, sample, cfg)?;
    Ok(brute(work, sample, cfg, &lay, dx, dy))
}

fn brute(work: &Work, sample: &Sample, cfg: &MatchConfig, lay: &Layout, dx: i32, dy: i32) -> Placement {
    let (wi, si) = (&work.image, &sample.image);
    let w = if work.constraint.is_some() {
        cfg.constraint_weight
    } else {
        0.0
    };
    let (mut ssd, mut overlap) = (0.0f64, 0.0f64);
    for y in 0..wi.height as i32 {
        let sy = y - dy;
        if sy < 0 || sy >= si.height as i32 {
            continue;
        }
        for x in 0..wi.width as i32 {
            let sx = x - dx;
            if sx < 0 || sx >= si.width as i32 {
                continue;
            }
            let (p, s) = (
                (y * wi.width as i32 + x) as usize,
                (sy * si.width as i32 + sx) as usize,
            );
            let mv = work.known[p] as f64 * sample.valid[s] as f64;
            let n = lay.n;
            let mut d = sq_diff(&wi.data[p * n..(p + 1) * n], &si.data[s * n..(s + 1) * n]);
            if let (Some(a), Some(b)) = (&work.constraint, &sample.constraint) {
                let k = lay.nc;
                d += w * sq_diff(&a.data[p * k..(p + 1) * k], &b.data[s * k..(s + 1) * k]);
            }
            ssd += mv * d;
            overlap += mv;
        }
    }
    let mass: f64 = work.known.iter().map(|&m| m as f64).sum();
    let max_valid = sample.valid.iter().fold(0.0f64, |a, &v| a.max(v as f64));
    scored(dx, dy, ssd, overlap, cfg.min_overlap, 1e-9 * mass * max_valid)
}

/// Σ (a − b)² in f64.
fn sq_diff(a: &[f32], b: &[f32]) -> f64 {
    a.iter()
        .zip(b)
        .map(|(&a, &b)| (a as f64 - b as f64).powi(2))
        .sum()
}

/// The placement (dx, dy) with its direct sums: cost SSD / overlap, or +∞
/// where [`accept`] rejects the overlap.
fn scored(dx: i32, dy: i32, ssd: f64, overlap: f64, min_overlap: f64, tol: f64) -> Placement {
    let cost = if accept(overlap, min_overlap, tol) {
        ssd / overlap
    } else {
        f64::INFINITY
    };
    Placement {
        dx,
        dy,
        cost,
        overlap,
    }
}

/// Brute-force [`CostMap`] over the same placements as [`Matcher::cost_map`].
pub fn brute_force_map(work: &Work, sample: &Sample, cfg: &MatchConfig) -> Result<CostMap> {
    let lay = Layout::new(work, sample, cfg)?;
    let columns = (lay.dx.1 - lay.dx.0 + 1) as usize;
    let rows = (lay.dy.1 - lay.dy.0 + 1) as usize;
    let all: Vec<Placement> = (0..rows * columns)
        .into_par_iter()
        .map(|i| {
            let (dx, dy) = (lay.dx.0 + (i % columns) as i32, lay.dy.0 + (i / columns) as i32);
            brute(work, sample, cfg, &lay, dx, dy)
        })
        .collect();
    Ok(CostMap {
        dx0: lay.dx.0,
        dy0: lay.dy.0,
        columns,
        rows,
        cost: all.iter().map(|p| p.cost).collect(),
        overlap: all.iter().map(|p| p.overlap).collect(),
    })
}

/// The placements [`Matcher::cost_map`] considers for a `work`-sized image
/// over a `sample`-sized one: the (dx, dy) ranges, inclusive.
pub fn placement_range(work: [usize; 2], sample: [usize; 2], span: Span) -> [(i32, i32); 2] {
    [axis(work[0], sample[0], span).0, axis(work[1], sample[1], span).0]
}

/// The exact cost of each of `placements` by direct sums over the work
/// image's known pixels, with the acceptance rule of [`Matcher::cost_map`]
/// (cost +∞ where rejected): the fine step of coarse-to-fine matching,
/// where only a few placements around the coarse minima are wanted. Each
/// placement is summed in pixel order on one thread, so the result does
/// not depend on the thread count.
pub fn direct_costs(
    work: &Work,
    sample: &Sample,
    cfg: &MatchConfig,
    placements: &[(i32, i32)],
) -> Result<Vec<Placement>> {
    let lay = Layout::new(work, sample, cfg)?;
    let (wi, si) = (&work.image, &sample.image);
    let (n, nc) = (lay.n, lay.nc);
    // the known pixels, struct of arrays: weight, features (and constraint)
    // gathered, and the sample index each lands on at placement (0, 0)
    let known: Vec<usize> = (0..wi.pixels()).filter(|&p| work.known[p] > 0.0).collect();
    let weight: Vec<f64> = known.iter().map(|&p| work.known[p] as f64).collect();
    // (in f64 already: the same differences as converting in the loop)
    let features: Vec<f64> = known
        .iter()
        .flat_map(|&p| &wi.data[p * n..(p + 1) * n])
        .map(|&v| v as f64)
        .collect();
    let constraint: Vec<f64> = match &work.constraint {
        Some(c) => known
            .iter()
            .flat_map(|&p| &c.data[p * nc..(p + 1) * nc])
            .map(|&v| v as f64)
            .collect(),
        None => Vec::new(),
    };
    let xy: Vec<[i64; 2]> = known
        .iter()
        .map(|&p| [(p % wi.width) as i64, (p / wi.width) as i64])
        .collect();
    let at_origin: Vec<i64> = xy.iter().map(|&[x, y]| y * si.width as i64 + x).collect();
    // the known pixels' bounding box, to tell placements wholly inside
    let [x0, y0, x1, y1] = xy.iter().fold([i64::MAX, i64::MAX, 0, 0], |b, &[x, y]| {
        [b[0].min(x), b[1].min(y), b[2].max(x), b[3].max(y)]
    });
    let mass: f64 = work.known.iter().map(|&m| m as f64).sum();
    let max_valid = sample.valid.iter().fold(0.0f64, |a, &v| a.max(v as f64));
    let tol = 1e-9 * mass * max_valid;
    let w = if work.constraint.is_some() {
        cfg.constraint_weight
    } else {
        0.0
    };
    let pixels = Known {
        xy: &xy,
        weight: &weight,
        features: &features,
        constraint: &constraint,
        at_origin: &at_origin,
    };
    let group_costs = |group: &[(i32, i32)]| -> Vec<Placement> {
        let mut inside = [false; DIRECT_GROUP];
        let mut shift = [0i64; DIRECT_GROUP];
        for (j, &(dx, dy)) in group.iter().enumerate() {
            // (x1 − dx ≥ x0 − dx ≥ 0 once the first two hold)
            inside[j] = !known.is_empty()
                && x0 - dx as i64 >= 0
                && y0 - dy as i64 >= 0
                && x1 - (dx as i64) < si.width as i64
                && y1 - (dy as i64) < si.height as i64;
            shift[j] = dy as i64 * si.width as i64 + dx as i64;
        }
        // colour samples (three channels) get the sum unrolled
        let (ssd, overlap) = if n == 3 {
            pixels.pass(sample, group, &inside, &shift, w, sq_diff3)
        } else {
            pixels.pass(sample, group, &inside, &shift, w, sq_diff_f64)
        };
        group
            .iter()
            .enumerate()
            .map(|(j, &(dx, dy))| scored(dx, dy, ssd[j], overlap[j], cfg.min_overlap, tol))
            .collect()
    };
    // placements in groups of neighbours (the list is in (dy, dx) order):
    // one pass over the known pixels serves a group, whose sample reads
    // lie close together; each placement still sums in pixel order
    Ok(placements
        .par_chunks(DIRECT_GROUP)
        .flat_map_iter(group_costs)
        .collect())
}

/// The work image's known pixels as [`direct_costs`] gathers them: (x, y),
/// weight, features and constraint (f64), and the sample index each lands
/// on at placement (0, 0).
struct Known<'a> {
    /// Each known pixel's (x, y) in the work image.
    xy: &'a [[i64; 2]],
    weight: &'a [f64],
    features: &'a [f64],
    constraint: &'a [f64],
    at_origin: &'a [i64],
}

impl Known<'_> {
    /// Σ m·v·(feature distance + w · constraint distance) and Σ m·v of each
    /// placement of `group` (at most [`DIRECT_GROUP`]; `inside`: wholly
    /// inside the sample, `shift`: its sample index offset), each summed in
    /// pixel order, with `diff` the features' squared distance.
    fn pass(
        &self,
        sample: &Sample,
        group: &[(i32, i32)],
        inside: &[bool; DIRECT_GROUP],
        shift: &[i64; DIRECT_GROUP],
        w: f64,
        diff: impl Fn(&[f64], &[f32]) -> f64,
    ) -> ([f64; DIRECT_GROUP], [f64; DIRECT_GROUP]) {
        // (placements wholly inside need no bounds test: a loop without it)
        if inside[..group.len()].iter().all(|&i| i) {
            self.sums::<false>(sample, group, shift, w, diff)
        } else {
            self.sums::<true>(sample, group, shift, w, diff)
        }
    }

    /// [`Known::pass`], testing each placement's sample bounds if `BOUNDS`.
    #[inline(always)]
    fn sums<const BOUNDS: bool>(
        &self,
        sample: &Sample,
        group: &[(i32, i32)],
        shift: &[i64; DIRECT_GROUP],
        w: f64,
        diff: impl Fn(&[f64], &[f32]) -> f64,
    ) -> ([f64; DIRECT_GROUP], [f64; DIRECT_GROUP]) {
        let si = &sample.image;
        let (n, nc) = (si.channels, sample.constraint.as_ref().map_or(0, |c| c.channels));
        let (width, height) = (si.width as i64, si.height as i64);
        let mut ssd = [0.0f64; DIRECT_GROUP];
        let mut overlap = [0.0f64; DIRECT_GROUP];
        for (k, &[px, py]) in self.xy.iter().enumerate() {
            let a = &self.features[k * n..(k + 1) * n];
            let (origin, weight) = (self.at_origin[k], self.weight[k]);
            for (j, &(dx, dy)) in group.iter().enumerate() {
                if BOUNDS {
                    let (sx, sy) = (px - dx as i64, py - dy as i64);
                    if sx < 0 || sy < 0 || sx >= width || sy >= height {
                        continue;
                    }
                }
                let s = (origin - shift[j]) as usize;
                let mv = weight * sample.valid[s] as f64;
                if mv == 0.0 {
                    continue;
                }
                let mut d = diff(a, &si.data[s * n..(s + 1) * n]);
                if let Some(b) = &sample.constraint {
                    let c = &self.constraint[k * nc..(k + 1) * nc];
                    d += w * sq_diff_f64(c, &b.data[s * nc..(s + 1) * nc]);
                }
                ssd[j] += mv * d;
                overlap[j] += mv;
            }
        }
        (ssd, overlap)
    }
}

/// [`sq_diff`] with `a` converted to f64 already (the same sum).
#[inline]
fn sq_diff_f64(a: &[f64], b: &[f32]) -> f64 {
    a.iter().zip(b).map(|(&a, &b)| (a - b as f64).powi(2)).sum()
}

/// [`sq_diff_f64`] of three channels.
#[inline(always)]
fn sq_diff3(a: &[f64], b: &[f32]) -> f64 {
    let (a, b): (&[f64; 3], &[f32; 3]) = (a.try_into().expect("3"), b.try_into().expect("3"));
    let d = [a[0] - b[0] as f64, a[1] - b[1] as f64, a[2] - b[2] as f64];
    -0.0 + d[0] * d[0] + d[1] * d[1] + d[2] * d[2]
}

/// Placements [`direct_costs`] sums in one pass over the known pixels: the
/// ±1 window around a coarse placement of factor 2.
const DIRECT_GROUP: usize = 9;

/// An owned sample copy in f32: maps `[y][x][c]` and validity `[y][x]`.
#[derive(Clone, Debug)]
pub struct SampleCopy {
    pub width: usize,
    pub height: usize,
    pub channels: usize,
    pub maps: Vec<f32>,
    pub valid: Vec<f32>,
}

impl SampleCopy {
    /// Rotated copy `r` of a factorization's geometry maps.
    pub fn rotated(svd: &SvdArtifact, r: usize) -> Result<SampleCopy> {
        let (maps16, valid8) = svd.rotated(r)?;
        let mut maps = vec![0f32; maps16.len()];
        maps16.convert_to_f32_slice(&mut maps);
        Ok(SampleCopy {
            width: svd.width,
            height: svd.height,
            channels: svd.terms,
            maps,
            valid: valid_to_f32(&valid8),
        })
    }

    /// Borrows it as a [`Sample`] cached under `key` (e.g. the rotation
    /// index, combined with anything else that distinguishes the source).
    pub fn sample(&self, key: u64) -> Sample<'_> {
        Sample {
            image: Image {
                width: self.width,
                height: self.height,
                channels: self.channels,
                data: &self.maps,
            },
            valid: &self.valid,
            constraint: None,
            key,
        }
    }
}

/// A u8 validity mask as weights: non-zero → 1.
pub fn valid_to_f32(valid: &[u8]) -> Vec<f32> {
    valid.iter().map(|&v| if v != 0 { 1.0 } else { 0.0 }).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fast_sizes() {
        for (n, want) in [
            (1, 1),
            (7, 8),
            (11, 12),
            (17, 18),
            (97, 100),
            (193, 200),
            (255, 256),
            (383, 384),
        ] {
            assert_eq!(fast_size(n), want, "{n}");
        }
        for n in 1..2000 {
            let f = fast_size(n);
            assert!(f >= n);
            let mut r = f;
            for p in [2, 3, 5] {
                while r % p == 0 {
                    r /= p;
                }
            }
            assert_eq!(r, 1, "{n} → {f}");
            assert!((n..f).all(|m| {
                let mut r = m;
                for p in [2, 3, 5] {
                    while r % p == 0 {
                        r /= p;
                    }
                }
                r != 1
            }));
        }
    }

    #[test]
    fn axis_ranges() {
        assert_eq!(axis(64, 192, Span::Contained), ((-128, 0), 192));
        assert_eq!(axis(20, 12, Span::Contained), ((0, 8), 20));
        assert_eq!(axis(9, 9, Span::Contained), ((0, 0), 9));
        assert_eq!(axis(5, 7, Span::Overlapping), ((-6, 4), 11));
    }

    #[test]
    fn unpack_recovers_lane_spectra() {
        let (nx, ny) = (6, 5);
        let mut planner = FftPlanner::new();
        let plans = Plans {
            nx,
            ny,
            fx: planner.plan_fft_forward(nx),
            fy: planner.plan_fft_forward(ny),
            ix: planner.plan_fft_inverse(nx),
            iy: planner.plan_fft_inverse(ny),
        };
        let a: Vec<f64> = (0..12).map(|i| (i as f64 * 0.7).sin()).collect();
        let b: Vec<f64> = (0..12).map(|i| (i as f64 * 1.3).cos()).collect();
        let spectrum = |f: &dyn Fn(usize) -> C64| {
            let mut rows = vec![ZERO; 3 * nx];
            for y in 0..3 {
                for x in 0..4 {
                    rows[y * nx + x] = f(y * 4 + x);
                }
            }
            let mut spec = vec![ZERO; nx * ny];
            forward_2d(&plans, &mut rows, 3, &mut spec, None);
            spec
        };
        let z = spectrum(&|i| C64::new(a[i], b[i]));
        let (fa, fb) = (
            spectrum(&|i| C64::new(a[i], 0.0)),
            spectrum(&|i| C64::new(b[i], 0.0)),
        );
        let mut out = vec![ZERO; nx * ny];
        for (part, want) in [(0, &fa), (1, &fb)] {
            unpack_lane(nx, ny, &z, part, &mut out);
            for (o, w) in out.iter().zip(want.iter()) {
                assert!((o - w).norm() < 1e-12, "{o} {w}");
            }
        }
    }
}
