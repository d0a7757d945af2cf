//! LSCM (Lévy et al. 2002) against exact flattenings, texture stretch
//! (Sander et al. 2001), and chart segmentation invariants on procedural and
//! shared meshes.

use std::collections::HashMap;
use std::path::Path;
use std::time::Instant;

use btfquilt::atlas::charts::{build_charts, Chart, ChartConfig};
use btfquilt::atlas::lscm::{area_distortion, lscm, signed_uv_areas, stretch};
use btfquilt::mesh::Mesh;

/// Deterministic pseudo-random numbers in [0, 1).
struct Lcg(u64);

impl Lcg {
    fn next(&mut self) -> f64 {
        self.0 = self
            .0
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (self.0 >> 11) as f64 / (1u64 << 53) as f64
    }
}

/// An irregular, non-convex planar triangulation: a graded grid (cells from
/// tiny to large) with jittered interior vertices, a notch cut out, warped by
/// a smooth orientation-preserving map. 2D points and counter-clockwise
/// triangles.
fn irregular_disk() -> (Vec<[f64; 2]>, Vec<[u32; 3]>) {
    let mut rng = Lcg(7);
    let n = 24;
    let mut pts = Vec::new();
    for j in 0..=n {
        for i in 0..=n {
            let (mut s, mut t) = (i as f64 / n as f64, j as f64 / n as f64);
            if i > 0 && i < n && j > 0 && j < n {
                s += 0.3 * (rng.next() - 0.5) / n as f64;
                t += 0.3 * (rng.next() - 0.5) / n as f64;
            }
            // grading: cells shrink towards the origin
            let (x, y) = (s.powf(1.8), t.powf(1.5));
            pts.push([
                x + 0.15 * (3.0 * y).sin(),
                y + 0.1 * (2.5 * x).sin() + 0.05 * x * y,
            ]);
        }
    }
    let id = |i: usize, j: usize| (j * (n + 1) + i) as u32;
    let mut tris = Vec::new();
    for j in 0..n {
        for i in 0..n {
            if i >= 2 * n / 3 && j >= n / 2 {
                continue; // notch
            }
            let (a, b, c, d) = (id(i, j), id(i + 1, j), id(i + 1, j + 1), id(i, j + 1));
            if rng.next() < 0.5 {
                tris.push([a, b, c]);
                tris.push([a, c, d]);
            } else {
                tris.push([a, b, d]);
                tris.push([b, c, d]);
            }
        }
    }
    // drop the vertices of the notch
    let mut used = vec![u32::MAX; pts.len()];
    let mut kept = Vec::new();
    for t in &mut tris {
        for v in t.iter_mut() {
            if used[*v as usize] == u32::MAX {
                used[*v as usize] = kept.len() as u32;
                kept.push(pts[*v as usize]);
            }
            *v = used[*v as usize];
        }
    }
    (kept, tris)
}

fn area2(a: [f64; 2], b: [f64; 2], c: [f64; 2]) -> f64 {
    0.5 * ((b[0] - a[0]) * (c[1] - a[1]) - (c[0] - a[0]) * (b[1] - a[1]))
}

/// Rotation matrix from axis-angle.
fn rotation(axis: [f64; 3], angle: f64) -> [[f64; 3]; 3] {
    let l = (axis[0] * axis[0] + axis[1] * axis[1] + axis[2] * axis[2]).sqrt();
    let (x, y, z) = (axis[0] / l, axis[1] / l, axis[2] / l);
    let (s, c) = angle.sin_cos();
    let t = 1.0 - c;
    [
        [t * x * x + c, t * x * y - s * z, t * x * z + s * y],
        [t * x * y + s * z, t * y * y + c, t * y * z - s * x],
        [t * x * z - s * y, t * y * z + s * x, t * z * z + c],
    ]
}

