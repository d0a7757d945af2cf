//! The quilting loop's working set and its steps (section III-B, Fig. 4):
//! picking the next work patch, matching, fitting, seam refinement, and the
//! state painting starts from.

use std::path::{Path, PathBuf};
use std::time::Instant;

use super::config::{CourseMode, TileConfig, TileReport};
use super::fit::{apply, fit_patch, Fit, INFINITE};
use super::flatten::rotation_index;
use super::matching::Matcher;
use super::occurrence::Occurrence;
use super::pager::TileGrid;
use super::placement::{lock_courses, placed_on_sample, PlacementChoice, Turn};
use super::sample::{basis_projection, dist, sample_svd, Sample, SizedSample};
use super::state::{Bfs, CourseLock, ForeignSample, State, Surface, WorkPatch};
use super::worker::{Outcome, StepStats, Worker};
use crate::artifact::gim::{Gim, EMPTY, TILE};
use crate::artifact::quilt::{Quilt, MAX_SAMPLES, NO_PATCH};
use crate::artifact::svd::SvdArtifact;
use crate::container::MemoryBudget;
use crate::field::StripePattern;
use crate::io::staging::same_file;
use crate::progress::Progress;
use crate::{Error, Result};

mod load;
mod refine;
mod verbatim;
mod write;

pub(super) use write::write_quilt;

/// Work patches per round of seam refinement: any number gives the quilt
/// of one patch at a time; more keep the threads busier.
pub(crate) const REFINE_ROUND: usize = 16;

/// The quilting loop's working set: the surface, the sample, the synthesis
/// state and the reusable buffers. [`tile`](super::tile) runs it from an empty surface;
/// painting (`crate::paint`) from a decorated one with a constraint.
pub(crate) struct Synthesis {
    pub(super) cfg: TileConfig,
    /// The share of `--memory` the work patches in flight may take
    /// together ([`LOOP_SHARES`]; one always goes).
    pub(super) patch_budget: u64,
    /// `--memory` less what the program and the sample's maps hold: what
    /// the loop's stores share ([`LOOP_SHARES`]).
    pub(super) loop_budget: MemoryBudget,
    pub(super) sample_path: PathBuf,
    /// Every sample the surface draws from ([`Quilt::samples`]); the active
    /// one is `sample_paths[state.active]`.
    sample_paths: Vec<PathBuf>,
    /// The preview colours of the other samples a loaded surface draws
    /// from (by index; `None` for the active one and unused ones).
    other_previews: Vec<Option<crate::io::imageio::RgbImage>>,
    pub(super) surface: Surface,
    pub(super) zipper_triangles: Vec<[u32; 3]>,
    pub(super) sample: Sample,
    pub(super) state: State,
    pub(super) bfs: Bfs,
    pub(super) matcher: Matcher,
    /// Matchers (sharing `matcher`'s spectrum cache) and traversals of work
    /// patches computed at once ([`super::rounds`]).
    pub(super) spares: Vec<(Matcher, Bfs)>,
    /// Whether idle matchers free their buffers: set when the patches'
    /// share cannot hold the loop's matcher's and one per patch at once
    /// ([`Synthesis::settle_memory`]).
    pub(super) release_idle: bool,
    /// Seam refinement's patches per round ([`REFINE_ROUND`]).
    pub(crate) refine_round: usize,
    /// How often each sample region shows on the surface (tiling only).
    pub(super) occurrence: Occurrence,
    /// The sample's mean neighbour difference, the unit of T_c.
    pub(super) reference: f64,
    pub(crate) report: TileReport,
    /// Painting (§IV): one min-cut per fitting, no T_c shrinking, and a
    /// fitting may keep every old value.
    pub(crate) painting: bool,
    /// Painting on a surface tiled with [`CourseMode::Locked`]: the painted
    /// quilt records the lock whatever the stroke's courses.
    pub(crate) base_locked_courses: bool,
    /// A painted surface's stored stripe pattern, written again when the
    /// stroke did not lock to it (a lock writes its own).
    pub(crate) kept_pattern: Option<StoredPattern>,
    pub(super) seam_sum: f64,
    pub(super) seam_cnt: usize,
    /// Original sample pixels per pixel of the (resampled) sample the loop
    /// works in; the quilt stores coordinates in original pixels.
    scale: [f64; 2],
    /// The original sample's size in pixels.
    original_size: [usize; 2],
    /// Mesh units each sample's width spans, where one was given (by index
    /// like `sample_paths`; the active one's is `active_span`).
    sample_spans: Vec<Option<f64>>,
    active_span: Option<f64>,
}

