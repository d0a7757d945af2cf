//! Mesh loading, repair and writing: shared real meshes, synthetic repair
//! cases with exact reports, PLY/OBJ round trips and bad input.

use btfquilt::mesh::io::{load, write_obj, write_ply, LoadOptions};
use btfquilt::mesh::repair::{repair, RepairReport};
use btfquilt::mesh::Mesh;
use btfquilt::Error;
use std::path::{Path, PathBuf};

/// Union-find for the invariant checks.
struct Sets(Vec<usize>);

impl Sets {
    fn new(n: usize) -> Self {
        Sets((0..n).collect())
    }
    fn find(&mut self, mut x: usize) -> usize {
        while self.0[x] != x {
            self.0[x] = self.0[self.0[x]];
            x = self.0[x];
        }
        x
    }
    fn join(&mut self, a: usize, b: usize) {
        let (a, b) = (self.find(a), self.find(b));
        self.0[a.max(b)] = a.min(b);
    }
}

/// Facts about a checked mesh.
struct Shape {
    components: usize,
    /// Euler characteristic of each closed component (sorted).
    closed_euler: Vec<i64>,
}

/// Asserts the post-repair invariants and returns the mesh's shape.
fn check_invariants(name: &str, mesh: &Mesh) -> Shape {
    let nv = mesh.positions.len();
    let tris = &mesh.triangles;
    let nf = tris.len();
    let diag = mesh.bbox_diagonal() as f64;
    for (f, t) in tris.iter().enumerate() {
        assert!(
            t.iter().all(|&v| (v as usize) < nv),
            "{name}: face {f} index out of range"
        );
        assert!(
            t[0] != t[1] && t[1] != t[2] && t[0] != t[2],
            "{name}: face {f} repeats a vertex"
        );
        assert!(
            mesh.face_area(f) as f64 > 1e-12 * diag * diag,
            "{name}: face {f} has zero area"
        );
    }
    if let Some(c) = &mesh.vertex_colors {
        assert_eq!(c.len(), nv, "{name}: colours");
    }
    if let Some(w) = &mesh.vertex_weights {
        assert_eq!(w.len(), nv, "{name}: weights");
    }
    // (low, high, face, forward)
    let mut edges: Vec<(u32, u32, usize, bool)> = Vec::new();
    for (f, t) in tris.iter().enumerate() {
        for i in 0..3 {
            let (a, b) = (t[i], t[(i + 1) % 3]);
            edges.push((a.min(b), a.max(b), f, a < b));
        }
    }
    edges.sort_unstable();
    let corner = |f: usize, v: u32| 3 * f + tris[f].iter().position(|&x| x == v).unwrap();
    let mut corners = Sets::new(3 * nf);
    let mut faces = Sets::new(nf);
    let mut boundary_faces = vec![false; nf];
    let mut i = 0;
    while i < edges.len() {
        let mut j = i + 1;
        while j < edges.len() && edges[j].0 == edges[i].0 && edges[j].1 == edges[i].1 {
            j += 1;
        }
        let run = &edges[i..j];
        assert!(
            run.len() <= 2,
            "{name}: edge {:?} has {} faces",
            (run[0].0, run[0].1),
            run.len()
        );
        if run.len() == 2 {
            let (f, g) = (run[0].2, run[1].2);
            assert_ne!(
                run[0].3, run[1].3,
                "{name}: faces {f} and {g} disagree in orientation"
            );
            for v in [run[0].0, run[0].1] {
                corners.join(corner(f, v), corner(g, v));
            }
            faces.join(f, g);
        } else {
            boundary_faces[run[0].2] = true;
        }
        i = j;
    }
    // One fan per vertex.
    let mut fan_of = vec![usize::MAX; nv];
    for c in 0..3 * nf {
        let v = tris[c / 3][c % 3] as usize;
        let root = corners.find(c);
        assert!(
            fan_of[v] == usize::MAX || fan_of[v] == root,
            "{name}: vertex {v} has several fans"
        );
        fan_of[v] = root;
    }
    assert!(
        fan_of.iter().all(|&r| r != usize::MAX),
        "{name}: unreferenced vertex"
    );
    // Components and Euler characteristic of the closed ones.
    let roots: Vec<usize> = (0..nf).map(|f| faces.find(f)).collect();
    let mut ids: Vec<usize> = roots.clone();
    ids.sort_unstable();
    ids.dedup();
    let topo = mesh.topology();
    assert_eq!(
        topo.components,
        ids.len(),
        "{name}: component count differs from Topology"
    );
    let mut closed_euler = Vec::new();
    for &id in &ids {
        let comp: Vec<usize> = (0..nf).filter(|&f| roots[f] == id).collect();
        if comp.iter().any(|&f| boundary_faces[f]) {
            continue;
        }
        let mut verts: Vec<u32> = comp.iter().flat_map(|&f| tris[f]).collect();
        verts.sort_unstable();
        verts.dedup();
        // Closed: every edge has two faces.
        let e = comp.len() * 3 / 2;
        closed_euler.push(verts.len() as i64 - e as i64 + comp.len() as i64);
    }
    closed_euler.sort_unstable();
    Shape {
        components: ids.len(),
        closed_euler,
    }
}

