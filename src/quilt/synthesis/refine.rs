//! Seam refinement (Kwatra et al. 2003, §3.3): work patches
//! re-fitted over the seams whose cost or broken features exceed a limit.

use super::*;

impl Synthesis {
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
    /// ([`crate::quilt::config::BROKEN_CONTINUATION`]) are visited too, whatever their
    /// step, and fitted with that many placements: the one whose cut ends
    /// fewest features at the patch's seams ([`ends`](crate::quilt::ends)) is chosen, and
    /// kept if it ends fewer than before at a cut under
    /// [`ENDS_DEARER`](crate::quilt::config::ENDS_DEARER) × the old seams' cost (or as many, at under
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
    /// from the other side by more than [`crate::quilt::config::BROKEN_CONTINUATION`] of
    /// them. Also those feature ends alone, ascending.
    pub(super) fn seams_to_refine(&self, step: f64, find_broken: bool) -> (Vec<(f64, u32)>, Vec<u32>) {
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
                let along = crate::quilt::ends::step(t, nb, grid.r, zipper);
                if let (true, Some(d)) = (find_broken, along) {
                    let gap = crate::quilt::ends::gap(
                        &fa,
                        &fb,
                        &mut fc,
                        |out| self.state.continued(&self.sample, t, d, out),
                        |out| self.state.continued(&self.sample, nb, (-d.0, -d.1), out),
                    );
                    ends = ends.max(gap);
                    // a course offset at the seam is an end, whatever the colours
                    if let Some(c) = &self.sample.courses {
                        let (a, b) = (self.state.coord_jacobian(t), self.state.coord_jacobian(nb));
                        if crate::quilt::courses::course_offset(c, a, b, d) {
                            ends = f64::MAX;
                        }
                    }
                }
            }
            if ends > crate::quilt::config::BROKEN_CONTINUATION * self.reference {
                broken.push(t);
                seeds.push((worst.max(ends), t));
            } else if worst > step * self.reference {
                seeds.push((worst, t));
            }
        }
        broken.sort_unstable();
        (seeds, broken)
    }
}
