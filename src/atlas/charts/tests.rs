use super::maps::{area_distortion_tail, parameterize};
use super::*;

fn mesh(positions: Vec<[f32; 3]>, triangles: Vec<[u32; 3]>) -> Mesh {
    Mesh {
        positions,
        triangles,
        ..Mesh::default()
    }
}

fn cube() -> Mesh {
    let p = (0..8)
        .map(|i| [(i & 1) as f32, ((i >> 1) & 1) as f32, ((i >> 2) & 1) as f32])
        .collect();
    // outward-facing quads (counter-clockwise seen from outside)
    let quads = [
        [0, 2, 3, 1],
        [4, 5, 7, 6],
        [0, 1, 5, 4],
        [2, 6, 7, 3],
        [0, 4, 6, 2],
        [1, 3, 7, 5],
    ];
    let t = quads
        .iter()
        .flat_map(|q| [[q[0], q[1], q[2]], [q[0], q[2], q[3]]])
        .collect();
    mesh(p, t)
}

fn coverage(m: &Mesh, charts: &[Chart]) -> Vec<u32> {
    let mut seen = vec![0u32; m.triangles.len()];
    for c in charts {
        for (&f, t) in c.faces.iter().zip(&c.triangles) {
            seen[f as usize] += 1;
            assert_eq!(t.map(|v| c.vertices[v as usize]), m.triangles[f as usize]);
        }
    }
    seen
}

#[test]
fn cube_sides_and_corners() {
    let m = cube();
    let cfg = ChartConfig::default();
    let topo = m.topology();
    // the segmentation keeps the sides apart (90° > 70°) ...
    let ctx = Ctx::new(&m, &topo, &cfg);
    assert_eq!(segment(&ctx).len(), 6);
    // ... but three sides around a corner stay within 70° of their mean
    // normal (54.7°), so merging may join them
    let charts = build_charts(&m, &topo, &cfg).unwrap();
    assert!((2..=6).contains(&charts.len()), "{}", charts.len());
    assert!(coverage(&m, &charts).iter().all(|&s| s == 1));
    for c in &charts {
        assert!(c.l2_stretch <= cfg.max_stretch);
    }
    let sides = ChartConfig {
        max_normal_deviation: 40.0,
        ..cfg
    };
    let charts = build_charts(&m, &topo, &sides).unwrap();
    assert_eq!(charts.len(), 6);
    for c in &charts {
        assert!((c.l2_stretch - 1.0).abs() < 1e-5 && (c.linf_stretch - 1.0).abs() < 1e-5);
        let max =
            c.uv.iter()
                .fold([0f32; 2], |m, p| [m[0].max(p[0]), m[1].max(p[1])]);
        assert!(
            (max[0] - 1.0).abs() < 1e-5 && (max[1] - 1.0).abs() < 1e-5,
            "{max:?}"
        );
    }
}

#[test]
fn two_components_and_a_sliver() {
    // a cube plus a flat strip whose boundary edge carries a zero-area sliver
    let mut m = cube();
    let base = m.positions.len() as u32;
    for i in 0..4 {
        m.positions.push([3.0 + i as f32, 0.0, 0.0]);
        m.positions.push([3.0 + i as f32, 1.0, 0.0]);
    }
    m.positions.push([3.5, 0.0, 0.0]); // midpoint of the first bottom edge
    let (a, b, c, mid) = (base, base + 2, base + 1, base + 8);
    m.triangles.push([a, mid, c]);
    m.triangles.push([mid, b, c]);
    m.triangles.push([a, b, mid]); // zero area
    m.triangles.push([b, base + 3, c]);
    for i in 1..3 {
        let (p, q, r, s) = (base + 2 * i, base + 2 * i + 2, base + 2 * i + 3, base + 2 * i + 1);
        m.triangles.push([p, q, r]);
        m.triangles.push([p, r, s]);
    }
    let topo = m.topology();
    assert_eq!(topo.components, 2);
    let sides = ChartConfig {
        max_normal_deviation: 40.0,
        ..ChartConfig::default()
    };
    let charts = build_charts(&m, &topo, &sides).unwrap();
    assert!(coverage(&m, &charts).iter().all(|&s| s == 1));
    assert_eq!(
        charts.len(),
        7,
        "six cube sides and the strip: {:?}",
        charts.iter().map(|c| &c.faces).collect::<Vec<_>>()
    );
}

