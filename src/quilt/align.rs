//! Feature alignment before the cut: the new patch's rigid placement is
//! bent by a few sample pixels so that its features meet the old texels of
//! the overlap (the feature matching and deformation of Wu & Yu 2004,
//! "Feature matching and deformation for texture synthesis", §4, on the
//! work patch). A rigid placement lines its courses up with the overlap on
//! average; where the old texels come from patches whose courses disagree
//! (the field turned between them), it can agree with only one, and the
//! cut shows a step at the other. Each stretch of the overlap finds the
//! shift of the new patch that best matches the old texels there; the
//! shifts are blended smoothly over the patch and fade out beyond the
//! overlap.

use super::flatten::WorkImage;
use super::sample::Sample;
#[cfg(doc)]
use super::state::State;

/// Alignment points are at least this many × the largest shift apart.
const POINT_SPACING: f64 = 2.0;

/// Old texels within this many × the largest shift of a point judge its
/// shift.
const WINDOW: f64 = 1.5;

/// At most this many old texels judge a shift (an even subset of the
/// window's, in patch order).
const WINDOW_TEXELS: usize = 32;

/// A shift is kept only if it brings the window's difference below this
/// share of the unshifted one.
const GAIN: f64 = 0.7;

/// A window whose root-mean-square difference from the new patch is below
/// this many sample neighbour differences is aligned already (no search);
/// one whose old texels vary by less has no features to align.
const SETTLED: f64 = 1.0;

/// Shifts blend over this many point spacings (the deviation of the
/// blending kernel). On Spot, 1.5 kept courses continuous with gentle
/// bends; 1 bent them into visible kinks, 2 and 3 left more ends.
const BLEND: f64 = 1.5;

/// Shifts `coord` (the new patch's unrotated sample coordinate per patch
/// vertex) by up to `max_shift` sample pixels where that makes the new
/// patch match the old texels of the overlap better (see the module doc).
/// `known` and `old` say which vertices were synthesized and their
/// features (`n` each, [`State::features_of`]); `reference` is the
/// sample's mean neighbour difference.
#[allow(clippy::too_many_arguments)]
pub(super) fn align_to_overlap(
    coord: &mut [[f64; 2]],
    sample: &Sample,
    work: &WorkImage,
    known: &[bool],
    old: &[f32],
    n: usize,
    max_shift: f64,
    reference: f64,
) {
    let overlap = Overlap {
        coords: &work.coords,
        size: [work.width, work.height],
        known,
        old,
        n,
    };
    let grid = Grid {
        maps: &sample.maps,
        width: sample.width,
        height: sample.height,
        n: sample.n,
        tileable: sample.tileable,
    };
    overlap.align(coord, &grid, max_shift, reference);
}

/// The sample's feature maps (`n` per pixel, row-major) read bilinearly
/// at whole-pixel shifts of a texel: the search only tries whole-pixel
/// shifts, so each texel's pixel and bilinear weights are found once.
struct Grid<'a> {
    maps: &'a [f32],
    width: usize,
    height: usize,
    n: usize,
    tileable: bool,
}

/// A sample coordinate split into its pixel and its fraction.
#[derive(Clone, Copy)]
struct Texel {
    x: i64,
    y: i64,
    fx: f32,
    fy: f32,
}