fn shared_meshes() -> Option<PathBuf> {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/data/meshes");
    if dir.is_dir() {
        Some(dir)
    } else {
        eprintln!(
            "note: {} is absent; skipping the shared-mesh tests",
            dir.display()
        );
        None
    }
}

fn load_shared(dir: &Path, file: &str) -> (Mesh, RepairReport, Shape) {
    let path = dir.join(file);
    let (mesh, report) = load(&path, &LoadOptions::default()).unwrap_or_else(|e| panic!("{e}"));
    println!("{file}: {report}");
    let shape = check_invariants(file, &mesh);
    assert_eq!(report.components, shape.components, "{file}");
    assert_eq!(mesh.positions.len(), report.output_vertices(), "{file}");
    assert_eq!(mesh.triangles.len(), report.output_faces(), "{file}");
    (mesh, report, shape)
}

#[test]
fn every_shared_mesh_loads_and_is_manifold() {
    let Some(dir) = shared_meshes() else { return };
    let mut files: Vec<String> = std::fs::read_dir(&dir)
        .unwrap()
        .filter_map(|e| e.ok()?.file_name().into_string().ok())
        .filter(|n| n.ends_with(".obj"))
        .collect();
    files.sort();
    assert!(!files.is_empty());
    for file in files {
        let (_, report, _) = load_shared(&dir, &file);
        println!("{file}: {report:?}");
    }
}

#[test]
fn shared_meshes_match_their_documented_topology() {
    let Some(dir) = shared_meshes() else { return };
    let (_, r, s) = load_shared(&dir, "spot_5.8k.obj");
    assert!(r.is_clean(), "{r}");
    assert_eq!((r.input_vertices, r.input_faces), (2930, 5856));
    assert_eq!(s.closed_euler, vec![2]);
    // cow: one pinched vertex, split into two; closed genus 0 afterwards.
    let (_, r, s) = load_shared(&dir, "cow_5.8k.obj");
    assert_eq!(
        (r.split_vertices, r.welded_vertices, r.nonmanifold_edges),
        (1, 0, 0),
        "{r}"
    );
    assert_eq!(s.closed_euler, vec![2]);
    // suzanne: 3 open parts; its non-manifold edge carries a double-sided fin
    // (two faces on the same vertices, one dropped as a duplicate) which
    // comes off as a fourth component.
    let (m, r, s) = load_shared(&dir, "suzanne_1k.obj");
    assert_eq!((r.nonmanifold_edges, r.degenerate_faces), (1, 1), "{r}");
    assert_eq!(s.components, 4, "{r}");
    let topo = m.topology();
    let mut sizes = vec![0; topo.components];
    for &c in &topo.face_component {
        sizes[c as usize] += 1;
    }
    sizes.sort_unstable();
    assert_eq!(sizes[0], 1, "the fin is one triangle: {sizes:?}");
    // teapot: 4 open parts. The file's 38 non-manifold vertices and 10
    // boundary loops come from 403 duplicated seam vertices; welded, the
    // parts have 6 loops and one pinched vertex remains.
    let (_, r, s) = load_shared(&dir, "teapot_6.3k.obj");
    assert_eq!(
        (s.components, r.welded_vertices, r.boundary_loops),
        (4, 403, 6),
        "{r}"
    );
    assert_eq!((r.split_vertices, r.nonmanifold_edges), (1, 0), "{r}");
    let (_, r, s) = load_shared(&dir, "torus_1.5k.obj");
    assert_eq!((s.components, r.boundary_loops), (1, 0));
    assert_eq!(s.closed_euler, vec![0]);
    let (_, r, s) = load_shared(&dir, "three_holes_4k.obj");
    assert_eq!((s.components, r.boundary_loops), (1, 0));
    assert_eq!(s.closed_euler, vec![-4]);
}

