//! The dense mesh: a multi-chart geometry image of Spot (shipped in data/)
//! and of every shared mesh, with its zippers checked in 3D and as a graph.

use std::path::{Path, PathBuf};

use btfquilt::artifact::gim::{Gim, EMPTY};
use btfquilt::atlas::{self, AtlasConfig};
use btfquilt::container::MemoryBudget;
use btfquilt::progress::Silent;

fn data(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("data").join(name)
}

fn shared_meshes() -> Option<PathBuf> {
    let p = Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/data/meshes");
    if p.is_dir() {
        Some(p)
    } else {
        eprintln!("skipping: {} is absent", p.display());
        None
    }
}

/// The `.obj` files in `dir`, sorted.
fn obj_files(dir: &Path) -> Vec<PathBuf> {
    let mut names: Vec<_> = std::fs::read_dir(dir)
        .unwrap()
        .filter_map(|e| e.ok())
        .map(|e| e.path())
        .filter(|p| p.extension().is_some_and(|e| e == "obj"))
        .collect();
    names.sort();
    names
}

fn build(mesh: &Path, out: &Path, resolution: usize) -> atlas::AtlasReport {
    let cfg = AtlasConfig {
        resolution,
        ..AtlasConfig::default()
    };
    atlas::build_gim(mesh, out, &cfg, &Silent).unwrap()
}

fn dist(a: &[f32], b: &[f32]) -> f64 {
    (0..3).map(|k| ((a[k] - b[k]) as f64).powi(2)).sum::<f64>().sqrt()
}

