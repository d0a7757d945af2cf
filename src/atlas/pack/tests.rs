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
                let lo =
                    |i: usize| (q.iter().map(|c| c[i]).fold(f64::INFINITY, f64::min) - 2.0).floor() as i64;
                let hi =
                    |i: usize| (q.iter().map(|c| c[i]).fold(f64::NEG_INFINITY, f64::max) + 2.0).ceil() as i64;
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
                let d = (q[1][0] - q[0][0]) * (q[2][1] - q[0][1]) - (q[2][0] - q[0][0]) * (q[1][1] - q[0][1]);
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
        assert!((len(p[0], p[1]) - 3.0 * scale).abs() < 1e-9 && (len(p[1], p[2]) - 2.0 * scale).abs() < 1e-9);
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
