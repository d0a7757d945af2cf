//! Packing charts into the R×R atlas at one uniform texel density.
//!
//! Charts arrive in surface units (uv area = 3D area). The packer finds the
//! largest scale s (texels per surface unit) at which every chart fits, by
//! bisection on s. At each scale a chart is rasterized into its footprint —
//! the texels the rasterizer will cover (centres within
//! [`COVER_RADIUS`] of a triangle), dilated by half the gutter — in each of
//! its four quarter turns (and, where those do not fit a scale and eighth
//! turns are asked for, the four again after an eighth turn), and placed
//! first-fit: each chart (largest first) takes the orientation and place
//! where its footprint first fits among the
//! texels already taken, scanning rows from the top and columns from the
//! left. Taken texels are kept as runs per row, so the holes between and
//! inside charts placed earlier are filled like open space: chart shapes
//! nest into each other's outlines instead of each claiming its bounding
//! rectangle. The bisection starts at the scale where shelf packing of the
//! padded bounding rectangles fits; shelves remain the fallback when
//! first-fit fits no larger scale.

use rayon::prelude::*;

use super::overlap::orient;

/// Texel centres this close (in texels) to a chart triangle are covered.
pub const COVER_RADIUS: f64 = 0.75;

/// A chart as the packer sees it: its uv (surface units, from 0 to
/// `extent`) and triangles.
pub struct Shape<'a> {
    pub uv: &'a [[f32; 2]],
    pub triangles: &'a [[u32; 3]],
    pub extent: [f64; 2],
}

/// Where each chart goes.
#[derive(Clone, Debug, PartialEq)]
pub struct Packing {
    /// Texels per surface unit, the same for every chart.
    pub scale: f64,
    /// Per chart, the atlas texel position of the corner of its box.
    pub offsets: Vec<[f64; 2]>,
    /// Per chart, its orientation: quarter turns (0-3, clockwise in the
    /// atlas) of its box, 4-7 the same after an eighth turn of the chart.
    pub turns: Vec<u8>,
}

impl Packing {
    /// Atlas texel coordinates of chart point `uv` (surface units) of a
    /// chart with `extent`: v is flipped (atlas rows run down, and the
    /// charts' uv is right-handed, so that keeps triangles counter-clockwise
    /// as seen on the surface), the box turned and moved into place.
    pub fn place(&self, chart: usize, extent: [f64; 2], uv: [f32; 2]) -> [f64; 2] {
        let t = in_box(self.turns[chart], extent, self.scale, uv);
        let o = self.offsets[chart];
        [o[0] + t[0], o[1] + t[1]]
    }
}

/// The quarter turns of a chart's box, orientations 0-3.
const QUARTER_TURNS: u8 = 4;
/// Orientations a chart is tried in with eighth turns: the quarter turns,
/// and the same four after an eighth turn.
const ORIENTATIONS: u8 = 2 * QUARTER_TURNS;

/// The box of a chart with `extent` in orientation `k` before its quarter
/// turns: the chart's own box, or for `k` ≥ 4 the box of the chart turned
/// an eighth counter-clockwise (that of its turned box, a square).
fn box_extent(k: u8, extent: [f64; 2]) -> [f64; 2] {
    if k >= QUARTER_TURNS {
        let side = (extent[0] + extent[1]) * std::f64::consts::FRAC_1_SQRT_2;
        [side, side]
    } else {
        extent
    }
}

/// Chart point `uv` (surface units) of a chart with `extent`, in texels
/// within its box at `scale`: for `k` ≥ 4 first turned an eighth
/// counter-clockwise in its box (see [`box_extent`]), then v flipped (see
/// [`Packing::place`]), the box turned `k` quarter turns. The packer's
/// footprints and the rasterizer's corners both go through here, so they
/// agree to the bit.
fn in_box(k: u8, extent: [f64; 2], scale: f64, uv: [f32; 2]) -> [f64; 2] {
    let (u, v) = (uv[0] as f64, uv[1] as f64);
    let p = if k >= QUARTER_TURNS {
        let s = std::f64::consts::FRAC_1_SQRT_2;
        [(u - v) * s + extent[1] * s, (u + v) * s]
    } else {
        [u, v]
    };
    let e = box_extent(k, extent);
    let local = [p[0] * scale, (e[1] - p[1]) * scale];
    turn(k, local, [e[0] * scale, e[1] * scale])
}

