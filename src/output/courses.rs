//! Courses across seams, for [`super::evaluate`]: when the first sample's
//! features run in rows (brick courses, lines of text, found from its row
//! profile), each texel's stored sample row gives its course phase, and
//! the phase tells a course that runs on across a seam from one that is
//! offset there or ends. Texels of another sample painted in count too
//! when its courses lie on the surface within [`PATTERN_FIT`] of the
//! first's (a damaged twin): their phase is read in their own sample's
//! courses.
//!
//! - offset: a seam edge whose phase step differs from the step the patch
//!   makes just before the seam by more than a sixth of a course;
//! - ends: a grid square around which the phase turns by a whole course
//!   (one course more on one side than on the other), counted with its
//!   multiplicity;
//! - forced ends (when asked for): the ends the smoothest stripe pattern
//!   along the atlas's field needs at this course period
//!   ([`crate::field::forced_ends`]), a reference for how many the field's
//!   geometry asks for.

use std::f64::consts::TAU;

use serde::Serialize;

use crate::artifact::gim::EMPTY;
use crate::field::wrap_angle as wrap;
use crate::io::imageio::RgbImage;
use crate::output::band::ColourBand;
use crate::quilt::courses::{Courses, OFFSET};
use crate::quilt::{NO_PATCH, PATTERN_FIT};

/// How courses continue across seams.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct CourseFigures {
    /// The sample's mean course period (sample pixels).
    pub period_px: f64,
    /// Courses found in the sample.
    pub courses_in_sample: usize,
    /// Seam edges inside charts between texels of the first sample (or of
    /// another sample with its courses).
    pub seam_edges: usize,
    /// Share of those where the course is offset by more than a sixth of
    /// a course.
    pub offset_share: f64,
    /// Course ends: grid squares inside charts around which the course
    /// phase turns by whole courses, each counted that many times.
    pub ends: usize,
    /// The ends of the smoothest stripe pattern along the atlas's field at
    /// this course period (with `evaluate --forced-ends`): a reference for
    /// `ends`, how many the field's geometry asks for.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub forced_ends: Option<usize>,
}

/// Counts of [`CourseFigures`] gathered band by band in
/// [`super::evaluate`]'s pass over the atlas.
#[derive(Default)]
pub(super) struct CourseCount {
    seam_edges: usize,
    offsets: usize,
    ends: usize,
}

/// The courses each sample's texels are read in: the first sample's when
/// it has courses, and another's whose courses span on the surface within
/// [`PATTERN_FIT`] of the first's (`None` for the others, whose texels
/// are not counted). `span`: mesh units one pixel of sample `k` spans.
/// `None` when the first sample has no courses.
pub(super) fn sample_courses(
    previews: &[RgbImage],
    span: impl Fn(usize) -> f64,
) -> Option<Vec<Option<Courses>>> {
    let first = Courses::detect(previews.first()?)?;
    let units = first.period() * span(0);
    let mut all = vec![Some(first)];
    for (k, p) in previews.iter().enumerate().skip(1) {
        all.push(Courses::detect(p).filter(|c| (c.period() * span(k) / units - 1.0).abs() <= PATTERN_FIT));
    }
    Some(all)
}

impl CourseCount {
    /// The band's own texels: each grid edge to the right and lower
    /// neighbour, each grid square to their lower right. `courses`: per
    /// sample, as [`sample_courses`] gives them.
    pub(super) fn gather(&mut self, b: &ColourBand, courses: &[Option<Courses>], r: usize) {
        let rows = b.covered.len() / r;
        let of = |t: usize| courses.get(b.index[t] as usize).and_then(Option::as_ref);
        let first =
            |t: usize| b.covered[t] && b.patch[t] != NO_PATCH && b.chart[t] != EMPTY && of(t).is_some();
        let phase = |t: usize| of(t).map_or(0.0, |c| c.phase(b.coords[t][1] as f64));
        let inside = |x: usize, y: usize| x < r && y < rows;
        for t in b.own_texels() {
            let (x, y) = (t % r, t / r);
            if !first(t) {
                continue;
            }
            let same = |n: usize| first(n) && b.chart[n] == b.chart[t];
            for (dx, dy) in [(1usize, 0usize), (0, 1)] {
                if !inside(x + dx, y + dy) {
                    continue;
                }
                let d = dx + dy * r;
                let n = t + d;
                if !same(n) || b.patch[n] == b.patch[t] {
                    continue;
                }
                // the step the patch makes just before the seam, from
                // either side, predicts the step across it
                let before = if x >= dx && y >= dy && same(t - d) && b.patch[t - d] == b.patch[t] {
                    Some(wrap(phase(t) - phase(t - d)))
                } else if inside(x + 2 * dx, y + 2 * dy) && same(n + d) && b.patch[n + d] == b.patch[n] {
                    Some(wrap(phase(n + d) - phase(n)))
                } else {
                    None
                };
                let step = wrap(phase(n) - phase(t) - before.unwrap_or(0.0));
                self.seam_edges += 1;
                self.offsets += (step.abs() > OFFSET) as usize;
            }
            if inside(x + 1, y + 1) && [t + 1, t + r + 1, t + r].into_iter().all(same) {
                let c = [t, t + 1, t + r + 1, t + r];
                // each edge's step taken the same way in every square
                // (from its lower index), so that squares sharing an edge
                // agree even on a step of exactly half a course
                let step = |a: usize, b: usize| {
                    if a < b {
                        wrap(phase(b) - phase(a))
                    } else {
                        -wrap(phase(a) - phase(b))
                    }
                };
                let turn: f64 = (0..4).map(|k| step(c[k], c[(k + 1) % 4])).sum();
                self.ends += (turn / TAU).round().abs() as usize;
            }
        }
    }