/// The stripe pattern a quilt stores ([`crate::artifact::quilt::Quilt::stripe_pattern`]):
/// a stroke painted on a locked surface locks to it instead of solving
/// one of its own, so its courses meet the surface's.
pub(crate) struct StoredPattern {
    /// The quilt it was read from, for messages.
    pub(crate) file: PathBuf,
    /// Row spacing in mesh units.
    pub(crate) period: f64,
    /// ψ per vertex of the subdivided mesh, as (re, im) pairs.
    pub(crate) psi: Vec<f32>,
    /// A sample whose courses do not fit the pattern ([`PATTERN_FIT`]) is
    /// laid free; otherwise it is refused.
    pub(crate) free_unless_fit: bool,
}

/// A stroke's sample locks to a surface's stored pattern when its course
/// period on the surface is within this share of the pattern's: its rows
/// are then stretched or squeezed by at most as much.
pub(crate) const PATTERN_FIT: f64 = 0.05;

/// Locked courses: the smoothest stripe pattern along the atlas's field at
/// the sample's course period (texels × the atlas's texel size), solved
/// within `budget` bytes of a `--memory` of `memory`; or, for a stroke on a locked surface, the `stored`
/// pattern, where the sample's courses fit it ([`PATTERN_FIT`]). `None`
/// where they do not and the stroke may be laid free.
fn course_lock(
    gim: &Gim,
    sample: &Sample,
    sample_path: &Path,
    (budget, memory): (u64, u64),
    stored: Option<&StoredPattern>,
) -> Result<Option<CourseLock>> {
    let free_unless_fit = stored.is_some_and(|s| s.free_unless_fit);
    let Some(courses) = &sample.courses else {
        if free_unless_fit {
            return Ok(None);
        }
        return Err(Error::input(
            sample_path,
            "has no courses (its row profile is not periodic): --courses locked needs a sample whose \
             features run in rows",
        ));
    };
    let period = courses.period();
    let units = period * gim.texel_size;
    let Some(s) = stored else {
        let pattern = StripePattern::new(&gim.mesh()?, &gim.face_field()?, units, budget, memory)?
            .ok_or_else(|| {
                Error::input(
                    gim.container().path(),
                    "its field admits no stripe pattern (a degenerate mesh)",
                )
            })?;
        return Ok(Some(CourseLock { pattern, period }));
    };
    let off = units / s.period - 1.0;
    if off.abs() > PATTERN_FIT {
        if free_unless_fit {
            return Ok(None);
        }
        return Err(Error::input(
            sample_path,
            format!(
                "has courses {units:.4} mesh units apart on the surface, {:+.1} % off the stripe pattern \
                 of {} ({:.4}): --courses locked needs them within {:.0} % (set --sample-width to fit, or \
                 paint with --courses free)",
                100.0 * off,
                s.file.display(),
                s.period,
                100.0 * PATTERN_FIT
            ),
        ));
    }
    // the stored pattern's own period: it fixes the subdivision ψ lives on
    let pattern =
        StripePattern::from_psi(&gim.mesh()?, &gim.face_field()?, s.period, &s.psi)?.ok_or_else(|| {
            Error::input(
                &s.file,
                format!(
                    "stores a stripe pattern (stripe_psi, {} values) that does not fit its atlas",
                    s.psi.len()
                ),
            )
        })?;
    Ok(Some(CourseLock { pattern, period }))
}