/// `p` in a `box_`-sized box turned by `k` quarter turns (a rotation: the
/// winding of triangles is kept), in the turned box.
fn turn(k: u8, p: [f64; 2], box_: [f64; 2]) -> [f64; 2] {
    match k % 4 {
        0 => p,
        1 => [box_[1] - p[1], p[0]],
        2 => [box_[0] - p[0], box_[1] - p[1]],
        _ => [p[1], box_[0] - p[0]],
    }
}

/// Texels kept free around each chart: half the gutter plus the coverage
/// dilation of the rasterizer (under one texel).
fn padding(gutter: usize) -> f64 {
    gutter as f64 / 2.0 + 1.0
}

/// Shelf-packs rectangles of `extents · scale` (plus padding) into
/// `resolution`²; the offsets, or `None` if they do not fit.
fn shelf(
    extents: &[[f64; 2]],
    order: &[usize],
    scale: f64,
    resolution: usize,
    gutter: usize,
) -> Option<Vec<[f64; 2]>> {
    let pad = padding(gutter);
    let r = resolution as f64;
    let mut offsets = vec![[0.0; 2]; extents.len()];
    let (mut x, mut y, mut shelf_h) = (0.0f64, 0.0f64, 0.0f64);
    for &c in order {
        let w = (extents[c][0] * scale + 2.0 * pad).ceil();
        let h = (extents[c][1] * scale + 2.0 * pad).ceil();
        if w > r || h > r {
            return None;
        }
        if x + w > r {
            x = 0.0;
            y += shelf_h;
            shelf_h = 0.0;
        }
        if y + h > r {
            return None;
        }
        offsets[c] = [x + pad, y + pad];
        x += w;
        shelf_h = shelf_h.max(h);
    }
    Some(offsets)
}

/// A chart's footprint in one turn: the texels it claims, as runs along
/// the rows of its bitmap, and the integer margin between the bitmap's
/// corner and the chart's box.
struct Footprint {
    /// Per bitmap row, the range of `spans` holding its runs.
    rows: Vec<(u32, u32)>,
    /// Runs `[start, end)` of claimed columns, row after row.
    spans: Vec<(i32, i32)>,
    margin: i32,
}

impl Footprint {
    /// The footprint of `shape` at `scale`, turned `k` times: texels whose
    /// centre is within [`COVER_RADIUS`] of a triangle, dilated by `grow`
    /// texels (Chebyshev). Holes stay holes, so other charts can use them.
    fn new(shape: &Shape, scale: f64, k: u8, grow: i32) -> Footprint {
        let e = box_extent(k, shape.extent);
        let box_ = [e[0] * scale, e[1] * scale];
        let turned = if k % 2 == 1 { [box_[1], box_[0]] } else { box_ };
        let margin = COVER_RADIUS.ceil() as i32 + grow + 1;
        let w = turned[0].ceil() as i32 + 2 * margin;
        let h = turned[1].ceil() as i32 + 2 * margin;
        // covered columns as half-open runs (row, start, end)
        let mut covered: Vec<(i32, i32, i32)> = Vec::new();
        let m = margin as f64;
        for t in shape.triangles {
            let p = t.map(|v| {
                let q = in_box(k, shape.extent, scale, shape.uv[v as usize]);
                [q[0] + m, q[1] + m]
            });
            let r = COVER_RADIUS + 1e-6;
            if orient(p[0], p[1], p[2]).abs() < 1e-18 {
                continue; // covers nothing (see closest_on_triangle)
            }
            let y_lo = (p.iter().map(|c| c[1]).fold(f64::INFINITY, f64::min) - r - 0.5).ceil() as i32;
            let y_hi = (p.iter().map(|c| c[1]).fold(f64::NEG_INFINITY, f64::max) + r - 0.5).floor() as i32;
            for y in y_lo.max(0)..=y_hi.min(h - 1) {
                let Some((a, b)) = near_on_row(&p, y as f64 + 0.5, r) else {
                    continue;
                };
                let x0 = ((a - 0.5).ceil() as i32).max(0);
                let x1 = ((b - 0.5).floor() as i32).min(w - 1);
                if x0 <= x1 {
                    covered.push((y, x0, x1 + 1));
                }
            }
        }
        // bucketed by row (a counting sort), each row's runs sorted
        let mut start = vec![0usize; h as usize + 1];
        for &(y, _, _) in &covered {
            start[y as usize + 1] += 1;
        }
        for y in 0..h as usize {
            start[y + 1] += start[y];
        }
        let mut by_row = vec![(0i32, 0i32); covered.len()];
        let mut next = start.clone();
        for &(y, a, b) in &covered {
            by_row[next[y as usize]] = (a, b);
            next[y as usize] += 1;
        }
        // Chebyshev dilation by `grow`: each run widened along its row, then
        // each row the union of the rows within `grow` of it
        let mut wide_rows = vec![(0u32, 0u32); h as usize];
        let mut wide = Vec::with_capacity(covered.len());
        for y in 0..h as usize {
            let row = &mut by_row[start[y]..start[y + 1]];
            row.sort_unstable();
            let first = wide.len();
            for &(a, b) in row.iter() {
                join_run(&mut wide, first, ((a - grow).max(0), (b + grow).min(w)));
            }
            wide_rows[y] = (first as u32, wide.len() as u32);
        }
        let mut rows = Vec::with_capacity(h as usize);
        let mut spans = Vec::new();
        let mut near = Vec::new();
        for y in 0..h {
            near.clear();
            for yy in (y - grow).max(0)..=(y + grow).min(h - 1) {
                let (a, b) = wide_rows[yy as usize];
                near.extend_from_slice(&wide[a as usize..b as usize]);
            }
            near.sort_unstable();
            let first = spans.len();
            for &run in &near {
                join_run(&mut spans, first, run);
            }
            rows.push((first as u32, spans.len() as u32));
        }
        Footprint { rows, spans, margin }
    }

