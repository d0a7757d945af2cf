use super::*;

/// A flat grid in the xy plane, n×n quads.
fn grid(n: usize) -> Mesh {
    let mut m = Mesh::default();
    for y in 0..=n {
        for x in 0..=n {
            m.positions.push([x as f32, y as f32, 0.0]);
        }
    }
    let id = |x: usize, y: usize| (y * (n + 1) + x) as u32;
    for y in 0..n {
        for x in 0..n {
            m.triangles.push([id(x, y), id(x + 1, y), id(x + 1, y + 1)]);
            m.triangles.push([id(x, y), id(x + 1, y + 1), id(x, y + 1)]);
        }
    }
    m
}

#[test]
fn keys_are_reproduced_at_their_faces_and_field_is_tangent() {
    let m = grid(10);
    let topo = m.topology();
    let keys = [
        FieldKey {
            face: 0,
            dir: [1.0, 0.0, 0.3],
        },
        FieldKey {
            face: 199,
            dir: [0.0, 1.0, 0.0],
        },
    ];
    let f = face_field(&m, &topo, &keys, None);
    assert!(Vec3::from(f[0]).dot(Vec3::X) > 0.99, "{:?}", f[0]);
    assert!(Vec3::from(f[199]).dot(Vec3::Y) > 0.99, "{:?}", f[199]);
    for v in &f {
        assert!((Vec3::from(*v).length_squared() - 1.0).abs() < 1e-4 && v[2].abs() < 1e-5);
    }
    // in between, the direction turns smoothly: neighbours differ little
    for (g, adj) in topo.face_adjacency.iter().enumerate() {
        for &h in adj {
            if h != NO_FACE {
                assert!(Vec3::from(f[g]).dot(f[h as usize].into()) > 0.8);
            }
        }
    }
}

#[test]
fn default_field_follows_the_long_axis_of_a_strip() {
    let mut m = grid(10);
    for p in &mut m.positions {
        p[0] *= 5.0; // 50 × 10: long along x
    }
    let f = face_field(&m, &m.topology(), &[], None);
    for v in &f {
        assert!(v[0].abs() > 0.99, "{v:?}");
    }
}

/// A torus around the z axis, radii `big` and `small`, n×m quads.
fn torus(n: usize, m: usize, big: f32, small: f32) -> Mesh {
    let mut mesh = Mesh::default();
    for i in 0..n {
        for j in 0..m {
            let (a, b) = (
                i as f32 / n as f32 * std::f32::consts::TAU,
                j as f32 / m as f32 * std::f32::consts::TAU,
            );
            let r = big + small * b.cos();
            mesh.positions.push([r * a.cos(), r * a.sin(), small * b.sin()]);
        }
    }
    let id = |i: usize, j: usize| ((i % n) * m + j % m) as u32;
    for i in 0..n {
        for j in 0..m {
            mesh.triangles.push([id(i, j), id(i + 1, j), id(i + 1, j + 1)]);
            mesh.triangles.push([id(i, j), id(i + 1, j + 1), id(i, j + 1)]);
        }
    }
    mesh
}

#[test]
fn default_field_on_a_torus_is_smoother_than_the_projected_axis() {
    // stretched along x so the principal axis lies in the ring's plane and
    // its projection has singularities where it meets the tube head-on;
    // a torus has a singularity-free field (around the ring), far smoother
    let mut m = torus(64, 24, 1.0, 0.35);
    for p in &mut m.positions {
        p[0] *= 1.3;
    }
    let topo = m.topology();
    let smooth = face_field(&m, &topo, &[], None);
    let (a1, _) = principal_axes(&m);
    assert!(a1.x.abs() > 0.99, "{a1:?}");
    let axis: Vec<[f32; 3]> = (0..m.triangles.len())
        .map(|f| unit_or(project(a1, m.face_normal(f).into()), Vec3::ZERO).to_array())
        .collect();
    // the field around the ring: no singularities, the obvious smooth field
    let ring: Vec<[f32; 3]> = (0..m.triangles.len())
        .map(|f| {
            let c = face_center(&m, f);
            let ring = Vec3::new(-c.y, c.x, 0.0);
            unit_or(project(ring, m.face_normal(f).into()), Vec3::ZERO).to_array()
        })
        .collect();
    let energy = |field: &[[f32; 3]]| field_energy(&m, &topo, field);
    let (e_smooth, e_axis, e_ring) = (energy(&smooth), energy(&axis), energy(&ring));
    assert!(
        e_smooth < 0.2 * e_axis && e_smooth <= 1.05 * e_ring,
        "smoothest {e_smooth}, axis {e_axis}, ring {e_ring}"
    );
    for (f, v) in smooth.iter().enumerate() {
        let (v, n) = (Vec3::from(*v), Vec3::from(m.face_normal(f)));
        assert!((v.length_squared() - 1.0).abs() < 1e-4 && v.dot(n).abs() < 1e-4);
    }
}