impl Synthesis {
    /// Opens the geometry image and the sample's `.svd` as `sized` brought
    /// it to the atlas's density (call [`Synthesis::set_scale`] with it
    /// next), with an empty state
    /// whose evicted tiles go to a scratch store beside `output`. Without
    /// `matching` (verbatim copy) the rotated copies are not needed:
    /// rotations are then quantized to the default 72 steps. Locked
    /// courses take the `stored` pattern where it is the one they need.
    pub(crate) fn open(
        gim: &Gim,
        sample_path: &Path,
        sized: &SizedSample,
        output: &Path,
        cfg: &TileConfig,
        matching: bool,
        stored: Option<&StoredPattern>,
    ) -> Result<Self> {
        // --memory, less what the program and the sample's own maps hold,
        // is shared by the loop ([`LOOP_SHARES`]): the rotated copies as
        // f32, the sample spectra of the matcher, the paged atlas (surface
        // and state tiles) and the work patches in flight; the .svd's
        // decoded tiles are only passed through (the loop reads the maps
        // whole, and each rotated copy whole when matching at full
        // resolution, by the rectangles it costs when coarse to fine), so
        // its cache is 2 MiB
        let svd = SvdArtifact::open(&sized.svd, MemoryBudget(2 << 20))?;
        if matching && svd.rotations == 0 {
            return Err(Error::input(
                sample_path,
                "has no rotated copies (factorize with --rotations 72)",
            ));
        }
        // the unrotated maps, f32 per pixel and term
        let maps = 4 * (svd.width * svd.height * svd.terms) as u64;
        let loop_budget = loop_budget(cfg.memory, maps);
        let [tiles, spectra, atlas, patches] = loop_budget.split(LOOP_SHARES);
        let rotated = MemoryBudget(tiles.bytes().max(1 << 20));
        let mut sample = Sample::from_svd(svd, rotated)?;
        sample.set_match_terms(cfg.match_terms);
        sample.spill_beside(output);
        if super::coarse::factor(sample.width.max(sample.height), cfg.coarse_above) > 1 {
            sample.read_by_rectangles();
        }
        let [surface_budget, state_budget] = atlas.split([8, 11]);
        // only seam refinement by structure and locked courses read the
        // courses; locked, both read the original sample's
        let locked = cfg.courses == CourseMode::Locked;
        if locked {
            sample.find_original_courses(sized)?;
        } else if cfg.refine_broken > 0 {
            sample.find_courses();
        }
        // the pattern is solved before the atlas's stores fill: the solve
        // may take what the rotated copies leave of the budget
        let lock = if locked {
            course_lock(
                gim,
                &sample,
                sample_path,
                (
                    cfg.memory.bytes().saturating_sub(rotated.bytes()),
                    cfg.memory.bytes(),
                ),
                stored,
            )?
        } else {
            None
        };
        let occurrence = Occurrence::new(sample.width, sample.height, sample.tileable, sample.rotations);
        let n = sample.n;
        let locked_course_ends = lock.as_ref().map(|l| l.pattern.ends());
        let surface = Surface::open(gim, surface_budget, lock)?;
        let reference = sample.neighbour_difference();
        let state = State::new(&surface, n, output, state_budget)?;
        let total = state.remaining;
        let original_size = [sample.width, sample.height];
        Ok(Synthesis {
            cfg: cfg.clone(),
            sample_path: sample_path.to_path_buf(),
            sample_paths: vec![sample_path.to_path_buf()],
            other_previews: Vec::new(),
            zipper_triangles: gim.zipper_triangles()?,
            sample,
            state,
            bfs: Bfs::default(),
            matcher: Matcher::with_cache_budget(spectra.bytes().max(1 << 20) as usize),
            patch_budget: patches.bytes(),
            loop_budget,
            spares: Vec::new(),
            release_idle: false,
            refine_round: REFINE_ROUND,
            occurrence,
            reference,
            report: TileReport {
                texels: total,
                locked_course_ends,
                ..TileReport::default()
            },
            original_size,
            surface,
            painting: false,
            base_locked_courses: false,
            kept_pattern: None,
            seam_sum: 0.0,
            seam_cnt: 0,
            scale: [1.0, 1.0],
            sample_spans: vec![None],
            active_span: None,
        })
    }

