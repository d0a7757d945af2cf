//! The quilting loop and seam refinement a round at a time: up to
//! [`TileConfig::round`](super::TileConfig::round) ([`REFINE_ROUND`](super::synthesis::REFINE_ROUND))
//! work patches that share no atlas tile are computed at once, each over
//! read-only views of its tiles ([`Worker`]), then accepted in order.
//!
//! A work patch reads only its tiles, and accepting one writes only its
//! tiles, so a patch computed with the round's first state equals the
//! patch computed after the earlier ones of its round were accepted. Which
//! patches form a round depends on the state alone, never on the threads,
//! so the quilt is the same for any thread count. A patch that reads
//! outside its tiles (a view sees a blank tile there) is computed again on
//! the whole state in its turn.
//!
//! Run from outside the thread pool (as the command line does), the
//! quilting loop's rounds are streamed ([`super::streamed`]): the same
//! rounds, patches and order of acceptance, with choosing and accepting
//! overlapping the computing.

use std::path::Path;
use std::sync::Mutex;

use super::config::TileConfig;
use super::matching::{Matcher, SpectraCache};
use super::occurrence::Occurrence;
use super::sample::Sample;
use super::state::{Bfs, State, Surface, WorkPatch};
use super::synthesis::Synthesis;
use super::worker::{Outcome, StepStats, Worker};
use crate::artifact::gim::TILE;
use crate::progress::{Progress, Silent};
use crate::Result;

/// Candidates tried for each further seed of a round before it ends short.
const TRIES: usize = 8;

/// The [`Context`] of a round of synthesis `$syn` (its spare matchers
/// taken for the round, to be given back): a macro, so that the fields it
/// borrows stay borrowed one by one.
macro_rules! round_context {
    ($syn:expr) => {
        $crate::quilt::rounds::Context {
            sample: &$syn.sample,
            zipper_triangles: &$syn.zipper_triangles,
            cfg: &$syn.cfg,
            sample_path: &$syn.sample_path,
            reference: $syn.reference,
            painting: $syn.painting,
            occurrence: (!$syn.painting).then(|| $syn.occurrence.snapshot()),
            spares: std::sync::Mutex::new(std::mem::take(&mut $syn.spares)),
            release: $syn.release_idle,
            spectra: $syn.matcher.spectra_cache(),
            base: $syn.report.patches as u64,
        }
    };
}
pub(super) use round_context;

/// What the work patches of a round share while they are computed.
pub(super) struct Context<'a> {
    pub(super) sample: &'a Sample,
    pub(super) zipper_triangles: &'a [[u32; 3]],
    pub(super) cfg: &'a TileConfig,
    pub(super) sample_path: &'a Path,
    pub(super) reference: f64,
    pub(super) painting: bool,
    /// The occurrence map as the round found it.
    pub(super) occurrence: Option<Occurrence>,
    pub(super) spares: Mutex<Vec<(Matcher, Bfs)>>,
    /// Whether a matcher frees its buffers when its patch is done
    /// ([`Synthesis::release_idle`]).
    pub(super) release: bool,
    pub(super) spectra: SpectraCache,
    /// Patches accepted before the round.
    pub(super) base: u64,
}

impl Context<'_> {
    /// Computes the round's `j`-th work patch with `f` over views of its
    /// tiles; `None` if it read outside them.
    pub(super) fn run<F>(
        &self,
        j: usize,
        job: &Job,
        surface: Surface,
        state: State,
        f: &F,
    ) -> Option<Result<Outcome>>
    where
        F: Fn(&mut Worker<'_>, u32) -> Result<Outcome> + Sync,
    {
        let spare = crate::lock(&self.spares).pop();
        let (mut matcher, mut bfs) =
            spare.unwrap_or_else(|| (Matcher::sharing(self.spectra.clone()), Bfs::default()));
        let mut occurrence = self.occurrence.clone();
        let mut worker = Worker {
            surface: &surface,
            state: &state,
            sample: self.sample,
            zipper_triangles: self.zipper_triangles,
            cfg: self.cfg,
            sample_path: self.sample_path,
            reference: self.reference,
            painting: self.painting,
            occurrence: occurrence.as_mut(),
            bfs: &mut bfs,
            ball: Some((&job.ball, job.radius + 2)),
            matcher: &mut matcher,
            counter: self.base + j as u64,
            stats: StepStats::default(),
        };
        let outcome = f(&mut worker, job.v);
        if self.release {
            matcher.release_buffers();
        }
        crate::lock(&self.spares).push((matcher, bfs));
        (!(surface.missed() || state.missed())).then_some(outcome)
    }
}