/// Largest distance between fitted uv and truth after the best similarity
/// (complex least squares: w ≈ a z + b).
fn procrustes_error(uv: &[[f64; 2]], truth: &[[f64; 2]]) -> f64 {
    let n = uv.len() as f64;
    let mz = uv
        .iter()
        .fold([0.0; 2], |m, p| [m[0] + p[0] / n, m[1] + p[1] / n]);
    let mw = truth
        .iter()
        .fold([0.0; 2], |m, p| [m[0] + p[0] / n, m[1] + p[1] / n]);
    let (mut re, mut im, mut nz) = (0.0, 0.0, 0.0);
    for (z, w) in uv.iter().zip(truth) {
        let (zx, zy) = (z[0] - mz[0], z[1] - mz[1]);
        let (wx, wy) = (w[0] - mw[0], w[1] - mw[1]);
        // conj(z) * w
        re += zx * wx + zy * wy;
        im += zx * wy - zy * wx;
        nz += zx * zx + zy * zy;
    }
    let (ar, ai) = (re / nz, im / nz);
    uv.iter()
        .zip(truth)
        .map(|(z, w)| {
            let (zx, zy) = (z[0] - mz[0], z[1] - mz[1]);
            let fx = ar * zx - ai * zy + mw[0];
            let fy = ar * zy + ai * zx + mw[1];
            ((fx - w[0]).powi(2) + (fy - w[1]).powi(2)).sqrt()
        })
        .fold(0.0, f64::max)
}

#[test]
fn planar_patch_is_flattened_isometrically() {
    let (pts, tris) = irregular_disk();
    for t in &tris {
        assert!(
            area2(pts[t[0] as usize], pts[t[1] as usize], pts[t[2] as usize]) > 0.0,
            "generator"
        );
    }
    let areas: Vec<f64> = tris
        .iter()
        .map(|t| area2(pts[t[0] as usize], pts[t[1] as usize], pts[t[2] as usize]))
        .collect();
    let (lo, hi) = areas
        .iter()
        .fold((f64::INFINITY, 0.0f64), |(l, h), &a| (l.min(a), h.max(a)));
    assert!(hi / lo > 20.0, "triangle sizes should vary: {lo} .. {hi}");
    let r = rotation([0.3, -0.8, 0.52], 1.1);
    let shift = [3.0, -1.5, 0.7];
    let positions: Vec<[f32; 3]> = pts
        .iter()
        .map(|p| {
            let q = [p[0], p[1], 0.0];
            let mut o = [0f32; 3];
            for k in 0..3 {
                o[k] = (r[k][0] * q[0] + r[k][1] * q[1] + r[k][2] * q[2] + shift[k]) as f32;
            }
            o
        })
        .collect();
    // truth: the f32 positions rotated back into the plane
    let truth: Vec<[f64; 2]> = positions
        .iter()
        .map(|p| {
            let q = [
                p[0] as f64 - shift[0],
                p[1] as f64 - shift[1],
                p[2] as f64 - shift[2],
            ];
            [
                r[0][0] * q[0] + r[1][0] * q[1] + r[2][0] * q[2],
                r[0][1] * q[0] + r[1][1] * q[1] + r[2][1] * q[2],
            ]
        })
        .collect();
    let diameter = truth
        .iter()
        .flat_map(|a| {
            truth
                .iter()
                .map(move |b| ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2)).sqrt())
        })
        .fold(0.0, f64::max);
    let uv = lscm(&positions, &tris).unwrap();
    let err = procrustes_error(&uv, &truth);
    assert!(
        err <= 1e-4 * diameter,
        "similarity-fit error {err} (diameter {diameter})"
    );
    let (l2, linf) = stretch(&positions, &tris, &uv);
    assert!(
        (l2 - 1.0).abs() < 1e-4 && (linf - 1.0).abs() < 1e-4,
        "stretch {l2} {linf}"
    );
    println!(
        "planar: {} triangles, fit error {:.2e} x diameter, L2 - 1 = {:.1e}, Linf - 1 = {:.1e}",
        tris.len(),
        err / diameter,
        l2 - 1.0,
        linf - 1.0
    );
    assert!(signed_uv_areas(&uv, &tris).iter().all(|&a| a > 0.0));
    let ad = area_distortion(&positions, &tris, &uv);
    assert!((ad - 1.0).abs() < 1e-4, "area distortion {ad}");
    // the mirrored winding is mirrored in uv too: areas stay positive
    let flipped: Vec<[u32; 3]> = tris.iter().map(|t| [t[0], t[2], t[1]]).collect();
    let uv = lscm(&positions, &flipped).unwrap();
    assert!(signed_uv_areas(&uv, &flipped).iter().all(|&a| a > 0.0));
}