    /// Empties the rotated copies' and the sample spectra's caches (what
    /// they held is computed again if asked for).
    pub(super) fn release_caches(&self) {
        self.sample.drop_rotations();
        self.matcher.clear_cache();
    }

    /// Whether the synthesis locks its courses to a stripe pattern.
    pub(crate) fn locks_courses(&self) -> bool {
        self.surface.lock.is_some()
    }

    /// Loads the sample's foreground mask m_P (a PNG the sample's size; any
    /// channel above one half counts as foreground, grey levels between).
    /// Call it before [`Synthesis::load`], which looks m_σ up per texel.
    pub(crate) fn set_mask(&mut self, path: &Path) -> Result<()> {
        let [w, h] = self.original_size;
        let mut mask = crate::io::imageio::read_sized_mask(
            path,
            w,
            h,
            "the sample's foreground mask must be the sample's size",
        )?;
        if self.scale != [1.0, 1.0] {
            let (to_w, to_h) = (self.sample.width, self.sample.height);
            mask = crate::io::imageio::resample(&mask, w, h, 1, to_w, to_h);
        }
        if !mask.iter().any(|&m| m >= 0.5) {
            return Err(Error::input(
                path,
                "marks no foreground (no pixel above one half)",
            ));
        }
        self.sample.mask = Some(mask);
        Ok(())
    }

    /// Works in the sample resampled as `sized` says (open the synthesis
    /// with `sized.svd`), before a mask is set or a surface loaded.
    pub(crate) fn set_scale(&mut self, sized: &SizedSample) {
        self.scale = sized.scale;
        self.original_size = sized.size;
        self.active_span = sized.native_reference.map(|_| sized.width_units);
        self.report.sample_width = sized.width_units;
        self.report.sample_scale = sized.scale[0];
        // seams are judged at the sample's own resolution or coarser
        if let Some(native) = sized.native_reference {
            self.reference = self.reference.max(native);
        }
    }

    /// Adds the structure channel with `weight` sample neighbour
    /// differences to the features (tiling; 0: colour only). Call it after
    /// [`Synthesis::set_scale`], before anything is matched.
    pub(crate) fn set_structure(&mut self, weight: f64) {
        if weight > 0.0 {
            self.sample.add_structure((weight * self.reference) as f32);
            self.state.n = self.sample.n;
        }
    }

    /// Sets m0 to the given values on a zone (`(texel, m0)`), 0 elsewhere.
    pub(crate) fn set_target_zone(&mut self, zone: &[(u32, f32)]) {
        self.state.constrain_everywhere(0.0);
        for &(t, m) in zone {
            self.state.texel_mut(t, |s, k| s.target[k] = m);
        }
    }

    /// Texels with m0 ≥ ½ (the region F) and with m0 > 0 (F and its
    /// transition zone).
    pub(crate) fn target_summary(&self) -> (usize, usize) {
        if !self.state.constrained {
            return (0, 0);
        }
        let grid = self.surface.grid();
        let (mut region, mut zone) = (0, 0);
        for k in 0..grid.tiles() {
            let (_, _, w, h) = grid.region(k);
            self.state.tile(k, |s| {
                for y in 0..h {
                    for m in &s.target[y * TILE..y * TILE + w] {
                        region += (*m >= 0.5) as usize;
                        zone += (*m > 0.0) as usize;
                    }
                }
            });
        }
        (region, zone)
    }