impl Grid<'_> {
    fn texel(c: [f64; 2]) -> Texel {
        // ⌊v⌋ from the truncation (no call to libm)
        let floor = |v: f64| {
            let t = v as i64;
            t - ((t as f64) > v) as i64
        };
        let (x, y) = (floor(c[0]), floor(c[1]));
        Texel {
            x,
            y,
            fx: (c[0] - x as f64) as f32,
            fy: (c[1] - y as f64) as f32,
        }
    }

    /// The features at `t` shifted by (dx, dy) pixels, bilinear like
    /// [`Sample::lookup`]; `false` outside a sample that does not tile.
    fn read(&self, t: Texel, dx: i64, dy: i64, out: &mut [f32]) -> bool {
        let (w, h) = (self.width as i64, self.height as i64);
        let (x0, y0, x1, y1);
        if self.tileable {
            (x0, y0) = ((t.x + dx).rem_euclid(w), (t.y + dy).rem_euclid(h));
            (x1, y1) = ((x0 + 1) % w, (y0 + 1) % h);
        } else {
            (x0, y0) = (t.x + dx, t.y + dy);
            // (the last column or row only with no fraction beyond it)
            if x0 < 0 || y0 < 0 || x0 > w - 1 || y0 > h - 1 {
                return false;
            }
            if (x0 == w - 1 && t.fx > 0.0) || (y0 == h - 1 && t.fy > 0.0) {
                return false;
            }
            (x1, y1) = ((x0 + 1).min(w - 1), (y0 + 1).min(h - 1));
        }
        let n = self.n;
        let at = |x: i64, y: i64| (y as usize * self.width + x as usize) * n;
        let (a, b, c, d) = (at(x0, y0), at(x1, y0), at(x0, y1), at(x1, y1));
        let m = self.maps;
        for (i, o) in out.iter_mut().enumerate().take(n) {
            let top = m[a + i] + (m[b + i] - m[a + i]) * t.fx;
            let bottom = m[c + i] + (m[d + i] - m[c + i]) * t.fx;
            *o = top + (bottom - top) * t.fy;
        }
        true
    }

    /// Whether a coordinate is on the sample ([`super::placement::inside_sample`]).
    fn inside(&self, c: [f64; 2]) -> bool {
        self.tileable
            || (c[0] >= 0.0
                && c[1] >= 0.0
                && c[0] <= self.width as f64 - 1.0
                && c[1] <= self.height as f64 - 1.0)
    }
}

/// ⌊v⌋ clamped to `0..count` (truncation is the floor from 0 up, and a
/// call to `floor` is not free in the hot loops here).
fn clamped_floor(v: f64, count: usize) -> usize {
    (v.max(0.0) as usize).min(count - 1)
}

/// What alignment reads of a work patch: each vertex's work coordinate
/// (inside `size`), whether it was synthesized before (`known`) and then
/// its old features (`n` channels per vertex in `old`).
struct Overlap<'a> {
    coords: &'a [[f64; 2]],
    size: [usize; 2],
    known: &'a [bool],
    old: &'a [f32],
    n: usize,
}