/// Chooses a round of the quilting loop a work patch at a time: the most
/// constrained texel first, then the most constrained texels (with at
/// least one synthesized neighbour) whose tiles are not the round's, from
/// the state as the round found it.
pub(super) struct Chooser {
    /// The round's tiles.
    used: Vec<bool>,
    /// Its tiles and those of seeds given up.
    blocked: Vec<bool>,
    chosen: usize,
    round: usize,
    radius: usize,
}

impl Chooser {
    pub(super) fn new(surface: &Surface, round: usize, radius: usize) -> Chooser {
        let used = vec![false; surface.grid().tiles()];
        Chooser {
            blocked: used.clone(),
            used,
            chosen: 0,
            round,
            radius,
        }
    }

    /// The round's next work patch; `None` once it is complete.
    pub(super) fn next(&mut self, bfs: &mut Bfs, surface: &Surface, state: &State) -> Option<Job> {
        let job = self.choose(bfs, surface, state);
        if job.is_none() {
            self.chosen = self.round;
        }
        job
    }

    fn choose(&mut self, bfs: &mut Bfs, surface: &Surface, state: &State) -> Option<Job> {
        let radius = self.radius;
        let (v, tiles, ball) = if self.chosen == 0 {
            let v = state.most_constrained()?;
            let (tiles, ball) = reach(bfs, surface, v, radius);
            (v, tiles, ball)
        } else if self.chosen < self.round {
            let mut found = None;
            for _ in 0..TRIES {
                let v = state.most_constrained_outside(&self.blocked, 1)?;
                match reach_unless_used(bfs, surface, v, radius, &self.used) {
                    Some((tiles, ball)) => {
                        found = Some((v, tiles, ball));
                        break;
                    }
                    None => self.blocked[surface.grid().locate(v).0] = true,
                }
            }
            found?
        } else {
            return None;
        };
        for &k in &tiles {
            self.used[k] = true;
            self.blocked[k] = true;
        }
        self.chosen += 1;
        Some(Job::new(v, &tiles, ball, radius, surface))
    }
}

/// A work patch of a round: its seed and the atlas tiles it may read.
pub(super) struct Job {
    pub(super) v: u32,
    /// The tiles it may read ([`reach`]).
    pub(super) tiles: Vec<usize>,
    /// Fewer tiles for its views to hold first, when it crosses charts
    /// ([`narrow_tiles`]).
    pub(super) narrow: Option<Vec<usize>>,
    /// Its traversal (the work patch and two hops more; [`reach`]).
    pub(super) ball: WorkPatch,
    /// The work patch's radius.
    pub(super) radius: usize,
}

impl Job {
    /// The patch at `v` whose [`reach`] is `tiles` and `ball`.
    fn new(v: u32, tiles: &[usize], ball: WorkPatch, radius: usize, surface: &Surface) -> Job {
        Job {
            v,
            tiles: tiles.to_vec(),
            narrow: narrow_tiles(surface, &ball),
            ball,
            radius,
        }
    }

    /// The tiles its views hold first.
    pub(super) fn view(&self) -> &[usize] {
        self.narrow.as_deref().unwrap_or(&self.tiles)
    }
}

impl Synthesis {
    /// The quilting loop (the paper's Fig. 4) until every texel is
    /// synthesized, from `first`. A round starts at the most constrained
    /// texel; its further seeds are the most constrained texels (with at
    /// least one synthesized neighbour) whose tiles are not the round's.
    pub(crate) fn synthesize(&mut self, first: u32, radius0: usize, progress: &dyn Progress) -> Result<()> {
        self.step(first, radius0, progress)?;
        let traversal = self.bfs.patch(&self.surface, first, radius0 + 2).texels.len();
        self.check_paging()?;
        // (inside the pool the calling thread is one of the round's, so
        // it cannot wait for the others while they compute)
        let streamed = rayon::current_thread_index().is_none();
        while self.state.remaining > 0 {
            self.settle_memory(traversal);
            if streamed {
                self.streamed_round(radius0, progress)?;
            } else {
                let jobs = self.quilting_round(radius0);
                let (outcomes, ()) = self.compute(&jobs, |w, v| w.step(v, radius0, &Silent), |_, _| ());
                self.accept_steps(jobs.iter().map(|j| j.v), outcomes, radius0, progress)?;
            }
        }
        Ok(())
    }