/// Grid over (i, j) with two triangles per cell, counter-clockwise in (i, j).
fn grid_triangles(ni: usize, nj: usize, id: impl Fn(usize, usize) -> u32) -> Vec<[u32; 3]> {
    let mut t = Vec::new();
    for j in 0..nj {
        for i in 0..ni {
            let (a, b, c, d) = (id(i, j), id(i + 1, j), id(i + 1, j + 1), id(i, j + 1));
            if (i + j) % 2 == 0 {
                t.push([a, b, c]);
                t.push([a, c, d]);
            } else {
                t.push([a, b, d]);
                t.push([b, c, d]);
            }
        }
    }
    t
}

#[test]
fn cylinder_patch_is_developed() {
    let (ni, nj) = (30, 12);
    let span = 150f64.to_radians();
    let mut p = Vec::new();
    for j in 0..=nj {
        for i in 0..=ni {
            let a = span * i as f64 / ni as f64;
            // outward normal: counter-clockwise in (angle, height) seen from outside
            p.push([
                (a.cos() * 1.3) as f32,
                (a.sin() * 1.3) as f32,
                (2.0 * j as f64 / nj as f64) as f32,
            ]);
        }
    }
    let t = grid_triangles(ni, nj, |i, j| (j * (ni + 1) + i) as u32);
    let uv = lscm(&p, &t).unwrap();
    let (l2, linf) = stretch(&p, &t, &uv);
    assert!(
        (l2 - 1.0).abs() < 1e-3 && (linf - 1.0).abs() < 1e-3,
        "stretch {l2} {linf}"
    );
    assert!(signed_uv_areas(&uv, &t).iter().all(|&a| a > 0.0));
    assert!((area_distortion(&p, &t, &uv) - 1.0).abs() < 1e-3);
}

#[test]
fn hemisphere_has_no_flips_and_moderate_stretch() {
    let (ni, nj) = (48, 16);
    let mut p = vec![[0.0f32, 0.0, 1.0]];
    for j in 1..=nj {
        let polar = std::f64::consts::FRAC_PI_2 * j as f64 / nj as f64;
        for i in 0..ni {
            let a = std::f64::consts::TAU * i as f64 / ni as f64;
            p.push([
                (polar.sin() * a.cos()) as f32,
                (polar.sin() * a.sin()) as f32,
                polar.cos() as f32,
            ]);
        }
    }
    let ring = |j: usize, i: usize| (1 + (j - 1) * ni + i % ni) as u32;
    let mut t: Vec<[u32; 3]> = (0..ni).map(|i| [0, ring(1, i), ring(1, i + 1)]).collect();
    for j in 1..nj {
        for i in 0..ni {
            t.push([ring(j, i), ring(j + 1, i), ring(j + 1, i + 1)]);
            t.push([ring(j, i), ring(j + 1, i + 1), ring(j, i + 1)]);
        }
    }
    let uv = lscm(&p, &t).unwrap();
    assert!(signed_uv_areas(&uv, &t).iter().all(|&a| a > 0.0));
    let (l2, linf) = stretch(&p, &t, &uv);
    println!(
        "hemisphere: L2 {l2:.4} Linf {linf:.4} area distortion {:.3}",
        area_distortion(&p, &t, &uv)
    );
    assert!(l2 < 1.3, "L2 {l2}");
}

fn torus(ni: usize, nj: usize, big: f64, small: f64) -> Mesh {
    let mut p = Vec::new();
    for j in 0..nj {
        for i in 0..ni {
            let u = std::f64::consts::TAU * i as f64 / ni as f64;
            let v = std::f64::consts::TAU * j as f64 / nj as f64;
            let r = big + small * v.cos();
            p.push([
                (r * u.cos()) as f32,
                (r * u.sin()) as f32,
                (small * v.sin()) as f32,
            ]);
        }
    }
    let triangles = grid_triangles(ni, nj, |i, j| ((j % nj) * ni + i % ni) as u32);
    Mesh {
        positions: p,
        triangles,
        ..Mesh::default()
    }
}