impl Overlap<'_> {
    /// The old features of vertex `j`.
    fn old(&self, j: usize) -> &[f32] {
        &self.old[j * self.n..(j + 1) * self.n]
    }

    /// [`align_to_overlap`] with the sample read through `grid`.
    fn align(&self, coord: &mut [[f64; 2]], grid: &Grid, max_shift: f64, reference: f64) {
        let (coords, m, n) = (self.coords, self.coords.len(), self.n);
        if max_shift <= 0.0 || m == 0 {
            return;
        }
        let olds: Vec<usize> = (0..m).filter(|&i| self.known[i]).collect();
        if olds.len() < 4 {
            return;
        }
        let d2 = |a: [f64; 2], b: [f64; 2]| (a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2);
        let spacing = POINT_SPACING * max_shift;
        let window_radius = WINDOW * max_shift;
        // the old texels and the points by cells `spacing` wide (wider than
        // a window): a point's neighbours are in the 3×3 cells around it
        let (cols, rows) = (
            (self.size[0] as f64 / spacing).floor() as usize + 1,
            (self.size[1] as f64 / spacing).floor() as usize + 1,
        );
        let axis = |v: f64, count: usize| clamped_floor(v / spacing, count);
        let cell = |c: [f64; 2]| axis(c[1], rows) * cols + axis(c[0], cols);
        // old texels by cell, in patch order within a cell (counting sort)
        let cells: Vec<usize> = olds.iter().map(|&i| cell(coords[i])).collect();
        let mut first = vec![0usize; cols * rows + 1];
        for &k in &cells {
            first[k + 1] += 1;
        }
        for k in 1..first.len() {
            first[k] += first[k - 1];
        }
        let mut by_cell = vec![0usize; olds.len()];
        let mut fill = first.clone();
        for (&i, &k) in olds.iter().zip(&cells) {
            by_cell[fill[k]] = i;
            fill[k] += 1;
        }
        // points over the overlap, `spacing` apart (greedy in patch order)
        let mut point_cells: Vec<Vec<usize>> = vec![Vec::new(); cols * rows];
        let mut points: Vec<usize> = Vec::new();
        for (&i, &k) in olds.iter().zip(&cells) {
            let c = coords[i];
            let (x, y) = (k % cols, k / cols);
            let near = |k: usize| {
                point_cells[k]
                    .iter()
                    .any(|&p| d2(coords[p], c) < spacing * spacing)
            };
            // (its own cell first: most texels near a point are in it)
            let taken = near(y * cols + x)
                || (y.saturating_sub(1)..(y + 2).min(rows)).any(|yy| {
                    (x.saturating_sub(1)..(x + 2).min(cols))
                        .any(|xx| (yy, xx) != (y, x) && near(yy * cols + xx))
                });
            if !taken {
                point_cells[y * cols + x].push(i);
                points.push(i);
            }
        }
        let mut looked = vec![0f32; n];
        let mut window: Vec<usize> = Vec::new();
        let (mut texels, mut olds_here, mut mean) = (Vec::new(), Vec::new(), vec![0f64; n]);
        let mut shifts: Vec<([f64; 2], usize)> = Vec::with_capacity(points.len());
        for &p in &points {
            // the old texels within the window (in the cells its box meets)
            let c = coords[p];
            window.clear();
            for yy in axis(c[1] - window_radius, rows)..=axis(c[1] + window_radius, rows) {
                for xx in axis(c[0] - window_radius, cols)..=axis(c[0] + window_radius, cols) {
                    let k = yy * cols + xx;
                    window.extend(
                        by_cell[first[k]..first[k + 1]]
                            .iter()
                            .filter(|&&j| d2(coords[j], c) <= window_radius * window_radius),
                    );
                }
            }
            window.sort_unstable();
            let stride = window.len().div_ceil(WINDOW_TEXELS).max(1);
            let count = window.len().div_ceil(stride);
            if count < 4 {
                continue;
            }
            texels.clear();
            olds_here.clear();
            for &j in window.iter().step_by(stride) {
                texels.push(Grid::texel(coord[j]));
                olds_here.extend_from_slice(self.old(j));
            }
            // a window without features (its old texels vary by less than
            // the sample's neighbour difference) says nothing about a shift
            mean.iter_mut().for_each(|m| *m = 0.0);
            for a in olds_here.chunks_exact(n) {
                for (m, &x) in mean.iter_mut().zip(a) {
                    *m += x as f64 / count as f64;
                }
            }
            let spread: f64 = olds_here
                .chunks_exact(n)
                .map(|a| {
                    a.iter()
                        .zip(&mean)
                        .map(|(&x, m)| (x as f64 - m).powi(2))
                        .sum::<f64>()
                })
                .sum();
            let settled = (SETTLED * reference).powi(2) * count as f64;
            if spread <= settled {
                continue;
            }
            // the window's difference from the new patch shifted by
            // (dx, dy) whole pixels, given up once above `limit`
            let mut cost = |dx: i64, dy: i64, limit: f64| -> f64 {
                let mut sum = 0.0;
                for (&t, a) in texels.iter().zip(olds_here.chunks_exact(n)) {
                    if !grid.read(t, dx, dy, &mut looked) {
                        return f64::INFINITY;
                    }
                    sum += a
                        .iter()
                        .zip(&looked)
                        .map(|(x, y)| ((x - y) as f64).powi(2))
                        .sum::<f64>();
                    if sum > limit {
                        return f64::INFINITY;
                    }
                }
                sum
            };
            let base = cost(0, 0, f64::INFINITY);
            if !base.is_finite() || base <= settled {
                shifts.push(([0.0, 0.0], p));
                continue;
            }
            // coarse to fine: a grid of steps of half the largest shift,
            // then halving steps around the best so far
            let mut best = (base, 0i64, 0i64);
            let mut step = (max_shift / 2.0).floor().max(1.0) as i64;
            let mut span = (max_shift / step as f64).ceil() as i64;
            let reach = max_shift * max_shift;
            loop {
                let (cx, cy) = (best.1, best.2);
                for sy in -span..=span {
                    for sx in -span..=span {
                        let (dx, dy) = (cx + sx * step, cy + sy * step);
                        if (dx * dx + dy * dy) as f64 > reach || (sx == 0 && sy == 0) {
                            continue;
                        }
                        // (the nearer of equals: flat stretches do not move)
                        let c = cost(dx, dy, best.0);
                        if c < best.0
                            || (c == best.0 && dx * dx + dy * dy < best.1 * best.1 + best.2 * best.2)
                        {
                            best = (c, dx, dy);
                        }
                    }
                }
                if step <= 1 {
                    break;
                }
                step = (step / 2).max(1);
                span = 1;
            }
            let shift = if best.0 < GAIN * base {
                [best.1 as f64, best.2 as f64]
            } else {
                [0.0, 0.0]
            };
            shifts.push((shift, p));
        }
        if shifts.iter().all(|(s, _)| s == &[0.0, 0.0]) {
            return;
        }
        // blend the shifts with a compact kernel, (1 − d²/R²)² with R = 2σ
        // (close to a Gaussian of deviation σ), on nodes half a spacing
        // apart, interpolated bilinearly between them; the full shift within
        // a spacing of a point, fading to none at R
        let reach2 = 4.0 * (BLEND * spacing).powi(2);
        let reach = reach2.sqrt();
        let node = 0.5 * spacing;
        let (nx, ny) = (
            (self.size[0] as f64 / node).ceil() as usize + 2,
            (self.size[1] as f64 / node).ceil() as usize + 2,
        );
        // per node: Σ w·shift (x, y), Σ w, the distance to the nearest point
        let mut nodes = vec![[0f64; 4]; nx * ny];
        for (k, v) in nodes.iter_mut().enumerate() {
            let at = [(k % nx) as f64 * node, (k / nx) as f64 * node];
            let mut nearest = reach2;
            for (s, p) in &shifts {
                let d = d2(coords[*p], at);
                if d < reach2 {
                    let w = (1.0 - d / reach2).powi(2);
                    v[0] += w * s[0];
                    v[1] += w * s[1];
                    v[2] += w;
                    nearest = nearest.min(d);
                }
            }
            v[3] = nearest.sqrt();
        }
        for (c, w) in coord.iter_mut().zip(coords) {
            let (gx, gy) = (w[0] / node, w[1] / node);
            let (x0, y0) = (clamped_floor(gx, nx - 1), clamped_floor(gy, ny - 1));
            let corners = [
                y0 * nx + x0,
                y0 * nx + x0 + 1,
                (y0 + 1) * nx + x0,
                (y0 + 1) * nx + x0 + 1,
            ];
            if corners.iter().all(|&k| nodes[k][0] == 0.0 && nodes[k][1] == 0.0) {
                // (every shift that reaches here is none: it stays where it is)
                continue;
            }
            let (fx, fy) = (gx - x0 as f64, gy - y0 as f64);
            let mut v = [0f64; 4];
            for (k, b) in
                corners
                    .into_iter()
                    .zip([(1.0 - fx) * (1.0 - fy), fx * (1.0 - fy), (1.0 - fx) * fy, fx * fy])
            {
                for (acc, x) in v.iter_mut().zip(nodes[k]) {
                    *acc += b * x;
                }
            }
            let [wx, wy, wsum, nearest] = v;
            if wsum <= 1e-12 {
                continue;
            }
            let f = ((reach - nearest) / (reach - spacing)).clamp(0.0, 1.0);
            let moved = [c[0] + f * wx / wsum, c[1] + f * wy / wsum];
            if grid.inside(moved) {
                *c = moved;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A sample of horizontal courses: a mortar line 2 pixels wide every
    /// 12 rows (one channel), read bilinearly, `size` square.
    fn courses(size: usize) -> (Vec<f32>, usize) {
        let img = (0..size * size)
            .map(|i| if (i / size) % 12 < 2 { 1.0 } else { 0.2 })
            .collect();
        (img, size)
    }

    fn lookup(img: &[f32], size: usize, c: [f64; 2], out: &mut [f32]) -> bool {
        let s = size as f64 - 1.0;
        if !(c[0] >= 0.0 && c[1] >= 0.0 && c[0] <= s && c[1] <= s) {
            return false;
        }
        let (x0, y0) = (c[0].floor() as usize, c[1].floor() as usize);
        let (x1, y1) = ((x0 + 1).min(size - 1), (y0 + 1).min(size - 1));
        let (fx, fy) = ((c[0] - x0 as f64) as f32, (c[1] - y0 as f64) as f32);
        let at = |x: usize, y: usize| img[y * size + x];
        let top = at(x0, y0) + (at(x1, y0) - at(x0, y0)) * fx;
        let bottom = at(x0, y1) + (at(x1, y1) - at(x0, y1)) * fx;
        out[0] = top + (bottom - top) * fy;
        true
    }

    /// Bilinear reading like `Sample::lookup`: `n` channels, `false`
    /// outside [0, w − 1] × [0, h − 1] unless the image tiles.
    fn bilinear(img: &[f32], [w, h, n]: [usize; 3], tileable: bool, c: [f64; 2], out: &mut [f32]) -> bool {
        let (mut x, mut y) = (c[0], c[1]);
        if tileable {
            x = x.rem_euclid(w as f64);
            y = y.rem_euclid(h as f64);
        } else if !(x >= 0.0 && y >= 0.0 && x <= (w - 1) as f64 && y <= (h - 1) as f64) {
            return false;
        }
        let (x0, y0) = (x.floor() as usize % w, y.floor() as usize % h);
        let (fx, fy) = ((x - x.floor()) as f32, (y - y.floor()) as f32);
        let (x1, y1) = if tileable {
            ((x0 + 1) % w, (y0 + 1) % h)
        } else {
            ((x0 + 1).min(w - 1), (y0 + 1).min(h - 1))
        };
        for (i, o) in out.iter_mut().enumerate() {
            let at = |x: usize, y: usize| img[(y * w + x) * n + i];
            let top = at(x0, y0) + (at(x1, y0) - at(x0, y0)) * fx;
            let bottom = at(x0, y1) + (at(x1, y1) - at(x0, y1)) * fx;
            *o = top + (bottom - top) * fy;
        }
        true
    }

    #[test]
    fn a_shifted_read_is_the_bilinear_read_at_the_shifted_coordinate() {
        // 7×5 pixels of 2 channels, tiling and not, read at fractions and
        // whole pixels in and around the image and shifted by up to 3
        let (w, h, n) = (7, 5, 2);
        let img: Vec<f32> = (0..w * h * n).map(|i| ((i * 37) % 11) as f32 / 10.0).collect();
        for tileable in [false, true] {
            let grid = Grid {
                maps: &img,
                width: w,
                height: h,
                n,
                tileable,
            };
            let (mut inside, mut outside) = (0, 0);
            for iy in -12..=28 {
                for ix in -12..=36 {
                    let c = [ix as f64 * 0.25 + 0.001 * (ix % 3) as f64, iy as f64 * 0.25];
                    let t = Grid::texel(c);
                    for (dx, dy) in [(0, 0), (1, 0), (-1, 2), (3, -3), (-2, -1)] {
                        let (mut a, mut b) = ([0f32; 2], [0f32; 2]);
                        let read = grid.read(t, dx, dy, &mut a);
                        let shifted = [c[0] + dx as f64, c[1] + dy as f64];
                        assert_eq!(
                            read,
                            bilinear(&img, [w, h, n], tileable, shifted, &mut b),
                            "{c:?} + ({dx}, {dy})"
                        );
                        assert_eq!(read, grid.inside(shifted), "{c:?} + ({dx}, {dy})");
                        if read {
                            inside += 1;
                            for (x, y) in a.iter().zip(&b) {
                                assert!((x - y).abs() < 1e-5, "{c:?} + ({dx}, {dy}): {a:?} against {b:?}");
                            }
                        } else {
                            outside += 1;
                        }
                    }
                }
            }
            assert!(
                inside > 1000 && (tileable || outside > 1000),
                "{inside} in, {outside} out"
            );
            assert!(!tileable || outside == 0);
        }
    }

    /// A 64×64 work patch (vertex = pixel) over the sample at offset
    /// (40, 40); its left `old_columns` columns already show the sample
    /// shifted down by `offset` rows. Returns the coordinates after
    /// alignment with a largest shift of 4 pixels.
    fn aligned(offset: f64, old_columns: usize) -> Vec<[f64; 2]> {
        let (img, size) = courses(160);
        let side = 64;
        let coords: Vec<[f64; 2]> = (0..side * side)
            .map(|i| [(i % side) as f64, (i / side) as f64])
            .collect();
        let mut coord: Vec<[f64; 2]> = coords.iter().map(|w| [w[0] + 40.0, w[1] + 40.0]).collect();
        let known: Vec<bool> = coords.iter().map(|w| (w[0] as usize) < old_columns).collect();
        let old: Vec<f32> = coords
            .iter()
            .map(|w| {
                let mut v = [0f32];
                lookup(&img, size, [w[0] + 40.0, w[1] + 40.0 + offset], &mut v);
                v[0]
            })
            .collect();
        let overlap = Overlap {
            coords: &coords,
            size: [side, side],
            known: &known,
            old: &old,
            n: 1,
        };
        let grid = Grid {
            maps: &img,
            width: size,
            height: size,
            n: 1,
            tileable: false,
        };
        overlap.align(&mut coord, &grid, 4.0, 0.05);
        coord
    }

    #[test]
    fn the_new_patch_bends_to_meet_the_old_courses_and_stays_rigid_far_away() {
        let side = 64;
        for offset in [3.0, -2.0] {
            let coord = aligned(offset, 24);
            // deep in the overlap the new patch shows what the old one did:
            // the sample moved by the offset, within a tenth of a pixel
            for y in 16..48 {
                let i = y * side + 8;
                let d = [coord[i][0] - (8.0 + 40.0), coord[i][1] - (y as f64 + 40.0)];
                assert!(
                    d[0].abs() < 0.1 && (d[1] - offset).abs() < 0.1,
                    "offset {offset}, row {y}: {d:?}"
                );
            }
            // beyond the blending reach (2σ = 24 px from the last point) it
            // keeps its rigid placement
            for y in 0..side {
                let i = y * side + 63;
                assert_eq!(coord[i], [63.0 + 40.0, y as f64 + 40.0], "offset {offset}");
            }
            // and in between it fades, never beyond the offset, and only
            // across the courses
            for (i, c) in coord.iter().enumerate() {
                let s = c[1] - ((i / side) as f64 + 40.0);
                assert!(s.abs() <= offset.abs() + 1e-9, "offset {offset} at {i}: {s}");
                assert!(
                    (c[0] - ((i % side) as f64 + 40.0)).abs() < 1e-9,
                    "offset {offset} at {i}: {c:?}"
                );
            }
        }
    }

    #[test]
    fn a_new_patch_that_meets_the_old_one_stays_rigid_and_no_shift_exceeds_the_limit() {
        let side = 64;
        let rigid: Vec<[f64; 2]> = (0..side * side)
            .map(|i| [(i % side) as f64 + 40.0, (i / side) as f64 + 40.0])
            .collect();
        // the old courses are where the new patch puts them
        assert_eq!(aligned(0.0, 24), rigid);
        // half a course (6 rows) off, beyond the 4-pixel limit
        for (c, r) in aligned(6.0, 24).iter().zip(&rigid) {
            let d = ((c[0] - r[0]).powi(2) + (c[1] - r[1]).powi(2)).sqrt();
            assert!(d <= 4.0 + 1e-9, "{c:?} from {r:?}");
        }
    }
}