fn report(v: usize, f: usize) -> RepairReport {
    RepairReport {
        input_vertices: v,
        input_faces: f,
        components: 1,
        boundary_loops: 1,
        ..Default::default()
    }
}

fn mesh(positions: &[[f32; 3]], triangles: &[[u32; 3]]) -> Mesh {
    Mesh {
        positions: positions.to_vec(),
        triangles: triangles.to_vec(),
        ..Default::default()
    }
}

#[test]
fn repair_welds_a_duplicated_vertex() {
    let p = [
        [0.0, 0.0, 0.0],
        [1.0, 0.0, 0.0],
        [0.0, 1.0, 0.0],
        [1.0, 1.0, 0.0],
        [1.0, 0.0, 0.0],
    ];
    let mut m = mesh(&p, &[[0, 1, 2], [2, 4, 3]]);
    let r = repair(&mut m, 1e-6);
    assert_eq!(
        r,
        RepairReport {
            welded_vertices: 1,
            ..report(5, 2)
        }
    );
    assert_eq!(m.triangles, vec![[0, 1, 2], [2, 1, 3]]);
    check_invariants("weld", &m);
    assert!(r.to_string().contains("welded 1 vertex"), "{r}");
}

#[test]
fn repair_drops_zero_area_and_repeated_index_faces() {
    let p = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.5, 0.0, 0.0]];
    let mut m = mesh(&p, &[[0, 1, 2], [0, 3, 1], [0, 0, 2]]);
    let r = repair(&mut m, 0.0);
    assert_eq!(
        r,
        RepairReport {
            degenerate_faces: 2,
            unreferenced_vertices: 1,
            ..report(4, 3)
        }
    );
    assert_eq!(m.triangles, vec![[0, 1, 2]]);
    check_invariants("degenerate", &m);
}

#[test]
fn repair_splits_a_bowtie_vertex() {
    let p = [
        [0.0, 0.0, 0.0],
        [1.0, 0.0, 0.0],
        [1.0, 1.0, 0.0],
        [-1.0, 0.0, 0.0],
        [-1.0, -1.0, 0.0],
    ];
    let mut m = mesh(&p, &[[0, 1, 2], [0, 3, 4]]);
    m.vertex_weights = Some(vec![7.0, 1.0, 2.0, 3.0, 4.0]);
    let r = repair(&mut m, 1e-6);
    assert_eq!(
        r,
        RepairReport {
            split_vertices: 1,
            components: 2,
            boundary_loops: 2,
            ..report(5, 2)
        }
    );
    assert_eq!(m.triangles, vec![[0, 1, 2], [5, 3, 4]]);
    assert_eq!(m.positions[5], [0.0, 0.0, 0.0]);
    assert_eq!(m.vertex_weights.as_ref().unwrap()[5], 7.0);
    check_invariants("bowtie", &m);
}

