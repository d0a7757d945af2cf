//! The quilting loop's working set and its steps (section III-B, Fig. 4):
//! picking the next work patch, matching, fitting, seam refinement, and the
//! state painting starts from.

use std::path::{Path, PathBuf};
use std::time::Instant;

use super::fit::{apply, fit_patch, Fit, INFINITE};
use super::flatten::rotation_index;
use super::matching::Matcher;
use super::occurrence::Occurrence;
use super::pager::TileGrid;
use super::placement::{to_sample, PlacementChoice};
use super::sample::{basis_projection, dist, dot_f32, sample_svd, Sample, SizedSample};
use super::state::{Bfs, State, Surface, WorkPatch, NO_FOREIGN};
use super::worker::{Outcome, StepStats, Worker};
use super::write::write_quilt;
use super::{TileConfig, TileReport};
use crate::artifact::gim::{Gim, EMPTY, TILE};
use crate::artifact::quilt::{Quilt, MAX_SAMPLES, NO_PATCH};
use crate::artifact::svd::SvdArtifact;
use crate::container::MemoryBudget;
use crate::io::staging::same_file;
use crate::progress::Progress;
use crate::{Error, Result};

/// The quilting loop's working set: the surface, the sample, the synthesis
/// state and the reusable buffers. [`tile`](super::tile) runs it from an empty surface;
/// painting (`crate::paint`) from a decorated one with a constraint.
pub(crate) struct Synthesis {
    pub(super) cfg: TileConfig,
    pub(super) sample_path: PathBuf,
    /// Every sample the surface draws from ([`Quilt::samples`]); the active
    /// one is `sample_paths[state.active]`.
    pub(super) sample_paths: Vec<PathBuf>,
    /// The preview colours of the other samples a loaded surface draws
    /// from (by index; `None` for the active one and unused ones).
    pub(super) other_previews: Vec<Option<crate::io::imageio::RgbImage>>,
    pub(super) surface: Surface,
    pub(super) zipper_triangles: Vec<[u32; 3]>,
    pub(super) sample: Sample,
    pub(super) state: State,
    pub(super) bfs: Bfs,
    pub(super) matcher: Matcher,
    /// Matchers (sharing `matcher`'s spectrum cache) and traversals of work
    /// patches computed at once ([`super::rounds`]).
    pub(super) spares: Vec<(Matcher, Bfs)>,
    /// Seam refinement's patches per round ([`super::rounds::REFINE_ROUND`]).
    pub(crate) refine_round: usize,
    /// How often each sample region shows on the surface (tiling only).
    pub(super) occurrence: Occurrence,
    /// The sample's mean neighbour difference, the unit of T_c.
    pub(super) reference: f64,
    pub(crate) report: TileReport,
    /// Painting (§IV): one min-cut per fitting, no T_c shrinking, and a
    /// fitting may keep every old value.
    pub(crate) painting: bool,
    pub(super) seam_sum: f64,
    pub(super) seam_cnt: usize,
    /// Original sample pixels per pixel of the (resampled) sample the loop
    /// works in; the quilt stores coordinates in original pixels.
    pub(super) scale: [f64; 2],
    /// The original sample's size in pixels.
    pub(super) original_size: [usize; 2],
    /// Mesh units each sample's width spans, where one was given (by index
    /// like `sample_paths`; the active one's is `active_span`).
    pub(super) sample_spans: Vec<Option<f64>>,
    pub(super) active_span: Option<f64>,
}