/// Minimal OBJ reader: `v` and `f` lines (polygons fanned, `a/b/c` and
/// negative indices accepted).
fn read_obj(path: &Path) -> Option<Mesh> {
    let text = std::fs::read_to_string(path).ok()?;
    let mut mesh = Mesh::default();
    for line in text.lines() {
        let mut it = line.split_whitespace();
        match it.next() {
            Some("v") => {
                let c: Vec<f32> = it.take(3).map(|s| s.parse().unwrap()).collect();
                mesh.positions.push([c[0], c[1], c[2]]);
            }
            Some("f") => {
                let n = mesh.positions.len() as i64;
                let idx: Vec<u32> = it
                    .map(|s| s.split('/').next().unwrap().parse::<i64>().unwrap())
                    .map(|i| if i < 0 { n + i } else { i - 1 } as u32)
                    .collect();
                for k in 1..idx.len() - 1 {
                    mesh.triangles.push([idx[0], idx[k], idx[k + 1]]);
                }
            }
            _ => {}
        }
    }
    Some(mesh)
}

/// Brute force: of about 250 000 grid points over the chart's uv box, how
/// many lie strictly inside two of its triangles or more (a chart that folds
/// over itself covers some twice although no triangle is flipped).
fn points_covered_twice(uv: &[[f64; 2]], triangles: &[[u32; 3]]) -> usize {
    let hi = uv
        .iter()
        .fold([0.0f64; 2], |m, p| [m[0].max(p[0]), m[1].max(p[1])]);
    let step = (hi[0] * hi[1] / 250_000.0).sqrt().max(1e-12);
    let (w, h) = ((hi[0] / step) as usize + 1, (hi[1] / step) as usize + 1);
    let mut count = vec![0u8; w * h];
    for t in triangles {
        let p = t.map(|v| uv[v as usize]);
        let d = (p[1][0] - p[0][0]) * (p[2][1] - p[0][1]) - (p[2][0] - p[0][0]) * (p[1][1] - p[0][1]);
        if d <= 0.0 {
            continue;
        }
        let lo = |k: usize| {
            (p.iter().map(|q| q[k]).fold(f64::INFINITY, f64::min) / step)
                .floor()
                .max(0.0) as usize
        };
        let up = |k: usize, n: usize| {
            ((p.iter().map(|q| q[k]).fold(0.0, f64::max) / step).ceil() as usize).min(n - 1)
        };
        for y in lo(1)..=up(1, h) {
            for x in lo(0)..=up(0, w) {
                let q = [(x as f64 + 0.5) * step, (y as f64 + 0.5) * step];
                let inside = (0..3).all(|e| {
                    let (a, b) = (p[e], p[(e + 1) % 3]);
                    (b[0] - a[0]) * (q[1] - a[1]) - (b[1] - a[1]) * (q[0] - a[0]) > 0.0
                });
                if inside {
                    count[y * w + x] = count[y * w + x].saturating_add(1);
                }
            }
        }
    }
    count.iter().filter(|&&n| n > 1).count()
}

