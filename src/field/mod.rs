//! The vector field: a unit tangent direction per face that orients the
//! sample on the surface (docs/design.md section 5.4).
//!
//! User keys (a direction at a few faces) are interpolated over the surface
//! with Gaussian radial basis functions centred at the key faces and
//! projected into each face's plane. Without keys, the default field is the
//! smoothest field (Knöppel, Crane, Pinkall, Schröder 2013, "Globally Optimal
//! Direction Fields"), turned by the one global angle that best aligns its
//! lines with the mesh's principal axis projected into each face plane. The
//! smoothness places the singularities that every field on a closed surface
//! of genus ≠ 1 must have where they cost least (a torus gets none), instead
//! of wherever the axis meets the surface head-on.

mod stripes;
pub use stripes::{forced_ends, ForcedEnds, StripePattern};

use std::path::Path;

use glam::{DVec3, Vec3};

use crate::math;
use crate::mesh::{unit_or, Mesh, Topology, NO_FACE};
use crate::{Error, Result};

/// A user direction at one face.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FieldKey {
    pub face: u32,
    pub dir: [f32; 3],
}

/// One key as a keys file gives it.
#[derive(serde::Deserialize)]
struct KeyRecord {
    face: f64,
    dir: [f64; 3],
}

/// Reads keys from JSON: `[{"face": 12, "dir": [1, 0, 0]}, …]`.
pub fn read_keys(path: &Path, face_count: usize) -> Result<Vec<FieldKey>> {
    let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
    let items: Vec<KeyRecord> = serde_json::from_slice(&bytes).map_err(|e| {
        Error::input(
            path,
            format!("not valid JSON field keys (expected a JSON array of {{\"face\": N, \"dir\": [x, y, z]}}): {e}"),
        )
    })?;
    let mut keys = Vec::with_capacity(items.len());
    for (i, item) in items.iter().enumerate() {
        let bad = |what: &str| Error::input(path, format!("key {i}: {what}"));
        let face = item.face;
        if face < 0.0 || face.fract() != 0.0 || face >= face_count as f64 {
            return Err(bad(&format!(
                "face {face} is not a face index (the mesh has {face_count} faces)"
            )));
        }
        let d = item.dir;
        let dir = [d[0] as f32, d[1] as f32, d[2] as f32];
        if !dir.iter().all(|v| v.is_finite()) || Vec3::from(dir).length_squared() == 0.0 {
            return Err(bad("\"dir\" must be a finite, non-zero vector"));
        }
        keys.push(FieldKey {
            face: face as u32,
            dir,
        });
    }
    Ok(keys)
}

fn face_center(mesh: &Mesh, f: usize) -> Vec3 {
    let [a, b, c] = mesh.corners(f).map(Vec3::from);
    (a + b + c) / 3.0
}

/// Projects `v` into the plane with unit normal `n`.
fn project(v: Vec3, n: Vec3) -> Vec3 {
    v - v.dot(n) * n
}

