//! Global overlap of a chart's map: whether its uv layout covers some point
//! twice although no triangle is flipped.
//!
//! With every triangle of a disk positively oriented, the number of
//! triangles covering a uv point (off the edges) is the winding number of
//! the chart's boundary around it. It is at most one everywhere exactly when
//! the boundary is a simple closed curve, so a chart folds over itself (an
//! ear of a head laid over the cheek, the rim of a cup over its side) if and
//! only if two of its boundary edges cross. Those crossings are found here
//! with a uniform grid over the boundary's bounding box.

/// The chart's boundary edges: corners `(a, b)` of triangle edges that no
/// other triangle of the chart uses, in triangle order.
fn boundary_edges(triangles: &[[u32; 3]]) -> Vec<[u32; 2]> {
    // every undirected edge once per use, sorted: the unpaired ones are the
    // boundary
    let mut edges: Vec<([u32; 2], u32)> = triangles
        .iter()
        .enumerate()
        .flat_map(|(f, t)| (0..3).map(move |i| ((t[i], t[(i + 1) % 3]), f as u32 * 3 + i as u32)))
        .map(|((a, b), at)| ([a.min(b), a.max(b)], at))
        .collect();
    edges.sort_unstable();
    let mut out: Vec<(u32, [u32; 2])> = Vec::new();
    let mut i = 0;
    while i < edges.len() {
        let mut j = i + 1;
        while j < edges.len() && edges[j].0 == edges[i].0 {
            j += 1;
        }
        if j - i == 1 {
            let at = edges[i].1;
            let t = triangles[at as usize / 3];
            let k = at as usize % 3;
            out.push((at, [t[k], t[(k + 1) % 3]]));
        }
        i = j;
    }
    out.sort_unstable();
    out.into_iter().map(|(_, e)| e).collect()
}

/// Twice the signed area of (a, b, c).
pub(super) fn orient(a: [f64; 2], b: [f64; 2], c: [f64; 2]) -> f64 {
    (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0])
}

/// Whether segments (p, q) and (r, s) cross at a point inside both (a
/// proper crossing: each separates the other's ends strictly).
fn cross(p: [f64; 2], q: [f64; 2], r: [f64; 2], s: [f64; 2]) -> bool {
    let (d1, d2) = (orient(r, s, p), orient(r, s, q));
    let (d3, d4) = (orient(p, q, r), orient(p, q, s));
    ((d1 > 0.0 && d2 < 0.0) || (d1 < 0.0 && d2 > 0.0)) && ((d3 > 0.0 && d4 < 0.0) || (d3 < 0.0 && d4 > 0.0))
}