/// Checks the chart invariants; returns (overall L2, overall L∞).
fn check_charts(name: &str, mesh: &Mesh, charts: &[Chart], cfg: &ChartConfig) -> (f64, f64) {
    let max_l2 = cfg.max_stretch as f64;
    let mut seen = vec![0u32; mesh.triangles.len()];
    let (mut num, mut den, mut linf) = (0.0f64, 0.0f64, 0.0f64);
    for (ci, c) in charts.iter().enumerate() {
        assert!(
            c.faces.windows(2).all(|w| w[0] < w[1]),
            "{name}: chart {ci} faces not ascending"
        );
        assert_eq!(c.faces.len(), c.triangles.len());
        assert_eq!(c.vertices.len(), c.uv.len());
        for (&f, t) in c.faces.iter().zip(&c.triangles) {
            seen[f as usize] += 1;
            let global = t.map(|v| c.vertices[v as usize]);
            assert_eq!(
                global, mesh.triangles[f as usize],
                "{name}: chart {ci} face {f} winding"
            );
        }
        // topological disk: V - E + F = 1 and exactly one boundary loop
        let mut edges: Vec<(u32, u32)> = Vec::new();
        for t in &c.triangles {
            for i in 0..3 {
                edges.push((t[i], t[(i + 1) % 3]));
            }
        }
        let mut undirected: Vec<(u32, u32)> = edges.iter().map(|&(a, b)| (a.min(b), a.max(b))).collect();
        undirected.sort_unstable();
        undirected.dedup();
        let chi = c.vertices.len() as i64 - undirected.len() as i64 + c.triangles.len() as i64;
        assert_eq!(
            chi,
            1,
            "{name}: chart {ci} ({} faces) Euler characteristic {chi}",
            c.faces.len()
        );
        let set: std::collections::HashSet<(u32, u32)> = edges.iter().copied().collect();
        let mut next: HashMap<u32, u32> = HashMap::new();
        for &(a, b) in &edges {
            if !set.contains(&(b, a)) {
                assert!(
                    next.insert(a, b).is_none(),
                    "{name}: chart {ci} pinched at a vertex"
                );
            }
        }
        let mut loops = 0;
        let mut visited = std::collections::HashSet::new();
        let mut starts: Vec<u32> = next.keys().copied().collect();
        starts.sort_unstable();
        for s in starts {
            if visited.contains(&s) {
                continue;
            }
            loops += 1;
            let mut v = s;
            while visited.insert(v) {
                v = next[&v];
            }
        }
        assert_eq!(loops, 1, "{name}: chart {ci} has {loops} boundary loops");
        // uv: positive areas, normalised placement and density
        let uv: Vec<[f64; 2]> = c.uv.iter().map(|p| [p[0] as f64, p[1] as f64]).collect();
        let areas = signed_uv_areas(&uv, &c.triangles);
        assert!(
            areas.iter().all(|&a| a > 0.0),
            "{name}: chart {ci} has flipped uv triangles"
        );
        let lo = uv
            .iter()
            .fold([f64::INFINITY; 2], |m, p| [m[0].min(p[0]), m[1].min(p[1])]);
        assert!(lo[0] == 0.0 && lo[1] == 0.0, "{name}: chart {ci} uv min {lo:?}");
        let twice = points_covered_twice(&uv, &c.triangles);
        assert_eq!(
            twice,
            0,
            "{name}: chart {ci} ({} faces) folds over itself",
            c.faces.len()
        );
        let positions: Vec<[f32; 3]> = c.vertices.iter().map(|&v| mesh.positions[v as usize]).collect();
        let a3: f64 = c.faces.iter().map(|&f| mesh.face_area(f as usize) as f64).sum();
        let auv: f64 = areas.iter().sum();
        assert!(
            (auv / a3 - 1.0).abs() < 1e-3,
            "{name}: chart {ci} uv area {auv} vs 3D {a3}"
        );
        let (l2, li) = stretch(&positions, &c.triangles, &uv);
        assert!(
            (l2 - c.l2_stretch as f64).abs() < 1e-3 * l2,
            "{name}: chart {ci} L2 {l2} vs {}",
            c.l2_stretch
        );
        assert!(
            c.faces.len() == 1 || l2 <= max_l2 * 1.001,
            "{name}: chart {ci} L2 {l2}"
        );
        assert!(
            c.faces.len() == 1 || li <= cfg.max_linf_stretch as f64 * 1.001,
            "{name}: chart {ci} L∞ {li}"
        );
        num += a3 * l2 * l2;
        den += a3;
        linf = linf.max(li);
    }
    assert!(
        seen.iter().all(|&s| s == 1),
        "{name}: a face is not in exactly one chart"
    );
    let l2 = (num / den).sqrt();
    assert!(l2 <= max_l2, "{name}: overall L2 {l2}");
    (l2, linf)
}

fn run(name: &str, mesh: &Mesh, max_charts: usize) {
    run_with(name, mesh, max_charts, &ChartConfig::default());
}