#[test]
fn default_field_on_a_square_runs_along_x_like_a_2d_synthesis() {
    for m in [grid(10), {
        // the same square in the xz plane: along x too
        let mut m = grid(10);
        m.positions.iter_mut().for_each(|p| *p = [p[0], 0.0, p[1]]);
        m
    }] {
        let f = face_field(&m, &m.topology(), &[], None);
        for v in &f {
            assert!(v[0] > 0.999, "{v:?}");
        }
    }
}

#[test]
fn bad_keys_are_refused_with_the_file_named() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("keys.json");
    for (text, needle) in [
        ("[{\"face\": 5, \"dir\": [1,0,0]}]", ""),
        ("[{\"face\": 50, \"dir\": [1,0,0]}]", "face 50"),
        ("[{\"face\": 1, \"dir\": [0,0,0]}]", "non-zero"),
        ("[{\"face\": 1}]", "dir"),
        ("{\"face\": 1}", "array"),
        ("[{\"face\": 1, \"dir\": [1,0,0]", "JSON"),
    ] {
        std::fs::write(&p, text).unwrap();
        match read_keys(&p, 10) {
            Ok(k) => assert!(needle.is_empty() && k.len() == 1),
            Err(e) => {
                let msg = e.to_string();
                assert!(
                    !needle.is_empty() && msg.contains("keys.json") && msg.contains(needle),
                    "{msg}"
                );
            }
        }
    }
}

#[test]
fn a_vortex_and_a_saddle_on_a_flat_grid_have_index_plus_and_minus_one() {
    let m = grid(10);
    let topo = m.topology();
    let centre = Vec3::new(5.0, 5.0, 0.0);
    for (sign, want) in [(1.0f32, 1), (-1.0, -1)] {
        // the direction at angle ±φ around the centre vertex
        let field: Vec<[f32; 3]> = (0..m.triangles.len())
            .map(|f| {
                let d = face_center(&m, f) - centre;
                let phi = sign * d.y.atan2(d.x);
                [phi.cos(), phi.sin(), 0.0]
            })
            .collect();
        let s = singularities(&m, &topo, &field);
        assert_eq!(s.len(), 1, "{s:?}");
        assert_eq!((s[0].index, s[0].position), (want, [5.0, 5.0, 0.0]));
    }
    // a constant field has none
    let flat = vec![[1.0, 0.0, 0.0]; m.triangles.len()];
    assert!(singularities(&m, &topo, &flat).is_empty());
}

#[test]
fn indices_sum_to_the_euler_characteristic() {
    // Poincaré–Hopf: the torus 0, Spot (a sphere) 2
    let t = torus(24, 12, 3.0, 1.0);
    let topo = t.topology();
    let s = singularities(&t, &topo, &face_field(&t, &topo, &[], None));
    assert_eq!(s.iter().map(|s| s.index).sum::<i32>(), 0, "{s:?}");
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("data/spot_5.8k.obj");
    let (spot, _) = crate::mesh::io::load(&path, &Default::default()).unwrap();
    let topo = spot.topology();
    let field = face_field(&spot, &topo, &[], None);
    let s = singularities(&spot, &topo, &field);
    assert_eq!(s.iter().map(|s| s.index).sum::<i32>(), 2, "{s:?}");
}

#[test]
fn singularities_move_where_turning_is_cheap() {
    // the smoothest field of a sphere has its two +1 singularities at
    // opposite poles; a cap halfway between them (within 60° of a point
    // on their equator) where turning costs 1/20 draws both in, and one
    // alone into a smaller cap (within 32°)
    let m = Mesh::icosphere(4);
    let topo = m.topology();
    let plain = singularities(&m, &topo, &face_field(&m, &topo, &[], None));
    assert_eq!(plain.len(), 2, "{plain:?}");
    let pole = Vec3::from(plain[0].position).normalize();
    assert!(
        plain[1].index == 1 && Vec3::from(plain[1].position).dot(pole) < -0.99,
        "{plain:?}"
    );
    let other = if pole.z.abs() < 0.9 { Vec3::Z } else { Vec3::X };
    let centre = pole.cross(other).normalize();
    let in_cap = |p: Vec3, cap: f32| p.normalize().dot(centre) > cap;
    for (cap, want) in [(0.5, 2), (0.85, 1)] {
        let turning: Vec<f64> = (0..m.triangles.len())
            .map(|f| {
                if in_cap(face_center(&m, f), cap) {
                    0.05
                } else {
                    1.0
                }
            })
            .collect();
        let s = singularities(&m, &topo, &face_field(&m, &topo, &[], Some(&turning)));
        assert_eq!(s.iter().map(|s| s.index).sum::<i32>(), 2, "{s:?}");
        assert_eq!(
            s.iter().filter(|s| in_cap(s.position.into(), cap)).count(),
            want,
            "cap {cap}: {s:?}"
        );
    }
    // uniform weights leave the singularities where they were
    let uniform = vec![0.3; m.triangles.len()];
    let u = singularities(&m, &topo, &face_field(&m, &topo, &[], Some(&uniform)));
    assert_eq!(u.len(), 2, "{u:?}");
    assert!(
        u.iter().all(|s| Vec3::from(s.position).dot(pole).abs() > 0.99),
        "{u:?}"
    );
}