    /// The first and one past the last bitmap row holding a run.
    fn used_rows(&self) -> Option<(i32, i32)> {
        let first = self.rows.iter().position(|r| r.1 > r.0)? as i32;
        let last = self.rows.iter().rposition(|r| r.1 > r.0)? as i32;
        Some((first, last + 1))
    }

    /// The first and one past the last bitmap column holding a run.
    fn used_columns(&self) -> Option<(i32, i32)> {
        let a = self.spans.iter().map(|s| s.0).min()?;
        let b = self.spans.iter().map(|s| s.1).max()?;
        Some((a, b))
    }

    /// Where the footprint first fits into `occupied`, scanning every
    /// `stride`-th row from the top and columns from the left: (row,
    /// column) of its bitmap's corner, so that every run lands on free
    /// texels inside `r`²; `None` if it fits nowhere. Holes left between
    /// charts placed earlier are tried like any free space.
    fn first_fit(&self, occupied: &Occupied, r: i32, stride: i32) -> Option<(i32, i32)> {
        let (top, bottom) = self.used_rows()?;
        let (left, right) = self.used_columns()?;
        // per row, its longest run; runs are tried longest first, as they
        // are the likeliest to meet taken texels
        let longest: Vec<i32> = (top..bottom)
            .map(|j| {
                let (a, b) = self.rows[j as usize];
                self.spans[a as usize..b as usize]
                    .iter()
                    .map(|&(s, e)| e - s)
                    .max()
                    .unwrap_or(0)
            })
            .collect();
        let mut runs: Vec<(i32, i32, i32)> = (top..bottom)
            .flat_map(|j| {
                let (a, b) = self.rows[j as usize];
                self.spans[a as usize..b as usize]
                    .iter()
                    .map(move |&(s, e)| (j, s, e))
            })
            .collect();
        runs.sort_by_key(|&(j, s, e)| (s - e, j, s));
        for y in (-top..=r - bottom).step_by(stride as usize) {
            // rows without a free stretch as long as the chart's run there
            if (top..bottom).any(|j| occupied.widest[(y + j) as usize] < longest[(j - top) as usize]) {
                continue;
            }
            let mut x = -left;
            'place: while x + right <= r {
                for &(j, s, e) in &runs {
                    if let Some(end) = occupied.blocked(y + j, x + s, x + e) {
                        // the run must start past the occupied texels
                        x = end - s;
                        continue 'place;
                    }
                }
                return Some((y, x));
            }
        }
        None
    }
}

/// Appends the half-open `run` to the sorted maximal runs `out[first..]`,
/// joining it to the last when they overlap or touch; runs arrive sorted by
/// start.
fn join_run(out: &mut Vec<(i32, i32)>, first: usize, run: (i32, i32)) {
    let n = out.len();
    if n > first && run.0 <= out[n - 1].1 {
        out[n - 1].1 = out[n - 1].1.max(run.1);
    } else {
        out.push(run);
    }
}