/// A dome: the sphere's cap down to `polar` degrees from the pole, `n`
/// rings.
pub(crate) fn dome(n: usize, polar: f64) -> Mesh {
    let (rings, segments) = (n, 4 * n);
    let mut p = vec![[0.0, 0.0, 1.0]];
    for i in 1..=rings {
        let th = (polar * i as f64 / rings as f64).to_radians();
        for j in 0..segments {
            let ph = std::f64::consts::TAU * j as f64 / segments as f64;
            p.push([
                (th.sin() * ph.cos()) as f32,
                (th.sin() * ph.sin()) as f32,
                th.cos() as f32,
            ]);
        }
    }
    let id = |i: usize, j: usize| (1 + (i - 1) * segments + j % segments) as u32;
    let mut t = Vec::new();
    for j in 0..segments {
        t.push([0, id(1, j), id(1, j + 1)]);
    }
    for i in 1..rings {
        for j in 0..segments {
            t.push([id(i, j), id(i + 1, j), id(i + 1, j + 1)]);
            t.push([id(i, j), id(i + 1, j + 1), id(i, j + 1)]);
        }
    }
    mesh(p, t)
}

/// With every limit out of the way the dome maps into charts whose
/// `worst` exceeds `limit`; with only `tighten` applied, more charts,
/// each within it, still covering every face once.
fn dome_split_by(tighten: fn(&mut ChartConfig), limit: f64, worst: &dyn Fn(&Mesh, &Chart) -> f64) {
    // deep enough that even the relaxed map is over every limit
    let m = dome(12, 150.0);
    let topo = m.topology();
    let loose = ChartConfig {
        max_normal_deviation: 180.0,
        max_stretch: 100.0,
        max_area_distortion: 100.0,
        max_linf_stretch: 100.0,
        compact: true,
    };
    let worst = |charts: &[Chart]| charts.iter().map(|c| worst(&m, c)).fold(1.0f64, f64::max);
    let one = build_charts(&m, &topo, &loose).unwrap();
    assert!(worst(&one) > limit, "the dome in few charts: {}", worst(&one));
    let mut strict = loose.clone();
    tighten(&mut strict);
    let split = build_charts(&m, &topo, &strict).unwrap();
    assert!(coverage(&m, &split).iter().all(|&s| s == 1));
    assert!(split.len() > one.len(), "{} vs {}", split.len(), one.len());
    assert!(worst(&split) <= limit, "{}", worst(&split));
}

#[test]
fn a_cap_lscm_must_split_maps_whole_when_relaxed() {
    let m = dome(12, 80.0);
    let topo = m.topology();
    let cfg = ChartConfig {
        max_normal_deviation: 180.0,
        compact: true,
        ..ChartConfig::default()
    };
    // without relaxation, LSCM's rim splits the cap
    let conformal_only = ChartConfig {
        compact: false,
        ..cfg.clone()
    };
    assert!(build_charts(&m, &topo, &conformal_only).unwrap().len() > 1);
    let faces: Vec<u32> = (0..m.triangles.len() as u32).collect();
    let conformal = lscm(&m.positions, &m.triangles).unwrap();
    let limit = cfg.max_area_distortion as f64;
    assert!(area_distortion_tail(&m.positions, &m.triangles, &conformal) > limit);
    let charts = build_charts(&m, &topo, &cfg).unwrap();
    assert_eq!(
        charts.len(),
        1,
        "{:?}",
        charts.iter().map(|c| c.faces.len()).collect::<Vec<_>>()
    );
    let c = &charts[0];
    assert_eq!(c.faces, faces);
    let pos: Vec<[f32; 3]> = c.vertices.iter().map(|&v| m.positions[v as usize]).collect();
    let uv: Vec<[f64; 2]> = c.uv.iter().map(|q| [q[0] as f64, q[1] as f64]).collect();
    assert!(area_distortion_tail(&pos, &c.triangles, &uv) <= limit);
    let (l2, linf) = stretch(&pos, &c.triangles, &uv);
    assert!(
        linf <= RELAXED_LINF_SHARE * cfg.max_linf_stretch as f64 + 1e-6,
        "{linf}"
    );
    assert!(l2 <= cfg.max_stretch as f64, "{l2}");
}