#[test]
fn repair_separates_three_faces_on_one_edge() {
    let p = [
        [0.0, 0.0, 0.0],
        [1.0, 0.0, 0.0],
        [0.5, 1.0, 0.0],
        [0.5, -1.0, 0.0],
        [0.5, 0.0, 1.0],
    ];
    let mut m = mesh(&p, &[[0, 1, 2], [1, 0, 3], [0, 1, 4]]);
    m.vertex_colors = Some(vec![
        [0.1, 0.2, 0.3],
        [0.4, 0.5, 0.6],
        [0.0; 3],
        [0.0; 3],
        [0.0; 3],
    ]);
    let r = repair(&mut m, 1e-6);
    assert_eq!(
        r,
        RepairReport {
            nonmanifold_edges: 1,
            split_vertices: 2,
            components: 2,
            boundary_loops: 2,
            ..report(5, 3)
        }
    );
    let colors = m.vertex_colors.as_ref().unwrap();
    assert_eq!(&colors[5..], &[[0.1, 0.2, 0.3], [0.4, 0.5, 0.6]]);
    check_invariants("three on an edge", &m);
}

#[test]
fn repair_separates_two_tetrahedra_sharing_an_edge() {
    // Two closed tetrahedra glued along edge 0-1: four faces on that edge.
    let p = [
        [0.0, 0.0, 0.0],
        [0.0, 0.0, 1.0],
        [1.0, 0.0, 0.5],
        [0.0, 1.0, 0.5],
        [-1.0, 0.0, 0.5],
        [0.0, -1.0, 0.5],
    ];
    let tet = |a: u32, b: u32, c: u32, d: u32| {
        // Outward orientation for a right-handed (a, b, c, d).
        vec![[a, c, b], [a, b, d], [a, d, c], [b, c, d]]
    };
    let mut t = tet(0, 1, 2, 3);
    t.extend(tet(0, 1, 4, 5));
    let mut m = mesh(&p, &t);
    let r = repair(&mut m, 1e-6);
    assert_eq!(r.nonmanifold_edges, 1);
    assert_eq!(r.components, 2, "{r}");
    let s = check_invariants("two tetrahedra", &m);
    println!("{r}");
    assert_eq!(s.closed_euler, vec![2, 2], "{r}");
}

#[test]
fn repair_flips_one_face_in_a_strip() {
    let p = [
        [0.0, 0.0, 0.0],
        [1.0, 0.0, 0.0],
        [2.0, 0.0, 0.0],
        [0.0, 1.0, 0.0],
        [1.0, 1.0, 0.0],
        [2.0, 1.0, 0.0],
    ];
    let mut m = mesh(&p, &[[0, 1, 4], [0, 4, 3], [1, 5, 2], [1, 5, 4]]);
    let r = repair(&mut m, 1e-6);
    assert_eq!(
        r,
        RepairReport {
            inconsistent_orientation: 1,
            ..report(6, 4)
        }
    );
    assert_eq!(m.triangles[2], [1, 2, 5]);
    check_invariants("strip", &m);
}

#[test]
fn repair_removes_an_unreferenced_vertex_and_remaps_paint() {
    let p = [[0.0, 0.0, 0.0], [9.0, 9.0, 9.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]];
    let mut m = mesh(&p, &[[0, 2, 3]]);
    m.vertex_colors = Some(vec![[0.0; 3], [1.0; 3], [0.5; 3], [0.25; 3]]);
    m.vertex_weights = Some(vec![0.0, 1.0, 2.0, 3.0]);
    let r = repair(&mut m, 1e-6);
    assert_eq!(
        r,
        RepairReport {
            unreferenced_vertices: 1,
            ..report(4, 1)
        }
    );
    assert_eq!(m.triangles, vec![[0, 1, 2]]);
    assert_eq!(m.vertex_colors.unwrap(), vec![[0.0; 3], [0.5; 3], [0.25; 3]]);
    assert_eq!(m.vertex_weights.unwrap(), vec![0.0, 2.0, 3.0]);
}