#[test]
fn spot_dense_mesh_is_zippered_and_uniform() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("spot.gim");
    let report = build(&data("spot_5.8k.obj"), &out, 384);
    eprintln!("{report}");
    assert!(report.charts >= 2 && report.charts <= 80, "{}", report.charts);
    assert!(report.l2_stretch < 1.3, "L2 stretch {}", report.l2_stretch);
    assert!(report.utilization > 0.3, "utilization {}", report.utilization);
    let g = Gim::open(&out, MemoryBudget::default()).unwrap();
    let r = g.resolution;
    let pos: Vec<f32> = g.read("position").unwrap();
    let nrm: Vec<f32> = g.read("normal").unwrap();
    let tan: Vec<f32> = g.read("tangent").unwrap();
    let bary: Vec<f32> = g.read("bary").unwrap();
    let graph = g.graph().unwrap();
    let texel = g.texel_size;

    // no chart is mirrored: seen from outside (counter-clockwise faces), an
    // image laid on the atlas (x right, rows down) must read the right way
    // round, so every face's atlas triangle turns clockwise in (x, y-down)
    let mesh = g.mesh().unwrap();
    let uv = g.corner_uv().unwrap();
    let mirrored = (0..mesh.triangles.len())
        .filter(|&f| {
            let [a, b, c] = [uv[f * 3], uv[f * 3 + 1], uv[f * 3 + 2]];
            (b[0] - a[0]) * (c[1] - a[1]) - (c[0] - a[0]) * (b[1] - a[1]) >= 0.0
        })
        .count();
    assert_eq!(
        mirrored,
        0,
        "{mirrored} of {} faces are mirrored in the atlas",
        mesh.triangles.len()
    );

    // attributes: barycentrics inside the face, unit normal, unit tangent ⟂ normal
    for t in 0..r * r {
        if graph.chart[t] == EMPTY {
            continue;
        }
        let (b1, b2) = (bary[t * 2], bary[t * 2 + 1]);
        assert!(b1 >= -1e-5 && b2 >= -1e-5 && b1 + b2 <= 1.0 + 1e-5);
        let n = &nrm[t * 3..t * 3 + 3];
        let tv = &tan[t * 3..t * 3 + 3];
        let dot = |a: &[f32], b: &[f32]| a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
        assert!(
            (dot(n, n) - 1.0).abs() < 1e-3 && (dot(tv, tv) - 1.0).abs() < 1e-3 && dot(n, tv).abs() < 1e-3
        );
    }

    // every zipper link is short in 3D: about one texel
    let links = g.zipper_links().unwrap();
    assert!(links.len() > 100, "{} links", links.len());
    let lens: Vec<f64> = links
        .iter()
        .map(|&[a, b]| dist(&pos[a as usize * 3..], &pos[b as usize * 3..]) / texel)
        .collect();
    let max = lens.iter().cloned().fold(0.0, f64::max);
    let mean = lens.iter().sum::<f64>() / lens.len() as f64;
    eprintln!("zipper links: {} mean {mean:.2} max {max:.2} texels", links.len());
    assert!(
        max <= btfquilt::artifact::gim::MAX_LINK + 1e-6 && mean < 1.6,
        "mean {mean} max {max}"
    );

    // every chart boundary of a closed surface is a seam: boundary texels are
    // linked across it, or sit next to a linked texel
    let mut linked = vec![false; r * r];
    for &[a, b] in &links {
        linked[a as usize] = true;
        linked[b as usize] = true;
    }
    let (mut boundary, mut with_link, mut near_link) = (0usize, 0usize, 0usize);
    for y in 1..r - 1 {
        for x in 1..r - 1 {
            let t = y * r + x;
            let c = graph.chart[t];
            if c == EMPTY {
                continue;
            }
            let nb = [t - 1, t + 1, t - r, t + r];
            if nb.iter().all(|&n| graph.chart[n] == c) {
                continue;
            }
            boundary += 1;
            if linked[t] {
                with_link += 1;
            } else if nb
                .iter()
                .chain(&[t - r - 1, t - r + 1, t + r - 1, t + r + 1])
                .any(|&n| linked[n] && graph.chart[n] == c)
            {
                near_link += 1;
            }
        }
    }
    eprintln!("boundary texels {boundary}: linked {with_link}, next to a linked one {near_link}");
    assert!(with_link as f64 > 0.6 * boundary as f64);
    assert!((with_link + near_link) as f64 > 0.99 * boundary as f64);

    // one connected graph for a one-component surface
    assert_eq!(graph.components(), 1);

    // uniform density: grid edges are about one texel long in 3D everywhere
    let mut per_chart: std::collections::BTreeMap<u32, (f64, usize)> = Default::default();
    for y in 0..r {
        for x in 0..r - 1 {
            let (a, b) = (y * r + x, y * r + x + 1);
            if graph.chart[a] != EMPTY && graph.chart[a] == graph.chart[b] {
                let e = per_chart.entry(graph.chart[a]).or_default();
                e.0 += dist(&pos[a * 3..], &pos[b * 3..]) / texel;
                e.1 += 1;
            }
        }
    }
    let means: Vec<f64> = per_chart
        .values()
        .filter(|v| v.1 > 50)
        .map(|v| v.0 / v.1 as f64)
        .collect();
    let (lo, hi) = (
        means.iter().cloned().fold(f64::INFINITY, f64::min),
        means.iter().cloned().fold(0.0, f64::max),
    );
    eprintln!("grid edge length per chart: {lo:.3}..{hi:.3} texels");
    assert!(lo > 0.6 && hi < 1.6, "{lo} {hi}");

    // breadth-first distances across seams are close to those inside charts:
    // hops per texel of 3D distance, for texels reached in another chart vs the same
    let (mut same, mut other) = ((0.0, 0usize), (0.0, 0usize));
    let covered: Vec<u32> = (0..(r * r) as u32).filter(|&t| graph.covered(t)).collect();
    for k in 0..12 {
        let s = covered[(k * 7919 * 13) % covered.len()];
        let hops = graph.bfs(s, 40);
        for (t, &h) in hops.iter().enumerate() {
            if h == u32::MAX || h < 10 {
                continue;
            }
            let d = dist(&pos[s as usize * 3..], &pos[t * 3..]) / texel;
            let acc = if graph.chart[t] == graph.chart[s as usize] {
                &mut same
            } else {
                &mut other
            };
            acc.0 += h as f64 / d;
            acc.1 += 1;
        }
    }
    assert!(other.1 > 100, "BFS never crossed a seam");
    let (rs, ro) = (same.0 / same.1 as f64, other.0 / other.1 as f64);
    eprintln!("hops per texel distance: inside charts {rs:.3}, across seams {ro:.3}");
    assert!((ro / rs - 1.0).abs() < 0.3, "{rs} vs {ro}");

    // dense triangles: grid triangles inside charts plus zipper strips
    let grid = btfquilt::artifact::gim::grid_triangles(&graph.chart, r);
    let zt = g.zipper_triangles().unwrap();
    assert!(grid.len() > report.texels && !zt.is_empty());
    for t in &zt {
        for (a, b) in [(t[0], t[1]), (t[1], t[2]), (t[0], t[2])] {
            assert!(
                dist(&pos[a as usize * 3..], &pos[b as usize * 3..])
                    <= 2.0 * btfquilt::artifact::gim::MAX_LINK * texel
            );
        }
    }
}