/// Faces meeting their own chart along at most one edge and another
/// chart along two: the spikes and notches straightening removes.
fn spikes(ctx: &Ctx, charts: &[Chart]) -> usize {
    let owner = owners(ctx, charts);
    (0..ctx.adj.len())
        .filter(|&f| {
            let around: Vec<u32> = ctx.adj[f]
                .iter()
                .filter(|&&g| g != NO_FACE)
                .map(|&g| owner[g as usize])
                .collect();
            let same = around.iter().filter(|&&o| o == owner[f]).count();
            same <= 1
                && around
                    .iter()
                    .any(|&o| o != owner[f] && around.iter().filter(|&&p| p == o).count() >= 2)
        })
        .count()
}

#[test]
fn straightening_after_merging_removes_spikes_and_keeps_charts_valid() {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/data/meshes/cow_5.8k.obj");
    if !path.is_file() {
        eprintln!("skipping: {} not found", path.display());
        return;
    }
    let (m, _) = crate::mesh::io::load(&path, &Default::default()).unwrap();
    let topo = m.topology();
    let cfg = ChartConfig {
        compact: true,
        ..ChartConfig::default()
    };
    let ctx = Ctx::new(&m, &topo, &cfg);
    let merged = merge(&ctx, split_until_mapped(&ctx, segment(&ctx)));
    let straight = straighten_charts(&ctx, merged.clone());
    let (before, after) = (spikes(&ctx, &merged), spikes(&ctx, &straight));
    println!("cow: {before} spike faces after merging, {after} after straightening");
    assert!(after < before, "{after} spikes after, {before} before");
    assert_eq!(straight.len(), merged.len());
    assert!(coverage(&m, &straight).iter().all(|&s| s == 1));
    for (a, b) in merged.iter().zip(&straight) {
        if a.faces != b.faces {
            // a changed chart is mapped afresh, within the limits
            let again = parameterize(&ctx, &b.faces).expect("a kept chart maps");
            assert_eq!(again.uv, b.uv);
        }
    }
}

#[test]
fn charts_keep_their_texel_density_within_the_area_limit() {
    // a conformal map of a dome shrinks its rim against its pole
    dome_split_by(|c| c.max_area_distortion = 1.5, 1.5, &|m, c| {
        let pos: Vec<[f32; 3]> = c.vertices.iter().map(|&v| m.positions[v as usize]).collect();
        let uv: Vec<[f64; 2]> = c.uv.iter().map(|q| [q[0] as f64, q[1] as f64]).collect();
        area_distortion_tail(&pos, &c.triangles, &uv)
    });
}

#[test]
fn charts_keep_every_triangle_within_the_linf_limit() {
    dome_split_by(|c| c.max_linf_stretch = 1.2, 1.2, &|_, c| c.linf_stretch as f64);
}

/// A flat `n`×`n` grid of unit squares, two triangles each.
fn grid(n: usize) -> Mesh {
    let id = |x: usize, y: usize| (y * (n + 1) + x) as u32;
    let p = (0..=n)
        .flat_map(|y| (0..=n).map(move |x| [x as f32, y as f32, 0.0]))
        .collect();
    let mut t = Vec::new();
    for y in 0..n {
        for x in 0..n {
            t.push([id(x, y), id(x + 1, y), id(x + 1, y + 1)]);
            t.push([id(x, y), id(x + 1, y + 1), id(x, y + 1)]);
        }
    }
    mesh(p, t)
}