    /// Accepts a round's quilting steps in order; a step that read outside
    /// its tiles is computed again on the whole state first.
    pub(super) fn accept_steps(
        &mut self,
        seeds: impl IntoIterator<Item = u32>,
        outcomes: Vec<Option<Result<Outcome>>>,
        radius0: usize,
        progress: &dyn Progress,
    ) -> Result<()> {
        for (v, outcome) in seeds.into_iter().zip(outcomes) {
            match outcome {
                Some(outcome) => self.accept_outcome(&outcome?, progress),
                None => {
                    if std::env::var_os("BTFQUILT_TRACE").is_some() {
                        progress.note(&format!("patch at {v} read outside its tiles: computed again"));
                    }
                    self.step(v, radius0, progress)?;
                }
            }
        }
        self.check_paging()
    }

    /// The seeds of the next round of the quilting loop.
    fn quilting_round(&mut self, radius0: usize) -> Vec<Job> {
        let mut chooser = Chooser::new(&self.surface, self.cfg.round, radius0);
        let mut jobs = Vec::new();
        while let Some(job) = chooser.next(&mut self.bfs, &self.surface, &self.state) {
            jobs.push(job);
        }
        jobs
    }

    /// Painting's work patches (§IV): every texel of `order` (the zone,
    /// deepest in F first) is synthesized again once, as the seed of a
    /// patch or inside one (not on its rim); the next seed is the next such
    /// texel not yet covered. A round takes the next seeds while their
    /// tiles are free; as a painting patch never shrinks, the seeds depend
    /// on the surface alone and the quilt is that of one patch at a time.
    /// `covered(n)` is told how many zone texels each round covered.
    pub(crate) fn paint_seeds(
        &mut self,
        order: &[u32],
        radius0: usize,
        covered: &dyn Fn(usize),
        progress: &dyn Progress,
    ) -> Result<()> {
        let grid = self.surface.grid();
        // only the zone's texels are open
        let mut open = vec![0u64; (grid.r * grid.r).div_ceil(64)];
        for &t in order {
            open[t as usize / 64] |= 1 << (t % 64);
        }
        let mut schedule = Schedule {
            seeds: order,
            next: 0,
            open,
            done: Done::Inside,
            radius: radius0,
            round: self.refine_round.max(1),
        };
        let (mut jobs, mut closed) = schedule.round(&mut self.bfs, &lent(&self.surface));
        while !jobs.is_empty() {
            // (the next round chosen while this one is computed)
            let (outcomes, next) = self.compute(
                &jobs,
                |w, v| w.step(v, radius0, &Silent),
                |bfs, lend| schedule.round(bfs, lend),
            );
            self.accept_steps(jobs.iter().map(|j| j.v), outcomes, radius0, progress)?;
            covered(closed);
            (jobs, closed) = next;
        }
        Ok(())
    }

    /// Seam refinement's patches at `seeds` (in the order
    /// [`Synthesis::refine`] gives them), each fitting `placements(seed)`
    /// placements: a round takes the next seeds in
    /// order while their tiles are free, so the seeds visited and the quilt are those
    /// of one patch at a time. Returns how many were kept.
    pub(super) fn refine_seeds(
        &mut self,
        seeds: &[u32],
        radius: usize,
        placements: &(dyn Fn(u32) -> (usize, bool) + Sync),
        progress: &dyn Progress,
    ) -> Result<usize> {
        let grid = self.surface.grid();
        let mut schedule = Schedule {
            seeds,
            next: 0,
            // every texel open
            open: vec![u64::MAX; (grid.r * grid.r).div_ceil(64)],
            done: Done::Core,
            radius,
            round: self.refine_round.max(1),
        };
        let mut kept = 0;
        let (mut jobs, _) = schedule.round(&mut self.bfs, &lent(&self.surface));
        while !jobs.is_empty() {
            // each patch computed as if none before it in the round is
            // kept, while the next round is chosen (the rounds depend on
            // the surface alone)
            let base = self.report.patches as u64;
            let (outcomes, next) = self.compute(
                &jobs,
                |w, v| {
                    w.counter = base;
                    w.refinement(v, radius, placements(v), 3)
                },
                |bfs, lend| schedule.round(bfs, lend),
            );
            for (job, outcome) in jobs.iter().zip(outcomes) {
                let outcome = match outcome {
                    // its seeded choice assumed another count
                    Some(Ok(o)) if o.stats.seeded && self.report.patches as u64 != base => None,
                    other => other,
                };
                let outcome = match outcome {
                    Some(outcome) => outcome?,
                    None => self.worker().refinement(job.v, radius, placements(job.v), 3)?,
                };
                self.add_stats(&outcome.stats);
                let fit = &outcome.fit;
                let cheaper = fit.flow < 0.9 * fit.baseline;
                let keep = match fit.ends {
                    // fewer features end, at a cut not much dearer than the
                    // seams it replaces; or as many, more cheaply
                    Some((before, after)) => {
                        (after < before && fit.flow < super::config::ENDS_DEARER * fit.baseline)
                            || (after <= before && cheaper)
                    }
                    None => cheaper,
                };
                if fit.taken > 0 && keep {
                    self.accept(&outcome.patch, fit, progress);
                    self.report.refined += 1;
                    kept += 1;
                }
            }
            self.check_paging()?;
            jobs = next.0;
        }
        Ok(kept)
    }