/// The two leading principal axes of the area-weighted face centres (a
/// world axis and the direction across it when the two are about equal).
fn principal_axes(mesh: &Mesh) -> (Vec3, Vec3) {
    let (mut mean, mut total) = (DVec3::ZERO, 0f64);
    for f in 0..mesh.triangles.len() {
        let (c, a) = (face_center(mesh, f), mesh.face_area(f) as f64);
        mean += a * c.as_dvec3();
        total += a;
    }
    let total = total.max(1e-30);
    mean /= total;
    let mut cov = [[0f64; 3]; 3];
    for f in 0..mesh.triangles.len() {
        let (c, a) = (face_center(mesh, f), mesh.face_area(f) as f64);
        let d = c.as_dvec3() - mean;
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
    let rayleigh = |v: [f64; 3]| -> f64 {
        (0..3)
            .map(|i| (0..3).map(|j| v[i] * cov[i][j] * v[j]).sum::<f64>())
            .sum()
    };
    let f = |v: DVec3| unit_or(v.as_vec3(), Vec3::ZERO);
    let (la, lb) = (rayleigh(a), rayleigh(b));
    let (a, b) = (DVec3::from(a), DVec3::from(b));
    if lb > ISOTROPIC * la {
        // no clear long axis (a square, a disk, a sphere): the world axis that
        // lies most in the leading plane, x before y before z on ties, so a
        // flat square in the xy plane is tiled along x like a 2D synthesis
        let in_plane = |e: DVec3| {
            let (pa, pb) = (e.dot(a), e.dot(b));
            pa * pa + pb * pb
        };
        let axes = [DVec3::X, DVec3::Y, DVec3::Z];
        let mut best = axes[0];
        for &e in &axes[1..] {
            if in_plane(e) > in_plane(best) + 1e-3 {
                best = e;
            }
        }
        let d: f64 = (0..3).map(|k| best[k] * a[k]).sum();
        let e: f64 = (0..3).map(|k| best[k] * b[k]).sum();
        let other = -e * a + d * b;
        return (f(best), f(other));
    }
    (f(a), f(b))
}

/// When the second principal variance exceeds this fraction of the first,
/// the mesh has no clear long axis ([`principal_axes`] then takes a world
/// axis).
const ISOTROPIC: f64 = 0.9;

/// A unit tangent direction per face: RBF-interpolated `keys`, or the
/// smooth default field when `keys` is empty. `turning`, when given, holds a
/// weight per face for the default field's smoothness: turning between two
/// faces costs the mean of their weights × the usual energy, so the field
/// turns, and its singularities sit, where the weights are low (the atlas
/// gives each face's exposure to a power, [`crate::mesh::exposure`]).
pub fn face_field(
    mesh: &Mesh,
    topology: &Topology,
    keys: &[FieldKey],
    turning: Option<&[f64]>,
) -> Vec<[f32; 3]> {
    let nf = mesh.triangles.len();
    let normals: Vec<[f32; 3]> = (0..nf).map(|f| mesh.face_normal(f)).collect();
    let (a1, a2) = principal_axes(mesh);
    let default_dir = |f: usize| {
        let n = Vec3::from(normals[f]);
        let t = project(a1, n);
        // near the axis' poles, lean on the second axis so the field stays defined
        let w = (t.length() / 0.3).min(1.0);
        let t2 = project(a2, n);
        unit_or(w * t + (1.0 - w) * t2, Vec3::ZERO).to_array()
    };
    let mut field: Vec<[f32; 3]> = if keys.is_empty() {
        let prior: Vec<[f32; 3]> = (0..nf)
            .map(|f| project(a1, normals[f].into()).to_array())
            .collect();
        match smoothest_field(mesh, topology, &normals, &prior, turning) {
            Some(u) => u,
            None => (0..nf).map(default_dir).collect(),
        }
    } else {
        rbf_field(mesh, &normals, keys, &default_dir)
    };
    // a face whose direction vanished (degenerate normal) gets any tangent
    for (f, v) in field.iter_mut().enumerate() {
        if !(Vec3::from(*v).length_squared() > 0.5) {
            let n = Vec3::from(normals[f]);
            let other = if n.x.abs() < 0.9 { Vec3::X } else { Vec3::Y };
            *v = unit_or(n.cross(other), Vec3::ZERO).to_array();
        }
    }
    field
}

/// A singular vertex of a face field: where the field turns by
/// `index` × 360° around the vertex (`index` ≠ 0). On a closed surface the
/// indices sum to its Euler characteristic (Poincaré–Hopf: 2 for a sphere,
/// 0 for a torus); there a sample's lines meet at an angle.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Singularity {
    pub vertex: u32,
    pub index: i32,
    pub position: [f32; 3],
    /// How exposed the surface around it is: the mean of its faces'
    /// [`crate::mesh::exposure::face_exposure`] (1: seen from every side;
    /// `NaN` until the atlas sets it).
    pub exposure: f32,
}

