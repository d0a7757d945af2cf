//! A sample whose features run in rows (brick courses, lines of text):
//! where its courses lie, found from its row profile, and the course phase
//! of a sample row. Seam refinement counts a course offset at a seam as a
//! feature that ends there ([`super::ends`]); `evaluate` counts offsets and
//! course ends from the stored sample rows ([`crate::output::courses`]).

use std::f64::consts::{PI, TAU};

use crate::field::wrap_angle as wrap;
use crate::io::imageio::RgbImage;

/// The sample has rows when its row profile correlates with itself
/// shifted by one period at least this well.
const MIN_ROW_CORRELATION: f64 = 0.5;

/// A phase step across a seam this far (radians) from the step before
/// it is an offset course: a sixth of a course.
pub(crate) const OFFSET: f64 = PI / 3.0;

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
        let w = sample.width;
        if w == 0 {
            return None;
        }
        let rows: Vec<f64> = sample
            .data
            .chunks_exact(w * 3)
            .map(crate::io::imageio::row_luminance)
            .collect();
        Courses::from_profile(&rows)
    }

    /// [`Courses::detect`] from the sample's row profile: the mean
    /// luminance of each row ([`crate::io::imageio::row_luminance`]).
    pub fn from_profile(profile: &[f64]) -> Option<Courses> {
        let h = profile.len();
        if h < 9 {
            return None;
        }
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

    /// These courses in a copy of the sample resampled to `1 / scale` of
    /// its rows, in the coordinates a quilt stores (a copy's row v is the
    /// original's row v × `scale`).
    pub(crate) fn scaled(&self, scale: f64) -> Courses {
        Courses {
            marks: self.marks.iter().map(|m| m / scale).collect(),
            height: self.height / scale,
        }
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
        // a stored row that is not a number (a damaged file) has phase 0
        if !v.is_finite() {
            return 0.0;
        }
        self.phase_and_rate(v).0
    }

    /// The course phase and its rate (radians per sample row) at a finite
    /// row `v`, from one lookup of the course holding it.
    fn phase_and_rate(&self, v: f64) -> (f64, f64) {
        let (m, h) = (&self.marks, self.height);
        let mut u = v.rem_euclid(h);
        if u < m[0] {
            u += h;
        }
        let k = m.partition_point(|&x| x <= u) - 1;
        let next = if k + 1 < m.len() { m[k + 1] } else { m[0] + h };
        let span = next - m[k];
        (TAU * (k as f64 + (u - m[k]) / span), TAU / span)
    }

    /// Moves each sample coordinate's row (`coord[i][1]`) to the nearest
    /// row whose course phase is `phase[i]` (modulo 2π): locked courses
    /// ([`crate::quilt::flatten::locked_work_image`]) then meet at every
    /// seam exactly, whatever the spacing of the sample's own courses. Two
    /// Newton steps on the piecewise linear phase; a row that is not a
    /// number stays.
    pub(crate) fn lock_rows(&self, coord: &mut [[f64; 2]], phase: &[f64]) {
        for (c, &target) in coord.iter_mut().zip(phase) {
            if !c[1].is_finite() {
                continue;
            }
            for _ in 0..2 {
                let (p, rate) = self.phase_and_rate(c[1]);
                c[1] -= wrap(p - target) / rate;
            }
        }
    }
}

/// Whether the course is offset at the grid edge from texel a to texel b
/// (atlas step `d`): the course phase b shows differs from the one a's
/// patch would show there (its sample row moved by its Jacobian) by more
/// than [`OFFSET`], judged from both sides (the smaller). Each side is its
/// stored sample coordinate and Jacobian (per atlas +x, +y).
pub(crate) fn course_offset(
    courses: &Courses,
    a: ([f32; 2], [f32; 4]),
    b: ([f32; 2], [f32; 4]),
    d: (f64, f64),
) -> bool {
    let row =
        |(c, j): ([f32; 2], [f32; 4]), s: f64| c[1] as f64 + s * (j[1] as f64 * d.0 + j[3] as f64 * d.1);
    let from_a = wrap(courses.phase(row(b, 0.0)) - courses.phase(row(a, 1.0))).abs();
    let from_b = wrap(courses.phase(row(a, 0.0)) - courses.phase(row(b, -1.0))).abs();
    from_a.min(from_b) > OFFSET
}