/// The atlas texels taken so far, as sorted disjoint runs per row.
struct Occupied {
    rows: Vec<Vec<(i32, i32)>>,
    /// Per row, its longest free stretch.
    widest: Vec<i32>,
    r: i32,
}

impl Occupied {
    fn new(r: usize) -> Occupied {
        Occupied {
            rows: vec![Vec::new(); r],
            widest: vec![r as i32; r],
            r: r as i32,
        }
    }

    /// If a taken run of row `y` meets `[a, b)`, the end of the first such.
    fn blocked(&self, y: i32, a: i32, b: i32) -> Option<i32> {
        let row = &self.rows[y as usize];
        let i = row.partition_point(|&(_, e)| e <= a);
        row.get(i).filter(|&&(s, _)| s < b).map(|&(_, e)| e)
    }

    /// Marks `[a, b)` of row `y` taken (it was free).
    fn take(&mut self, y: i32, a: i32, b: i32) {
        let row = &mut self.rows[y as usize];
        let i = row.partition_point(|&(_, e)| e < a);
        // merge with touching neighbours
        let mut run = (a, b);
        let mut j = i;
        while j < row.len() && row[j].0 <= b {
            run = (run.0.min(row[j].0), run.1.max(row[j].1));
            j += 1;
        }
        row.splice(i..j, [run]);
        let mut widest = 0;
        let mut free_from = 0;
        for &(s, e) in row.iter() {
            widest = widest.max(s - free_from);
            free_from = e;
        }
        self.widest[y as usize] = widest.max(self.r - free_from);
    }
}

/// The stretch of the line at height `y` within `r` of triangle `p`: the
/// triangle grown by a disc is convex, so it is the hull of what the line
/// keeps of the three edges grown by the disc (a slab beside each edge and
/// a disc at each corner). `None` if the line misses it.
fn near_on_row(p: &[[f64; 2]; 3], y: f64, r: f64) -> Option<(f64, f64)> {
    let mut lo = f64::INFINITY;
    let mut hi = f64::NEG_INFINITY;
    for e in 0..3 {
        let (a, b) = (p[e], p[(e + 1) % 3]);
        let dy = y - a[1];
        if dy.abs() <= r {
            let half = (r * r - dy * dy).sqrt();
            lo = lo.min(a[0] - half);
            hi = hi.max(a[0] + half);
        }
        let (ex, ey) = (b[0] - a[0], b[1] - a[1]);
        let len = (ex * ex + ey * ey).sqrt();
        if len == 0.0 {
            continue;
        }
        let (ux, uy) = (ex / len, ey / len);
        // along the edge: 0 ≤ (x - ax)·ux + dy·uy ≤ len;
        // across it: |-(x - ax)·uy + dy·ux| ≤ r
        let mut span = (f64::NEG_INFINITY, f64::INFINITY);
        let mut keep = |coef: f64, c0: f64, lo_v: f64, hi_v: f64| -> bool {
            // lo_v ≤ coef·t + c0 ≤ hi_v with t = x - ax
            if coef.abs() < 1e-300 {
                return c0 >= lo_v && c0 <= hi_v;
            }
            let (t0, t1) = ((lo_v - c0) / coef, (hi_v - c0) / coef);
            let (t0, t1) = if t0 <= t1 { (t0, t1) } else { (t1, t0) };
            span = (span.0.max(t0), span.1.min(t1));
            span.0 <= span.1
        };
        if keep(ux, dy * uy, 0.0, len) && keep(-uy, dy * ux, -r, r) {
            lo = lo.min(a[0] + span.0);
            hi = hi.max(a[0] + span.1);
        }
    }
    (lo <= hi).then_some((lo, hi))
}

