//! A chart's map: LSCM or its ARAP relaxation, and the checks it must pass
//! (disk, no flips or folds, stretch and area distortion within their limits).

use super::*;
use crate::math;

/// LSCM of a set of faces (sorted), or for a compact atlas its ARAP
/// relaxation when LSCM is over a stretch limit (the relaxed map within
/// [`RELAXED_LINF_SHARE`] of the L∞ limit), normalised to uniform density
/// and oriented; `None` if a triangle flips, the map folds over itself (two
/// boundary edges cross) or both maps are over a limit.
pub(super) fn parameterize(ctx: &Ctx, faces: &[u32]) -> Option<Chart> {
    parameterize_relaxing(ctx, faces, ctx.compact)
}

/// [`parameterize`], relaxing a stretched conformal map (ARAP) when
/// `relax_stretched`.
pub(super) fn parameterize_relaxing(ctx: &Ctx, faces: &[u32], relax_stretched: bool) -> Option<Chart> {
    let mesh = ctx.mesh;
    let mut vertices: Vec<u32> = faces.iter().flat_map(|&f| mesh.triangles[f as usize]).collect();
    vertices.sort_unstable();
    vertices.dedup();
    let local = |v: u32| vertices.binary_search(&v).expect("vertex of the chart") as u32;
    let triangles: Vec<[u32; 3]> = faces
        .iter()
        .map(|&f| mesh.triangles[f as usize].map(local))
        .collect();
    let positions: Vec<[f32; 3]> = vertices.iter().map(|&v| mesh.positions[v as usize]).collect();
    let uv = if faces.len() == 1 {
        // local vertices are sorted by global id; triangle corners may not be
        let mut uv = vec![[0.0; 2]; 3];
        let (q, _) = local_frame(triangles[0].map(|v| to_dvec3(positions[v as usize])));
        for (k, &v) in triangles[0].iter().enumerate() {
            uv[v as usize] = q[k];
        }
        uv
    } else {
        let conformal = lscm(&positions, &triangles).ok()?;
        // no flip and no fold, or the chart is split; within the stretch
        // limits, or the ARAP relaxation of the conformal map must be
        match acceptable(
            ctx,
            faces,
            &positions,
            &triangles,
            &conformal,
            ctx.max_linf_stretch,
        ) {
            Some(Check::Within) => conformal,
            Some(Check::Stretched) if relax_stretched => {
                let relaxed = relax(&positions, &triangles, &conformal, ARAP_ITERATIONS)?;
                match acceptable(ctx, faces, &positions, &triangles, &relaxed, ctx.max_relaxed_linf) {
                    Some(Check::Within) => relaxed,
                    _ => return None,
                }
            }
            Some(Check::Stretched) | None => return None,
        }
    };
    let (l2, linf) = stretch(&positions, &triangles, &uv);
    let uv = normalize_uv(&positions, &triangles, &uv);
    Some(Chart {
        faces: faces.to_vec(),
        vertices,
        triangles,
        uv,
        l2_stretch: l2 as f32,
        linf_stretch: linf as f32,
    })
}

enum Check {
    /// No flip, no fold, within every stretch limit.
    Within,
    /// No flip and no fold, but over a stretch or area-distortion limit.
    Stretched,
}

/// Judges a map of several faces against the chart limits, with `max_linf`
/// for its L∞ stretch: `None` if a triangle flips or the map folds over
/// itself (two boundary edges cross).
fn acceptable(
    ctx: &Ctx,
    faces: &[u32],
    positions: &[[f32; 3]],
    triangles: &[[u32; 3]],
    uv: &[[f64; 2]],
    max_linf: f64,
) -> Option<Check> {
    for (&f, t) in faces.iter().zip(triangles) {
        let (a, b, c) = (uv[t[0] as usize], uv[t[1] as usize], uv[t[2] as usize]);
        let s = (b[0] - a[0]) * (c[1] - a[1]) - (c[0] - a[0]) * (b[1] - a[1]);
        if !(s > 0.0 || ctx.area[f as usize] == 0.0) {
            return None;
        }
    }
    if crate::atlas::overlap::boundary_crosses(uv, triangles) {
        return None;
    }
    let (l2, linf) = stretch(positions, triangles, uv);
    if l2.is_nan()
        || l2 > ctx.max_stretch
        || linf > max_linf
        || area_distortion_tail(positions, triangles, uv) > ctx.max_area_distortion
    {
        return Some(Check::Stretched);
    }
    Some(Check::Within)
}

/// A chart is split when more than this fraction of its area is off its
/// mean texel density by more than [`ChartConfig::max_area_distortion`].
const AREA_DISTORTION_SHARE: f64 = 0.05;

/// The chart's area distortion at the [`AREA_DISTORTION_SHARE`] tail: the
/// area-weighted (1 − share)-quantile of max(r, 1/r), r a triangle's
/// uv-to-3D area ratio over the chart's.
pub(super) fn area_distortion_tail(positions: &[[f32; 3]], triangles: &[[u32; 3]], uv: &[[f64; 2]]) -> f64 {
    crate::atlas::lscm::area_distortion_quantile(positions, triangles, uv, 1.0 - AREA_DISTORTION_SHARE)
}