/// The singular interior vertices of `field` (one unit tangent per face),
/// in vertex order: the field's turning around each vertex, measured
/// relative to the discrete Levi-Civita transport between neighbouring
/// faces, plus the vertex's angle defect.
/// Boundary and non-manifold vertices are skipped.
pub fn singularities(mesh: &Mesh, topology: &Topology, field: &[[f32; 3]]) -> Vec<Singularity> {
    use std::f64::consts::TAU;
    let nf = mesh.triangles.len();
    let frames = face_frames(mesh);
    // one face (and its corner) per vertex to start the walk from
    let mut start = vec![(NO_FACE, 0usize); mesh.positions.len()];
    for (f, t) in mesh.triangles.iter().enumerate() {
        for (k, &v) in t.iter().enumerate() {
            if start[v as usize].0 == NO_FACE {
                start[v as usize] = (f as u32, k);
            }
        }
    }
    let corner_angle = |f: usize, k: usize| {
        let c = mesh.corners(f).map(|p| Vec3::from(p).as_dvec3());
        let (a, b) = (c[(k + 1) % 3] - c[k], c[(k + 2) % 3] - c[k]);
        a.angle_between(b)
    };
    let mut out = Vec::new();
    for (v, &(f0, k0)) in start.iter().enumerate() {
        if f0 == NO_FACE {
            continue;
        }
        // counter-clockwise around v: from face f (v at corner k) across its
        // edge from corner k + 2 to corner k
        let (mut f, mut k) = (f0 as usize, k0);
        let (mut turning, mut angles) = (0f64, 0f64);
        let mut closed = false;
        for _ in 0..=nf.min(64) {
            angles += corner_angle(f, k);
            let g = topology.face_adjacency[f][(k + 2) % 3];
            if g == NO_FACE {
                break;
            }
            let g = g as usize;
            let Some(kg) = mesh.triangles[g].iter().position(|&w| w as usize == v) else {
                break;
            };
            let t = mesh.triangles[f];
            let edge = Vec3::from(mesh.positions[t[k] as usize])
                - Vec3::from(mesh.positions[t[(k + 2) % 3] as usize]);
            // carries f's angles into g's frame
            let rho = frame_angle(edge, frames[g]) - frame_angle(edge, frames[f]);
            let (a, b) = (
                frame_angle(field[f].into(), frames[f]),
                frame_angle(field[g].into(), frames[g]),
            );
            turning += wrap_angle(b - (a + rho));
            (f, k) = (g, kg);
            if f == f0 as usize {
                closed = true;
                break;
            }
        }
        if !closed {
            continue;
        }
        let index = ((turning + (TAU - angles)) / TAU).round() as i32;
        if index != 0 {
            out.push(Singularity {
                vertex: v as u32,
                index,
                position: mesh.positions[v],
                exposure: f32::NAN,
            });
        }
    }
    out
}

/// `a` (radians) wrapped into [−π, π).
pub(crate) fn wrap_angle(a: f64) -> f64 {
    use std::f64::consts::{PI, TAU};
    a - TAU * ((a + PI) / TAU).floor()
}

/// The sparse Cholesky factorization of a Hermitian positive definite
/// form given by its complex entries above the diagonal (`(i, j, a, b)`
/// for a + ib at row i < column j) and its real diagonal, as the real
/// 2N × 2N symmetric matrix whose complex entry a + ib is the block
/// [[a, −b], [b, a]] (upper triangle).
pub(crate) fn factorize_hermitian(
    upper: &[(usize, usize, f64, f64)],
    diagonal: &[f64],
) -> Option<crate::sparse::SpdFactor> {
    use faer::sparse::{SparseColMat, Triplet};
    let n = diagonal.len();
    let mut trip: Vec<Triplet<usize, usize, f64>> = Vec::with_capacity(4 * upper.len() + 2 * n);
    for &(i, j, a, b) in upper {
        trip.push(Triplet::new(2 * i, 2 * j, a));
        trip.push(Triplet::new(2 * i, 2 * j + 1, -b));
        trip.push(Triplet::new(2 * i + 1, 2 * j, b));
        trip.push(Triplet::new(2 * i + 1, 2 * j + 1, a));
    }
    for (i, &d) in diagonal.iter().enumerate() {
        trip.push(Triplet::new(2 * i, 2 * i, d));
        trip.push(Triplet::new(2 * i + 1, 2 * i + 1, d));
    }
    let h = SparseColMat::<usize, f64>::try_new_from_triplets(2 * n, 2 * n, &trip).ok()?;
    crate::sparse::SpdFactor::new(&h).ok()
}

/// The shift ε of L + εM in the inverse iteration, in units of
/// 1 / (bounding-box diagonal)²: small against the eigenvalues of a curved
/// surface's smoothest fields, large enough to keep a flat one's (zero)
/// factorizable.
const SMOOTHEST_SHIFT: f64 = 1e-3;

/// Implicit steps of the weighted flow of [`smoothest_field`] (with
/// `turning`): each solves (L_w + τM) u' = τM û, û the field at unit length
/// per face, the discrete heat flow of the weighted energy by steps of 1/τ
/// renormalised (a Ginzburg–Landau-style relaxation). On a sphere whose cap
/// (z > 0.5) weighs 0.05, 30 steps brought both singularities into the cap,
/// 100 steps brought one into smaller caps (z > 0.7 and z > 0.85), with the other
/// opposite.
const FLOW_STEPS: usize = 100;

