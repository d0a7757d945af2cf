//! One work patch's computation (section III-B, Fig. 4, steps 2–5): the work
//! patch, its work image, patch matching and the graphcut fitting — every
//! read, no write. The synthesis accepts the outcome afterwards, so work
//! patches that share no atlas tile can be computed at once, each over views
//! of its own tiles ([`super::rounds`]).

use std::path::Path;
use std::time::Instant;

use super::config::TileConfig;
use super::ends::broken_around;
use super::fit::{fit_patch, Fit};
use super::flatten::{
    chart_work_image, flattened_work_image, locked_work_image, unfolded_work_image, Flattening, WorkImage,
    WorkInputs,
};
use super::matching::Matcher;
use super::occurrence::Occurrence;
use super::placement::{
    choose_placement, covering_candidates, distinct_best, lock_courses, place_covering, PlacementChoice,
    REFINE_SPACING,
};
use super::sample::Sample;
use super::state::{Bfs, State, Surface, WorkPatch};
use crate::math;
use crate::progress::Progress;
use crate::{Error, Result};

/// Time and retries of one work patch, added to the report when it is
/// accepted.
#[derive(Clone, Copy, Debug, Default)]
pub(super) struct StepStats {
    pub(super) shrinks: usize,
    pub(super) matching_seconds: f64,
    pub(super) graphcut_seconds: f64,
    /// Whether the seeded choice (and so the patch counter) decided a
    /// placement of seam refinement.
    pub(super) seeded: bool,
}

/// A computed work patch, not yet accepted: the patch, its fitting, and
/// whether its work image is the rigid unfolding.
pub(super) struct Outcome {
    pub(super) patch: WorkPatch,
    pub(super) fit: Fit,
    pub(super) unfolded: bool,
    pub(super) stats: StepStats,
}

/// What computing a work patch reads (the surface and state whole, or views
/// of some tiles) and the buffers it reuses.
pub(super) struct Worker<'a> {
    pub(super) surface: &'a Surface,
    pub(super) state: &'a State,
    pub(super) sample: &'a Sample,
    pub(super) zipper_triangles: &'a [[u32; 3]],
    pub(super) cfg: &'a TileConfig,
    pub(super) sample_path: &'a Path,
    /// The sample's mean neighbour difference, the unit of T_c.
    pub(super) reference: f64,
    /// Painting (§IV): one min-cut per fitting, no T_c shrinking.
    pub(super) painting: bool,
    /// The occurrence map matching penalizes with (tiling only).
    pub(super) occurrence: Option<&'a mut Occurrence>,
    pub(super) bfs: &'a mut Bfs,
    /// A traversal from the seed already made, and its radius: patches
    /// up to that radius are its prefixes ([`Bfs::prefix`]).
    pub(super) ball: Option<(&'a WorkPatch, usize)>,
    pub(super) matcher: &'a mut Matcher,
    /// The seeded choice's counter: patches accepted before this one.
    pub(super) counter: u64,
    pub(super) stats: StepStats,
}