/// Scales uv to the 3D area, rotates the longer side of the minimum-area
/// bounding rectangle onto u, and moves the minimum to the origin.
fn normalize_uv(positions: &[[f32; 3]], triangles: &[[u32; 3]], uv: &[[f64; 2]]) -> Vec<[f32; 2]> {
    let mut a3 = 0.0;
    let mut auv = 0.0;
    for t in triangles {
        let (_, a) = local_frame(t.map(|v| to_dvec3(positions[v as usize])));
        a3 += a;
        let (p, q, r) = (uv[t[0] as usize], uv[t[1] as usize], uv[t[2] as usize]);
        auv += 0.5 * ((q[0] - p[0]) * (r[1] - p[1]) - (r[0] - p[0]) * (q[1] - p[1])).abs();
    }
    let s = if a3 > 0.0 && auv > 0.0 {
        (a3 / auv).sqrt()
    } else {
        1.0
    };
    let n = uv.len() as f64;
    let mean = uv
        .iter()
        .fold([0.0; 2], |m, p| [m[0] + p[0] / n, m[1] + p[1] / n]);
    let (sin, cos) = math::sin_cos(orientation(uv));
    let rotated: Vec<[f64; 2]> = uv
        .iter()
        .map(|p| {
            let (x, y) = ((p[0] - mean[0]) * s, (p[1] - mean[1]) * s);
            [cos * x + sin * y, -sin * x + cos * y]
        })
        .collect();
    let lo = rotated
        .iter()
        .fold([f64::INFINITY; 2], |m, p| [m[0].min(p[0]), m[1].min(p[1])]);
    rotated
        .iter()
        .map(|p| [(p[0] - lo[0]) as f32, (p[1] - lo[1]) as f32])
        .collect()
}

/// Whether all faces lie within the normal cone around their area-weighted
/// mean normal.
pub(super) fn within_cone(ctx: &Ctx, faces: &[u32]) -> bool {
    let mut sum = DVec3::ZERO;
    for &f in faces {
        let (n, a) = (ctx.normal[f as usize], ctx.area[f as usize]);
        sum += a * n;
    }
    let mean = dunit_or(sum, DVec3::ZERO);
    faces.iter().all(|&f| {
        let n = ctx.normal[f as usize];
        n == DVec3::ZERO || n.dot(mean) >= ctx.cos_max
    })
}

/// Angle of the direction to rotate onto +u: the longer side of the
/// minimum-area bounding rectangle (one side lies on a convex-hull edge), or
/// the principal axis (PCA) when the hull is degenerate.
fn orientation(uv: &[[f64; 2]]) -> f64 {
    let mut pts: Vec<[f64; 2]> = uv.to_vec();
    pts.sort_unstable_by(|a, b| a[0].total_cmp(&b[0]).then(a[1].total_cmp(&b[1])));
    pts.dedup();
    let cross =
        |o: [f64; 2], a: [f64; 2], b: [f64; 2]| (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0]);
    // Andrew's monotone chain
    let mut hull: Vec<[f64; 2]> = Vec::with_capacity(pts.len() + 1);
    for pass in 0..2 {
        let start = hull.len();
        let iter: Box<dyn Iterator<Item = &[f64; 2]>> = if pass == 0 {
            Box::new(pts.iter())
        } else {
            Box::new(pts.iter().rev())
        };
        for &p in iter {
            while hull.len() >= start + 2 && cross(hull[hull.len() - 2], hull[hull.len() - 1], p) <= 0.0 {
                hull.pop();
            }
            hull.push(p);
        }
        hull.pop();
    }
    let mut best: Option<(f64, f64)> = None; // (area, angle)
    if hull.len() >= 3 {
        for i in 0..hull.len() {
            let (a, b) = (hull[i], hull[(i + 1) % hull.len()]);
            let d = [b[0] - a[0], b[1] - a[1]];
            let l = (d[0] * d[0] + d[1] * d[1]).sqrt();
            if l <= 0.0 {
                continue;
            }
            let (ux, uy) = (d[0] / l, d[1] / l);
            let (mut lo, mut hi) = ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]);
            for p in &hull {
                let (x, y) = (p[0] * ux + p[1] * uy, -p[0] * uy + p[1] * ux);
                lo = [lo[0].min(x), lo[1].min(y)];
                hi = [hi[0].max(x), hi[1].max(y)];
            }
            let (w, h) = (hi[0] - lo[0], hi[1] - lo[1]);
            let area = w * h;
            let mut angle = math::atan2(uy, ux);
            if h > w {
                angle += std::f64::consts::FRAC_PI_2;
            }
            if best.map_or(true, |(a, _)| area < a * (1.0 - 1e-9)) {
                best = Some((area, angle));
            }
        }
    }
    if let Some((_, angle)) = best {
        return angle;
    }
    let n = uv.len() as f64;
    let mean = uv
        .iter()
        .fold([0.0; 2], |m, p| [m[0] + p[0] / n, m[1] + p[1] / n]);
    let (mut sxx, mut sxy, mut syy) = (0.0, 0.0, 0.0);
    for p in uv {
        let (x, y) = (p[0] - mean[0], p[1] - mean[1]);
        sxx += x * x;
        sxy += x * y;
        syy += y * y;
    }
    0.5 * math::atan2(2.0 * sxy, sxx - syy)
}

pub(super) enum Outcome {
    Done(Chart),
    Split(Vec<Vec<u32>>),
}

/// Checks and parameterises one region, or says how to split it.
pub(super) fn evaluate(ctx: &Ctx, faces: &[u32]) -> Outcome {
    if faces.len() == 1 {
        return Outcome::Done(parameterize(ctx, faces).expect("a single triangle always maps"));
    }
    let patch = Patch::new(ctx, faces.to_vec());
    let parts = patch.split_components();
    if parts.len() > 1 {
        return Outcome::Split(parts);
    }
    if patch.is_disk(ctx) {
        if let Some(chart) = parameterize(ctx, faces) {
            return Outcome::Done(chart);
        }
    }
    Outcome::Split(patch.split_in_two(ctx))
}