/// τ of the weighted flow, in units of 1 / (bounding-box diagonal)²: long
/// steps (singularities move slowly under the flow); 0.1 and 3 behaved alike
/// on the sphere above, 100 moved them a quarter as far.
const FLOW_SHIFT: f64 = 1.0;

/// Inverse-iteration steps of [`smoothest_field`].
const INVERSE_ITERATIONS: usize = 40;

/// Each face's tangent frame: the unit first edge and the normal × it.
fn face_frame(mesh: &Mesh, f: usize, n: Vec3) -> (DVec3, DVec3) {
    let [a, b, _] = mesh.corners(f).map(Vec3::from);
    let e1 = unit_or(b - a, Vec3::ZERO);
    let e2 = n.cross(e1);
    (e1.as_dvec3(), e2.as_dvec3())
}

/// Every face's tangent frame ([`face_frame`]) about its own normal.
fn face_frames(mesh: &Mesh) -> Vec<(DVec3, DVec3)> {
    (0..mesh.triangles.len())
        .map(|f| face_frame(mesh, f, mesh.face_normal(f).into()))
        .collect()
}

/// The coordinates of 3D vector `d` in frame `(e1, e2)`.
fn frame_coords(d: Vec3, (e1, e2): (DVec3, DVec3)) -> (f64, f64) {
    let d = d.as_dvec3();
    (d.dot(e1), d.dot(e2))
}

/// The angle of 3D vector `d` in frame `(e1, e2)`.
fn frame_angle(d: Vec3, frame: (DVec3, DVec3)) -> f64 {
    let (x, y) = frame_coords(d, frame);
    math::atan2(y, x)
}

/// The discrete connection of a face pair: for each interior edge (f, g)
/// with f < g, the dual weight |e| / |c_f − c_g| and the transport angle ρ
/// that carries g's frame angles into f's (u_f ≈ e^{iρ} u_g).
fn connection(mesh: &Mesh, topology: &Topology, frames: &[(DVec3, DVec3)]) -> Vec<(u32, u32, f64, f64)> {
    let mut edges = Vec::new();
    for (f, adj) in topology.face_adjacency.iter().enumerate() {
        for (i, &g) in adj.iter().enumerate() {
            if g == NO_FACE || (g as usize) <= f {
                continue;
            }
            let t = mesh.triangles[f];
            let d = Vec3::from(mesh.positions[t[(i + 1) % 3] as usize])
                - Vec3::from(mesh.positions[t[i] as usize]);
            let h = face_center(mesh, f) - face_center(mesh, g as usize);
            let (l, h) = (d.length() as f64, h.length() as f64);
            if !(l > 0.0 && h > 0.0) {
                continue;
            }
            let rho = frame_angle(d, frames[f]) - frame_angle(d, frames[g as usize]);
            edges.push((f as u32, g, l / h, rho));
        }
    }
    edges
}

/// The connection Dirichlet energy Σ w |u_f − e^{iρ} u_g|² of a unit
/// tangent field (the quadratic form whose smallest eigenvector, relative to
/// the area mass, `smoothest_field` finds).
pub fn field_energy(mesh: &Mesh, topology: &Topology, field: &[[f32; 3]]) -> f64 {
    let frames = face_frames(mesh);
    connection(mesh, topology, &frames)
        .into_iter()
        .map(|(f, g, w, rho)| {
            let (f, g) = (f as usize, g as usize);
            let a = frame_angle(field[f].into(), frames[f]);
            let b = frame_angle(field[g].into(), frames[g]) + rho;
            w * ((math::cos(a) - math::cos(b)).powi(2) + (math::sin(a) - math::sin(b)).powi(2))
        })
        .sum()
}