impl Worker<'_> {
    /// The work patch of `radius` at `v` ([`Bfs::patch`]), from the
    /// traversal already made when there is one.
    fn patch_at(&mut self, v: u32, radius: usize) -> WorkPatch {
        match self.ball {
            Some((ball, r)) if ball.texels.first() == Some(&v) && radius <= r => {
                self.bfs.prefix(self.surface, ball, radius)
            }
            _ => self.bfs.patch(self.surface, v, radius),
        }
    }

    /// One step of the quilting loop (the paper's Fig. 4) at vertex `v`:
    /// work patch P(v) of radius r_w, work image I(v), patch matching,
    /// graphcut fitting, and the hierarchical search that shrinks r_w by 0.8
    /// (down to the minimum) while the seam cost exceeds T_c.
    pub(super) fn step(&mut self, v: u32, radius0: usize, progress: &dyn Progress) -> Result<Outcome> {
        let cfg = self.cfg;
        let mut radius = radius0;
        let mut flattening: Option<Flattening> = None;
        let painting = self.painting;
        // the rejected fitting with the lowest mean seam cost: if no radius
        // passes T_c, it is taken instead of the smallest patch (fewer,
        // larger pieces than always ending at r_w = 4)
        let mut best: Option<(f64, WorkPatch, Fit, bool)> = None;
        loop {
            let patch = self.patch_at(v, radius);
            let (work, unfolded) = self.work_image(&patch, &mut flattening);
            let fit = self.match_and_fit(&patch, &work, painting, 0)?;
            let mean = if fit.seam_edges > 0 {
                fit.seam_cost / fit.seam_edges as f64
            } else {
                0.0
            };
            // (painting takes its one min-cut per fitting: its seams must
            // cross the foreground's border where m0 demands it, which T_c
            // would read as a bad fit)
            let (mut patch, mut fit, mut unfolded) = (patch, fit, unfolded);
            if !painting && mean > cfg.seam_threshold * self.reference && fit.taken_new_synth > 0 {
                if radius > cfg.min_radius {
                    if best.as_ref().map_or(true, |b| mean < b.0) {
                        best = Some((mean, patch, fit, unfolded));
                    }
                    radius = ((radius as f64 * 0.8) as usize).max(cfg.min_radius);
                    self.stats.shrinks += 1;
                    continue;
                }
                if let Some(b) = best.take().filter(|b| b.0 < mean) {
                    if std::env::var_os("BTFQUILT_TRACE").is_some() {
                        progress.note(&format!("best of the radii: {:.3} instead of {mean:.3}", b.0));
                    }
                    (patch, fit, unfolded) = (b.1, b.2, b.3);
                }
            }
            if fit.taken == 0 && !painting {
                // nothing could be placed (sample too small for the work
                // image): shrink, or give up on this vertex at the minimum
                if radius > cfg.min_radius {
                    radius = ((radius as f64 * 0.8) as usize).max(cfg.min_radius);
                    self.stats.shrinks += 1;
                    continue;
                }
                let (sw, sh) = (self.sample.width, self.sample.height);
                return Err(Error::input(
                    self.sample_path,
                    format!("is too small ({sw}×{sh}) to cover a work patch of radius {radius}"),
                ));
            }
            if std::env::var_os("BTFQUILT_TRACE").is_some() {
                progress.note(&format!(
                    "patch {} v {v} radius {radius} texels {} taken {} cross {}",
                    self.counter,
                    patch.texels.len(),
                    fit.taken,
                    patch.crosses_charts
                ));
            }
            return Ok(Outcome {
                patch,
                fit,
                unfolded,
                stats: self.stats,
            });
        }
    }

    /// Seam refinement's work patch at `v` (see
    /// [`Synthesis::refine`](super::synthesis::Synthesis::refine)): the
    /// cheapest cut of the `placements` best covering placements, the core
    /// of `core` hops around the seam taking the new values.
    pub(super) fn refinement(
        &mut self,
        v: u32,
        radius: usize,
        (placements, by_ends): (usize, bool),
        core: u16,
    ) -> Result<Outcome> {
        let patch = self.patch_at(v, radius);
        let (work, _) = self.work_image(&patch, &mut None);
        let fit = self.best_of_placements(&patch, &work, placements, core, by_ends)?;
        Ok(Outcome {
            patch,
            fit,
            unfolded: false,
            stats: self.stats,
        })
    }

    /// Patch matching of the work image against the sample, then the
    /// graphcut fitting of the chosen placement ([`fit_patch`], which says
    /// what `keep_outside_target` and `core` do), timed into the stats.
    pub(super) fn match_and_fit(
        &mut self,
        patch: &WorkPatch,
        work: &WorkImage,
        keep_outside_target: bool,
        core: u16,
    ) -> Result<Fit> {
        let t = Instant::now();
        let occurrence = if self.painting {
            None
        } else {
            self.occurrence.as_deref_mut()
        };
        let placement = place_covering(
            self.sample,
            self.matcher,
            work,
            self.cfg,
            self.reference,
            occurrence,
            self.counter,
        )?;
        self.stats.matching_seconds += t.elapsed().as_secs_f64();
        let t = Instant::now();
        let fit = self.fit_placement(patch, work, &placement, keep_outside_target, core);
        self.stats.graphcut_seconds += t.elapsed().as_secs_f64();
        Ok(fit)
    }

    /// The graphcut fitting of one placement ([`fit_patch`]).
    pub(super) fn fit_placement(
        &self,
        patch: &WorkPatch,
        work: &WorkImage,
        placement: &PlacementChoice,
        keep_outside_target: bool,
        core: u16,
    ) -> Fit {
        let locked = lock_courses(self.sample, work, placement);
        let placement = locked.as_ref().unwrap_or(placement);
        fit_patch(
            self.sample,
            self.state,
            self.surface,
            patch,
            work,
            placement,
            self.cfg.constraint_weight * self.reference,
            keep_outside_target,
            core,
            // (where the field is constant, as on a flat square, neighbouring
            // patches are not turned against each other: nothing to align)
            (
                if self.painting || work.field_spread == 0.0 {
                    0.0
                } else {
                    self.cfg.feature_align
                },
                self.reference,
            ),
        )
    }

    /// Seam refinement's fitting: the graphcut of each of the `count` best
    /// covering placements ([`distinct_best`]), the one with the cheapest cut
    /// kept. A refinement has to beat the seams already there, and the
    /// cheapest match is not always the cheapest cut. With `by_ends` (a seam
    /// where a feature ends) the cut that ends fewest features at the
    /// patch's seams is kept, the cheapest among those, and [`Fit::ends`]
    /// says how many ended there before and would after.
    fn best_of_placements(
        &mut self,
        patch: &WorkPatch,
        work: &WorkImage,
        count: usize,
        core: u16,
        by_ends: bool,
    ) -> Result<Fit> {
        let t = Instant::now();
        let (rotation, covering) =
            covering_candidates(self.sample, self.matcher, work, self.cfg, self.reference, None)?;
        let mut picks: Vec<PlacementChoice> = distinct_best(&covering, count, REFINE_SPACING)
            .into_iter()
            .map(|p| PlacementChoice {
                rotation,
                dx: p.dx as f64,
                dy: p.dy as f64,
            })
            .collect();
        if picks.is_empty() {
            // no match covers the patch: the seeded spot the quilting step
            // would take
            self.stats.seeded = true;
            picks.push(choose_placement(
                self.sample,
                work,
                self.cfg,
                self.counter,
                rotation,
                &covering,
            ));
        }
        self.stats.matching_seconds += t.elapsed().as_secs_f64();
        let t = Instant::now();
        let mut best: Option<Fit> = None;
        let limit = super::config::BROKEN_CONTINUATION * self.reference;
        let around = |fit: Option<&Fit>| {
            broken_around(self.sample, self.state, self.surface, self.bfs, patch, fit, limit)
        };
        let before = by_ends.then(|| around(None));
        for placement in picks {
            let mut fit = self.fit_placement(patch, work, &placement, false, core);
            fit.ends = before.map(|b| (b, around(Some(&fit))));
            // fewest features ending at its seams, then the cheapest cut
            let rank = |f: &Fit| (f.ends.map_or(0, |e| e.1), f.flow);
            if best.as_ref().map_or(true, |b| rank(&fit) < rank(b)) {
                best = Some(fit);
            }
        }
        self.stats.graphcut_seconds += t.elapsed().as_secs_f64();
        Ok(best.expect("picks is not empty"))
    }

    /// The work image I(v) of a work patch: the chart image inside a chart;
    /// across charts the flattening (reused from `flattening` when the same
    /// seed's patch shrinks), or the rigid unfolding where that fails — and
    /// whether it is that unfolding.
    pub(super) fn work_image(
        &self,
        patch: &WorkPatch,
        flattening: &mut Option<Flattening>,
    ) -> (WorkImage, bool) {
        let (mut work, unfolded) = self.work_image_of(patch, flattening);
        // matching that may turn the sample and feature alignment read it
        if !self.painting && (self.cfg.field_turn > 0 || self.cfg.feature_align > 0.0) {
            work.field_spread = field_spread(self.surface, patch);
            // only the rotation climb reads it, where the field turns
            if work.field_spread > 0.0 && self.cfg.field_turn > 0 {
                work.neighbour_angle =
                    neighbour_angle(self.surface, self.state, patch, &self.bfs, &work.coords);
            }
        }
        (work, unfolded)
    }

    fn work_image_of(&self, patch: &WorkPatch, flattening: &mut Option<Flattening>) -> (WorkImage, bool) {
        let inputs = WorkInputs {
            surface: self.surface,
            sample: self.sample,
            state: self.state,
            bfs: &self.bfs,
            zipper_triangles: self.zipper_triangles,
            max_distortion: self.cfg.max_distortion,
        };
        let (surface, state, sample) = (self.surface, self.state, self.sample);
        if let Some(work) = locked_work_image(&inputs, patch) {
            return (work, false);
        }
        if !patch.crosses_charts {
            return (chart_work_image(surface, sample, state, patch), false);
        }
        if let Some(work) = flattening.as_ref().and_then(|f| f.work_image(&inputs, patch)) {
            return (work, false);
        }
        if let Some((work, coords)) = flattened_work_image(&inputs, patch) {
            let mut c: Vec<(u32, [f64; 2])> = patch.texels.iter().copied().zip(coords).collect();
            c.sort_unstable_by_key(|e| e.0);
            *flattening = Some(Flattening {
                coords: c,
                angle: work.angle,
            });
            return (work, false);
        }
        (
            unfolded_work_image(surface, sample, state, patch, &self.bfs),
            true,
        )
    }
}