    /// Texels whose patch id differs from `base`'s.
    pub(crate) fn changed_patches(&self, base: &Quilt) -> Result<usize> {
        let grid = self.surface.grid();
        let mut changed = 0;
        for k in 0..grid.tiles() {
            let (x0, y0, w, h) = grid.region(k);
            let before = base.texel_region(x0, y0, w, h)?.patch;
            self.state.tile(k, |s| {
                for y in 0..h {
                    for x in 0..w {
                        changed += (s.patch[y * TILE + x] != before[y * w + x]) as usize;
                    }
                }
            });
        }
        Ok(changed)
    }

    /// Sets m0 = 0 everywhere (a foreground mask keeps the foreground out
    /// of the whole surface), before the loop starts.
    pub(crate) fn constrain_to_background(&mut self) {
        self.state.constrain_everywhere(0.0);
    }

    /// Resolution R of the atlas.
    pub(crate) fn resolution(&self) -> usize {
        self.surface.r
    }

    /// The chart of texel `t` ([`EMPTY`] outside the charts).
    pub(crate) fn chart(&self, t: u32) -> u32 {
        self.surface.chart(t)
    }

    /// Calls `f` for every neighbour of dense vertex `t` in M_d (whether
    /// across a zipper link as the second argument).
    pub(crate) fn for_each_neighbour(&self, t: u32, f: impl FnMut(u32, bool)) {
        self.surface.for_each_neighbour(t, f)
    }

    /// 3D position of a dense vertex, in the mesh's units.
    pub(crate) fn position(&self, t: u32) -> [f32; 3] {
        self.surface.position(t).map(|c| c / self.surface.unit)
    }

    /// The sample's width and foreground mask (empty without one).
    pub(crate) fn sample_mask(&self) -> (usize, &[f32]) {
        (self.sample.width, self.sample.mask.as_deref().unwrap_or(&[]))
    }

    /// The work-patch radius r_w: 32 per 512 texels of atlas (the paper's
    /// figure), but at most a quarter of the sample's smaller side, so a
    /// work image (about 2 r_w across) leaves room to place and turn the
    /// sample: on Spot at 1024² with a 128² BTF, r_w 32 instead of 64 took
    /// 17 s instead of 35–43 s with a seam ratio of 1.28 instead of 1.40;
    /// with a 192² crop, 48 instead of 64 gave 0.91 instead of 0.97.
    pub(crate) fn radius0(&self) -> usize {
        let cfg = &self.cfg;
        let by_atlas = 32 * self.surface.r / 512;
        let by_sample = self.sample.width.min(self.sample.height) / 4;
        cfg.patch_radius
            .unwrap_or(by_atlas.min(by_sample))
            .max(cfg.min_radius)
    }