fn run_with(name: &str, mesh: &Mesh, max_charts: usize, cfg: &ChartConfig) {
    let topo = mesh.topology();
    let start = Instant::now();
    let charts = build_charts(mesh, &topo, cfg).unwrap();
    let secs = start.elapsed().as_secs_f64();
    let (l2, linf) = check_charts(name, mesh, &charts, cfg);
    let largest = charts.iter().map(|c| c.faces.len()).max().unwrap_or(0);
    let distortion = charts
        .iter()
        .map(|c| {
            let p: Vec<[f32; 3]> = c.vertices.iter().map(|&v| mesh.positions[v as usize]).collect();
            let uv: Vec<[f64; 2]> = c.uv.iter().map(|q| [q[0] as f64, q[1] as f64]).collect();
            area_distortion(&p, &c.triangles, &uv)
        })
        .fold(1.0, f64::max);
    println!(
        "{name}: {} faces, {} components -> {} charts (largest {largest} faces), L2 {l2:.4}, Linf {linf:.3}, \
         area distortion {distortion:.2}, {secs:.3} s",
        mesh.triangles.len(),
        topo.components,
        charts.len()
    );
    assert!(
        charts.len() >= 2 && charts.len() <= max_charts,
        "{name}: {} charts",
        charts.len()
    );
    let again = build_charts(mesh, &topo, cfg).unwrap();
    assert_eq!(charts.len(), again.len(), "{name}: not deterministic");
    for (a, b) in charts.iter().zip(&again) {
        assert_eq!(a.faces, b.faces, "{name}: not deterministic");
        assert_eq!(a.uv, b.uv, "{name}: not deterministic");
    }
}

#[test]
fn sphere_charts() {
    run("icosphere", &Mesh::icosphere(4), 50);
}

#[test]
fn torus_charts() {
    run("torus", &torus(96, 32, 1.0, 0.35), 50);
}

#[test]
fn shared_mesh_charts() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/data/meshes");
    if !dir.is_dir() {
        eprintln!("skipping: {} not found", dir.display());
        return;
    }
    for (file, max_charts) in [
        ("spot_5.8k.obj", 60),
        ("bob_10.7k.obj", 80),
        ("blub_14k.obj", 80),
        ("torus_1.5k.obj", 50),
        ("three_holes_4k.obj", 80),
        ("fandisk_13k.obj", 120),
        ("cow_5.8k.obj", 200),
        ("bunny_npm_3.7k.obj", 200),
        ("suzanne_1k.obj", 200),
        ("teapot_6.3k.obj", 200),
    ] {
        let Some(mesh) = read_obj(&dir.join(file)) else {
            eprintln!("skipping {file}");
            continue;
        };
        run(file, &mesh, max_charts);
        let compact = ChartConfig {
            compact: true,
            ..ChartConfig::default()
        };
        run_with(&format!("{file}, compact"), &mesh, max_charts, &compact);
    }
}

#[test]
fn limits_are_enforced() {
    let loose = ChartConfig {
        max_normal_deviation: 180.0,
        max_stretch: 1.25,
        max_area_distortion: 1.5,
        max_linf_stretch: 2.0,
        compact: false,
    };
    let strict = ChartConfig {
        max_normal_deviation: 25.0,
        max_stretch: 1.02,
        max_area_distortion: 1.1,
        max_linf_stretch: 1.1,
        compact: false,
    };
    for (name, mesh) in [
        ("icosphere", Mesh::icosphere(3)),
        ("torus", torus(48, 16, 1.0, 0.4)),
    ] {
        run_with(&format!("{name} loose"), &mesh, 50, &loose);
        run_with(&format!("{name} strict"), &mesh, 400, &strict);
        let compact = |c: &ChartConfig| ChartConfig {
            compact: true,
            ..c.clone()
        };
        run_with(&format!("{name} loose, compact"), &mesh, 50, &compact(&loose));
        run_with(&format!("{name} strict, compact"), &mesh, 400, &compact(&strict));
    }
}

#[test]
fn independent_of_thread_count() {
    let mesh = torus(64, 24, 1.0, 0.45);
    let topo = mesh.topology();
    let cfg = ChartConfig::default();
    let with = |threads: usize| {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        pool.install(|| build_charts(&mesh, &topo, &cfg).unwrap())
    };
    let (one, three) = (with(1), with(3));
    assert_eq!(one.len(), three.len());
    for (a, b) in one.iter().zip(&three) {
        assert_eq!(a.faces, b.faces);
        assert_eq!(a.uv, b.uv);
    }
}
