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
//! and are cached by [`Matcher`] under the caller's `key`; spectra larger
//! than the cache's budget are transformed a pair at a time as the sum
//! reaches them, never held together (the same costs, bit for bit).
//!
//! FFT size: for [`Span::Contained`] (one image inside the other, as in the
//! paper) no index ever wraps for a wanted placement once the transform is at
//! least max(W_S, W_I) long, so that (rounded up to 2^a·3^b·5^c) is used; for
//! [`Span::Overlapping`] (every placement with any overlap) the linear size
//! W_S + W_I − 1 is needed. The forward transform skips the all-zero padding
//! rows and the inverse computes only the rows holding placements. All
//! parallel steps are element- or row-wise independent, so results do not
//! depend on the thread count. The transforms are rustfft's scalar ones,
//! the same arithmetic on every CPU.

use std::sync::{Arc, Mutex};

use half::slice::HalfFloatSliceExt;
use rayon::prelude::*;
use rustfft::num_complex::Complex;
// the scalar planner: rustfft's AVX, SSE and NEON code round differently
// from each other, so scores (and a near tie between placements) would
// depend on the CPU; scalar code is the same arithmetic everywhere
use rustfft::{Fft, FftPlannerScalar as FftPlanner};

use crate::artifact::svd::SvdArtifact;
use crate::container::{BoundedCache, MemoryBudget};
use crate::{Error, Result};

mod direct;
mod fft;
mod placements;

