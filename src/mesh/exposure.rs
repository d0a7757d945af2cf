//! How exposed each face is to view: the cosine-weighted share of the
//! directions around its normal from which it is seen unoccluded (one minus
//! its ambient occlusion). A face in a crease, under a chin or between
//! legs is seen from few directions; a face on a convex bulge from its
//! whole hemisphere. `atlas` reports it at the field's singularities, and
//! with `--field-exposure` the default vector field turns where it is low,
//! so its singularities sit where they are seen least (`crate::field`).
//!
//! Visibility comes from orthographic depth maps of the whole mesh along
//! [`DIRECTIONS`] directions spread over the sphere (a Fibonacci lattice):
//! a face is seen from a direction when it faces it and its centre is no
//! deeper than the nearest surface there.

use glam::DVec3;
use rayon::prelude::*;

use super::Mesh;
use crate::math;

/// Directions the mesh is viewed from.
pub const DIRECTIONS: usize = 96;

/// Depth map edge in pixels (over the mesh's extent across the direction).
const PIXELS: usize = 192;

/// A face centre counts as seen when it lies within this many pixel widths
/// behind the nearest surface (its own triangle's depth varies across the
/// pixel it falls in, and neighbours share its pixels).
const DEPTH_SLACK: f64 = 1.5;

/// Each face's exposure in 0..=1 (1: seen from its whole hemisphere).
/// Deterministic: the sums run over directions in a fixed order whatever
/// the thread count.
pub fn face_exposure(mesh: &Mesh) -> Vec<f32> {
    let nf = mesh.triangles.len();
    let mut seen = vec![0f64; nf];
    let mut facing = vec![0f64; nf];
    if nf == 0 {
        return Vec::new();
    }
    let positions: Vec<DVec3> = mesh
        .positions
        .iter()
        .map(|p| DVec3::new(p[0] as f64, p[1] as f64, p[2] as f64))
        .collect();
    let normals: Vec<DVec3> = (0..nf)
        .map(|f| {
            let n = mesh.face_normal(f);
            DVec3::new(n[0] as f64, n[1] as f64, n[2] as f64)
        })
        .collect();
    let centres: Vec<DVec3> = mesh
        .triangles
        .iter()
        .map(|t| t.iter().map(|&v| positions[v as usize]).sum::<DVec3>() / 3.0)
        .collect();
    // each direction's seen faces, computed in parallel a group at a time
    // and summed in direction order (the sums do not depend on threads)
    let golden = std::f64::consts::PI * (3.0 - 5f64.sqrt());
    let seen_from = |k: usize| -> (DVec3, Vec<bool>) {
        // the Fibonacci lattice on the sphere
        let z = 1.0 - (2 * k + 1) as f64 / DIRECTIONS as f64;
        let r = (1.0 - z * z).max(0.0).sqrt();
        let phi = golden * k as f64;
        let d = DVec3::new(r * math::cos(phi), r * math::sin(phi), z);
        let (u, v) = d.any_orthonormal_pair();
        // project: (u, v) on the image plane, height along d (towards the viewer)
        let projected: Vec<(f64, f64, f64)> =
            positions.iter().map(|p| (p.dot(u), p.dot(v), p.dot(d))).collect();
        let (mut lo, mut hi) = ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]);
        for q in &projected {
            lo = [lo[0].min(q.0), lo[1].min(q.1)];
            hi = [hi[0].max(q.0), hi[1].max(q.1)];
        }
        let extent = (hi[0] - lo[0]).max(hi[1] - lo[1]).max(1e-30);
        let scale = (PIXELS - 1) as f64 / extent;
        let to_pixel = |q: (f64, f64, f64)| ((q.0 - lo[0]) * scale, (q.1 - lo[1]) * scale, q.2);
        let mut depth = vec![f64::NEG_INFINITY; PIXELS * PIXELS];
        for t in &mesh.triangles {
            let [a, b, c] = t.map(|v| to_pixel(projected[v as usize]));
            rasterize_depth(&mut depth, a, b, c);
        }
        let slack = DEPTH_SLACK / scale;
        let seen = (0..nf)
            .map(|f| {
                let c = centres[f];
                let (x, y, h) = to_pixel((c.dot(u), c.dot(v), c.dot(d)));
                let (px, py) = (x.round() as usize, y.round() as usize);
                px < PIXELS && py < PIXELS && h + slack >= depth[py * PIXELS + px]
            })
            .collect();
        (d, seen)
    };
    let group = rayon::current_num_threads().max(1) * 2;
    for first in (0..DIRECTIONS).step_by(group) {
        let views: Vec<(DVec3, Vec<bool>)> = (first..(first + group).min(DIRECTIONS))
            .into_par_iter()
            .map(seen_from)
            .collect();
        for (d, view) in &views {
            for f in 0..nf {
                let cos = normals[f].dot(*d);
                if cos > 0.0 {
                    facing[f] += cos;
                    if view[f] {
                        seen[f] += cos;
                    }
                }
            }
        }
    }
    seen.iter()
        .zip(&facing)
        .map(|(&s, &f)| if f > 0.0 { (s / f) as f32 } else { 1.0 })
        .collect()
}