/// The smoothest unit field (Knöppel et al. 2013, section 5.1): the
/// eigenvector of the connection Laplacian, Σ w |u_f − e^{iρ} u_g|² over
/// complex u_f in per-face frames, with the smallest eigenvalue relative to
/// the area mass, by inverse iteration (one sparse Cholesky factorization of
/// the real 2F × 2F form of L + εM, [`INVERSE_ITERATIONS`] solves) run
/// separately on each connected component; with `turning` (a weight per
/// face; each dual edge weighs the mean of its two faces'), [`FLOW_STEPS`]
/// steps of the weighted flow follow. Each component's field is then
/// turned by the global angle that best aligns its lines with `prior`'s
/// (pointing along `prior` rather than against it), and
/// normalised; faces where it vanishes (the singularities) keep the prior's
/// direction. None if the system cannot be solved.
fn smoothest_field(
    mesh: &Mesh,
    topology: &Topology,
    normals: &[[f32; 3]],
    prior: &[[f32; 3]],
    turning: Option<&[f64]>,
) -> Option<Vec<[f32; 3]>> {
    let nf = mesh.triangles.len();
    if nf == 0 {
        return Some(Vec::new());
    }
    let frames: Vec<_> = (0..nf).map(|f| face_frame(mesh, f, normals[f].into())).collect();
    let diag = (mesh.bbox_diagonal() as f64).max(1e-30);
    let mass: Vec<f64> = (0..nf).map(|f| mesh.face_area(f) as f64).collect();
    let in_frame = |f: usize, v: [f32; 3]| frame_coords(v.into(), frames[f]);
    // a degenerate (zero-area) face cut off from its neighbours would leave a
    // zero row: its shift term gets a floor
    let floor = 1e-6 * mass.iter().sum::<f64>() / nf as f64;
    let edges = connection(mesh, topology, &frames);
    // the real 2F × 2F form of L + shift·M, each dual edge's weight × the
    // mean of its faces' `turning` weights when given
    let factorize = |shift: f64, turning: Option<&[f64]>| {
        let mut diagonal: Vec<f64> = mass.iter().map(|m| shift * m.max(floor)).collect();
        let mut upper = Vec::with_capacity(edges.len());
        for &(f, g, w, rho) in &edges {
            let (f, g) = (f as usize, g as usize);
            let w = turning.map_or(w, |t| w * 0.5 * (t[f] + t[g]));
            diagonal[f] += w;
            diagonal[g] += w;
            // the complex entry −w e^{iρ} at (f, g), f < g
            upper.push((f, g, -w * math::cos(rho), -w * math::sin(rho)));
        }
        factorize_hermitian(&upper, &diagonal)
    };
    let factor = factorize(SMOOTHEST_SHIFT / (diag * diag), None)?;
    let components = topology.components.max(1);
    let component = |f: usize| topology.face_component.get(f).map_or(0, |&c| c as usize);
    // normalise each component's part to unit mass-norm (each component is
    // its own eigenproblem: L and M are block diagonal over components)
    let normalise = |u: &mut [f64]| {
        let mut norm = vec![0f64; components];
        for f in 0..nf {
            norm[component(f)] += mass[f] * (u[2 * f] * u[2 * f] + u[2 * f + 1] * u[2 * f + 1]);
        }
        for f in 0..nf {
            let n = norm[component(f)].sqrt();
            if n > 0.0 {
                u[2 * f] /= n;
                u[2 * f + 1] /= n;
            }
        }
    };
    let mut u = vec![0f64; 2 * nf];
    for f in 0..nf {
        let (x, y) = in_frame(f, prior[f]);
        // the start must not be orthogonal to the wanted eigenvector: add a
        // fixed, non-symmetric perturbation to the prior
        let (px, py) = ((f as f64 * 0.618_034).fract(), (f as f64 * 0.414_214).fract());
        u[2 * f] = x + 0.1 * (px - 0.5);
        u[2 * f + 1] = y + 0.1 * (py - 0.5);
    }
    normalise(&mut u);
    for _ in 0..INVERSE_ITERATIONS {
        let b: Vec<f64> = (0..2 * nf).map(|k| mass[k / 2] * u[k]).collect();
        u = factor.solve(b);
        if !u.iter().all(|v| v.is_finite()) {
            return None;
        }
        normalise(&mut u);
    }
    if let Some(turning) = turning {
        // with weights, the relaxed eigenvector would gather its length where
        // turning is cheap and so put its zeros (the singularities) elsewhere:
        // a flow of the weighted energy from it, at unit length per face,
        // moves them where turning is cheap instead
        let tau = FLOW_SHIFT / (diag * diag);
        let flow = factorize(tau, Some(turning))?;
        for _ in 0..FLOW_STEPS {
            let b: Vec<f64> = (0..2 * nf)
                .map(|i| {
                    let f = i / 2;
                    let r = (u[2 * f] * u[2 * f] + u[2 * f + 1] * u[2 * f + 1]).sqrt();
                    if r > 0.0 {
                        tau * mass[f] * u[i] / r
                    } else {
                        0.0
                    }
                })
                .collect();
            u = flow.solve(b);
            if !u.iter().all(|v| v.is_finite()) {
                return None;
            }
        }
    }
    // per component, the global angle θ that best aligns the field with the
    // prior's lines: θ maximises Σ A_f |p_f|² cos 2(θ + arg u_f − arg p_f),
    // θ = ½ arg Σ A_f (p_f conj û_f)²; then of θ and θ + π the one that points
    // along the prior rather than against it
    let unit = |x: f64, y: f64| {
        let r = (x * x + y * y).sqrt();
        if r > 0.0 {
            (x / r, y / r)
        } else {
            (0.0, 0.0)
        }
    };
    let mut lines = vec![(0f64, 0f64); components];
    for f in 0..nf {
        let (px, py) = in_frame(f, prior[f]);
        let (ux, uy) = unit(u[2 * f], u[2 * f + 1]);
        // q = p conj(û), then q²
        let (qx, qy) = (px * ux + py * uy, py * ux - px * uy);
        let l = &mut lines[component(f)];
        l.0 += mass[f] * (qx * qx - qy * qy);
        l.1 += mass[f] * 2.0 * qx * qy;
    }
    let mut align: Vec<(f64, f64)> = lines
        .iter()
        .map(|&(re, im)| {
            let t = 0.5 * math::atan2(im, re);
            (math::cos(t), math::sin(t))
        })
        .collect();
    let mut along = vec![0f64; components];
    for f in 0..nf {
        let (px, py) = in_frame(f, prior[f]);
        let (c, s) = align[component(f)];
        let (ux, uy) = unit(u[2 * f], u[2 * f + 1]);
        // Re(p conj(e^{iθ} û))
        along[component(f)] += mass[f] * (px * (c * ux - s * uy) + py * (s * ux + c * uy));
    }
    for (a, &d) in align.iter_mut().zip(&along) {
        if d < 0.0 {
            *a = (-a.0, -a.1);
        }
    }
    let field = (0..nf)
        .map(|f| {
            let (e1, e2) = frames[f];
            let (c, s) = align[component(f)];
            let (ux, uy) = (u[2 * f], u[2 * f + 1]);
            let (x, y) = (c * ux - s * uy, s * ux + c * uy);
            let v = (x * e1 + y * e2).as_vec3();
            if v.length_squared() > 1e-20 && v.is_finite() {
                unit_or(v, Vec3::ZERO).to_array()
            } else {
                unit_or(prior[f].into(), Vec3::ZERO).to_array()
            }
        })
        .collect();
    Some(field)
}