#[test]
fn straightening_removes_spikes_and_teeth_and_keeps_regions_whole() {
    let n = 16;
    let m = grid(n);
    let topo = m.topology();
    let ctx = Ctx::new(&m, &topo, &ChartConfig::default());
    let whole = Patch::whole(&ctx);
    // left and right halves, the border zig-zagging by a column per
    // row, a one-face-wide spike of the left reaching along row 8, a
    // lone right face inside the left and a third region of one face
    let mut label: Vec<u32> = (0..m.triangles.len())
        .map(|f| {
            let (x, y) = ((f / 2) % n, (f / 2) / n);
            let edge = n / 2 + y % 2;
            u32::from(x >= edge)
        })
        .collect();
    for x in n / 2..n - 2 {
        label[2 * (8 * n + x)] = 0;
    }
    label[2 * (3 * n + 2)] = 1;
    label[2 * (12 * n + 12) + 1] = 2;
    let border = |label: &[u32]| {
        (0..label.len())
            .flat_map(|f| ctx.adj[f].map(|g| (f, g)))
            .filter(|&(f, g)| g != NO_FACE && label[f] != label[g as usize])
            .count()
            / 2
    };
    let before = border(&label);
    whole.straighten(&ctx, &mut label);
    let after = border(&label);
    assert!(after < before / 2, "border {before} -> {after} edges");
    // every region is still there and in one piece
    for l in 0..3 {
        let faces: Vec<u32> = (0..label.len() as u32)
            .filter(|&f| label[f as usize] == l)
            .collect();
        assert!(!faces.is_empty(), "region {l} vanished");
        assert_eq!(
            Patch::new(&ctx, faces).split_components().len(),
            1,
            "region {l} torn"
        );
    }
    // no face is left meeting another region along two edges while
    // meeting its own along at most one (the flat grid has no crease)
    for f in 0..label.len() {
        let others: Vec<u32> = ctx.adj[f]
            .iter()
            .filter(|&&g| g != NO_FACE && label[g as usize] != label[f])
            .map(|&g| label[g as usize])
            .collect();
        let same = ctx.adj[f].iter().filter(|&&g| g != NO_FACE).count() - others.len();
        let pair = others
            .iter()
            .any(|&l| others.iter().filter(|&&k| k == l).count() >= 2);
        let last = label.iter().filter(|&&l| l == label[f]).count() == 1;
        assert!(same > 1 || !pair || last, "face {f} still a spike or notch");
    }
}

#[test]
fn a_tiny_chart_is_shared_out_to_its_nearest_neighbours() {
    let n = 8;
    let m = grid(n);
    let topo = m.topology();
    let ctx = Ctx::new(&m, &topo, &ChartConfig::default());
    let column = |f: u32| (f as usize / 2) % n;
    let row = |f: u32| (f as usize / 2) / n;
    // left and right halves, and a 2×2-square chart astride their border
    let part = |f: u32| match (column(f), row(f)) {
        (3..=4, 3..=4) => 2,
        (x, _) => usize::from(x >= n / 2),
    };
    let faces = |p: usize| -> Vec<u32> { (0..m.triangles.len() as u32).filter(|&f| part(f) == p).collect() };
    let charts: Vec<Chart> = (0..3)
        .map(|p| parameterize(&ctx, &faces(p)).expect("a flat disk maps"))
        .collect();
    let owner = owners(&ctx, &charts);
    let grown = dissolve(&ctx, &charts, &owner, 2).expect("both halves take their side");
    assert_eq!(grown.iter().map(|g| g.0).collect::<Vec<_>>(), [0, 1]);
    for (k, chart) in grown {
        // each half takes the tiny chart's faces on its own side
        let want: Vec<u32> = (0..m.triangles.len() as u32)
            .filter(|&f| usize::from(column(f) >= n / 2) == k)
            .collect();
        assert_eq!(chart.faces, want, "half {k}");
        assert!(chart.l2_stretch < 1.0001, "a flat chart maps isometrically");
    }
    // a chart with no neighbour (the whole grid) cannot be shared out
    let all = vec![parameterize(&ctx, &(0..m.triangles.len() as u32).collect::<Vec<_>>()).unwrap()];
    assert!(dissolve(&ctx, &all, &owners(&ctx, &all), 0).is_none());
}

#[test]
fn bad_input() {
    let m = cube();
    let topo = m.topology();
    let bad = ChartConfig {
        max_stretch: 0.5,
        ..ChartConfig::default()
    };
    assert!(build_charts(&m, &topo, &bad).is_err());
    let bad = ChartConfig {
        max_area_distortion: 0.9,
        ..ChartConfig::default()
    };
    assert!(build_charts(&m, &topo, &bad).is_err());
    let bad = ChartConfig {
        max_linf_stretch: f32::NAN,
        ..ChartConfig::default()
    };
    assert!(build_charts(&m, &topo, &bad).is_err());
    let bad = ChartConfig {
        max_normal_deviation: 0.0,
        ..ChartConfig::default()
    };
    assert!(build_charts(&m, &topo, &bad).is_err());
    let other = mesh(vec![[0.0; 3]; 3], vec![[0, 1, 2]]);
    assert!(build_charts(&other, &topo, &ChartConfig::default()).is_err());
    let empty = Mesh::default();
    assert!(build_charts(&empty, &empty.topology(), &ChartConfig::default())
        .unwrap()
        .is_empty());
}