    /// A worker over the whole surface and state, counting from the
    /// patches accepted so far.
    pub(super) fn worker(&mut self) -> Worker<'_> {
        Worker {
            surface: &self.surface,
            state: &self.state,
            sample: &self.sample,
            zipper_triangles: &self.zipper_triangles,
            cfg: &self.cfg,
            sample_path: &self.sample_path,
            reference: self.reference,
            painting: self.painting,
            occurrence: Some(&mut self.occurrence),
            bfs: &mut self.bfs,
            ball: None,
            matcher: &mut self.matcher,
            counter: self.report.patches as u64,
            stats: StepStats::default(),
        }
    }

    /// One step of the quilting loop at vertex `v` ([`Worker::step`]),
    /// accepted. Returns the vertices of the accepted work patch.
    pub(crate) fn step(&mut self, v: u32, radius0: usize, progress: &dyn Progress) -> Result<WorkPatch> {
        let outcome = self.worker().step(v, radius0, progress)?;
        self.accept_outcome(&outcome, progress);
        Ok(outcome.patch)
    }

    /// Accepts a computed work patch: its stats into the report, its
    /// fitting into the state.
    pub(super) fn accept_outcome(&mut self, outcome: &Outcome, progress: &dyn Progress) {
        ledger!(self).accept_outcome(&mut self.state, &self.surface, outcome, progress);
    }

    pub(super) fn add_stats(&mut self, stats: &StepStats) {
        add_stats(&mut self.report, stats);
    }

    /// Records an accepted fitting under the next patch id.
    pub(super) fn accept(&mut self, patch: &WorkPatch, fit: &Fit, progress: &dyn Progress) {
        ledger!(self).accept(&mut self.state, &self.surface, patch, fit, progress);
    }

    /// The first error met paging the atlas in or out, if any.
    pub(super) fn check_paging(&mut self) -> Result<()> {
        self.surface.take_error()?;
        self.state.take_error()
    }

    /// Mean seam cost per seam edge in units of the sample's neighbour
    /// difference.
    pub(super) fn finish_report(&mut self, start: Instant) {
        self.report.mean_seam_cost = if self.seam_cnt > 0 {
            self.seam_sum / self.seam_cnt as f64 / self.reference
        } else {
            0.0
        };
        self.report.seconds = start.elapsed().as_secs_f64();
        self.report.atlas_tiles = self.surface.grid().tiles();
        self.report.tiles_read = self.surface.tiles_read() + self.state.tiles_read();
        self.report.scratch_bytes = self.state.scratch_bytes();
    }
}

/// The [`Ledger`] of synthesis `$syn`: a macro, so that the fields it
/// borrows stay borrowed one by one (beside the state and surface it
/// accepts into, and a round's [`super::rounds::Context`]).
macro_rules! ledger {
    ($syn:expr) => {
        $crate::quilt::synthesis::Ledger {
            sample: &$syn.sample,
            occurrence: (!$syn.painting).then_some(&mut $syn.occurrence),
            report: &mut $syn.report,
            seam_sum: &mut $syn.seam_sum,
            seam_cnt: &mut $syn.seam_cnt,
        }
    };
}
pub(super) use ledger;

/// What accepting a work patch changes besides the state: the parts of a
/// [`Synthesis`] borrowed one by one, so that a round's patches can be
/// accepted while its later ones are still computed
/// ([`super::rounds`]).
pub(super) struct Ledger<'a> {
    pub(super) sample: &'a Sample,
    /// The occurrence map (tiling only).
    pub(super) occurrence: Option<&'a mut Occurrence>,
    pub(super) report: &'a mut TileReport,
    pub(super) seam_sum: &'a mut f64,
    pub(super) seam_cnt: &'a mut usize,
}

impl Ledger<'_> {
    /// Records an accepted fitting into `state` under the next patch id.
    pub(super) fn accept(
        &mut self,
        state: &mut State,
        surface: &Surface,
        patch: &WorkPatch,
        fit: &Fit,
        progress: &dyn Progress,
    ) {
        let id = state.next_patch;
        state.next_patch += 1;
        apply(
            state,
            self.sample,
            surface,
            patch,
            fit,
            id,
            self.occurrence.as_deref_mut(),
            progress,
        );
        *self.seam_sum += fit.seam_cost;
        *self.seam_cnt += fit.seam_edges;
        self.report.patches += 1;
    }

    /// Accepts a computed work patch: its stats into the report, its
    /// fitting into `state`.
    pub(super) fn accept_outcome(
        &mut self,
        state: &mut State,
        surface: &Surface,
        outcome: &Outcome,
        progress: &dyn Progress,
    ) {
        add_stats(self.report, &outcome.stats);
        self.report.cross_chart_patches += outcome.patch.crosses_charts as usize;
        self.report.unfolded_patches += outcome.unfolded as usize;
        self.accept(state, surface, &outcome.patch, &outcome.fit, progress);
    }
}

