//! Courses across seams, for [`super::evaluate`]: when the first sample's
//! features run in rows (brick courses, lines of text, found from its row
//! profile), each texel's stored sample row gives its course phase, and
//! the phase tells a course that runs on across a seam from one that is
//! offset there or ends.
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

use std::f64::consts::{PI, TAU};

use serde::Serialize;

use crate::artifact::gim::EMPTY;
use crate::io::imageio::RgbImage;
use crate::output::band::ColourBand;
use crate::quilt::NO_PATCH;

/// The sample has rows when its row profile correlates with itself
/// shifted by one period at least this well.
const MIN_ROW_CORRELATION: f64 = 0.5;

/// A phase step across a seam this far (radians) from the step before
/// it is an offset course: a sixth of a course.
const OFFSET: f64 = PI / 3.0;

/// How courses continue across seams.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct CourseFigures {
    /// The sample's mean course period (sample pixels).
    pub period_px: f64,
    /// Courses found in the sample.
    pub courses_in_sample: usize,
    /// Seam edges inside charts between texels of the first sample.
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

/// Where a sample's courses lie: the rows (sample pixels, ascending) of
/// its mortar lines (or whatever marks each course the same way), over a
/// sample `height` rows high.
#[derive(Clone, Debug, PartialEq)]
pub struct Courses {
    marks: Vec<f64>,
    height: f64,
}

impl Courses {
    /// The courses of `sample` when its features run in rows: the period
    /// from the autocorrelation of its row means, one mark per period at
    /// the row profile's sharper extremes (bright or dark lines). `None`
    /// when the profile is not periodic enough or holds fewer than three
    /// courses.
    pub fn detect(sample: &RgbImage) -> Option<Courses> {
        let (w, h) = (sample.width, sample.height);
        if w == 0 || h < 9 {
            return None;
        }
        let profile: Vec<f64> = (0..h)
            .map(|y| {
                let row = &sample.data[y * w * 3..(y + 1) * w * 3];
                row.chunks_exact(3)
                    .map(|c| 0.2126 * c[0] as f64 + 0.7152 * c[1] as f64 + 0.0722 * c[2] as f64)
                    .sum::<f64>()
                    / w as f64
            })
            .collect();
        let mean = profile.iter().sum::<f64>() / h as f64;
        let p: Vec<f64> = profile.iter().map(|v| v - mean).collect();
        if !(p.iter().any(|v| v.abs() > 1e-9)) {
            return None;
        }
        // the period: the first peak of the autocorrelation past its first
        // dip, of the profile smoothed over 5 rows (thin lines a pixel or
        // two apart from period to period still overlap)
        let smooth: Vec<f64> = (0..h)
            .map(|y| {
                (0..5)
                    .map(|k| [1.0, 2.0, 3.0, 2.0, 1.0][k] * p[(y + h + k - 2) % h])
                    .sum::<f64>()
                    / 9.0
            })
            .collect();
        let energy: f64 = smooth.iter().map(|v| v * v).sum();
        let corr = |lag: usize| (0..h).map(|y| smooth[y] * smooth[(y + lag) % h]).sum::<f64>() / energy;
        let (mut lag, mut best) = (0, 0.0);
        let mut dipped = false;
        for l in 2..=h / 3 {
            let c = corr(l);
            dipped |= c < 0.0;
            if dipped && c >= MIN_ROW_CORRELATION && c >= corr(l - 1) && c >= corr(l + 1) {
                (lag, best) = (l, c);
                break;
            }
        }
        if lag == 0 || best < MIN_ROW_CORRELATION {
            return None;
        }
        // the sharper side marks the courses: thin lines stand further
        // from the mean than the courses' bodies
        let hi = p.iter().cloned().fold(f64::MIN, f64::max);
        let lo = -p.iter().cloned().fold(f64::MAX, f64::min);
        let s = if hi >= lo { 1.0 } else { -1.0 };
        let v = |y: isize| s * p[y.rem_euclid(h as isize) as usize];
        let half = (lag / 2) as isize;
        let mut marks = Vec::new();
        for y in 0..h as isize {
            // a mark is the first maximum within half a period each way
            let is_peak = (1..=half).all(|k| v(y) > v(y - k) && v(y) >= v(y + k));
            if is_peak {
                // sub-pixel: the vertex of the parabola through its neighbours
                let (a, b, c) = (v(y - 1), v(y), v(y + 1));
                let d = a - 2.0 * b + c;
                let off = if d < 0.0 {
                    (0.5 * (a - c) / d).clamp(-0.5, 0.5)
                } else {
                    0.0
                };
                marks.push((y as f64 + off).rem_euclid(h as f64));
            }
        }
        marks.sort_by(f64::total_cmp);
        (marks.len() >= 3).then_some(Courses {
            marks,
            height: h as f64,
        })
    }

    /// The mean course period (sample pixels).
    pub fn period(&self) -> f64 {
        self.height / self.marks.len() as f64
    }