impl Synthesis {
    /// Opens the geometry image and the sample's `.svd`, with an empty state
    /// whose evicted tiles go to a scratch store beside `output`. Without
    /// `matching` (verbatim copy) the rotated copies are not needed:
    /// rotations are then quantized to the default 72 steps.
    pub(crate) fn open(
        gim: &Gim,
        sample_path: &Path,
        svd_path: &Path,
        output: &Path,
        cfg: &TileConfig,
        matching: bool,
    ) -> Result<Self> {
        // --memory is shared by the stores of the loop: the rotated copies
        // as f32, the sample spectra of the matcher and the paged atlas
        // (surface and state tiles) a quarter each; the .svd's decoded
        // tiles are only passed through (the loop reads the maps and each
        // rotated copy into the sample whole), so its cache is 2 MiB; the
        // work patch's own buffers come on top
        let [tiles, _, _, atlas] = cfg.memory.split([1, 1, 1, 1]);
        let quarter = MemoryBudget(tiles.bytes().max(1 << 20));
        let [surface_budget, state_budget] = atlas.split([8, 11]);
        let svd = SvdArtifact::open(svd_path, MemoryBudget(quarter.bytes().min(2 << 20)))?;
        if matching && svd.rotations == 0 {
            return Err(Error::input(
                sample_path,
                "has no rotated copies (factorize with --rotations 72)",
            ));
        }
        let sample = Sample::from_svd(svd, quarter)?;
        let occurrence = Occurrence::new(sample.width, sample.height, sample.tileable, sample.rotations);
        let n = sample.n;
        let surface = Surface::open(gim, surface_budget)?;
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
            matcher: Matcher::with_cache_budget(quarter.bytes() as usize),
            spares: Vec::new(),
            refine_round: super::rounds::REFINE_ROUND,
            occurrence,
            reference,
            report: TileReport {
                texels: total,
                ..TileReport::default()
            },
            original_size,
            surface,
            painting: false,
            seam_sum: 0.0,
            seam_cnt: 0,
            scale: [1.0, 1.0],
            sample_spans: vec![None],
            active_span: None,
        })
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

    /// Starts from a decorated surface: its coordinates, rotations, patch
    /// ids, Jacobians and sample indices. The features are looked up in each
    /// texel's own sample; texels of another sample than the one opened
    /// (painting with a new sample) are projected into its basis, g ↦ P_aᵀ
    /// P_k g (both appearance bases orthonormal, so this is the closest
    /// vector of the active rank-n space to the texel's value), and count as
    /// background (m_σ = 0). The opened sample joins the surface's list if
    /// it is new.
    pub(crate) fn load(&mut self, quilt: &Quilt, progress: &dyn Progress) -> Result<()> {
        let r = self.surface.r;
        if quilt.resolution != r {
            return Err(Error::input(
                quilt.container().path(),
                format!("is {}² but its geometry image is {r}²", quilt.resolution),
            ));
        }
        let mut paths = quilt.samples.clone();
        let active = match paths.iter().position(|p| same_file(p, &self.sample_path)) {
            Some(k) => k,
            None if paths.len() < MAX_SAMPLES => {
                paths.push(self.sample_path.clone());
                paths.len() - 1
            }
            None => {
                return Err(Error::input(
                    quilt.container().path(),
                    format!("already draws from {MAX_SAMPLES} samples, the most one surface can"),
                ))
            }
        };
        // the other samples in use, with their projections into the active basis
        let grid = self.surface.grid();
        let mut others: Vec<Option<(Sample, Vec<f32>)>> = (0..paths.len()).map(|_| None).collect();
        let mut previews = vec![None; paths.len()];
        let mut used = vec![false; paths.len()];
        for k in 0..grid.tiles() {
            let (x0, y0, w, h) = grid.region(k);
            let region = quilt.texel_region(x0, y0, w, h)?;
            for (&p, &s) in region.patch.iter().zip(&region.sample) {
                used[s as usize] |= p != NO_PATCH;
            }
        }
        let active_p = self.sample.svd.appearance()?;
        for k in (0..paths.len()).filter(|&k| used[k] && k != active) {
            let (svd_path, _tmp) = sample_svd(&paths[k], false, progress)?;
            let svd = SvdArtifact::open(&svd_path, self.cfg.memory)?;
            crate::artifact::svd::same_directions(&self.sample.svd, &svd)?;
            let projection =
                basis_projection(&active_p, self.sample.svd.terms, &svd.appearance()?, svd.terms);
            previews[k] = Some(svd.preview()?);
            // only their unrotated maps are read: no rotated copy is cached
            others[k] = Some((Sample::from_svd(svd, MemoryBudget(0))?, projection));
        }
        let n = self.state.n;
        let mut scratch = Vec::new();
        let [sx, sy] = self.scale;
        let scaled = self.scale != [1.0, 1.0];
        self.state.active = active as u8;
        self.state.remaining = 0;
        let mut next = 0u32;
        for k in 0..grid.tiles() {
            let (x0, y0, w, h) = grid.region(k);
            let q = quilt.texel_region(x0, y0, w, h)?;
            let chart = self.surface.chart_tile(k);
            let (sample, st) = (&self.sample, &mut self.state);
            // (held alone while loading: taken out without a copy)
            let held = std::mem::take(&mut st.foreign_features);
            let mut foreign_features = std::sync::Arc::try_unwrap(held).unwrap_or_else(|a| a.to_vec());
            let loaded = st.tile_mut(k, |s| -> Result<()> {
                for y in 0..h {
                    for x in 0..w {
                        let (i, j) = (y * TILE + x, y * w + x);
                        if chart[i] == EMPTY {
                            continue;
                        }
                        if q.patch[j] == NO_PATCH {
                            return Err(Error::input(
                                quilt.container().path(),
                                "is not fully decorated (texels without a patch)",
                            ));
                        }
                        s.synthesized[i] = true;
                        s.coord[i] = q.coord[j];
                        s.rotation[i] = q.rotation[j];
                        s.patch[i] = q.patch[j];
                        s.jacobian[i] = q.jacobian[j];
                        if q.sample[j] as usize == active && scaled {
                            // the file holds original sample pixels; the loop
                            // works in the resampled sample's
                            let (c, jc) = (q.coord[j], q.jacobian[j]);
                            s.coord[i] = [(c[0] as f64 / sx) as f32, (c[1] as f64 / sy) as f32];
                            s.jacobian[i] = [
                                (jc[0] as f64 / sx) as f32,
                                (jc[1] as f64 / sy) as f32,
                                (jc[2] as f64 / sx) as f32,
                                (jc[3] as f64 / sy) as f32,
                            ];
                        }
                        s.source[i] = q.sample[j];
                        next = next.max(q.patch[j] + 1);
                        let c = [s.coord[i][0] as f64, s.coord[i][1] as f64];
                        match &others[q.sample[j] as usize] {
                            None => {
                                s.foreign[i] = NO_FOREIGN;
                                s.mask[i] = sample.mask_at(c);
                            }
                            Some((other, projection)) => {
                                scratch.clear();
                                scratch.resize(other.n, 0f32);
                                other.lookup(c, &mut scratch);
                                s.foreign[i] = (foreign_features.len() / n) as u32;
                                for a in 0..n {
                                    let v = dot_f32(&projection[a * other.n..(a + 1) * other.n], &scratch);
                                    foreign_features.push(v);
                                }
                                s.mask[i] = 0.0;
                            }
                        }
                    }
                }
                Ok(())
            });
            st.foreign_features = std::sync::Arc::new(foreign_features);
            loaded?;
            self.state.refresh_frontier(&self.surface, &[k]);
        }
        let st = &mut self.state;
        st.next_patch = next;
        self.sample_spans = (0..paths.len())
            .map(|k| {
                match quilt
                    .container()
                    .metadata()
                    .param(&format!("{}_span", sample_role(k)))
                {
                    Some(crate::container::Param::Float(v)) => Some(*v),
                    _ => None,
                }
            })
            .collect();
        self.sample_paths = paths;
        self.other_previews = previews;
        Ok(())
    }

    /// Writes the state as a `.quilt` (see [`tile`](super::tile)); `paint_log` for a
    /// painted surface.
    pub(crate) fn write(
        &mut self,
        out: &Path,
        gim: &Gim,
        gim_path: &Path,
        paint_log: Option<&str>,
        start: Instant,
    ) -> Result<TileReport> {
        self.finish_report(start);
        let report = self.report.clone();
        write_quilt(out, &self.cfg, gim, gim_path, self, paint_log, &report)?;
        Ok(report)
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

    /// Seam refinement (Kwatra et al. 2003, §3.3, "patch placement on
    /// seams"): once the surface is covered, the visible seams — edges of
    /// the dense graph (grid edges and zipper links) across patches whose
    /// step exceeds `step` × the sample's neighbour difference — each get
    /// one more work patch of radius `radius` centred on them, matched
    /// against the finished surface, whose core (3 hops around the seam)
    /// must take the new values; the graphcut with seam nodes then places
    /// the new seams, and the fitting is kept only if its cut costs less
    /// than 0.9 × the old seams it replaces. Returns how many were kept.
    /// Seams already inside a refined patch are not visited again. The seams
    /// are visited in [`visit_order`], which keeps the tiles a round reads
    /// few. With `broken_placements` > 0, seams where a feature ends
    /// ([`super::BROKEN_CONTINUATION`]) are visited too, whatever their
    /// step, and fitted with that many placements: the one whose cut ends
    /// fewest features at the patch's seams ([`super::ends`]) is chosen, and
    /// kept if it ends fewer than before at a cut under
    /// [`super::ENDS_DEARER`] × the old seams' cost (or as many, at under
    /// 0.9×). With `step` infinite only those seams are visited.
    pub(crate) fn refine(
        &mut self,
        radius: usize,
        step: f64,
        broken_placements: usize,
        progress: &dyn Progress,
    ) -> Result<usize> {
        let (seeds, broken) = self.seams_to_refine(step, broken_placements > 0);
        let grid = self.surface.grid();
        let seeds = visit_order(&grid, seeds, REFINE_RUNS);
        let base = self.cfg.refine_placements;
        let placements = |v: u32| {
            if broken.binary_search(&v).is_ok() {
                (broken_placements, true)
            } else {
                (base, false)
            }
        };
        self.refine_seeds(&seeds, radius, &placements, progress)
    }

    /// The seams [`Synthesis::refine`] visits: (the seam's step, texel) for
    /// each texel with a neighbour of another patch whose colour step is
    /// over `step` sample neighbour differences, or (with `broken`) where a
    /// feature ends: one side's patch, continued one texel across, differs
    /// from the other side by more than [`super::BROKEN_CONTINUATION`] of
    /// them. Also those feature ends alone, ascending.
    fn seams_to_refine(&self, step: f64, find_broken: bool) -> (Vec<(f64, u32)>, Vec<u32>) {
        let n = self.state.n;
        let (mut fa, mut fb, mut fc) = (vec![0f32; n], vec![0f32; n], vec![0f32; n]);
        let mut seeds: Vec<(f64, u32)> = Vec::new();
        // seams where a feature ends, ascending
        let mut broken: Vec<u32> = Vec::new();
        let mut across: Vec<(u32, bool)> = Vec::with_capacity(8);
        let grid = self.surface.grid();
        // tile by tile (the seeds are sorted after)
        for t in (0..grid.tiles()).flat_map(|k| {
            let (x0, y0, w, h) = grid.region(k);
            (0..h).flat_map(move |y| (0..w).map(move |x| ((y0 + y) * grid.r + x0 + x) as u32))
        }) {
            if !self.surface.covered(t) {
                continue;
            }
            // seams inside charts and across zippers alike: a seam that runs
            // along a chart border is as visible as any other
            across.clear();
            let own = self.state.patch(t);
            self.surface.for_each_neighbour(t, |nb, zipper| {
                if nb > t && self.state.patch(nb) != own {
                    across.push((nb, zipper));
                }
            });
            if across.is_empty() {
                continue;
            }
            self.state.feature_into(&self.sample, t, &mut fa);
            let (mut worst, mut ends) = (0f64, 0f64);
            for &(nb, zipper) in &across {
                self.state.feature_into(&self.sample, nb, &mut fb);
                worst = worst.max(dist(&fa, &fb));
                // grid edges: each side continued one texel across against
                // what the other shows (zipper links have no common step)
                let along = super::ends::step(t, nb, grid.r, zipper);
                if let (true, Some(d)) = (find_broken, along) {
                    let gap = super::ends::gap(&fa, &fb, &mut fc, |back, out| match back {
                        false => self.state.continued(&self.sample, t, d, out),
                        true => self.state.continued(&self.sample, nb, (-d.0, -d.1), out),
                    });
                    ends = ends.max(gap);
                }
            }
            if ends > super::BROKEN_CONTINUATION * self.reference {
                broken.push(t);
                seeds.push((worst.max(ends), t));
            } else if worst > step * self.reference {
                seeds.push((worst, t));
            }
        }
        broken.sort_unstable();
        (seeds, broken)
    }

    /// Records an accepted fitting under the next patch id.
    pub(super) fn accept(&mut self, patch: &WorkPatch, fit: &Fit, progress: &dyn Progress) {
        ledger!(self).accept(&mut self.state, &self.surface, patch, fit, progress);
    }

    /// Verbatim copy (§IV): the sample's foreground, its point `centre`
    /// (unrotated sample pixels) put on dense vertex `v`, turned by `angle`
    /// (radians) from the field direction, over a work patch of `radius`.
    /// With `preview`, only computes the direct projection (no graphcut: the
    /// foreground pasted over the old colours in the patch's atlas box) and
    /// returns it; otherwise merges it with a graphcut seam: foreground
    /// texels are forced to the copy, the rest chooses by the smoothness
    /// term. Returns the foreground texels the copy covers.
    pub(crate) fn verbatim(
        &mut self,
        v: u32,
        radius: usize,
        angle: f64,
        centre: [f64; 2],
        preview: bool,
        progress: &dyn Progress,
    ) -> Result<(usize, Option<Projection>)> {
        let t0 = Instant::now();
        let trace = |what: &str| crate::progress::trace(progress, t0, &format!("verbatim {what}"));
        let patch = self.bfs.patch(&self.surface, v, radius);
        trace("work patch");
        // (a preview reads only the work coordinates)
        let (work, coords, field) = if preview {
            let (coords, field) = super::flatten::work_coords(
                &self.surface,
                &patch,
                &self.bfs,
                &self.zipper_triangles,
                self.cfg.max_distortion,
            );
            (None, coords, field)
        } else {
            let (work, _) = self.worker().work_image(&patch, &mut None);
            let (coords, field) = (work.coords.clone(), work.angle);
            (Some(work), coords, field)
        };
        trace("work image");
        let rotations = self.sample.rotations;
        let rotation = rotation_index(field + angle, rotations);
        let theta = rotation as f64 * std::f64::consts::TAU / rotations as f64;
        let (s, c) = theta.sin_cos();
        let mid = [
            (self.sample.width as f64 - 1.0) / 2.0,
            (self.sample.height as f64 - 1.0) / 2.0,
        ];
        let d = [centre[0] - mid[0], centre[1] - mid[1]];
        let q = [c * d[0] - s * d[1], s * d[0] + c * d[1]];
        let placement = PlacementChoice {
            rotation,
            dx: coords[0][0] - mid[0] - q[0],
            dy: coords[0][1] - mid[1] - q[1],
        };
        let placed: Vec<[f64; 2]> = coords
            .iter()
            .map(|&w| to_sample(&self.sample, rotation, placement.dx, placement.dy, w))
            .collect();
        let fg: Vec<f32> = placed.iter().map(|&c| self.sample.mask_at(c)).collect();
        trace("placed");
        if preview {
            let colours = self.sample.svd.preview()?;
            let r = self.surface.r;
            let (x0, y0, w, h) = patch.atlas_box(r);
            let mut data = vec![0f32; w * h * 3];
            let mut covered = vec![false; w * h];
            // the surface as it is, a state tile at a time
            let grid = self.surface.grid();
            let (ty0, ty1) = (y0 / TILE, (y0 + h - 1) / TILE);
            let (tx0, tx1) = (x0 / TILE, (x0 + w - 1) / TILE);
            for k in (ty0..=ty1).flat_map(|ty| (tx0..=tx1).map(move |tx| ty * grid.across + tx)) {
                let (kx, ky, kw, kh) = grid.region(k);
                let (ax0, ax1) = (kx.max(x0), (kx + kw).min(x0 + w));
                let (ay0, ay1) = (ky.max(y0), (ky + kh).min(y0 + h));
                self.state.tile(k, |s| {
                    for ay in ay0..ay1 {
                        for ax in ax0..ax1 {
                            let i = (ay - ky) * TILE + (ax - kx);
                            if !s.synthesized[i] {
                                continue;
                            }
                            let c = s.coord[i];
                            let from = self.other_previews.get(s.source[i] as usize);
                            let col = crate::io::imageio::bilinear(
                                from.and_then(Option::as_ref).unwrap_or(&colours),
                                c[0],
                                c[1],
                            );
                            let o = (ay - y0) * w + ax - x0;
                            data[o * 3..o * 3 + 3].copy_from_slice(&col);
                            covered[o] = true;
                        }
                    }
                });
            }
            for (i, &t) in patch.texels.iter().enumerate() {
                if fg[i] >= 0.5 {
                    let (x, y) = (t as usize % r - x0, t as usize / r - y0);
                    let col =
                        crate::io::imageio::bilinear(&colours, placed[i][0] as f32, placed[i][1] as f32);
                    data[(y * w + x) * 3..(y * w + x) * 3 + 3].copy_from_slice(&col);
                    covered[y * w + x] = true;
                }
            }
            trace("projected");
            let image = crate::io::imageio::RgbImage {
                width: w,
                height: h,
                data,
            };
            let taken = fg.iter().filter(|&&m| m >= 0.5).count();
            return Ok((
                taken,
                Some(Projection {
                    x0,
                    y0,
                    image,
                    covered,
                }),
            ));
        }
        // m0 = the placed foreground on the patch, 0 elsewhere
        self.state.constrain_everywhere(0.0);
        for (i, &t) in patch.texels.iter().enumerate() {
            self.state.texel_mut(t, |s, k| s.target[k] = fg[i]);
        }
        let work = work.expect("a merge has its work image");
        let t = Instant::now();
        let fit = fit_patch(
            &self.sample,
            &self.state,
            &self.surface,
            &patch,
            &work,
            &placement,
            INFINITE.sqrt(),
            false,
            0,
            (0.0, self.reference),
        );
        self.report.graphcut_seconds += t.elapsed().as_secs_f64();
        self.accept(&patch, &fit, progress);
        Ok((fit.taken, None))
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

/// The role under which a quilt records sample `k`: `sample` for the
/// tiling's, `sample_K` for one painted in.
pub(crate) fn sample_role(k: usize) -> String {
    if k == 0 {
        "sample".to_string()
    } else {
        format!("sample_{k}")
    }
}

/// Runs of [`visit_order`]: enough for a refinement round
/// ([`super::rounds::REFINE_ROUND`]) to hold about half as many patches.
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

#[cfg(test)]
mod tests {
    use super::{visit_order, Synthesis};
    use crate::artifact::gim::{Gim, TILE};
    use crate::container::MemoryBudget;
    use crate::progress::Silent;
    use crate::quilt::ends::broken_around;
    use crate::quilt::pager::TileGrid;
    use crate::quilt::state::NO_FOREIGN;
    use crate::quilt::TileConfig;

    /// A flat square atlased at 64² that shows a sample of horizontal
    /// mortar lines (2 rows of every 8) as one patch, except where `other`
    /// (x, y) holds, which shows it as another patch, moved down by
    /// `offset` rows; and how many texels of column 31 there are.
    fn halves(offset: f32, other: impl Fn(f32, f32) -> bool) -> (tempfile::TempDir, Synthesis, usize) {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path();
        let obj = d.join("square.obj");
        std::fs::write(&obj, "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nf 1 2 3\nf 1 3 4\n").unwrap();
        let gim_path = d.join("square.gim");
        let atlas = crate::atlas::AtlasConfig {
            resolution: 64,
            ..crate::atlas::AtlasConfig::default()
        };
        crate::atlas::build_gim(&obj, &gim_path, &atlas, &Silent).unwrap();
        let size = 96;
        let img = crate::io::imageio::RgbImage {
            width: size,
            height: size,
            data: (0..size * size)
                .flat_map(|i| [if (i / size) % 8 < 2 { 0.9f32 } else { 0.1 }; 3])
                .collect(),
        };
        let png = d.join("courses.png");
        crate::io::imageio::write_rgb(&png, &img).unwrap();
        let gim = Gim::open(&gim_path, MemoryBudget(1 << 20)).unwrap();
        let sized =
            super::super::sample::sample_at_density(&png, gim.texel_size, None, true, &Silent).unwrap();
        let cfg = TileConfig::default();
        let mut syn = Synthesis::open(&gim, &png, &sized.svd, &d.join("out.quilt"), &cfg, true).unwrap();
        let r = syn.surface.r;
        let mut seam_rows = 0;
        for t in 0..(r * r) as u32 {
            if !syn.surface.covered(t) {
                continue;
            }
            let (x, y) = ((t as usize % r) as f32, (t as usize / r) as f32);
            let right = other(x, y);
            seam_rows += (x == 31.0) as usize;
            syn.state.texel_mut(t, |s, k| {
                s.synthesized[k] = true;
                s.coord[k] = [x + 8.0, y + 8.0 + if right { offset } else { 0.0 }];
                s.jacobian[k] = [1.0, 0.0, 0.0, 1.0];
                s.patch[k] = right as u32;
                s.source[k] = 0;
                s.foreign[k] = NO_FOREIGN;
            });
        }
        syn.state.next_patch = 2;
        (dir, syn, seam_rows)
    }

    /// The seams [`Synthesis::seams_to_refine`] finds between [`halves`]
    /// with and without looking for feature ends (step 1000: none by
    /// colour step).
    fn seams_between_halves(offset: f32) -> (Vec<u32>, usize, usize) {
        let (_dir, syn, seam_rows) = halves(offset, |x, _| x >= 32.0);
        let r = syn.surface.r;
        let (by_step, _) = syn.seams_to_refine(1000.0, false);
        let (seeds, broken) = syn.seams_to_refine(1000.0, true);
        assert!(by_step.is_empty(), "no colour step is that large");
        assert_eq!(seeds.iter().map(|s| s.1).collect::<Vec<_>>(), broken);
        (broken, seam_rows, r)
    }

    #[test]
    fn refinement_finds_the_mortar_lines_that_end_at_a_seam() {
        // half a period down: every mortar line of the left half meets
        // brick on the right and the other way round, on the seam's column
        let (broken, seam_rows, r) = seams_between_halves(4.0);
        assert!(broken.iter().all(|&t| t as usize % r == 31), "on the seam only");
        // two mortar rows of every 8 on each side end there: half the
        // seam's rows (give or take the rows blurred across a line's edge)
        let rows = broken.len();
        assert!(
            rows * 2 >= seam_rows - 4 && rows * 2 <= seam_rows + 8,
            "{rows} of {seam_rows} rows"
        );
        // a whole period down, or none: the lines run on, nothing is broken
        for offset in [0.0, 8.0] {
            let (broken, _, _) = seams_between_halves(offset);
            assert!(broken.is_empty(), "offset {offset}: {broken:?}");
        }
    }

    /// Refinement where features end predicts, for the cut it chooses, the
    /// features ending at the patch's seams once it is accepted: the count
    /// over the changed surface is the one predicted, and it is lower than
    /// before around an island of courses offset by half a period.
    #[test]
    fn refinement_counts_the_features_its_cut_would_end() {
        let island = |x: f32, y: f32| (x - 31.0).powi(2) + (y - 30.0).powi(2) < 100.0;
        let (_dir, mut syn, _) = halves(4.0, island);
        let r = syn.surface.r;
        let limit = crate::quilt::BROKEN_CONTINUATION * syn.reference;
        // on the island's edge
        let v = (30 * r + 41) as u32;
        let outcome = syn.worker().refinement(v, 8, (4, true), 3).unwrap();
        let (before, after) = outcome.fit.ends.expect("counted");
        let count = |syn: &Synthesis, patch| {
            broken_around(
                &syn.sample,
                &syn.state,
                &syn.surface,
                &syn.bfs,
                patch,
                None,
                limit,
            )
        };
        assert_eq!(count(&syn, &outcome.patch), before, "the surface as it is");
        assert!(before > 0 && after < before, "{before} → {after}");
        syn.accept(&outcome.patch, &outcome.fit, &Silent);
        assert_eq!(
            count(&syn, &outcome.patch),
            after,
            "the surface once the patch is accepted"
        );
    }

    #[test]
    fn seams_are_visited_once_each_by_runs_that_walk_the_tiles() {
        let grid = TileGrid::new(4 * TILE);
        // as many seeds in every tile, steps in a scrambled order
        let seeds: Vec<(f64, u32)> = (0..grid.r * grid.r)
            .filter(|&t| grid.locate(t as u32).1 % 7 == 0)
            .map(|t| (((t * 7919) % 1000) as f64, t as u32))
            .collect();
        let order = visit_order(&grid, seeds.clone(), 4);
        let mut sorted = order.clone();
        sorted.sort_unstable();
        let mut expect: Vec<u32> = seeds.iter().map(|s| s.1).collect();
        expect.sort_unstable();
        assert_eq!(sorted, expect, "every seed once");
        let tile = |t: u32| grid.locate(t).0;
        // the four runs take turns: neighbours in the order are a quarter
        // of the atlas apart, each run is one quarter in Z order
        let quarter = |t: u32| {
            let (x, y) = grid.xy(t);
            (y / (2 * TILE)) * 2 + x / (2 * TILE)
        };
        for (i, w) in order.chunks(4).enumerate() {
            let q: Vec<usize> = w.iter().map(|&t| quarter(t)).collect();
            assert_eq!(q, vec![0, 1, 2, 3], "turn {i}");
        }
        // within a run, tiles change rarely and steps fall within a tile
        let run: Vec<u32> = order.iter().step_by(4).copied().collect();
        let changes = run.windows(2).filter(|w| tile(w[0]) != tile(w[1])).count();
        assert_eq!(changes, 3, "a run visits its four tiles one after another");
        let step = |t: u32| seeds.iter().find(|s| s.1 == t).expect("a seed").0;
        assert!(run
            .windows(2)
            .all(|w| tile(w[0]) != tile(w[1]) || step(w[0]) >= step(w[1])));
    }
}