#[test]
fn repair_is_deterministic_and_stable() {
    let Some(dir) = shared_meshes() else { return };
    for file in ["teapot_6.3k.obj", "suzanne_1k.obj", "cow_5.8k.obj"] {
        let (a, first) = load(&dir.join(file), &LoadOptions::default()).unwrap();
        let (b, _) = load(&dir.join(file), &LoadOptions::default()).unwrap();
        assert_eq!(a, b, "{file}");
        // Repairing again welds the copies made at non-manifold spots and
        // separates them again: the mesh comes back unchanged.
        let mut c = a.clone();
        let again = repair(&mut c, 1e-6);
        println!("{file} again: {again}");
        assert_eq!(a, c, "{file}");
        assert_eq!(again.welded_vertices, again.split_vertices, "{file}: {again}");
        assert!(again.split_vertices <= first.split_vertices, "{file}: {again}");
        assert_eq!(
            (again.degenerate_faces, again.inconsistent_orientation),
            (0, 0),
            "{file}: {again}"
        );
    }
}

fn quad_mesh() -> Mesh {
    Mesh {
        positions: vec![
            [0.0, 0.0, 0.0],
            [1.0, 0.0, 0.0],
            [1.0, 1.0, 0.0],
            [0.0, 1.0, 0.25],
        ],
        triangles: vec![[0, 1, 2], [0, 2, 3]],
        vertex_colors: Some(vec![
            [1.0, 0.0, 0.0],
            [0.0, 1.0, 0.0],
            [0.0, 0.0, 1.0],
            [0.2, 0.4, 0.6],
        ]),
        vertex_weights: Some(vec![0.5, 1.5, -2.0, 0.125]),
    }
}

#[test]
fn ply_ascii_round_trip() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("quad.ply");
    let m = quad_mesh();
    write_ply(&path, &m).unwrap();
    let (back, r) = load(&path, &LoadOptions::default()).unwrap();
    assert!(r.is_clean(), "{r}");
    assert_eq!(back.positions, m.positions);
    assert_eq!(back.triangles, m.triangles);
    assert_eq!(back.vertex_weights, m.vertex_weights);
    let (c0, c1) = (back.vertex_colors.unwrap(), m.vertex_colors.unwrap());
    for (a, b) in c0.iter().zip(&c1) {
        for k in 0..3 {
            assert!((a[k] - b[k]).abs() <= 0.5 / 255.0 + 1e-6, "{a:?} vs {b:?}");
        }
    }
}

#[test]
fn ply_binary_little_endian_with_quad() {
    let mut bytes = b"ply\nformat binary_little_endian 1.0\ncomment hand made\n\
element vertex 4\nproperty float x\nproperty float y\nproperty float z\n\
property uchar red\nproperty uchar green\nproperty uchar blue\nproperty float quality\n\
element face 1\nproperty list uchar int vertex_indices\nend_header\n"
        .to_vec();
    let verts: [([f32; 3], [u8; 3], f32); 4] = [
        ([0.0, 0.0, 0.0], [255, 0, 0], 0.25),
        ([1.0, 0.0, 0.0], [0, 255, 0], 0.5),
        ([1.0, 1.0, 0.0], [0, 0, 255], 0.75),
        ([0.0, 1.0, 0.0], [51, 102, 153], 1.0),
    ];
    for (p, c, w) in verts {
        for x in p {
            bytes.extend(x.to_le_bytes());
        }
        bytes.extend(c);
        bytes.extend(w.to_le_bytes());
    }
    bytes.push(4);
    for i in [0i32, 1, 2, 3] {
        bytes.extend(i.to_le_bytes());
    }
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("quad.PLY");
    std::fs::write(&path, &bytes).unwrap();
    let (m, r) = load(&path, &LoadOptions::default()).unwrap();
    assert!(r.is_clean(), "{r}");
    assert_eq!(r.input_faces, 2);
    assert_eq!(m.triangles, vec![[0, 1, 2], [0, 2, 3]]);
    assert_eq!(m.positions[2], [1.0, 1.0, 0.0]);
    let c = m.vertex_colors.unwrap();
    assert_eq!(c[0], [1.0, 0.0, 0.0]);
    assert_eq!(c[3], [0.2, 0.4, 0.6]);
    assert_eq!(m.vertex_weights.unwrap(), vec![0.25, 0.5, 0.75, 1.0]);
}