#[test]
fn geometry_image_is_identical_with_one_or_two_threads() {
    let dir = tempfile::tempdir().unwrap();
    let outs: Vec<PathBuf> = [1, 2]
        .iter()
        .map(|&t| {
            let out = dir.path().join(format!("t{t}.gim"));
            let pool = rayon::ThreadPoolBuilder::new().num_threads(t).build().unwrap();
            pool.install(|| build(&data("spot_5.8k.obj"), &out, 200));
            // the exposure's views run in parallel too
            let hidden = dir.path().join(format!("e{t}.gim"));
            let cfg = AtlasConfig {
                resolution: 200,
                field_exposure: 2.0,
                ..AtlasConfig::default()
            };
            pool.install(|| atlas::build_gim(&data("spot_5.8k.obj"), &hidden, &cfg, &Silent).unwrap());
            out
        })
        .collect();
    assert_eq!(std::fs::read(&outs[0]).unwrap(), std::fs::read(&outs[1]).unwrap());
    let hidden = |t: usize| std::fs::read(dir.path().join(format!("e{t}.gim"))).unwrap();
    assert_eq!(hidden(1), hidden(2));
    assert_ne!(hidden(1), std::fs::read(&outs[0]).unwrap(), "the field moved");
}

#[test]
fn field_keys_orient_the_tangent_frames() {
    let dir = tempfile::tempdir().unwrap();
    let keys = dir.path().join("keys.json");
    std::fs::write(
        &keys,
        r#"[{"face": 100, "dir": [0, 1, 0]}, {"face": 3000, "dir": [1, 0, 0]}]"#,
    )
    .unwrap();
    let out = dir.path().join("k.gim");
    let cfg = AtlasConfig {
        resolution: 256,
        field_keys: Some(keys),
        ..AtlasConfig::default()
    };
    atlas::build_gim(&data("spot_5.8k.obj"), &out, &cfg, &Silent).unwrap();
    let g = Gim::open(&out, MemoryBudget::default()).unwrap();
    let mesh = g.mesh().unwrap();
    let field: Vec<f32> = g.read("face_field").unwrap();
    for (f, want) in [(100usize, [0.0f32, 1.0, 0.0]), (3000, [1.0, 0.0, 0.0])] {
        let n = mesh.face_normal(f);
        let d = want[0] * n[0] + want[1] * n[1] + want[2] * n[2];
        let p = [want[0] - d * n[0], want[1] - d * n[1], want[2] - d * n[2]];
        let pl = (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt();
        let v = &field[f * 3..f * 3 + 3];
        let cos = (v[0] * p[0] + v[1] * p[1] + v[2] * p[2]) / pl;
        assert!(cos > 0.98, "face {f}: cos {cos}");
    }
}

/// The issue's measure of a folded or overlapping atlas: texel centres
/// inside two chart triangles or more, over every shared mesh at 1024².
#[test]
fn no_texel_is_covered_twice_on_any_shared_mesh() {
    let Some(dir) = shared_meshes() else { return };
    let tmp = tempfile::tempdir().unwrap();
    let names = obj_files(&dir);
    assert!(names.len() >= 5, "{} meshes in {}", names.len(), dir.display());
    for mesh in names {
        let report = build(&mesh, &tmp.path().join("m.gim"), 1024);
        eprintln!("{}: {report}", mesh.display());
        assert_eq!(report.overlapping_texels, 0, "{}: {report}", mesh.display());
    }
}

/// A closed plate of genus `holes`: the surface of a row of voxels
/// (`2·holes+1` × 3 × 1) with a hole through every other middle voxel, each
/// voxel face cut into `n`×`n` squares (two triangles each), vertices nudged
/// by a fixed pseudo-random offset so no chart is exactly flat. OBJ text.
fn holed_plate_obj(holes: usize, n: usize) -> String {
    let (nx, ny) = (2 * holes + 1, 3);
    let filled = |x: i64, y: i64, z: i64| {
        (0..nx as i64).contains(&x) && (0..ny).contains(&y) && z == 0 && !(y == 1 && x % 2 == 1)
    };
    let mut ids: std::collections::HashMap<[i64; 3], usize> = std::collections::HashMap::new();
    let mut verts: Vec<[i64; 3]> = Vec::new();
    let mut faces: Vec<[usize; 3]> = Vec::new();
    let n = n as i64;
    let mut id = |p: [i64; 3], verts: &mut Vec<[i64; 3]>| {
        *ids.entry(p).or_insert_with(|| {
            verts.push(p);
            verts.len() - 1
        })
    };
    for x in 0..nx as i64 {
        for y in 0..ny {
            if !filled(x, y, 0) {
                continue;
            }
            for axis in 0..3 {
                for side in [0i64, 1] {
                    let mut q = [x, y, 0];
                    q[axis] += if side == 1 { 1 } else { -1 };
                    if filled(q[0], q[1], q[2]) {
                        continue;
                    }
                    // the face's two in-plane axes, ordered so (u, v, outward) is right-handed
                    let (u, v) = ((axis + 1) % 3, (axis + 2) % 3);
                    let (u, v) = if side == 1 { (u, v) } else { (v, u) };
                    let mut base = [x * n, y * n, 0];
                    base[axis] += side * n;
                    for i in 0..n {
                        for j in 0..n {
                            let at = |di: i64, dj: i64| {
                                let mut p = base;
                                p[u] += i + di;
                                p[v] += j + dj;
                                p
                            };
                            let c = [at(0, 0), at(1, 0), at(1, 1), at(0, 1)].map(|p| id(p, &mut verts));
                            faces.push([c[0], c[1], c[2]]);
                            faces.push([c[0], c[2], c[3]]);
                        }
                    }
                }
            }
        }
    }
    let mut obj = String::new();
    for (k, p) in verts.iter().enumerate() {
        let h = (k as u64).wrapping_mul(0x9e37_79b9_7f4a_7c15) >> 40;
        let jitter = |s: u64| ((h >> s) & 0xff) as f64 / 255.0 - 0.5;
        let c = [0, 1, 2].map(|a| p[a] as f64 / n as f64 + 0.08 / n as f64 * jitter(8 * a as u64));
        obj += &format!("v {} {} {}\n", c[0], c[1], c[2]);
    }
    for f in &faces {
        obj += &format!("f {} {} {}\n", f[0] + 1, f[1] + 1, f[2] + 1);
    }
    obj
}

/// Generated meshes of genus 1 to 4: no texel covered twice, and the dense
/// grid holds one component per surface.
#[test]
fn no_texel_is_covered_twice_on_high_genus_plates() {
    let tmp = tempfile::tempdir().unwrap();
    for holes in 1..=4 {
        let obj = tmp.path().join(format!("plate{holes}.obj"));
        std::fs::write(&obj, holed_plate_obj(holes, 6)).unwrap();
        let gim = tmp.path().join("plate.gim");
        let report = build(&obj, &gim, 1024);
        eprintln!("genus {holes}: {report}");
        assert_eq!(report.overlapping_texels, 0, "genus {holes}: {report}");
        let g = Gim::open(&gim, MemoryBudget::default()).unwrap();
        let m = g.mesh().unwrap();
        let topo = m.topology();
        assert_eq!(topo.components, 1);
        // Euler characteristic 2 - 2g of the closed surface
        let mut edges: Vec<(u32, u32)> = m
            .triangles
            .iter()
            .flat_map(|t| (0..3).map(move |i| (t[i].min(t[(i + 1) % 3]), t[i].max(t[(i + 1) % 3]))))
            .collect();
        edges.sort_unstable();
        edges.dedup();
        let chi = m.positions.len() as i64 - edges.len() as i64 + m.triangles.len() as i64;
        assert_eq!(chi, 2 - 2 * holes as i64, "genus {holes}");
        assert_eq!(g.graph().unwrap().components(), 1, "genus {holes}");
    }
}

#[test]
fn every_shared_mesh_builds_or_fails_clearly() {
    let Some(dir) = shared_meshes() else { return };
    let tmp = tempfile::tempdir().unwrap();
    let names = obj_files(&dir);
    for mesh in names {
        let out = tmp.path().join("m.gim");
        let cfg = AtlasConfig {
            resolution: 256,
            ..AtlasConfig::default()
        };
        match atlas::build_gim(&mesh, &out, &cfg, &Silent) {
            Ok(report) => {
                eprintln!("{}: {report}", mesh.display());
                let g = Gim::open(&out, MemoryBudget::default()).unwrap();
                let m = g.mesh().unwrap();
                // one dense component per surface component (tiny components may
                // rasterize to nothing at this resolution, never to more)
                let comps = m.topology().components;
                let dense = g.graph().unwrap().components();
                assert!(
                    dense >= 1 && dense <= comps,
                    "{}: {dense} dense vs {comps} surface",
                    mesh.display()
                );
            }
            Err(e) => {
                let msg = e.to_string();
                eprintln!("{}: {msg}", mesh.display());
                assert!(msg.contains(mesh.file_name().unwrap().to_str().unwrap()), "{msg}");
                assert!(!out.exists());
            }
        }
    }
}

#[test]
fn bad_inputs_are_refused_without_output() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("o.gim");
    let empty = dir.path().join("empty.obj");
    std::fs::write(&empty, "# nothing\n").unwrap();
    let e = atlas::build_gim(&empty, &out, &AtlasConfig::default(), &Silent)
        .err()
        .unwrap()
        .to_string();
    assert!(e.contains("empty.obj"), "{e}");
    let cfg = AtlasConfig {
        resolution: 8,
        ..AtlasConfig::default()
    };
    let e = atlas::build_gim(&data("spot_5.8k.obj"), &out, &cfg, &Silent)
        .err()
        .unwrap()
        .to_string();
    assert!(e.contains("--resolution 8"), "{e}");
    let keys = dir.path().join("keys.json");
    std::fs::write(&keys, r#"[{"face": 999999, "dir": [0, 1, 0]}]"#).unwrap();
    let cfg = AtlasConfig {
        resolution: 128,
        field_keys: Some(keys),
        ..AtlasConfig::default()
    };
    let e = atlas::build_gim(&data("spot_5.8k.obj"), &out, &cfg, &Silent)
        .err()
        .unwrap()
        .to_string();
    assert!(e.contains("keys.json") && e.contains("999999"), "{e}");
    assert!(!out.exists());
}