/// Barycentrics of `q` in triangle `p`, and the distance from `q` to the
/// triangle with the barycentrics of the closest point; `None` for a
/// degenerate triangle (which covers nothing). The packer's footprints and
/// the rasterizer's coverage both use it, so they agree texel for texel.
pub(super) fn closest_on_triangle(p: &[[f64; 2]; 3], q: [f64; 2]) -> Option<(f64, [f64; 3])> {
    let v0 = [p[1][0] - p[0][0], p[1][1] - p[0][1]];
    let v1 = [p[2][0] - p[0][0], p[2][1] - p[0][1]];
    let v2 = [q[0] - p[0][0], q[1] - p[0][1]];
    let d = v0[0] * v1[1] - v1[0] * v0[1];
    if d.abs() < 1e-18 {
        return None;
    }
    let l1 = (v2[0] * v1[1] - v1[0] * v2[1]) / d;
    let l2 = (v0[0] * v2[1] - v2[0] * v0[1]) / d;
    let l0 = 1.0 - l1 - l2;
    if l0 >= 0.0 && l1 >= 0.0 && l2 >= 0.0 {
        return Some((0.0, [l0, l1, l2]));
    }
    // closest point on the three edges
    let mut best = (f64::INFINITY, [0.0; 3]);
    for e in 0..3 {
        let (a, b) = (p[e], p[(e + 1) % 3]);
        let ab = [b[0] - a[0], b[1] - a[1]];
        let len2 = ab[0] * ab[0] + ab[1] * ab[1];
        let t = if len2 > 0.0 {
            (((q[0] - a[0]) * ab[0] + (q[1] - a[1]) * ab[1]) / len2).clamp(0.0, 1.0)
        } else {
            0.0
        };
        let c = [a[0] + t * ab[0], a[1] + t * ab[1]];
        let dist = ((q[0] - c[0]).powi(2) + (q[1] - c[1]).powi(2)).sqrt();
        if dist < best.0 {
            let mut bary = [0.0; 3];
            bary[e] = 1.0 - t;
            bary[(e + 1) % 3] = t;
            best = (dist, bary);
        }
    }
    Some(best)
}

/// Places the charts (in `order`) one after another at `scale`, each in
/// the first `orientations` whose footprint fits first (topmost row, then
/// leftmost column): per chart the offset of its box and its orientation,
/// or `None` if one does not fit.
fn first_fit(
    shapes: &[Shape],
    order: &[usize],
    scale: f64,
    resolution: usize,
    gutter: usize,
    orientations: u8,
) -> Option<(Vec<[f64; 2]>, Vec<u8>)> {
    let r = resolution as i32;
    // half the gutter on each chart: two footprints that do not meet leave
    // at least 2·grow ≥ gutter free texels between covered ones
    let grow = (gutter as i32 + 1) / 2;
    // rows tried: every one up to 1024², a stride above
    let stride = (resolution / 1024).max(1) as i32;
    let mut occupied = Occupied::new(resolution);
    let mut offsets = vec![[0.0; 2]; shapes.len()];
    let mut turns = vec![0u8; shapes.len()];
    for &c in order {
        let tries: Vec<(Footprint, Option<(i32, i32)>)> = (0..orientations)
            .into_par_iter()
            .map(|k| {
                let f = Footprint::new(&shapes[c], scale, k, grow);
                let at = f.first_fit(&occupied, r, stride);
                (f, at)
            })
            .collect();
        let (k, (y, x)) = tries
            .iter()
            .enumerate()
            .filter_map(|(k, t)| t.1.map(|p| (k as u8, p)))
            .min_by_key(|&(k, p)| (p, k))?;
        let f = &tries[k as usize].0;
        for (j, &(a, b)) in f.rows.iter().enumerate() {
            for &(s, e) in &f.spans[a as usize..b as usize] {
                occupied.take(y + j as i32, x + s, x + e);
            }
        }
        offsets[c] = [(x + f.margin) as f64, (y + f.margin) as f64];
        turns[c] = k;
    }
    Some((offsets, turns))
}