#[test]
fn obj_vertex_colours_round_trip() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("quad.obj");
    let m = quad_mesh();
    write_obj(&path, &m, None, None).unwrap();
    let (back, r) = load(&path, &LoadOptions::default()).unwrap();
    assert!(r.is_clean(), "{r}");
    assert_eq!(back.positions, m.positions);
    assert_eq!(back.triangles, m.triangles);
    assert_eq!(back.vertex_colors, m.vertex_colors);
    assert_eq!(back.vertex_weights, None);
}

#[test]
fn obj_with_uvs_reads_back_with_tobj() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("atlas.obj");
    let mut m = quad_mesh();
    m.vertex_colors = None;
    // Corner UVs with one seam: vertex 0 and 2 have different UVs per face.
    let uvs = [
        [0.0, 0.0],
        [0.5, 0.0],
        [0.5, 0.5],
        [0.6, 0.0],
        [0.9, 0.5],
        [0.6, 0.5],
    ];
    write_obj(&path, &m, Some(&uvs), Some(("atlas.mtl", "quilt"))).unwrap();
    let text = std::fs::read_to_string(&path).unwrap();
    assert!(
        text.contains("mtllib atlas.mtl\n") && text.contains("usemtl quilt\n"),
        "{text}"
    );
    let opts = tobj::LoadOptions {
        triangulate: true,
        ..Default::default()
    };
    let (models, _) = tobj::load_obj_buf(&mut text.as_bytes(), &opts, |_| Ok(Default::default())).unwrap();
    assert_eq!(models.len(), 1);
    let t = &models[0].mesh;
    assert_eq!(t.positions.len(), 3 * 4);
    assert_eq!(t.indices.len(), 3 * 2);
    assert_eq!(t.texcoords.len(), 2 * 6);
    assert_eq!(t.texcoord_indices.len(), 3 * 2);
    for (k, &ti) in t.texcoord_indices.iter().enumerate() {
        let uv = [t.texcoords[2 * ti as usize], t.texcoords[2 * ti as usize + 1]];
        assert_eq!(uv, uvs[k]);
    }
    // Wrong UV count is refused with the file named.
    let e = write_obj(&path, &m, Some(&uvs[..5]), None)
        .unwrap_err()
        .to_string();
    assert!(e.contains("atlas.obj") && e.contains("corner UVs"), "{e}");
}

#[test]
fn obj_groups_share_vertices_and_polygons_are_triangulated() {
    let obj = b"mtllib none.mtl\nv 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nv 2 0 0\nv 2 1 0\n\
g left\nusemtl a\nf 1 2 3 4\ng right\nusemtl b\nf 2/1/1 5 6 3\n";
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("groups.obj");
    std::fs::write(&path, obj).unwrap();
    let (m, r) = load(&path, &LoadOptions::default()).unwrap();
    assert_eq!(
        r,
        RepairReport {
            input_vertices: 6,
            input_faces: 4,
            components: 1,
            boundary_loops: 1,
            ..Default::default()
        }
    );
    check_invariants("groups", &m);
}

/// Writes `content` to a temporary file called `name` and loads it.
fn load_text(name: &str, content: &[u8]) -> (String, Error) {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join(name);
    std::fs::write(&path, content).unwrap();
    let err = load(&path, &LoadOptions::default()).unwrap_err();
    (err.to_string(), err)
}

#[test]
fn bad_obj_nan_coordinate() {
    let (msg, _) = load_text("nan.obj", b"v 0 0 0\nv 1 0 0\nv 0 nan 0\nf 1 2 3\n");
    assert!(
        msg.contains("nan.obj") && msg.contains("vertex 3") && msg.contains("non-finite"),
        "{msg}"
    );
}

#[test]
fn bad_ply_nan_coordinate() {
    // ASCII PLY has no spelling for NaN, so build a binary big-endian file.
    let mut ply = b"ply\nformat binary_big_endian 1.0\nelement vertex 3\nproperty double x\n\
property double y\nproperty double z\nelement face 1\nproperty list uchar uint vertex_indices\n\
end_header\n"
        .to_vec();
    for x in [0.0f64, 0.0, 0.0, 1.0, f64::NAN, 0.0, 0.0, 1.0, 0.0] {
        ply.extend(x.to_be_bytes());
    }
    ply.push(3);
    for i in [0u32, 1, 2] {
        ply.extend(i.to_be_bytes());
    }
    let (msg, _) = load_text("nan.ply", &ply);
    assert!(
        msg.contains("nan.ply") && msg.contains("vertex 1") && msg.contains("non-finite"),
        "{msg}"
    );
}