/// Test support: a grey sample `h` rows high with a bright line at each
/// of `marks`.
#[cfg(test)]
pub(crate) fn row_sample(w: usize, h: usize, marks: &[usize]) -> RgbImage {
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn courses_are_found_at_their_lines() {
        let marks = [3, 21, 40, 58, 77, 96, 114, 133, 151, 170];
        let c = Courses::detect(&row_sample(32, 188, &marks)).expect("rows");
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
        // far from the sample, below it and not a number
        assert!(wrap(c.phase(3.0 + 188.0 * 1e6) - 0.0).abs() < 1e-6);
        assert!(wrap(c.phase(-185.0) - 0.0).abs() < 1e-9);
        for v in [f64::NAN, f64::INFINITY, f64::NEG_INFINITY] {
            assert_eq!(c.phase(v), 0.0);
        }
        // dark lines on a light ground as well
        let mut dark = row_sample(32, 188, &marks);
        dark.data.iter_mut().for_each(|v| *v = 1.3 - *v);
        assert_eq!(Courses::detect(&dark).map(|c| c.len()), Some(marks.len()));
    }

    /// Every locked row shows its target phase, and moves by less than a
    /// course to get there (the nearest such row).
    #[test]
    fn locked_rows_show_their_phase() {
        // courses of uneven spacing: marks at 3, 21, 38, 57 of 72 rows
        let c = Courses::detect(&row_sample(16, 72, &[3, 21, 38, 57])).unwrap();
        assert_eq!(c.len(), 4);
        let mut state = 3u64;
        let mut next = || {
            state = crate::rng::mix64(state);
            (state >> 11) as f64 / (1u64 << 53) as f64
        };
        let (coord, phase): (Vec<[f64; 2]>, Vec<f64>) = (0..500)
            .map(|_| ([next() * 16.0, next() * 72.0], (next() - 0.5) * 40.0))
            .unzip();
        let mut locked = coord.clone();
        c.lock_rows(&mut locked, &phase);
        for ((a, b), &p) in coord.iter().zip(&locked).zip(&phase) {
            assert_eq!(a[0], b[0]);
            assert!(
                wrap(c.phase(b[1]) - p).abs() < 1e-9,
                "row {} → {}: {} against {p}",
                a[1],
                b[1],
                c.phase(b[1])
            );
            assert!((a[1] - b[1]).abs() < 19.0, "row {} moved to {}", a[1], b[1]);
        }
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
        assert_eq!(Courses::detect(&row_sample(16, 64, &[])), None);
        assert_eq!(
            Courses::detect(&row_sample(16, 64, &[10, 40])),
            None,
            "two lines are not courses"
        );
    }

    #[test]
    fn a_course_offset_at_a_seam_is_seen_from_either_side() {
        let c = Courses::detect(&row_sample(8, 100, &[0, 20, 40, 60, 80])).unwrap();
        let id = [1.0f32, 0.0, 0.0, 1.0];
        // texel a and its neighbour b one atlas `step` away, both of a
        // patch with Jacobian j
        let offset =
            |j: [f32; 4], a: [f32; 2], b: [f32; 2], step: (f64, f64)| course_offset(&c, (a, j), (b, j), step);
        // a step down (+y) from row 30 to row 31: the course runs on, also
        // a whole course (20 rows) further on
        assert!(!offset(id, [5.0, 30.0], [9.0, 31.0], (0.0, 1.0)));
        assert!(!offset(id, [5.0, 30.0], [9.0, 51.0], (0.0, 1.0)));
        // 5 rows (a quarter course) off: offset; 2 rows (a tenth): not
        assert!(offset(id, [5.0, 30.0], [9.0, 36.0], (0.0, 1.0)));
        assert!(!offset(id, [5.0, 30.0], [9.0, 33.0], (0.0, 1.0)));
        // a step along the course (+x) keeps the row; a patch turned a
        // quarter (its rows run along atlas y) moves rows with x
        assert!(!offset(id, [5.0, 30.0], [6.0, 30.0], (1.0, 0.0)));
        let turned = [0.0f32, 1.0, -1.0, 0.0];
        assert!(!offset(turned, [5.0, 30.0], [5.0, 31.0], (1.0, 0.0)));
        assert!(offset(turned, [5.0, 30.0], [5.0, 35.0], (1.0, 0.0)));
    }
}