/// Packs the charts into `resolution`² with at least `gutter` texels
/// between the texels the rasterizer covers (see the module documentation);
/// with `eighth_turns`, charts are also tried after an eighth turn where
/// their quarter turns do not fit a scale.
pub fn pack(shapes: &[Shape], resolution: usize, gutter: usize, eighth_turns: bool) -> Packing {
    let extents: Vec<[f64; 2]> = shapes.iter().map(|s| s.extent).collect();
    // tallest first (ties by index), so shelves fill evenly
    let mut order: Vec<usize> = (0..extents.len()).collect();
    order.sort_by(|&a, &b| extents[b][1].total_cmp(&extents[a][1]).then(a.cmp(&b)));
    let area: f64 = extents.iter().map(|e| e[0] * e[1]).sum::<f64>().max(1e-30);
    // upper bound: the charts' total area cannot exceed the atlas
    let top = resolution as f64 / area.sqrt();
    let (mut lo, mut hi) = (0.0, top);
    for _ in 0..60 {
        let mid = 0.5 * (lo + hi);
        if shelf(&extents, &order, mid, resolution, gutter).is_some() {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    let shelf_scale = lo;
    // first-fit, largest uv area first, from the shelf's scale up to what
    // the charts' own area allows
    let uv_area = |s: &Shape| {
        s.triangles
            .iter()
            .map(|t| {
                let p = t.map(|v| s.uv[v as usize]);
                0.5 * ((p[1][0] - p[0][0]) * (p[2][1] - p[0][1]) - (p[2][0] - p[0][0]) * (p[1][1] - p[0][1]))
                    as f64
            })
            .sum::<f64>()
    };
    let areas: Vec<f64> = shapes.iter().map(uv_area).collect();
    let mut by_area: Vec<usize> = (0..shapes.len()).collect();
    by_area.sort_by(|&a, &b| areas[b].total_cmp(&areas[a]).then(a.cmp(&b)));
    let total: f64 = areas.iter().sum::<f64>().max(1e-30);
    let (mut lo, mut hi) = (shelf_scale, resolution as f64 / total.sqrt());
    let mut found = None;
    if hi > lo {
        for _ in 0..12 {
            let mid = 0.5 * (lo + hi);
            // quarter turns alone, or with eighth turns too: the greedy
            // placement is not monotone in its choices, so either may fit
            let fit = first_fit(shapes, &by_area, mid, resolution, gutter, QUARTER_TURNS).or_else(|| {
                eighth_turns
                    .then(|| first_fit(shapes, &by_area, mid, resolution, gutter, ORIENTATIONS))
                    .flatten()
            });
            match fit {
                Some(p) => {
                    lo = mid;
                    found = Some(p);
                }
                None => hi = mid,
            }
        }
    }
    match found {
        Some((offsets, turns)) => Packing {
            scale: lo,
            offsets,
            turns,
        },
        None => {
            let offsets = shelf(&extents, &order, shelf_scale, resolution, gutter)
                .unwrap_or_else(|| vec![[0.0; 2]; extents.len()]);
            Packing {
                scale: shelf_scale,
                offsets,
                turns: vec![0; extents.len()],
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The unit squares `(x, y)` of a `w`×`h` grid that `keep` keeps, as
    /// triangles counter-clockwise in surface units.
    fn cells(w: usize, h: usize, keep: impl Fn(usize, usize) -> bool) -> (Vec<[f32; 2]>, Vec<[u32; 3]>) {
        let id = |x: usize, y: usize| (y * (w + 1) + x) as u32;
        let uv = (0..=h)
            .flat_map(|y| (0..=w).map(move |x| [x as f32, y as f32]))
            .collect();
        let mut tris = Vec::new();
        for y in 0..h {
            for x in 0..w {
                if keep(x, y) {
                    tris.push([id(x, y), id(x + 1, y), id(x + 1, y + 1)]);
                    tris.push([id(x, y), id(x + 1, y + 1), id(x, y + 1)]);
                }
            }
        }
        (uv, tris)
    }

    /// An L-shaped chart (`w`×`h` box, arms `t` thick).
    fn ell(w: usize, h: usize, t: usize) -> (Vec<[f32; 2]>, Vec<[u32; 3]>) {
        cells(w, h, |x, y| x < t || y < t)
    }

    /// Texels the rasterizer covers for each chart at its packed place.
    fn covered(shapes: &[Shape], p: &Packing, r: usize) -> Vec<Vec<(i64, i64)>> {
        shapes
            .iter()
            .enumerate()
            .map(|(c, s)| {
                let mut out = Vec::new();
                for t in s.triangles {
                    let q = t.map(|v| p.place(c, s.extent, s.uv[v as usize]));
                    let lo = |i: usize| {
                        (q.iter().map(|c| c[i]).fold(f64::INFINITY, f64::min) - 2.0).floor() as i64
                    };
                    let hi = |i: usize| {
                        (q.iter().map(|c| c[i]).fold(f64::NEG_INFINITY, f64::max) + 2.0).ceil() as i64
                    };
                    for y in lo(1)..=hi(1) {
                        for x in lo(0)..=hi(0) {
                            if closest_on_triangle(&q, [x as f64 + 0.5, y as f64 + 0.5])
                                .is_some_and(|(d, _)| d <= COVER_RADIUS)
                            {
                                out.push((x, y));
                            }
                        }
                    }
                }
                out.sort_unstable();
                out.dedup();
                assert!(out
                    .iter()
                    .all(|&(x, y)| x >= 0 && y >= 0 && x < r as i64 && y < r as i64));
                out
            })
            .collect()
    }

    #[test]
    fn packed_charts_keep_the_gutter_and_nest() {
        let charts: Vec<(Vec<[f32; 2]>, Vec<[u32; 3]>)> = (0..24)
            .map(|i| ell(3 + i % 5, 2 + (i * 3) % 6, 1 + i % 2))
            .collect();
        let shapes: Vec<Shape> = charts
            .iter()
            .map(|(uv, t)| {
                let ex = uv
                    .iter()
                    .fold([0f64; 2], |m, p| [m[0].max(p[0] as f64), m[1].max(p[1] as f64)]);
                Shape {
                    uv,
                    triangles: t,
                    extent: ex,
                }
            })
            .collect();
        let (r, gutter) = (256usize, 2usize);
        for eighth_turns in [false, true] {
            let p = pack(&shapes, r, gutter, eighth_turns);
            let most = if eighth_turns { ORIENTATIONS } else { QUARTER_TURNS };
            assert!(p.scale > 0.0 && p.turns.iter().all(|&k| k < most));
            let cover = covered(&shapes, &p, r);
            // owner per texel: no texel twice, and at least `gutter` free
            // texels between two charts along rows and columns
            let mut owner = vec![usize::MAX; r * r];
            for (c, texels) in cover.iter().enumerate() {
                for &(x, y) in texels {
                    let o = &mut owner[y as usize * r + x as usize];
                    assert_eq!(*o, usize::MAX, "texel ({x}, {y}) in two charts");
                    *o = c;
                }
            }
            let g = gutter as i64;
            for (c, texels) in cover.iter().enumerate() {
                for &(x, y) in texels {
                    for dy in -g..=g {
                        for dx in -g..=g {
                            let (nx, ny) = (x + dx, y + dy);
                            if nx >= 0 && ny >= 0 && nx < r as i64 && ny < r as i64 {
                                let o = owner[ny as usize * r + nx as usize];
                                assert!(
                                    o == usize::MAX || o == c,
                                    "charts {c} and {o} closer than the gutter"
                                );
                            }
                        }
                    }
                }
            }
            // the L shapes nest: a larger scale than their bounding rectangles
            // allow on shelves
            let extents: Vec<[f64; 2]> = shapes.iter().map(|s| s.extent).collect();
            let order: Vec<usize> = (0..extents.len()).collect();
            assert!(
                shelf(&extents, &order, p.scale, r, gutter).is_none(),
                "scale {}",
                p.scale
            );
            // and the turned boxes keep every triangle counter-clockwise
            for (c, s) in shapes.iter().enumerate() {
                for t in s.triangles {
                    let q = t.map(|v| p.place(c, s.extent, s.uv[v as usize]));
                    // atlas rows run down: counter-clockwise on the surface is
                    // clockwise in (x, y-down)
                    let d =
                        (q[1][0] - q[0][0]) * (q[2][1] - q[0][1]) - (q[2][0] - q[0][0]) * (q[1][1] - q[0][1]);
                    assert!(d < 0.0, "chart {c} turn {}", p.turns[c]);
                }
            }
        }
    }

    #[test]
    fn a_small_chart_fills_the_hole_of_a_large_one() {
        // a square ring (12 units, arms 2 thick) and a 3-unit square: at the
        // largest scale the ring spans the atlas, and the square must go
        // into its hole
        let ring = cells(12, 12, |x, y| x < 2 || y < 2 || x >= 10 || y >= 10);
        let square = cells(3, 3, |_, _| true);
        let shapes = [
            Shape {
                uv: &ring.0,
                triangles: &ring.1,
                extent: [12.0, 12.0],
            },
            Shape {
                uv: &square.0,
                triangles: &square.1,
                extent: [3.0, 3.0],
            },
        ];
        let r = 128;
        let p = pack(&shapes, r, 2, false);
        let cover = covered(&shapes, &p, r);
        let span = |c: usize, i: usize| {
            let v = cover[c].iter().map(|t| if i == 0 { t.0 } else { t.1 });
            (v.clone().min().unwrap(), v.max().unwrap())
        };
        for i in 0..2 {
            let (ring_lo, ring_hi) = span(0, i);
            let (sq_lo, sq_hi) = span(1, i);
            assert!(ring_hi - ring_lo > r as i64 * 3 / 4, "the ring spans the atlas");
            assert!(sq_lo > ring_lo && sq_hi < ring_hi, "the square sits in the hole");
        }
    }

    #[test]
    fn rows_near_a_triangle_match_the_closest_point_test() {
        // thin, wide, tiny and obtuse triangles, both windings
        let tris = [
            [[1.3, 2.2], [9.7, 3.1], [4.4, 8.9]],
            [[2.0, 2.0], [12.5, 2.3], [7.0, 2.6]],
            [[5.1, 5.2], [5.4, 5.1], [5.2, 5.5]],
            [[1.0, 6.0], [11.0, 6.0], [2.0, 7.5]],
            [[3.0, 1.0], [3.2, 11.0], [2.9, 6.0]],
        ];
        let r = COVER_RADIUS;
        for p in tris {
            for q in [p, [p[0], p[2], p[1]]] {
                for y in 0..16 {
                    let yc = y as f64 + 0.5;
                    let row = near_on_row(&q, yc, r);
                    for x in 0..16 {
                        let xc = x as f64 + 0.5;
                        let near = closest_on_triangle(&q, [xc, yc]).is_some_and(|(d, _)| d <= r);
                        let inside = row.is_some_and(|(a, b)| a <= xc && xc <= b);
                        assert_eq!(near, inside, "{q:?} texel ({x}, {y}) row {row:?}");
                    }
                }
            }
        }
    }

    #[test]
    fn quarter_turns_are_rotations_of_the_box() {
        let b = [3.0, 2.0];
        for k in 0..QUARTER_TURNS {
            let corners = [[0.0, 0.0], [3.0, 0.0], [3.0, 2.0], [0.0, 2.0]].map(|p| turn(k, p, b));
            let size = if k % 2 == 1 { [2.0, 3.0] } else { b };
            for c in corners {
                assert!(c[0] >= 0.0 && c[1] >= 0.0 && c[0] <= size[0] && c[1] <= size[1]);
            }
            // a rotation keeps the winding of the box
            let d = (corners[1][0] - corners[0][0]) * (corners[2][1] - corners[0][1])
                - (corners[2][0] - corners[0][0]) * (corners[1][1] - corners[0][1]);
            assert!(d > 0.0, "turn {k}");
        }
    }

    #[test]
    fn every_orientation_keeps_the_chart_in_its_box_and_its_winding() {
        let extent = [3.0, 2.0];
        let corners: [[f32; 2]; 4] = [[0.0, 0.0], [3.0, 0.0], [3.0, 2.0], [0.0, 2.0]];
        let scale = 1.5;
        for k in 0..ORIENTATIONS {
            let e = box_extent(k, extent);
            let size = if k % 2 == 1 { [e[1], e[0]] } else { e };
            let p = corners.map(|c| in_box(k, extent, scale, c));
            for q in p {
                for d in 0..2 {
                    assert!(
                        q[d] >= -1e-9 && q[d] <= size[d] * scale + 1e-9,
                        "orientation {k}: {q:?} in {size:?}"
                    );
                }
            }
            // lengths kept (a rotation, then a mirror in v)
            let len = |a: [f64; 2], b: [f64; 2]| (a[0] - b[0]).hypot(a[1] - b[1]);
            assert!(
                (len(p[0], p[1]) - 3.0 * scale).abs() < 1e-9 && (len(p[1], p[2]) - 2.0 * scale).abs() < 1e-9
            );
            // v flipped: counter-clockwise on the surface, clockwise in rows
            let d = (p[1][0] - p[0][0]) * (p[2][1] - p[0][1]) - (p[2][0] - p[0][0]) * (p[1][1] - p[0][1]);
            assert!(d < 0.0, "orientation {k}");
            // an eighth turn lays the box's bottom edge at 45°
            let angle = (p[1][1] - p[0][1])
                .atan2(p[1][0] - p[0][0])
                .to_degrees()
                .rem_euclid(90.0);
            let want = if k >= QUARTER_TURNS { 45.0 } else { 0.0 };
            assert!(
                (angle - want).abs() < 1e-6 || (angle - want).abs() > 90.0 - 1e-6,
                "orientation {k}: {angle}"
            );
        }
    }
}