/// Whether two boundary edges of the layout `uv` of `triangles` cross:
/// the chart then covers part of its uv domain twice (see the module
/// documentation). Edges sharing a corner are not compared.
pub(super) fn boundary_crosses(uv: &[[f64; 2]], triangles: &[[u32; 3]]) -> bool {
    let edges = boundary_edges(triangles);
    let n = edges.len();
    if n < 4 {
        return false;
    }
    let (mut lo, mut hi) = ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]);
    for e in &edges {
        for &v in e {
            let p = uv[v as usize];
            for k in 0..2 {
                lo[k] = lo[k].min(p[k]);
                hi[k] = hi[k].max(p[k]);
            }
        }
    }
    if !(lo[0].is_finite() && lo[1].is_finite() && hi[0].is_finite() && hi[1].is_finite()) {
        return false;
    }
    // about one edge per cell
    let g = ((n as f64).sqrt().ceil() as usize).clamp(1, 1024);
    let cell = |x: f64, k: usize| {
        let span = hi[k] - lo[k];
        if span <= 0.0 {
            0
        } else {
            (((x - lo[k]) / span * g as f64) as usize).min(g - 1)
        }
    };
    let range = |e: &[u32; 2], k: usize| {
        let (a, b) = (uv[e[0] as usize][k], uv[e[1] as usize][k]);
        (cell(a.min(b), k), cell(a.max(b), k))
    };
    // cells as a flat list of (cell, edge), sorted by cell
    let mut entries: Vec<(u32, u32)> = Vec::with_capacity(2 * n);
    for (i, e) in edges.iter().enumerate() {
        let ((x0, x1), (y0, y1)) = (range(e, 0), range(e, 1));
        for y in y0..=y1 {
            for x in x0..=x1 {
                entries.push(((y * g + x) as u32, i as u32));
            }
        }
    }
    entries.sort_unstable();
    let mut start = 0;
    while start < entries.len() {
        let mut end = start + 1;
        while end < entries.len() && entries[end].0 == entries[start].0 {
            end += 1;
        }
        let here = &entries[start..end];
        for (k, &(_, i)) in here.iter().enumerate() {
            let a = edges[i as usize];
            for &(_, j) in &here[k + 1..] {
                let b = edges[j as usize];
                if a.iter().any(|v| b.contains(v)) {
                    continue;
                }
                let p = |v: u32| uv[v as usize];
                if cross(p(a[0]), p(a[1]), p(b[0]), p(b[1])) {
                    return true;
                }
            }
        }
        start = end;
    }
    false
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A w×h grid of unit squares, two triangles each, counter-clockwise.
    fn grid(w: usize, h: usize) -> (Vec<[f64; 2]>, Vec<[u32; 3]>) {
        let uv = (0..=h)
            .flat_map(|y| (0..=w).map(move |x| [x as f64, y as f64]))
            .collect();
        let id = |x: usize, y: usize| (y * (w + 1) + x) as u32;
        let mut t = Vec::new();
        for y in 0..h {
            for x in 0..w {
                t.push([id(x, y), id(x + 1, y), id(x + 1, y + 1)]);
                t.push([id(x, y), id(x + 1, y + 1), id(x, y + 1)]);
            }
        }
        (uv, t)
    }

    /// Brute force over every pair of boundary edges.
    fn crosses_by_pairs(uv: &[[f64; 2]], triangles: &[[u32; 3]]) -> bool {
        let e = boundary_edges(triangles);
        (0..e.len()).any(|i| {
            (i + 1..e.len()).any(|j| {
                !e[i].iter().any(|v| e[j].contains(v))
                    && cross(
                        uv[e[i][0] as usize],
                        uv[e[i][1] as usize],
                        uv[e[j][0] as usize],
                        uv[e[j][1] as usize],
                    )
            })
        })
    }

    #[test]
    fn a_flat_grid_has_a_simple_boundary() {
        let (uv, t) = grid(7, 5);
        assert_eq!(boundary_edges(&t).len(), 2 * (7 + 5));
        assert!(!boundary_crosses(&uv, &t));
    }

    #[test]
    fn a_strip_wound_past_a_full_turn_crosses_itself() {
        // a strip of quads wound along a widening spiral: each quad turns
        // by `step`; no triangle flips, but past 360° the strip's end lies
        // over its start
        for (quads, step, folds) in [
            (30usize, 10.0f64, false),
            (37, 9.5, false),
            (40, 9.5, true),
            (50, 9.5, true),
        ] {
            let mut uv = Vec::new();
            for i in 0..=quads {
                let a = (i as f64 * step).to_radians();
                let inner = 10.0 + 0.05 * i as f64;
                for radius in [inner, inner + 2.0] {
                    uv.push([radius * a.cos(), radius * a.sin()]);
                }
            }
            let mut t = Vec::new();
            for i in 0..quads as u32 {
                let (a, b, c, d) = (2 * i, 2 * i + 1, 2 * i + 3, 2 * i + 2);
                t.push([a, d, c]);
                t.push([a, c, b]);
            }
            // every triangle keeps one orientation
            let signs: Vec<bool> = t
                .iter()
                .map(|f| orient(uv[f[0] as usize], uv[f[1] as usize], uv[f[2] as usize]) > 0.0)
                .collect();
            assert!(signs.iter().all(|&s| s == signs[0]));
            assert_eq!(boundary_crosses(&uv, &t), folds, "{quads} quads of {step}°");
            assert_eq!(crosses_by_pairs(&uv, &t), folds);
        }
    }

    #[test]
    fn the_grid_finds_what_every_pair_finds() {
        // random perturbations of a grid's vertices, some of which fold
        let mut state = 0x9e3779b97f4a7c15u64;
        let mut next = || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            (state >> 11) as f64 / (1u64 << 53) as f64
        };
        let mut seen = [0usize; 2];
        for _ in 0..300 {
            let (mut uv, t) = grid(6, 4);
            let amount = 2.0 * next();
            for p in &mut uv {
                p[0] += amount * (next() - 0.5);
                p[1] += amount * (next() - 0.5);
            }
            let by_pairs = crosses_by_pairs(&uv, &t);
            assert_eq!(boundary_crosses(&uv, &t), by_pairs);
            seen[by_pairs as usize] += 1;
        }
        assert!(seen[0] > 10 && seen[1] > 10, "{seen:?}");
    }
}
