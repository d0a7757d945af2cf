use super::*;

fn mesh(positions: &[[f32; 3]], triangles: &[[u32; 3]]) -> Mesh {
    Mesh {
        positions: positions.to_vec(),
        triangles: triangles.to_vec(),
        ..Default::default()
    }
}

#[test]
fn mesh_repair_weld_with_tolerance_keeps_lowest_index() {
    let mut m = mesh(
        &[
            [0.0, 0.0, 0.0],
            [1.0, 0.0, 0.0],
            [0.0, 1.0, 0.0],
            [1.0, 1e-4, 0.0],
            [1.0, 1.0, 0.0],
        ],
        &[[0, 1, 2], [2, 3, 4]],
    );
    let r = repair(&mut m, 1e-3);
    assert_eq!(r.welded_vertices, 1);
    assert_eq!(m.positions.len(), 4);
    assert_eq!(m.positions[1], [1.0, 0.0, 0.0]);
    assert_eq!(m.triangles, vec![[0, 1, 2], [2, 1, 3]]);
    // Without tolerance the near vertex stays separate.
    let mut m = mesh(
        &[
            [0.0, 0.0, 0.0],
            [1.0, 0.0, 0.0],
            [0.0, 1.0, 0.0],
            [1.0, 1e-4, 0.0],
            [1.0, 1.0, 0.0],
        ],
        &[[0, 1, 2], [2, 3, 4]],
    );
    assert_eq!(repair(&mut m, 0.0).welded_vertices, 0);
}

#[test]
fn mesh_repair_duplicate_faces_dropped_and_empty_mesh_ok() {
    let mut m = mesh(
        &[[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]],
        &[[0, 1, 2], [1, 2, 0], [0, 2, 1]],
    );
    let r = repair(&mut m, 0.0);
    assert_eq!(r.degenerate_faces, 2);
    assert_eq!(m.triangles, vec![[0, 1, 2]]);
    let mut empty = Mesh::default();
    let r = repair(&mut empty, 1e-6);
    assert_eq!(r.components, 0);
    assert!(r.is_clean());
}

#[test]
fn mesh_repair_bad_indices_and_nan_do_not_panic() {
    let mut m = mesh(
        &[
            [0.0, 0.0, 0.0],
            [1.0, 0.0, 0.0],
            [0.0, 1.0, 0.0],
            [f32::NAN, 0.0, 0.0],
        ],
        &[[0, 1, 2], [0, 1, 9], [0, 3, 1]],
    );
    let r = repair(&mut m, 1e-6);
    assert_eq!(r.degenerate_faces, 2);
    assert_eq!(r.unreferenced_vertices, 1);
    assert_eq!(m.positions.len(), 3);
}

#[test]
fn mesh_repair_display() {
    let r = RepairReport {
        input_vertices: 4,
        input_faces: 2,
        components: 1,
        boundary_loops: 1,
        ..Default::default()
    };
    assert_eq!(
        r.to_string(),
        "4 vertices, 2 faces, 1 component, 1 boundary loop; no repair needed"
    );
    let r = RepairReport {
        welded_vertices: 1,
        degenerate_faces: 2,
        input_faces: 4,
        ..r
    };
    assert_eq!(
        r.to_string(),
        "3 vertices, 2 faces (input 4, 4), 1 component, 1 boundary loop; \
         repaired: welded 1 vertex, dropped 2 degenerate faces"
    );
}