    /// Computes the round's work patches with `f`, at once when there are
    /// several, each over views of its tiles and counting from the patches
    /// accepted so far plus its place in the round, while `alongside` runs
    /// on the whole surface. `None` for a patch that read outside its
    /// tiles.
    fn compute<F, A, R>(&mut self, jobs: &[Job], f: F, alongside: A) -> (Vec<Option<Result<Outcome>>>, R)
    where
        F: Fn(&mut Worker<'_>, u32) -> Result<Outcome> + Sync,
        A: FnOnce(&mut Bfs, Lend) -> R + Send,
        R: Send,
    {
        if jobs.len() <= 1 {
            let outcomes = jobs.iter().map(|j| Some(f(&mut self.worker(), j.v))).collect();
            return (outcomes, alongside(&mut self.bfs, &lent(&self.surface)));
        }
        let (at_once, by_memory) = self.at_once(jobs);
        self.idle_main_matcher();
        let job = round_context!(self);
        let (outcomes, other): (Vec<Option<Result<Outcome>>>, R) = if at_once <= 1 {
            // one at a time, each over its views all the same (a patch that
            // reads outside its tiles is computed again in its turn)
            let outcomes = jobs
                .iter()
                .enumerate()
                .map(|(j, w)| job.run(j, w, self.surface.view(w.view()), self.state.view(w.view()), &f))
                .collect();
            (outcomes, alongside(&mut self.bfs, &lent(&self.surface)))
        } else {
            // `at_once` tasks take the patches in turn, largest traversal
            // first (so that the round ends on small ones and no task waits
            // long for the other): no more are in flight (nor matchers
            // held) however the threads steal work. A view pins its tiles
            // until its patch is computed: the views of as many patches as
            // memory holds in flight are made now, the others by the task
            // that takes the patch, from the pagers shared under a lock
            // (also lent to `alongside`)
            let mut order: Vec<usize> = (0..jobs.len()).collect();
            order.sort_by_key(|&j| std::cmp::Reverse(jobs[j].ball.texels.len()));
            let ahead = by_memory.min(jobs.len());
            let mut views: Vec<Mutex<Option<(Surface, State)>>> =
                jobs.iter().map(|_| Mutex::new(None)).collect();
            for &j in &order[..ahead] {
                let view = jobs[j].view();
                views[j] = Mutex::new(Some((self.surface.view(view), self.state.view(view))));
            }
            let slots: Vec<Mutex<Option<Option<Result<Outcome>>>>> =
                jobs.iter().map(|_| Mutex::new(None)).collect();
            let next = std::sync::atomic::AtomicUsize::new(0);
            let main_bfs = &mut self.bfs;
            let pagers = Mutex::new((&mut self.surface, &mut self.state));
            let (job, views, slots, next, pagers, f, order) =
                (&job, &views, &slots, &next, &pagers, &f, &order);
            let other = rayon::scope(|s| {
                for _ in 0..at_once {
                    s.spawn(move |_| loop {
                        let Some(&j) = order.get(next.fetch_add(1, std::sync::atomic::Ordering::Relaxed))
                        else {
                            break;
                        };
                        let made = crate::lock(&views[j]).take();
                        let (surface, state) = made.unwrap_or_else(|| {
                            let p = crate::lock(pagers);
                            (p.0.view(jobs[j].view()), p.1.view(jobs[j].view()))
                        });
                        *crate::lock(&slots[j]) = Some(job.run(j, &jobs[j], surface, state, f));
                    });
                }
                // lent a traversal at a time, so that tasks wait for the
                // lock one traversal at most
                alongside(main_bfs, &|f| f(crate::lock(pagers).0))
            });
            self.report.late_views += jobs.len() - ahead;
            let outcomes = slots
                .iter()
                .map(|slot| crate::lock(slot).take().expect("every patch computed"))
                .collect();
            (outcomes, other)
        };
        let mut outcomes = outcomes;
        self.recompute_narrow(&job, jobs.iter().enumerate(), &mut outcomes, &f);
        self.report.concurrent_patches += jobs.len();
        self.report.recomputed_patches += outcomes.iter().filter(|o| o.is_none()).count();
        self.spares = job.spares.into_inner().unwrap_or_else(|e| e.into_inner());
        (outcomes, other)
    }

    /// Of the round's patches `jobs` (with their place in it) and their
    /// `outcomes`, those that read outside their view's tiles but not
    /// outside their reach, computed again over views of their reach
    /// before any of them is accepted (no patch accepted before reads or
    /// writes their tiles, so the same outcome as over them first).
    pub(super) fn recompute_narrow<'j, F>(
        &self,
        context: &Context<'_>,
        jobs: impl Iterator<Item = (usize, &'j Job)>,
        outcomes: &mut [Option<Result<Outcome>>],
        f: &F,
    ) where
        F: Fn(&mut Worker<'_>, u32) -> Result<Outcome> + Sync,
    {
        for ((j, w), o) in jobs.zip(outcomes) {
            if o.is_none() && w.narrow.is_some() {
                *o = context.run(j, w, self.surface.view(&w.tiles), self.state.view(&w.tiles), f);
            }
        }
    }

    /// A work patch's memory in flight by the texels of its traversal: the
    /// largest matcher's buffers and what its largest match held besides
    /// them ([`Matcher::match_bytes`]), a whole rotated copy too large for
    /// its cache ([`Sample::uncached_bytes`](super::sample::Sample::uncached_bytes)),
    /// and [`bytes_per_texel`] per texel.
    pub(super) fn patch_bytes(&self) -> impl Fn(usize) -> u64 {
        let buffers = self
            .spares
            .iter()
            .map(|(m, _)| m.match_bytes())
            .chain([self.matcher.match_bytes()])
            .max()
            .unwrap_or(0) as u64
            + self.sample.uncached_bytes();
        let per_texel = bytes_per_texel(self.sample.n);
        move |texels| buffers + per_texel * texels as u64
    }

    /// Divides `--memory` once matching has sized the matchers' buffers
    /// (before that the work patches in flight keep their whole share):
    /// the patches in flight get what as many as may run at once need (one
    /// per thread, at most a round; traversals taken half again as large
    /// as `traversal`, the first one's), up to their share of
    /// [`LOOP_SHARES`](super::synthesis); the rotated copies and the sample
    /// spectra split what the atlas leaves. Budgets never change the quilt.
    pub(super) fn settle_memory(&mut self, traversal: usize) {
        let patch = self.patch_bytes();
        if patch(0) == 0 {
            return;
        }
        let [_, _, atlas, patches] = self.loop_budget.split(super::synthesis::LOOP_SHARES);
        let at_once = rayon::current_num_threads().min(self.cfg.round).max(1) as u64;
        // the loop's own matcher and one per patch at once, all sized
        self.release_idle = (at_once + 1) * patch(0) > patches.bytes();
        let budget = (at_once * patch(traversal + traversal / 2)).min(patches.bytes());
        if budget == self.patch_budget {
            return;
        }
        self.patch_budget = budget;
        let caches = (self.loop_budget.bytes())
            .saturating_sub(atlas.bytes() + budget)
            .max(2 << 20)
            / 2;
        self.sample
            .set_rotated_budget(crate::container::MemoryBudget(caches));
        self.matcher.set_cache_budget(caches as usize);
    }

    /// Frees the loop's own matcher's buffers before a round's patches
    /// take matchers of their own, when memory does not hold them all
    /// ([`Synthesis::release_idle`]).
    pub(super) fn idle_main_matcher(&mut self) {
        if self.release_idle {
            self.matcher.release_buffers();
        }
    }

    /// How many of `jobs` to compute at once: one per thread, fewer when
    /// the work patches in flight would need more than their share of the
    /// loop's budget ([`Synthesis::settle_memory`]; each: the matcher's
    /// buffers and [`bytes_per_texel`] per texel of the largest
    /// traversal), and how many memory would hold. How many run at once
    /// never changes the quilt.
    fn at_once(&self, jobs: &[Job]) -> (usize, usize) {
        let texels = jobs.iter().map(|j| j.ball.texels.len()).max().unwrap_or(0);
        let patch = self.patch_bytes()(texels);
        let by_memory = (self.patch_budget / patch.max(1)).max(1) as usize;
        (
            rayon::current_num_threads().min(jobs.len()).min(by_memory),
            by_memory,
        )
    }
}

/// A work patch's own memory per texel of its traversal, besides the
/// matcher's buffers: its work image, flattening, graph and max-flow, and
/// the tiles its views pin, for a sample of `channels` channels (the work
/// image and the fitting hold a few copies of them per texel). Measured on
/// Spot 4096² with the wall resampled to 768² (patches of radius 192,
/// 76–89 thousand texels, 3 channels, one allocator arena): a second patch
/// in flight raised the peak RSS by about 62 MB, its 12.5 MB of matcher
/// buffers included, about 580 bytes a texel. A program using the library
/// with glibc's per-thread arenas may hold more (each thread keeps what it
/// freed). Feature alignment adds three indices per old texel (its cell,
/// and the texels by cell: [`super::align`]), counted here for every
/// texel.
fn bytes_per_texel(channels: usize) -> u64 {
    512 + 3 * std::mem::size_of::<usize>() as u64 + 16 * channels as u64
}

/// The atlas tiles computing a work patch of `radius` at `v` may read (the
/// bounding boxes, per chart, of the texels within `radius` + 2 hops, grown
/// by one texel), and that traversal (its texels within `radius` hops, in
/// order, are the work patch). Both depend on the surface alone.
fn reach(bfs: &mut Bfs, surface: &Surface, v: u32, radius: usize) -> (Vec<usize>, WorkPatch) {
    let ball = bfs.patch(surface, v, radius + 2);
    (reach_tiles(surface, &ball), ball)
}

/// [`reach`], or `None` where it would hold a tile marked in `used` — given
/// up as soon as the traversal meets a texel of such a tile (the tiles of
/// the traversal's texels are among those of its boxes).
fn reach_unless_used(
    bfs: &mut Bfs,
    surface: &Surface,
    v: u32,
    radius: usize,
    used: &[bool],
) -> Option<(Vec<usize>, WorkPatch)> {
    let grid = surface.grid();
    let ball = bfs.patch_unless(surface, v, radius + 2, |t| used[grid.locate(t).0])?;
    let tiles = reach_tiles(surface, &ball);
    (!tiles.iter().any(|&k| used[k])).then_some((tiles, ball))
}

/// The tiles of [`reach`] for its traversal `ball`.
fn reach_tiles(surface: &Surface, ball: &WorkPatch) -> Vec<usize> {
    let grid = surface.grid();
    // (chart, x0, y0, x1, y1)
    let mut boxes: Vec<(u32, usize, usize, usize, usize)> = Vec::new();
    for &t in &ball.texels {
        let (x, y) = grid.xy(t);
        let c = surface.chart(t);
        match boxes.iter_mut().find(|b| b.0 == c) {
            Some(b) => {
                b.1 = b.1.min(x);
                b.2 = b.2.min(y);
                b.3 = b.3.max(x);
                b.4 = b.4.max(y);
            }
            None => boxes.push((c, x, y, x, y)),
        }
    }
    let mut tiles = Vec::new();
    for &(_, x0, y0, x1, y1) in &boxes {
        let (tx0, ty0) = (x0.saturating_sub(1) / TILE, y0.saturating_sub(1) / TILE);
        let (tx1, ty1) = ((x1 + 1).min(grid.r - 1) / TILE, (y1 + 1).min(grid.r - 1) / TILE);
        for ty in ty0..=ty1 {
            tiles.extend((tx0..=tx1).map(|tx| ty * grid.across + tx));
        }
    }
    tiles.sort_unstable();
    tiles.dedup();
    tiles
}

/// The tiles a work patch's views hold first where its traversal crosses
/// charts (`None` inside one chart, whose work image reads the patch's
/// whole atlas box: its [`reach`]): across charts the work image reads only
/// the patch's texels, so the tiles of the traversal's texels and their
/// eight neighbours — far fewer than the charts' boxes, which a patch of
/// large radius spreads over hundreds of tiles. A patch that reads outside
/// them (one that shrinks into a single chart reads that chart's box) is
/// computed again over its reach before the round is accepted.
fn narrow_tiles(surface: &Surface, ball: &WorkPatch) -> Option<Vec<usize>> {
    let chart = ball.texels.first().map(|&t| surface.chart(t));
    if ball.texels.iter().all(|&t| Some(surface.chart(t)) == chart) {
        return None;
    }
    let grid = surface.grid();
    let last = grid.r as i64 - 1;
    let mut held = vec![false; grid.tiles()];
    for &t in &ball.texels {
        let (x, y) = grid.xy(t);
        for dy in -1..=1i64 {
            for dx in -1..=1i64 {
                let (cx, cy) = ((x as i64 + dx).clamp(0, last), (y as i64 + dy).clamp(0, last));
                held[cy as usize / TILE * grid.across + cx as usize / TILE] = true;
            }
        }
    }
    Some((0..held.len()).filter(|&k| held[k]).collect())
}

/// The texels of a traversal within `radius` hops with their depth, and the
/// largest such depth (the work patch's rim).
fn within(ball: &WorkPatch, radius: usize) -> (impl Iterator<Item = (u32, u16)> + '_, u16) {
    let rim = ball
        .depth
        .iter()
        .copied()
        .filter(|&d| d as usize <= radius)
        .max()
        .unwrap_or(0);
    let texels = ball
        .texels
        .iter()
        .zip(&ball.depth)
        .filter(move |&(_, &d)| d as usize <= radius)
        .map(|(&t, &d)| (t, d));
    (texels, rim)
}

/// Which texels of a taken work patch are done with (no seed there is
/// taken again).
#[derive(Clone, Copy)]
enum Done {
    /// More than two hops inside the rim (seam refinement's core).
    Core,
    /// The seed and every texel inside the rim (painting).
    Inside,
}

/// Seeds taken in order, a round at a time, skipping those a taken patch
/// is done with: seam refinement's and painting's, which depend on the
/// surface alone.
struct Schedule<'a> {
    seeds: &'a [u32],
    next: usize,
    /// One bit per texel: open until a taken patch is done with it.
    open: Vec<u64>,
    done: Done,
    radius: usize,
    /// Seeds per round at most.
    round: usize,
}

impl Schedule<'_> {
    /// The next round: the next open seeds, in order, while their tiles
    /// are free (empty when every seed is taken), and how many open texels
    /// its patches closed.
    fn round(&mut self, bfs: &mut Bfs, lend: Lend) -> (Vec<Job>, usize) {
        let mut jobs: Vec<Job> = Vec::new();
        let mut closed = 0;
        let mut used = Vec::new();
        lend(&mut |surface| used = vec![false; surface.grid().tiles()]);
        while self.next < self.seeds.len() && jobs.len() < self.round {
            let v = self.seeds[self.next];
            if self.open[v as usize / 64] >> (v % 64) & 1 == 0 {
                self.next += 1;
                continue;
            }
            let (radius, mut job) = (self.radius, None);
            lend(&mut |surface| {
                if let Some((tiles, ball)) = reach_unless_used(bfs, surface, v, radius, &used) {
                    job = Some(Job::new(v, &tiles, ball, radius, surface));
                }
            });
            let Some(job) = job else { break };
            let (texels, rim) = within(&job.ball, self.radius);
            for (t, d) in texels {
                let done = match self.done {
                    Done::Core => d + 2 < rim,
                    Done::Inside => d < rim || t == v,
                };
                let bit = 1u64 << (t % 64);
                if done && self.open[t as usize / 64] & bit != 0 {
                    self.open[t as usize / 64] &= !bit;
                    closed += 1;
                }
            }
            for &k in &job.tiles {
                used[k] = true;
            }
            jobs.push(job);
            self.next += 1;
        }
        (jobs, closed)
    }
}

/// The whole surface lent for one piece of work at a time (while a round
/// is computed, under the lock its tasks make views under).
type Lend<'a> = &'a dyn Fn(&mut dyn FnMut(&Surface));

/// `surface` lent whole, where no other thread reads it.
fn lent(surface: &Surface) -> impl Fn(&mut dyn FnMut(&Surface)) + '_ {
    move |f| f(surface)
}

#[cfg(test)]
mod tests;
