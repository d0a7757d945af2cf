//! The vector field: a unit tangent direction per face that orients the
//! sample on the surface (DESIGN.md section 2, "Vector field").
//!
//! User keys (a direction at a few faces) are interpolated over the surface
//! with Gaussian radial basis functions centred at the key faces and
//! projected into each face's plane. Without keys, a smooth default field is
//! the mesh's principal axis projected into each face plane, smoothed by a few
//! rounds of neighbour averaging (its singularities sit where the axis meets
//! the surface head-on, as any field on a sphere must have some).

use std::path::Path;

use crate::json::Json;
use crate::mesh::{cross, dot, normalize, sub, Mesh, Topology, NO_FACE};
use crate::{Error, Result};

/// A user direction at one face.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FieldKey {
    pub face: u32,
    pub dir: [f32; 3],
}

/// Reads keys from JSON: `[{"face": 12, "dir": [1, 0, 0]}, …]`.
pub fn read_keys(path: &Path, face_count: usize) -> Result<Vec<FieldKey>> {
    let text = std::fs::read_to_string(path).map_err(|e| Error::io(path, e))?;
    let doc = Json::parse(&text).map_err(|e| Error::input(path, format!("not valid JSON: {e}")))?;
    let items = doc
        .as_array()
        .ok_or_else(|| Error::input(path, "expected a JSON array of {\"face\": N, \"dir\": [x, y, z]}"))?;
    let mut keys = Vec::with_capacity(items.len());
    for (i, item) in items.iter().enumerate() {
        let bad = |what: &str| Error::input(path, format!("key {i}: {what}"));
        let face = item
            .get("face")
            .and_then(Json::as_f64)
            .ok_or_else(|| bad("missing \"face\" number"))?;
        if face < 0.0 || face.fract() != 0.0 || face >= face_count as f64 {
            return Err(bad(&format!(
                "face {face} is not a face index (the mesh has {face_count} faces)"
            )));
        }
        let d = item
            .get("dir")
            .and_then(Json::as_vec::<3>)
            .ok_or_else(|| bad("\"dir\" must be [x, y, z]"))?;
        let dir = [d[0] as f32, d[1] as f32, d[2] as f32];
        if !dir.iter().all(|v| v.is_finite()) || dot(dir, dir) == 0.0 {
            return Err(bad("\"dir\" must be a finite, non-zero vector"));
        }
        keys.push(FieldKey {
            face: face as u32,
            dir,
        });
    }
    Ok(keys)
}

fn face_center(mesh: &Mesh, f: usize) -> [f32; 3] {
    let [a, b, c] = mesh.corners(f);
    [
        (a[0] + b[0] + c[0]) / 3.0,
        (a[1] + b[1] + c[1]) / 3.0,
        (a[2] + b[2] + c[2]) / 3.0,
    ]
}

/// Projects `v` into the plane with unit normal `n`.
fn project(v: [f32; 3], n: [f32; 3]) -> [f32; 3] {
    let d = dot(v, n);
    [v[0] - d * n[0], v[1] - d * n[1], v[2] - d * n[2]]
}

/// The two leading principal axes of the area-weighted face centres.
fn principal_axes(mesh: &Mesh) -> ([f32; 3], [f32; 3]) {
    let (mut mean, mut total) = ([0f64; 3], 0f64);
    for f in 0..mesh.triangles.len() {
        let (c, a) = (face_center(mesh, f), mesh.face_area(f) as f64);
        for k in 0..3 {
            mean[k] += a * c[k] as f64;
        }
        total += a;
    }
    let total = total.max(1e-30);
    mean.iter_mut().for_each(|m| *m /= total);
    let mut cov = [[0f64; 3]; 3];
    for f in 0..mesh.triangles.len() {
        let (c, a) = (face_center(mesh, f), mesh.face_area(f) as f64);
        let d = [
            c[0] as f64 - mean[0],
            c[1] as f64 - mean[1],
            c[2] as f64 - mean[2],
        ];
        for i in 0..3 {
            for j in 0..3 {
                cov[i][j] += a * d[i] * d[j];
            }
        }
    }
    let power = |deflate: Option<[f64; 3]>| {
        let mut v = [0.6f64, 0.7, 0.4];
        for _ in 0..200 {
            let mut w = [0f64; 3];
            for i in 0..3 {
                w[i] = (0..3).map(|j| cov[i][j] * v[j]).sum();
            }
            if let Some(u) = deflate {
                let d: f64 = (0..3).map(|k| w[k] * u[k]).sum();
                (0..3).for_each(|k| w[k] -= d * u[k]);
            }
            let n = (w.iter().map(|x| x * x).sum::<f64>()).sqrt();
            if n < 1e-300 {
                break;
            }
            v = [w[0] / n, w[1] / n, w[2] / n];
        }
        v
    };
    let a = power(None);
    let b = power(Some(a));
    let f = |v: [f64; 3]| normalize([v[0] as f32, v[1] as f32, v[2] as f32]);
    (f(a), f(b))
}