    /// Courses in the sample.
    pub fn len(&self) -> usize {
        self.marks.len()
    }

    /// Always false: a detected sample has at least three courses.
    pub fn is_empty(&self) -> bool {
        self.marks.is_empty()
    }

    /// The course phase (radians, modulo 2π) of sample row `v`: 2π per
    /// course, linear between the marks, wrapped with the sample.
    pub fn phase(&self, v: f64) -> f64 {
        let (m, h) = (&self.marks, self.height);
        let mut v = v.rem_euclid(h);
        if v < m[0] {
            v += h;
        }
        let k = m.partition_point(|&x| x <= v) - 1;
        let next = if k + 1 < m.len() { m[k + 1] } else { m[0] + h };
        TAU * (k as f64 + (v - m[k]) / (next - m[k]))
    }
}

fn wrap(a: f64) -> f64 {
    a - TAU * ((a + PI) / TAU).floor()
}

/// Counts of [`CourseFigures`] gathered band by band in
/// [`super::evaluate`]'s pass over the atlas.
#[derive(Default)]
pub(super) struct CourseCount {
    seam_edges: usize,
    offsets: usize,
    ends: usize,
}

impl CourseCount {
    /// The band's own texels: each grid edge to the right and lower
    /// neighbour, each grid square to their lower right.
    pub(super) fn gather(&mut self, b: &ColourBand, courses: &Courses, r: usize) {
        let rows = b.covered.len() / r;
        let first =
            |t: usize| b.covered[t] && b.patch[t] != NO_PATCH && b.index[t] == 0 && b.chart[t] != EMPTY;
        let phase = |t: usize| courses.phase(b.coords[t][1] as f64);
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

    /// A grey sample `h` rows high with a bright line at each of `marks`.
    fn rows(w: usize, h: usize, marks: &[usize]) -> RgbImage {
        let mut data = vec![0.4f32; w * h * 3];
        for &m in marks {
            data[m * w * 3..(m + 1) * w * 3].fill(0.9);
        }
        RgbImage {
            width: w,
            height: h,
            data,
        }
    }

    #[test]
    fn courses_are_found_at_their_lines() {
        let marks = [3, 21, 40, 58, 77, 96, 114, 133, 151, 170];
        let c = Courses::detect(&rows(32, 188, &marks)).expect("rows");
        assert_eq!(c.len(), marks.len());
        assert!((c.period() - 18.8).abs() < 1e-9);
        for (k, &m) in marks.iter().enumerate() {
            assert!(wrap(c.phase(m as f64) - TAU * k as f64).abs() < 1e-9);
        }
        // halfway between two lines is half a course on, also across the wrap
        assert!(wrap(c.phase(30.5) - (TAU + PI)).abs() < 1e-9);
        let across = 170.0 + (188.0 + 3.0 - 170.0) / 2.0;
        assert!(wrap(c.phase(across) - (9.0 * TAU + PI)).abs() < 1e-9);
        assert!(wrap(c.phase(across + 188.0) - c.phase(across)).abs() < 1e-9);
        // dark lines on a light ground as well
        let mut dark = rows(32, 188, &marks);
        dark.data.iter_mut().for_each(|v| *v = 1.3 - *v);
        assert_eq!(Courses::detect(&dark).map(|c| c.len()), Some(marks.len()));
    }

    #[test]
    fn samples_without_rows_have_no_courses() {
        let mut seed = 7u64;
        let data = (0..64 * 64 * 3)
            .map(|_| {
                seed = seed
                    .wrapping_mul(6364136223846793005)
                    .wrapping_add(1442695040888963407);
                (seed >> 40) as f32 / (1u64 << 24) as f32
            })
            .collect();
        assert_eq!(
            Courses::detect(&RgbImage {
                width: 64,
                height: 64,
                data
            }),
            None
        );
        assert_eq!(Courses::detect(&rows(16, 64, &[])), None);
        assert_eq!(
            Courses::detect(&rows(16, 64, &[10, 40])),
            None,
            "two lines are not courses"
        );
    }

    /// A band of `w`×`h` texels in one chart, every texel of the first
    /// sample: patch and sample row per texel from `f(x, y)`.
    fn band(w: usize, h: usize, f: impl Fn(usize, usize) -> (u32, f32)) -> ColourBand {
        let n = w * h;
        let (mut patch, mut coords) = (Vec::new(), Vec::new());
        for y in 0..h {
            for x in 0..w {
                let (p, v) = f(x, y);
                patch.push(p);
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
            vec![0; n],
            vec![0; n],
            coords,
        )
    }

    fn count(b: &ColourBand, c: &Courses, r: usize) -> CourseCount {
        let mut k = CourseCount::default();
        k.gather(b, c, r);
        k
    }

    #[test]
    fn offsets_and_ends_are_counted_at_seams_only() {
        let c = Courses::detect(&rows(8, 100, &[0, 20, 40, 60, 80])).unwrap();
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