#[test]
fn bad_obj_index_out_of_range() {
    let (msg, _) = load_text("range.obj", b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\nf 1 2 7\n");
    assert!(
        msg.contains("range.obj") && msg.contains("face 2") && msg.contains("vertex 7"),
        "{msg}"
    );
}

#[test]
fn bad_ply_index_out_of_range() {
    let ply = b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n\
property float z\nelement face 2\nproperty list uchar int vertex_indices\nend_header\n\
0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n3 0 1 3\n";
    let (msg, _) = load_text("range.ply", ply);
    assert!(
        msg.contains("range.ply") && msg.contains("face 1") && msg.contains("vertex 3"),
        "{msg}"
    );
}

#[test]
fn bad_empty_file() {
    for name in ["empty.obj", "empty.ply"] {
        let (msg, _) = load_text(name, b"");
        assert!(msg.contains(name) && msg.contains("empty file"), "{msg}");
    }
}

#[test]
fn bad_only_vertices() {
    let (msg, _) = load_text("points.obj", b"v 0 0 0\nv 1 0 0\nv 0 1 0\n");
    assert!(
        msg.contains("points.obj") && msg.contains("no usable triangles"),
        "{msg}"
    );
    let ply = b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\n\
property float z\nend_header\n0 0 0\n";
    let (msg, _) = load_text("points.ply", ply);
    assert!(
        msg.contains("points.ply") && msg.contains("no usable triangles"),
        "{msg}"
    );
}

#[test]
fn bad_only_degenerate_faces() {
    let (msg, _) = load_text("flat.obj", b"v 0 0 0\nv 1 0 0\nv 2 0 0\nf 1 2 3\n");
    assert!(
        msg.contains("flat.obj") && msg.contains("no usable triangles"),
        "{msg}"
    );
}

#[test]
fn bad_unknown_extension() {
    let (msg, _) = load_text("mesh.stl", b"solid x\n");
    assert!(
        msg.contains("mesh.stl") && msg.contains("unknown mesh format"),
        "{msg}"
    );
}

#[test]
fn bad_garbage_ply() {
    let garbage: Vec<u8> = (0..4000u32)
        .map(|i| (i.wrapping_mul(2654435761) >> 13) as u8)
        .collect();
    let (msg, _) = load_text("garbage.ply", &garbage);
    assert!(msg.contains("garbage.ply") && msg.contains("PLY"), "{msg}");
    // A valid header followed by a truncated binary body.
    let mut bytes = b"ply\nformat binary_little_endian 1.0\nelement vertex 3\nproperty float x\n\
property float y\nproperty float z\nend_header\n"
        .to_vec();
    bytes.extend([0u8; 10]);
    let (msg, _) = load_text("short.ply", &bytes);
    assert!(msg.contains("short.ply") && msg.contains("vertex"), "{msg}");
}

#[test]
fn bad_garbage_obj() {
    let (msg, _) = load_text("garbage.obj", &[0xff, 0xfe, 0x00, 0x41, 0x80]);
    assert!(msg.contains("garbage.obj") && msg.contains("UTF-8"), "{msg}");
    let (msg, _) = load_text("words.obj", b"v 0 0 0\nv 1 zero 0\nv 0 1 0\nf 1 2 3\n");
    assert!(msg.contains("words.obj") && msg.contains("vertex 2"), "{msg}");
}

#[test]
fn bad_missing_file() {
    let dir = tempfile::tempdir().unwrap();
    for name in ["missing.obj", "missing.ply"] {
        let path = dir.path().join(name);
        let err = load(&path, &LoadOptions::default()).unwrap_err();
        assert!(matches!(err, Error::Io { .. }), "{err:?}");
        assert!(err.to_string().contains(name), "{err}");
    }
}