/// Keeps the largest height over the pixel centres inside triangle `a b c`
/// (pixel coordinates, height along the view direction).
fn rasterize_depth(depth: &mut [f64], a: (f64, f64, f64), b: (f64, f64, f64), c: (f64, f64, f64)) {
    let area = (b.0 - a.0) * (c.1 - a.1) - (c.0 - a.0) * (b.1 - a.1);
    if area.abs() < 1e-12 {
        return;
    }
    let x0 = a.0.min(b.0).min(c.0).ceil().max(0.0) as usize;
    let y0 = a.1.min(b.1).min(c.1).ceil().max(0.0) as usize;
    let x1 = (a.0.max(b.0).max(c.0).floor().max(-1.0) as isize).min(PIXELS as isize - 1);
    let y1 = (a.1.max(b.1).max(c.1).floor().max(-1.0) as isize).min(PIXELS as isize - 1);
    for y in y0 as isize..=y1 {
        for x in x0 as isize..=x1 {
            let (px, py) = (x as f64, y as f64);
            let w0 = ((b.0 - px) * (c.1 - py) - (c.0 - px) * (b.1 - py)) / area;
            let w1 = ((c.0 - px) * (a.1 - py) - (a.0 - px) * (c.1 - py)) / area;
            let w2 = 1.0 - w0 - w1;
            if w0 < -1e-9 || w1 < -1e-9 || w2 < -1e-9 {
                continue;
            }
            let h = w0 * a.2 + w1 * b.2 + w2 * c.2;
            let cell = &mut depth[y as usize * PIXELS + x as usize];
            if h > *cell {
                *cell = h;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A closed box: every face sees its whole hemisphere (exposure ≈ 1).
    fn cube() -> Mesh {
        let p = |x: f32, y: f32, z: f32| [x, y, z];
        let positions = vec![
            p(0., 0., 0.),
            p(1., 0., 0.),
            p(1., 1., 0.),
            p(0., 1., 0.),
            p(0., 0., 1.),
            p(1., 0., 1.),
            p(1., 1., 1.),
            p(0., 1., 1.),
        ];
        let quads = [
            [0, 3, 2, 1],
            [4, 5, 6, 7],
            [0, 1, 5, 4],
            [2, 3, 7, 6],
            [1, 2, 6, 5],
            [0, 4, 7, 3],
        ];
        let triangles = quads
            .iter()
            .flat_map(|q| [[q[0], q[1], q[2]], [q[0], q[2], q[3]]])
            .collect();
        Mesh {
            positions,
            triangles,
            ..Default::default()
        }
    }

    #[test]
    fn a_convex_box_is_seen_from_everywhere_and_a_hidden_floor_is_not() {
        let m = cube();
        let e = face_exposure(&m);
        assert!(e.iter().all(|&x| x > 0.95), "{e:?}");
        // a floor under a lid: the floor's upper side sees only the gap
        // at the sides, the lid's upper side the whole sky
        let mut m = Mesh::default();
        let mut quad = |z: f32, half: f32, up: bool| {
            let b = m.positions.len() as u32;
            for (x, y) in [(-half, -half), (half, -half), (half, half), (-half, half)] {
                m.positions.push([x, y, z]);
            }
            let (t0, t1) = if up {
                ([b, b + 1, b + 2], [b, b + 2, b + 3])
            } else {
                ([b, b + 2, b + 1], [b, b + 3, b + 2])
            };
            m.triangles.push(t0);
            m.triangles.push(t1);
        };
        quad(0.0, 1.0, true); // floor, facing up
        quad(0.2, 2.0, true); // lid above it, facing up
        let e = face_exposure(&m);
        assert!(e[0] < 0.3 && e[1] < 0.3, "floor {e:?}");
        assert!(e[2] > 0.95 && e[3] > 0.95, "lid {e:?}");
    }
}
