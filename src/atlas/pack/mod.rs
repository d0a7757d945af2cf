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
mod tests;