/// Gaussian RBF interpolation of the key directions (docs/design.md section
/// 5.4: "interpolated by Gaussian radial basis functions").
fn rbf_field(
    mesh: &Mesh,
    normals: &[[f32; 3]],
    keys: &[FieldKey],
    default_dir: &dyn Fn(usize) -> [f32; 3],
) -> Vec<[f32; 3]> {
    let centers: Vec<Vec3> = keys.iter().map(|k| face_center(mesh, k.face as usize)).collect();
    let dirs: Vec<Vec3> = keys
        .iter()
        .map(|k| {
            let dir = unit_or(k.dir.into(), Vec3::ZERO);
            unit_or(project(dir, normals[k.face as usize].into()), Vec3::ZERO)
        })
        .collect();
    let k = keys.len();
    let dist = |a: Vec3, b: Vec3| a.distance(b) as f64;
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
    let phi = |r: f64| math::exp(-(r / sigma) * (r / sigma));
    // solve (Φ + εI) W = D by Gaussian elimination with partial pivoting
    let mut a: Vec<Vec<f64>> = (0..k)
        .map(|i| {
            let mut row: Vec<f64> = (0..k).map(|j| phi(dist(centers[i], centers[j]))).collect();
            row[i] += 1e-6;
            row.extend(dirs[i].as_dvec3().to_array());
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
    let w: Vec<DVec3> = (0..k)
        .map(|i| {
            let p = a[i][i];
            if p.abs() < 1e-300 {
                DVec3::ZERO
            } else {
                DVec3::new(a[i][k], a[i][k + 1], a[i][k + 2]) / p
            }
        })
        .collect();
    (0..mesh.triangles.len())
        .map(|f| {
            let c = face_center(mesh, f);
            let mut v = DVec3::ZERO;
            for i in 0..k {
                let s = phi(dist(c, centers[i]));
                v += s * w[i];
            }
            let t = project(v.as_vec3(), normals[f].into());
            if t.length_squared() > 1e-12 {
                unit_or(t, Vec3::ZERO).to_array()
            } else {
                default_dir(f)
            }
        })
        .collect()
}

#[cfg(test)]
mod tests;