fn add_stats(report: &mut TileReport, stats: &StepStats) {
    report.shrinks += stats.shrinks;
    report.matching_seconds += stats.matching_seconds;
    report.graphcut_seconds += stats.graphcut_seconds;
}

/// A verbatim copy's direct projection (§IV's fast preview): the work
/// patch's atlas box from texel `(x0, y0)`, the foreground pasted over the
/// surface's preview colours (linear RGB), and which of its texels hold a
/// colour (the rest lie outside every chart).
pub struct Projection {
    pub x0: usize,
    pub y0: usize,
    pub image: crate::io::imageio::RgbImage,
    pub covered: Vec<bool>,
}

pub(crate) use crate::artifact::quilt::sample_role;

/// Runs of [`visit_order`]: enough for a refinement round
/// ([`REFINE_ROUND`]) to hold about half as many patches.
/// Not tied to the round, so the quilt is the same for any round size.
const REFINE_RUNS: usize = 8;

/// The order seam refinement visits its `seeds` (seam step, texel) in:
/// along the atlas tiles in Z order (largest step first within a tile),
/// the list cut into `runs` equal runs that take turns. Consecutive
/// seeds thus lie far apart, so a round can take several of them at once,
/// while each run walks the atlas tile by tile, so the tiles paged in stay
/// few (largest step first over the whole atlas reads each tile many times).
fn visit_order(grid: &TileGrid, mut seeds: Vec<(f64, u32)>, runs: usize) -> Vec<u32> {
    /// Bits of `v` (< 2¹⁶) spread to the even places.
    fn spread(v: usize) -> u64 {
        let mut v = v as u64 & 0xffff;
        v = (v | v << 8) & 0x00ff_00ff;
        v = (v | v << 4) & 0x0f0f_0f0f;
        v = (v | v << 2) & 0x3333_3333;
        (v | v << 1) & 0x5555_5555
    }
    let z = |t: u32| {
        let (k, _) = grid.locate(t);
        spread(k % grid.across) | spread(k / grid.across) << 1
    };
    seeds.sort_by(|a, b| z(a.1).cmp(&z(b.1)).then(b.0.total_cmp(&a.0)).then(a.1.cmp(&b.1)));
    let runs = runs.max(1);
    let per = seeds.len().div_ceil(runs);
    (0..per)
        .flat_map(|i| (0..runs).map(move |s| s * per + i))
        .filter_map(|i| seeds.get(i).map(|s| s.1))
        .collect()
}

/// How the quilting loop divides its budget ([`loop_budget`]), in
/// proportion: the sample's rotated copies, the matcher's sample spectra,
/// the paged atlas (surface and state tiles) and the work patches in
/// flight ([`Synthesis::patch_bytes`] each). Once matching has sized a work
/// patch, the patches keep what as many as run at once need and the two
/// caches split the rest ([`Synthesis::settle_memory`]).
pub(super) const LOOP_SHARES: [u64; 4] = [2, 2, 4, 8];

/// What the program itself holds besides the loop's stores: its code and
/// libraries (about 12 MB resident on Linux x86-64), thread stacks, the
/// surface's per-tile bookkeeping and the allocator's slack (freed memory
/// it keeps). 48 MiB keeps the peak within `--memory` on the runs of
/// docs/measurements.md, "Memory of the quilting loop"; the share is never
/// more than half the budget ([`loop_budget`]).
pub(super) const PROGRAM_BYTES: u64 = 48 << 20;

/// The quilting loop's budget: `--memory` less the program
/// ([`PROGRAM_BYTES`]) and the sample's unrotated maps (`sample_bytes`),
/// never less than half of `--memory`.
fn loop_budget(memory: MemoryBudget, sample_bytes: u64) -> MemoryBudget {
    memory.less(PROGRAM_BYTES + sample_bytes)
}

#[cfg(test)]
mod tests;