/// How far the field turns inside a work patch: the circular standard
/// deviation √(−2 ln R) of the texels' field directions, R the mean
/// resultant length pooled over the patch's charts (each chart's
/// directions against its own mean: atlas angles compare only within a
/// chart). 0 where the field is constant.
fn field_spread(surface: &Surface, patch: &WorkPatch) -> f64 {
    // (chart, Σ cos, Σ sin) per chart met
    let mut sums: Vec<(u32, f64, f64)> = Vec::new();
    for &t in &patch.texels {
        let (c, a) = (surface.chart(t), surface.texel_angle(t));
        let k = match sums.iter().position(|e| e.0 == c) {
            Some(k) => k,
            None => {
                sums.push((c, 0.0, 0.0));
                sums.len() - 1
            }
        };
        sums[k].1 += math::cos(a);
        sums[k].2 += math::sin(a);
    }
    let n = patch.texels.len().max(1) as f64;
    let r: f64 = sums.iter().map(|e| math::hypot(e.1, e.2)).sum::<f64>() / n;
    (-2.0 * math::ln(r.clamp(1e-12, 1.0))).sqrt()
}

/// The direction the sample already has around a work patch, in the work
/// image (radians, like [`WorkImage::angle`]): the circular mean over the
/// patch's synthesized texels of the sample's x axis as their stored
/// Jacobian (atlas steps to sample offsets) and the work coordinates of
/// their atlas neighbours (atlas steps to work offsets) place it. `None`
/// where no synthesized texel has neighbours in the patch and chart.
fn neighbour_angle(
    surface: &Surface,
    state: &State,
    patch: &WorkPatch,
    bfs: &Bfs,
    coords: &[[f64; 2]],
) -> Option<f64> {
    let r = surface.r;
    let (mut cs, mut sn, mut n) = (0f64, 0f64, 0usize);
    for (i, &t) in patch.texels.iter().enumerate() {
        if !state.synthesized(t) {
            continue;
        }
        let chart = surface.chart(t);
        let (x, y) = (t as usize % r, t as usize / r);
        // work offset per atlas step along one axis, from a neighbour of
        // the patch in the same chart (either side)
        let step = |dx: usize, dy: usize| -> Option<[f64; 2]> {
            let fwd = (x + dx < r && y + dy < r).then(|| t + (dx + dy * r) as u32);
            let back = (x >= dx && y >= dy).then(|| t - (dx + dy * r) as u32);
            for (nb, sign) in [(fwd, 1.0), (back, -1.0)] {
                let Some(nb) = nb else { continue };
                if surface.chart(nb) != chart {
                    continue;
                }
                if let Some(k) = bfs.contains(nb) {
                    return Some([
                        sign * (coords[k][0] - coords[i][0]),
                        sign * (coords[k][1] - coords[i][1]),
                    ]);
                }
            }
            None
        };
        let (Some(ax), Some(ay)) = (step(1, 0), step(0, 1)) else {
            continue;
        };
        let det = ax[0] * ay[1] - ay[0] * ax[1];
        if det <= 0.0 {
            continue;
        }
        let j = state.texel(t, |s, k| s.jacobian[k]).map(f64::from);
        // sample offset per work +x step: J · A⁻¹ · e₁
        let (a, b) = (ay[1] / det, -ax[1] / det);
        let (u, v) = (j[0] * a + j[2] * b, j[1] * a + j[3] * b);
        if u == 0.0 && v == 0.0 {
            continue;
        }
        // a placement turned by θ steps the sample by (cos θ, −sin θ)
        let theta = math::atan2(-v, u);
        cs += math::cos(theta);
        sn += math::sin(theta);
        n += 1;
    }
    (n > 0 && math::hypot(cs, sn) > 0.0).then(|| math::atan2(sn, cs))
}