    /// The figures, with the ends the field forces.
    pub(super) fn figures(&self, courses: &Courses, forced_ends: Option<usize>) -> CourseFigures {
        CourseFigures {
            period_px: courses.period(),
            courses_in_sample: courses.len(),
            seam_edges: self.seam_edges,
            offset_share: self.offsets as f64 / self.seam_edges.max(1) as f64,
            ends: self.ends,
            forced_ends,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::quilt::courses::row_sample;

    /// A band of `w`×`h` texels in one chart, every texel of the first
    /// sample: patch and sample row per texel from `f(x, y)`.
    fn band(w: usize, h: usize, f: impl Fn(usize, usize) -> (u32, f32)) -> ColourBand {
        two_samples(w, h, |x, y| {
            let (p, v) = f(x, y);
            (p, 0, v)
        })
    }

    /// The same with each texel's sample index from `f` too.
    fn two_samples(w: usize, h: usize, f: impl Fn(usize, usize) -> (u32, u8, f32)) -> ColourBand {
        let n = w * h;
        let (mut patch, mut index, mut coords) = (Vec::new(), Vec::new(), Vec::new());
        for y in 0..h {
            for x in 0..w {
                let (p, k, v) = f(x, y);
                patch.push(p);
                index.push(k);
                coords.push([x as f32, v]);
            }
        }
        ColourBand::from_parts(
            0,
            0,
            n,
            vec![0.5; 3 * n],
            vec![true; n],
            patch,
            index,
            vec![0; n],
            coords,
        )
    }

    fn count(b: &ColourBand, c: &Courses, r: usize) -> CourseCount {
        let mut k = CourseCount::default();
        k.gather(b, &[Some(c.clone())], r);
        k
    }

    #[test]
    fn another_sample_counts_in_its_own_courses_when_they_fit() {
        let wall = row_sample(8, 100, &[0, 20, 40, 60, 80]);
        // a twin whose mortar lines lie 8 rows lower; one with wider rows
        let twin = row_sample(8, 100, &[8, 28, 48, 68, 88]);
        let wide = row_sample(8, 120, &[0, 24, 48, 72, 96]);
        let samples = [wall, twin, wide];
        let courses = sample_courses(&samples, |_| 0.01).unwrap();
        assert!(courses[1].is_some() && courses[2].is_none());
        // at a pixel 20 % smaller on the surface the wide rows fit
        let fitted = sample_courses(&samples, |k| if k == 2 { 0.01 / 1.2 } else { 0.01 }).unwrap();
        assert!(fitted[2].is_some());
        // the right patch from the twin, its rows 8 lower: courses run on
        let (w, h) = (30, 60);
        let right = |k: u8, shift: f32| {
            two_samples(w, h, move |x, y| {
                if x >= 15 {
                    (1, k, y as f32 + shift)
                } else {
                    (0, 0, y as f32)
                }
            })
        };
        let gather = |b: &ColourBand, c: &[Option<Courses>]| {
            let mut k = CourseCount::default();
            k.gather(b, c, w);
            (k.seam_edges, k.offsets, k.ends)
        };
        assert_eq!(gather(&right(1, 8.0), &courses), (h, 0, 0));
        // read in the first sample's courses they would be offset
        assert_eq!(gather(&right(0, 8.0), &courses), (h, h, 0));
        // texels of a sample whose courses do not fit are left out
        assert_eq!(gather(&right(2, 0.0), &courses), (0, 0, 0));
    }

    #[test]
    fn offsets_and_ends_are_counted_at_seams_only() {
        let c = Courses::detect(&row_sample(8, 100, &[0, 20, 40, 60, 80])).unwrap();
        let (w, h) = (30, 60);
        // two patches split at x = 15 whose courses run on
        let k = count(
            &band(w, h, |x, y| {
                ((x >= 15) as u32, y as f32 + 40.0 * (x >= 15) as u32 as f32)
            }),
            &c,
            w,
        );
        assert_eq!((k.seam_edges, k.offsets, k.ends), (h, 0, 0));
        // the right patch offset by 0.4 course: every seam edge
        let k = count(
            &band(w, h, |x, y| {
                ((x >= 15) as u32, y as f32 + 8.0 * (x >= 15) as u32 as f32)
            }),
            &c,
            w,
        );
        assert_eq!((k.seam_edges, k.offsets, k.ends), (h, h, 0));
        // the right patch squeezes one course more into the height: the
        // courses drift apart along the seam and one of them ends there
        let k = count(
            &band(w, h, |x, y| {
                (
                    (x >= 15) as u32,
                    y as f32 * if x >= 15 { 80.0 / 60.0 } else { 1.0 },
                )
            }),
            &c,
            w,
        );
        assert_eq!(k.ends, 1);
        assert!(k.offsets > 0 && k.offsets < h);
        // inside one patch nothing counts, however the courses bend
        let k = count(&band(w, h, |x, y| (0, y as f32 * 1.3 + x as f32 * 0.4)), &c, w);
        assert_eq!((k.seam_edges, k.offsets, k.ends), (0, 0, 0));
    }
}