pub use direct::{
    brute_force_cost, brute_force_map, direct_costs, direct_costs_in, footprint, known_box, placement_range,
    valid_to_f32, SampleCopy,
};
pub use fft::fast_size;
use fft::{
    accumulate, axis, cols_per_task, fft_rows, forward_2d, m_lane, neg_index, pack_pair, sample_lane,
    sq_norm, unpack_lane, v_lane, work_lane, CacheKey, Layout, Plans, SampleIn, SampleSpectra, Values,
    WorkTag,
};
pub(in crate::quilt) use placements::near_limit;
pub use placements::{best_of, choose, CostMap, Placement};

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
        self.check_len(what, self.data.len())
    }

    /// [`Image::check`] for `len` values held elsewhere.
    fn check_len(&self, what: &str, len: usize) -> Result<()> {
        if self.width == 0 || self.height == 0 {
            return Err(Error::Config(format!(
                "{what}: empty ({}×{})",
                self.width, self.height
            )));
        }
        if len != self.pixels() * self.channels {
            return Err(Error::Config(format!(
                "{what}: {} values for {}×{}×{}",
                len, self.width, self.height, self.channels
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

/// Whether an overlap weight counts: above the numerical noise floor `tol`
/// and at least the minimum (up to `tol`).
fn accept(overlap: f64, min_overlap: f64, tol: f64) -> bool {
    overlap > tol && overlap >= min_overlap - tol && overlap > 0.0
}

/// A matcher's cache of sample spectra, shared between matchers.
#[derive(Clone)]
pub struct SpectraCache(Arc<Mutex<BoundedCache<CacheKey, Arc<SampleSpectra>>>>);

/// Entire-patch matcher: owns the FFT planner, reusable buffers and a cache
/// of sample spectra (kept when they fit its budget beside the entries in
/// use, least recently used ones dropped first).
pub struct Matcher {
    planner: FftPlanner<f64>,
    rows: Vec<C64>,
    spec: Vec<C64>,
    zm: Vec<C64>,
    acc: Vec<C64>,
    out: Vec<C64>,
    /// A sample pair's spectrum and F(V), for sample spectra too large for
    /// the cache ([`SampleSide::Streamed`]).
    ys: Vec<C64>,
    fv: Vec<C64>,
    energy: Vec<f64>,
    /// The spectra Z_j of the last keyed work image ([`Matcher::cost_map_for`]).
    work_spectra: Vec<C64>,
    work_tag: Option<WorkTag>,
    /// Shared with the matchers of [`Matcher::sharing`].
    cache: Arc<Mutex<BoundedCache<CacheKey, Arc<SampleSpectra>>>>,
    computed: u64,
    reused: u64,
    /// The most the buffers held before [`Matcher::release_buffers`].
    released: usize,
    /// The most a match held besides the buffers: its cost map, and the
    /// sample spectra it computed whole when the cache, shrunk meanwhile,
    /// could not keep them.
    transient: usize,
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

    /// A matcher whose spectrum cache holds up to `bytes` (spectra larger
    /// than that are streamed a pair at a time, never kept).
    pub fn with_cache_budget(bytes: usize) -> Matcher {
        Matcher {
            planner: FftPlanner::new(),
            rows: Vec::new(),
            spec: Vec::new(),
            zm: Vec::new(),
            acc: Vec::new(),
            out: Vec::new(),
            ys: Vec::new(),
            fv: Vec::new(),
            energy: Vec::new(),
            work_spectra: Vec::new(),
            work_tag: None,
            cache: Arc::new(Mutex::new(BoundedCache::new(MemoryBudget(bytes as u64)))),
            computed: 0,
            reused: 0,
            released: 0,
            transient: 0,
        }
    }

    /// Bytes of this matcher's buffers (sized by the largest match so far,
    /// also when they were released since) and of what the largest match
    /// held besides them (its cost map; sample spectra too large for the
    /// cache are transformed a pair at a time into two of the buffers).
    pub fn match_bytes(&self) -> usize {
        let complex = [
            &self.rows,
            &self.spec,
            &self.zm,
            &self.acc,
            &self.out,
            &self.ys,
            &self.fv,
            &self.work_spectra,
        ];
        let held = complex.iter().map(|b| b.capacity()).sum::<usize>() * std::mem::size_of::<C64>()
            + self.energy.capacity() * 8;
        held.max(self.released) + self.transient
    }

    /// Frees the buffers, for a matcher left idle while memory does not
    /// hold every matcher's: its next match allocates them again, with the
    /// same costs (a match never reads what an earlier one left in them).
    pub fn release_buffers(&mut self) {
        self.released = self.match_bytes() - self.transient;
        for b in [
            &mut self.rows,
            &mut self.spec,
            &mut self.zm,
            &mut self.acc,
            &mut self.out,
            &mut self.ys,
            &mut self.fv,
            &mut self.work_spectra,
        ] {
            *b = Vec::new();
        }
        self.energy = Vec::new();
        self.work_tag = None;
    }

    /// Sets the budget of the spectrum cache (shared with the matchers
    /// [`Matcher::sharing`] it), evicting down to it.
    pub fn set_cache_budget(&self, bytes: usize) {
        crate::lock(&self.cache).set_budget(MemoryBudget(bytes as u64));
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

    /// The spectrum cache's budget in bytes.
    pub fn cache_budget(&self) -> usize {
        crate::lock(&self.cache).budget() as usize
    }

    /// Bytes held by the spectrum cache.
    pub fn cache_bytes(&self) -> usize {
        crate::lock(&self.cache).bytes() as usize
    }

    /// Drops every cached sample spectrum (the cache is shared with the
    /// matchers [`Matcher::sharing`] it).
    pub fn clear_cache(&self) {
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
        let values = Values::F32(sample.image.data);
        self.cost_map_in(
            work,
            work_key,
            &SampleIn {
                sample: *sample,
                values,
            },
            cfg,
        )
    }

    /// [`Matcher::cost_map_for`] of a sample whose feature values are the
    /// f16 `values` (a rotated copy as the `.svd` stores it, half the
    /// bytes of its f32 copy): the costs of the f32 copy of the same
    /// values, bit for bit. `sample.image.data` is not read (it may be
    /// empty).
    pub fn cost_map_half(
        &mut self,
        work: &Work,
        work_key: Option<u64>,
        sample: &Sample,
        values: &[half::f16],
        cfg: &MatchConfig,
    ) -> Result<CostMap> {
        let values = Values::F16(values);
        self.cost_map_in(
            work,
            work_key,
            &SampleIn {
                sample: *sample,
                values,
            },
            cfg,
        )
    }

    fn cost_map_in(
        &mut self,
        work: &Work,
        work_key: Option<u64>,
        sample_in: &SampleIn,
        cfg: &MatchConfig,
    ) -> Result<CostMap> {
        let sample = &sample_in.sample;
        let lay = Layout::with_values(work, sample, sample_in.values.len(), cfg)?;
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
        // the sample side: cached spectra, or spectra computed whole in
        // room reserved in the cache beside the entries in use, or else
        // streamed a pair at a time
        let whole = ((lay.pairs + 1) * nn * std::mem::size_of::<C64>()) as u64;
        let (cached, room) = {
            let mut cache = crate::lock(&self.cache);
            let cached = cache.get(&lay.key).cloned();
            let room = cached.is_none() && cache.reserve(whole);
            (cached, room)
        };
        let mut uncached = 0;
        let side = match cached {
            Some(e) => {
                self.reused += 1;
                SampleSide::Held(e)
            }
            None if room => {
                let e = Arc::new(self.sample_spectra(&plans, sample_in, &lay));
                let bytes = e.bytes() as u64;
                if !crate::lock(&self.cache).insert_reserved(lay.key, Arc::clone(&e), whole, bytes) {
                    uncached = bytes as usize;
                }
                SampleSide::Held(e)
            }
            None => {
                self.computed += 1;
                for buf in [&mut self.ys, &mut self.fv] {
                    buf.resize(nn, ZERO);
                }
                SampleSide::Streamed(SampleEnergy::new(sample_in, &lay))
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
        // Z_j kept from the last match of this work image, or transformed
        let kept = tag.is_some() && tag == self.work_tag;
        if !kept {
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
        }
        let energy = &self.energy;
        self.acc.fill(ZERO);
        for j in 0..lay.pairs {
            let ys = side.pair(
                j,
                &plans,
                &mut self.rows,
                sample_in,
                &lay,
                &mut self.ys,
                &mut self.fv,
            );
            if kept {
                let zs = &self.work_spectra[j * nn..(j + 1) * nn];
                self.acc
                    .par_chunks_mut(TASK_ELEMS)
                    .zip(zs.par_chunks(TASK_ELEMS))
                    .zip(ys.par_chunks(TASK_ELEMS))
                    .for_each(|((acc, zs), ys)| accumulate(acc, zs, ys));
                continue;
            }
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
            forward_2d(
                &plans,
                &mut self.rows,
                wi.height,
                target,
                Some((&mut self.acc, ys)),
            );
        }
        if tag.is_some() {
            // F(M) of the kept spectra, where the unkept path transforms it
            self.zm[..nn].copy_from_slice(&self.work_spectra[m_pair * nn..(m_pair + 1) * nn]);
            self.work_tag = tag;
        }

        // Hermitian part of the sum (→ SSD) + i F(M) conj F(V) (→ overlap)
        let (fv, max_valid) = match &side {
            SampleSide::Held(e) => (&e.fv, e.max_valid),
            SampleSide::Streamed(en) => (&self.fv, en.max_valid),
        };
        let (acc, zm) = (&self.acc, &self.zm);
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
        let tol = 1e-9 * mass * max_valid;
        let scale = 1.0 / nn as f64;
        self.transient = self.transient.max(uncached + prow * columns * 16);
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
    fn sample_spectra(&mut self, plans: &Plans, sample: &SampleIn, lay: &Layout) -> SampleSpectra {
        self.computed += 1;
        let nn = lay.nx * lay.ny;
        let en = SampleEnergy::new(sample, lay);
        let mut pairs = vec![ZERO; lay.pairs * nn];
        let mut fv = vec![ZERO; nn];
        for (j, spec) in pairs.chunks_exact_mut(nn).enumerate() {
            en.pair(plans, &mut self.rows, sample, lay, j, spec, &mut fv);
        }
        SampleSpectra {
            pairs,
            fv,
            max_valid: en.max_valid,
        }
    }
}

/// The sample's side of a match (the Y_j and F(V)).
enum SampleSide {
    /// All pairs' spectra, cached or to be.
    Held(Arc<SampleSpectra>),
    /// Spectra too large for the cache: each pair transformed into the
    /// matcher's buffer as the sum over pairs reaches it, F(V) with its
    /// pair, so that no more than one pair is held (the same values).
    Streamed(SampleEnergy),
}

impl SampleSide {
    /// Y_j: the held pair's spectrum, or pair `j` transformed into `ys`
    /// (and F(V) into `fv` with its pair).
    #[allow(clippy::too_many_arguments)]
    fn pair<'a>(
        &'a self,
        j: usize,
        plans: &Plans,
        rows: &mut [C64],
        sample: &SampleIn,
        lay: &Layout,
        ys: &'a mut [C64],
        fv: &mut [C64],
    ) -> &'a [C64] {
        match self {
            SampleSide::Held(e) => {
                let nn = lay.nx * lay.ny;
                &e.pairs[j * nn..(j + 1) * nn]
            }
            SampleSide::Streamed(en) => {
                en.pair(plans, rows, sample, lay, j, ys, fv);
                ys
            }
        }
    }
}

/// Per-pixel sums the sample's lanes need (V‖S‖², V‖mP‖²) and its largest
/// validity.
struct SampleEnergy {
    energy: Vec<f64>,
    cenergy: Vec<f64>,
    max_valid: f64,
}

impl SampleEnergy {
    fn new(sample_in: &SampleIn, lay: &Layout) -> SampleEnergy {
        let (sample, values) = (&sample_in.sample, sample_in.values);
        let si = &sample.image;
        let energy = (0..si.pixels())
            .map(|i| sample.valid[i] as f64 * values.sq_norm(i * lay.n..(i + 1) * lay.n))
            .collect();
        let cenergy = match &sample.constraint {
            Some(c) => (0..si.pixels())
                .map(|i| sample.valid[i] as f64 * sq_norm(&c.data[i * lay.nc..(i + 1) * lay.nc]))
                .collect(),
            None => Vec::new(),
        };
        let max_valid = sample.valid.iter().fold(0.0f64, |a, &v| a.max(v as f64));
        SampleEnergy {
            energy,
            cenergy,
            max_valid,
        }
    }

    /// Transforms the sample's lane pair `j` into `spec` (through `rows`),
    /// and F(V) into `fv` when the pair holds V.
    #[allow(clippy::too_many_arguments)]
    fn pair(
        &self,
        plans: &Plans,
        rows: &mut [C64],
        sample: &SampleIn,
        lay: &Layout,
        j: usize,
        spec: &mut [C64],
        fv: &mut [C64],
    ) {
        let si = &sample.sample.image;
        pack_pair(rows, lay.nx, si.width, si.height, lay.lanes, j, |c, i| {
            sample_lane(sample, lay, &self.energy, &self.cenergy, c, i)
        });
        forward_2d(plans, rows, si.height, spec, None);
        let vl = v_lane(lay.n);
        if j == vl / 2 {
            unpack_lane(lay.nx, lay.ny, spec, vl % 2, fv);
        }
    }
}

#[cfg(test)]
mod tests;