/// A unit tangent direction per face: RBF-interpolated `keys`, or the
/// smooth default field when `keys` is empty.
pub fn face_field(mesh: &Mesh, topology: &Topology, keys: &[FieldKey]) -> Vec<[f32; 3]> {
    let nf = mesh.triangles.len();
    let normals: Vec<[f32; 3]> = (0..nf).map(|f| mesh.face_normal(f)).collect();
    let (a1, a2) = principal_axes(mesh);
    let default_dir = |f: usize| {
        let n = normals[f];
        let t = project(a1, n);
        // near the axis' poles, lean on the second axis so the field stays defined
        let w = (dot(t, t).sqrt() / 0.3).min(1.0);
        let t2 = project(a2, n);
        normalize([
            w * t[0] + (1.0 - w) * t2[0],
            w * t[1] + (1.0 - w) * t2[1],
            w * t[2] + (1.0 - w) * t2[2],
        ])
    };
    let mut field: Vec<[f32; 3]> = if keys.is_empty() {
        (0..nf).map(default_dir).collect()
    } else {
        rbf_field(mesh, &normals, keys, &default_dir)
    };
    if keys.is_empty() {
        // Jacobi smoothing: each face takes the mean of its own and its
        // neighbours' directions, projected into its plane
        for _ in 0..8 {
            let next: Vec<[f32; 3]> = (0..nf)
                .map(|f| {
                    let mut s = field[f];
                    for &g in &topology.face_adjacency[f] {
                        if g != NO_FACE {
                            let v = field[g as usize];
                            s = [s[0] + v[0], s[1] + v[1], s[2] + v[2]];
                        }
                    }
                    let p = normalize(project(s, normals[f]));
                    if dot(p, p) > 0.5 {
                        p
                    } else {
                        field[f]
                    }
                })
                .collect();
            field = next;
        }
    }
    // a face whose direction vanished (degenerate normal) gets any tangent
    for (f, v) in field.iter_mut().enumerate() {
        if !(dot(*v, *v) > 0.5) {
            let n = normals[f];
            let other = if n[0].abs() < 0.9 {
                [1.0, 0.0, 0.0]
            } else {
                [0.0, 1.0, 0.0]
            };
            *v = normalize(cross(n, other));
        }
    }
    field
}

/// Gaussian RBF interpolation of the key directions (DESIGN.md: "interpolated
/// to all faces with radial basis functions").
fn rbf_field(
    mesh: &Mesh,
    normals: &[[f32; 3]],
    keys: &[FieldKey],
    default_dir: &dyn Fn(usize) -> [f32; 3],
) -> Vec<[f32; 3]> {
    let centers: Vec<[f32; 3]> = keys.iter().map(|k| face_center(mesh, k.face as usize)).collect();
    let dirs: Vec<[f32; 3]> = keys
        .iter()
        .map(|k| normalize(project(normalize(k.dir), normals[k.face as usize])))
        .collect();
    let k = keys.len();
    let dist = |a: [f32; 3], b: [f32; 3]| {
        let d = sub(a, b);
        dot(d, d).sqrt() as f64
    };
    // kernel width: the mean spacing between keys (half the bounding-box
    // diagonal for a single key), so the interpolant turns smoothly between them
    let diag = mesh.bbox_diagonal() as f64;
    let mut sigma = 0.5 * diag;
    if k > 1 {
        let mean_nn: f64 = (0..k)
            .map(|i| {
                (0..k)
                    .filter(|&j| j != i)
                    .map(|j| dist(centers[i], centers[j]))
                    .fold(f64::INFINITY, f64::min)
            })
            .sum::<f64>()
            / k as f64;
        sigma = mean_nn.clamp(0.05 * diag, diag);
    }
    let phi = |r: f64| (-(r / sigma) * (r / sigma)).exp();
    // solve (Φ + εI) W = D by Gaussian elimination with partial pivoting
    let mut a: Vec<Vec<f64>> = (0..k)
        .map(|i| {
            let mut row: Vec<f64> = (0..k).map(|j| phi(dist(centers[i], centers[j]))).collect();
            row[i] += 1e-6;
            row.extend(dirs[i].iter().map(|&v| v as f64));
            row
        })
        .collect();
    for col in 0..k {
        let piv = (col..k)
            .max_by(|&x, &y| a[x][col].abs().total_cmp(&a[y][col].abs()))
            .unwrap_or(col);
        a.swap(col, piv);
        let p = a[col][col];
        if p.abs() < 1e-300 {
            continue;
        }
        for r in 0..k {
            if r != col {
                let factor = a[r][col] / p;
                if factor != 0.0 {
                    for c in col..k + 3 {
                        a[r][c] -= factor * a[col][c];
                    }
                }
            }
        }
    }
    let w: Vec<[f64; 3]> = (0..k)
        .map(|i| {
            let p = a[i][i];
            if p.abs() < 1e-300 {
                [0.0; 3]
            } else {
                [a[i][k] / p, a[i][k + 1] / p, a[i][k + 2] / p]
            }
        })
        .collect();
    (0..mesh.triangles.len())
        .map(|f| {
            let c = face_center(mesh, f);
            let mut v = [0f64; 3];
            for i in 0..k {
                let s = phi(dist(c, centers[i]));
                (0..3).for_each(|d| v[d] += s * w[i][d]);
            }
            let t = project([v[0] as f32, v[1] as f32, v[2] as f32], normals[f]);
            if dot(t, t) > 1e-12 {
                normalize(t)
            } else {
                default_dir(f)
            }
        })
        .collect()
}

#[cfg(test)]
mod tests {
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
        let f = face_field(&m, &topo, &keys);
        assert!(dot(f[0], [1.0, 0.0, 0.0]) > 0.99, "{:?}", f[0]);
        assert!(dot(f[199], [0.0, 1.0, 0.0]) > 0.99, "{:?}", f[199]);
        for v in &f {
            assert!((dot(*v, *v) - 1.0).abs() < 1e-4 && v[2].abs() < 1e-5);
        }
        // in between, the direction turns smoothly: neighbours differ little
        for (g, adj) in topo.face_adjacency.iter().enumerate() {
            for &h in adj {
                if h != NO_FACE {
                    assert!(dot(f[g], f[h as usize]) > 0.8);
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
        let f = face_field(&m, &m.topology(), &[]);
        for v in &f {
            assert!(v[0].abs() > 0.99, "{v:?}");
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
}
