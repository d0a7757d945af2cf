//! Work images I(v) (section III-B, step 3): a chart's own sub-image, or the
//! work patch flattened across charts (charts' LSCM layouts aligned over the
//! zipper links and their gaps closed, else the rigid field-based unfolding)
//! and resampled at one texel per pixel.

use faer::{c64, Mat};
use glam::Vec3;

use super::sample::Sample;
use super::state::{Bfs, State, Surface, WorkPatch};
use crate::math;

mod aligned;
mod locked;
mod membrane;
pub(super) use aligned::*;
pub(super) use locked::*;
pub(super) use membrane::*;

/// The work image of a patch and where each patch vertex sits in it.
pub(super) struct WorkImage {
    pub(super) width: usize,
    pub(super) height: usize,
    pub(super) features: Vec<f32>,
    pub(super) known: Vec<f32>,
    /// Work-image coordinates of each patch vertex (pixel indices, continuous).
    pub(super) coords: Vec<[f64; 2]>,
    /// Mean field direction in the work image (radians, y down).
    pub(super) angle: f64,
    /// How far the field's direction varies over the patch (radians, a
    /// circular standard deviation; 0 for a constant field): matching may
    /// turn the sample this far from `angle`.
    pub(super) field_spread: f64,
    /// The direction the sample already has in the patch's synthesized
    /// texels, in the work image (radians), when known.
    pub(super) neighbour_angle: Option<f64>,
    /// Local linear map from atlas steps (+x, +y) to work-image offsets, for
    /// in-chart work images (identity) — used for the Jacobian.
    pub(super) atlas_to_work: Option<[f64; 4]>,
    /// m0 per work pixel (empty when unconstrained).
    pub(super) constraint: Vec<f32>,
    /// Locked courses ([`locked_work_image`]): the course phase each patch
    /// vertex must show (radians, unwrapped over the patch from the
    /// seed's); empty otherwise.
    pub(super) course_phase: Vec<f64>,
}

impl WorkImage {
    /// A `width`×`height` work image with nothing known yet: `n` feature
    /// channels, and an m0 channel when the synthesis is constrained.
    fn blank(width: usize, height: usize, state: &State, coords: Vec<[f64; 2]>, angle: f64) -> WorkImage {
        WorkImage {
            width,
            height,
            features: vec![0f32; width * height * state.n],
            known: vec![0f32; width * height],
            coords,
            angle,
            field_spread: 0.0,
            neighbour_angle: None,
            atlas_to_work: None,
            constraint: vec![0f32; if state.constrained { width * height } else { 0 }],
            course_phase: Vec::new(),
        }
    }
}

fn mean_angle(angles: impl Iterator<Item = f64>) -> f64 {
    let (mut c, mut s) = (0.0, 0.0);
    for a in angles {
        c += math::cos(a);
        s += math::sin(a);
    }
    math::atan2(s, c)
}

/// In-chart work coordinates: the patch's atlas positions from the corner
/// of its atlas box, and the mean field angle.
fn chart_coords(surface: &Surface, patch: &WorkPatch) -> (Vec<[f64; 2]>, f64) {
    let r = surface.r;
    let (x0, y0, _, _) = patch.atlas_box(r);
    let coords = patch
        .texels
        .iter()
        .map(|&t| [(t as usize % r - x0) as f64, (t as usize / r - y0) as f64])
        .collect();
    let angle = mean_angle(patch.texels.iter().map(|&t| surface.texel_angle(t)));
    (coords, angle)
}

/// In-chart work image: the chart's sub-image around the patch.
pub(super) fn chart_work_image(
    surface: &Surface,
    sample: &Sample,
    state: &State,
    patch: &WorkPatch,
) -> WorkImage {
    let r = surface.r;
    let chart = surface.chart(patch.texels[0]);
    let (x0, y0, w, h) = patch.atlas_box(r);
    let n = state.n;
    let (coords, angle) = chart_coords(surface, patch);
    let mut work = WorkImage::blank(w, h, state, coords, angle);
    work.atlas_to_work = Some([1.0, 0.0, 0.0, 1.0]);
    for y in 0..h {
        for x in 0..w {
            let (t, p) = (((y0 + y) * r + x0 + x) as u32, y * w + x);
            if surface.chart(t) == chart && state.synthesized(t) {
                work.known[p] = 1.0;
                state.feature_into(sample, t, &mut work.features[p * n..(p + 1) * n]);
            }
            if let Some(m0) = state.target(t) {
                work.constraint[p] = m0;
            }
        }
    }
    work
}

/// The patch's triangles (local indices): grid blocks inside charts, then
/// zipper triangles, all wound like the surface; and how many are grid ones.
fn patch_triangles(
    surface: &Surface,
    patch: &WorkPatch,
    bfs: &Bfs,
    zipper_triangles: &[[u32; 3]],
) -> (Vec<[u32; 3]>, Vec<[f32; 3]>, usize) {
    let r = surface.r;
    let local = |t: u32| bfs.contains(t);
    // triangles: grid blocks inside charts, plus zipper triangles, all in P
    let mut tris: Vec<[u32; 3]> = Vec::new();
    for &t in &patch.texels {
        let (x, y) = (t as usize % r, t as usize / r);
        if x + 1 < r && y + 1 < r {
            for tri in crate::artifact::gim::block_triangles_by(|t| surface.chart(t), r, x, y) {
                if let (Some(a), Some(b), Some(c)) = (local(tri[0]), local(tri[1]), local(tri[2])) {
                    tris.push([a as u32, b as u32, c as u32]);
                }
            }
        }
    }
    let grid_count = tris.len();
    for z in zipper_triangles {
        if let (Some(a), Some(b), Some(c)) = (local(z[0]), local(z[1]), local(z[2])) {
            tris.push([a as u32, b as u32, c as u32]);
        }
    }
    let positions: Vec<[f32; 3]> = patch.texels.iter().map(|&t| surface.position(t)).collect();
    // wind every triangle like the surface (its 3D normal along the texels'
    // normals): zipper triangles are stored unoriented, and the distortion
    // check reads flips from the orientation
    for tri in &mut tris {
        let p = tri.map(|i| Vec3::from(positions[i as usize]));
        let n = (p[1] - p[0]).cross(p[2] - p[0]);
        let mut avg = Vec3::ZERO;
        for &i in tri.iter() {
            avg += Vec3::from(surface.normal(patch.texels[i as usize]));
        }
        if n.dot(avg) < 0.0 {
            tri.swap(1, 2);
        }
    }
    (tris, positions, grid_count)
}

/// The patch flattened across charts (the paper flattens such patches with
/// LSCM; here the charts' own LSCM layouts are aligned by
/// [`aligned_unfolding`] and their seams closed by [`close_gaps`], which
/// never fails on the thin zipper strips a global LSCM solve broke down
/// on), scaled so grid edges average one pixel, and the mean field
/// direction in that frame. `None` if a grid triangle's area changed by
/// more than T_d (or flipped) against its atlas area — the charts are
/// near-isometric, so that is the area distortion against the surface — or
/// if gaps of more than a texel remain across the zippers (a patch around a
/// cone point).
fn flatten(
    surface: &Surface,
    patch: &WorkPatch,
    bfs: &Bfs,
    grid_triangles: &[[u32; 3]],
    max_distortion: f64,
) -> Option<(Vec<[f64; 2]>, f64)> {
    let r = surface.r;
    let local = |t: u32| bfs.contains(t);
    let mut uv = aligned_unfolding(surface, patch, bfs);
    close_gaps(surface, patch, bfs, &mut uv, 300);
    let gap = zipper_gap(surface, patch, bfs, &uv);
    // grid triangles have atlas area ½; those touching a chart border are
    // left out (conservative coverage overlaps the charts there by up to a
    // texel, which closing the gaps squeezes out)
    let on_border: Vec<bool> = patch
        .texels
        .iter()
        .map(|&t| {
            let mut on = false;
            surface.for_each_neighbour(t, |_, zipper| on |= zipper);
            on
        })
        .collect();
    let border = |i: u32| on_border[i as usize];
    let area = |p: [[f64; 2]; 3]| {
        0.5 * ((p[1][0] - p[0][0]) * (p[2][1] - p[0][1]) - (p[2][0] - p[0][0]) * (p[1][1] - p[0][1]))
    };
    let atlas = |i: u32| {
        let t = patch.texels[i as usize] as usize;
        [(t % r) as f64, (t / r) as f64]
    };
    let mut ratios: Vec<f64> = grid_triangles
        .iter()
        .filter(|t| !t.iter().any(|&i| border(i)))
        .map(|t| {
            // against the triangle's atlas area (±½, signed like the atlas)
            let a = area(t.map(|i| uv[i as usize])) / area(t.map(atlas));
            if a > 0.0 {
                a.max(1.0 / a)
            } else {
                f64::INFINITY
            }
        })
        .collect();
    // T_d on the 98th percentile: a few triangles squeezed or folded where
    // a seam closes do not spoil a work image, a patch that cannot lie
    // flat does
    let distortion = if ratios.is_empty() {
        1.0
    } else {
        let k = (ratios.len() * 98 / 100).min(ratios.len() - 1);
        *ratios.select_nth_unstable_by(k, f64::total_cmp).1
    };
    if std::env::var_os("BTFQUILT_TRACE").is_some() {
        eprintln!("flattening distortion {distortion} gap {gap}");
    }
    if !(gap <= 1.0 && distortion <= max_distortion) {
        return None;
    }
    // scale so grid edges average one pixel; measure the frame's rotation
    // against the atlas on grid edges
    let (mut len, mut cnt, mut rc, mut rs) = (0.0, 0usize, 0.0, 0.0);
    for (i, &t) in patch.texels.iter().enumerate() {
        if (t as usize % r) + 1 < r && surface.chart(t + 1) == surface.chart(t) {
            if let Some(j) = local(t + 1) {
                let d = [uv[j][0] - uv[i][0], uv[j][1] - uv[i][1]];
                len += (d[0] * d[0] + d[1] * d[1]).sqrt();
                cnt += 1;
                // the atlas +x direction maps to angle atan2(d): field angle
                // in the work frame = atlas angle + this rotation
                let a = math::atan2(d[1], d[0]);
                let fa = surface.texel_angle(t) + a;
                rc += math::cos(fa);
                rs += math::sin(fa);
            }
        }
    }
    if cnt == 0 || len <= 0.0 {
        return None;
    }
    let scale = cnt as f64 / len;
    let (mut minu, mut minv) = (f64::INFINITY, f64::INFINITY);
    for p in &uv {
        minu = minu.min(p[0] * scale);
        minv = minv.min(p[1] * scale);
    }
    let coords: Vec<[f64; 2]> = uv
        .iter()
        .map(|p| [p[0] * scale - minu, p[1] * scale - minv])
        .collect();
    Some((coords, math::atan2(rs, rc)))
}

/// Shifts work-image coordinates so they start at 0; the pixel size of the
/// image that holds them.
fn shift_to_origin(coords: &mut [[f64; 2]]) -> (usize, usize) {
    let minx = coords.iter().map(|c| c[0]).fold(f64::INFINITY, f64::min);
    let miny = coords.iter().map(|c| c[1]).fold(f64::INFINITY, f64::min);
    for c in coords.iter_mut() {
        c[0] -= minx;
        c[1] -= miny;
    }
    let w = coords.iter().map(|c| c[0]).fold(0.0, f64::max).ceil() as usize + 1;
    let h = coords.iter().map(|c| c[1]).fold(0.0, f64::max).ceil() as usize + 1;
    (w, h)
}

/// [`shift_to_origin`], and the work image's size, unless the patch
/// flattened implausibly large (a side over four atlas sides).
fn shift_within_bound(coords: &mut [[f64; 2]], r: usize) -> Option<(usize, usize)> {
    let (w, h) = shift_to_origin(coords);
    (w <= 4 * r && h <= 4 * r).then_some((w, h))
}

/// The work image of a flattened patch: coordinates shifted to start at 0,
/// a pixel known where a triangle of three synthesized vertices covers it
/// (features interpolated). `None` if the patch flattened implausibly large.
fn raster_work_image(
    sample: &Sample,
    state: &State,
    patch: &WorkPatch,
    tris: &[[u32; 3]],
    mut coords: Vec<[f64; 2]>,
    angle: f64,
    r: usize,
) -> Option<WorkImage> {
    let (w, h) = shift_within_bound(&mut coords, r)?;
    let n = state.n;
    let mut work = WorkImage::blank(w, h, state, coords, angle);
    // each patch vertex's values once (a vertex is a corner of up to six
    // triangles): whether it is synthesized, its features and its m0
    let (synthesized, features) = state.features_of(sample, &patch.texels);
    let m0: Vec<f32> = if state.constrained {
        patch
            .texels
            .iter()
            .map(|&t| state.target(t).unwrap_or(0.0))
            .collect()
    } else {
        Vec::new()
    };
    for tri in tris {
        if !tri.iter().all(|&i| synthesized[i as usize]) {
            continue;
        }
        let corner_m0 = state.constrained.then(|| tri.map(|i| m0[i as usize]));
        let corner = tri.map(|i| &features[i as usize * n..(i as usize + 1) * n]);
        let p = [
            work.coords[tri[0] as usize],
            work.coords[tri[1] as usize],
            work.coords[tri[2] as usize],
        ];
        let d = (p[1][0] - p[0][0]) * (p[2][1] - p[0][1]) - (p[2][0] - p[0][0]) * (p[1][1] - p[0][1]);
        if d.abs() < 1e-12 {
            continue;
        }
        let lo = |k: usize| {
            p.iter()
                .map(|q| q[k])
                .fold(f64::INFINITY, f64::min)
                .floor()
                .max(0.0) as usize
        };
        let hi = |k: usize, m: usize| (p.iter().map(|q| q[k]).fold(0.0, f64::max).ceil() as usize).min(m - 1);
        for y in lo(1)..=hi(1, h) {
            for x in lo(0)..=hi(0, w) {
                let q = [x as f64, y as f64];
                let l1 =
                    ((q[0] - p[0][0]) * (p[2][1] - p[0][1]) - (p[2][0] - p[0][0]) * (q[1] - p[0][1])) / d;
                let l2 =
                    ((p[1][0] - p[0][0]) * (q[1] - p[0][1]) - (q[0] - p[0][0]) * (p[1][1] - p[0][1])) / d;
                let l0 = 1.0 - l1 - l2;
                if l0 < -1e-9 || l1 < -1e-9 || l2 < -1e-9 {
                    continue;
                }
                let i = y * w + x;
                work.known[i] = 1.0;
                if let Some(m0) = corner_m0 {
                    work.constraint[i] = (l0 as f32) * m0[0] + (l1 as f32) * m0[1] + (l2 as f32) * m0[2];
                }
                for c in 0..n {
                    work.features[i * n + c] =
                        (l0 as f32) * corner[0][c] + (l1 as f32) * corner[1][c] + (l2 as f32) * corner[2][c];
                }
            }
        }
    }
    Some(work)
}

/// What a work image is made from besides its patch (section III-B):
/// the surface, the sample, the synthesis so far, the patch's BFS ball,
/// the zipper triangles and the flattening's distortion bound T_d.
pub(in crate::quilt) struct WorkInputs<'a> {
    pub(in crate::quilt) surface: &'a Surface,
    pub(in crate::quilt) sample: &'a Sample,
    pub(in crate::quilt) state: &'a State,
    pub(in crate::quilt) bfs: &'a Bfs,
    pub(in crate::quilt) zipper_triangles: &'a [[u32; 3]],
    pub(in crate::quilt) max_distortion: f64,
}

/// Cross-chart work image: the patch flattened by [`flatten()`] and resampled.
/// `None` if it cannot be flattened within the distortion bound.
pub(super) fn flattened_work_image(
    inputs: &WorkInputs,
    patch: &WorkPatch,
) -> Option<(WorkImage, Vec<[f64; 2]>)> {
    let (surface, bfs) = (inputs.surface, inputs.bfs);
    let (tris, _, grid_count) = patch_triangles(surface, patch, bfs, inputs.zipper_triangles);
    let (coords, angle) = flatten(surface, patch, bfs, &tris[..grid_count], inputs.max_distortion)?;
    let work = raster_work_image(
        inputs.sample,
        inputs.state,
        patch,
        &tris,
        coords.clone(),
        angle,
        surface.r,
    )?;
    Some((work, coords))
}

/// The work coordinates (per patch vertex) and field angle the work image
/// of a patch has, without the image: the same choice between the chart's
/// own layout, the flattening and the rigid unfolding, for readers of the
/// coordinates alone (the verbatim preview).
pub(super) fn work_coords(
    surface: &Surface,
    patch: &WorkPatch,
    bfs: &Bfs,
    zipper_triangles: &[[u32; 3]],
    max_distortion: f64,
) -> (Vec<[f64; 2]>, f64) {
    if !patch.crosses_charts {
        return chart_coords(surface, patch);
    }
    let (tris, _, grid_count) = patch_triangles(surface, patch, bfs, zipper_triangles);
    coords_over(surface, patch, bfs, &tris[..grid_count], max_distortion)
}

/// [`work_coords`] of a patch across charts, given its grid triangles.
fn coords_over(
    surface: &Surface,
    patch: &WorkPatch,
    bfs: &Bfs,
    grid_tris: &[[u32; 3]],
    max_distortion: f64,
) -> (Vec<[f64; 2]>, f64) {
    if let Some((mut coords, angle)) = flatten(surface, patch, bfs, grid_tris, max_distortion) {
        if shift_within_bound(&mut coords, surface.r).is_some() {
            return (coords, angle);
        }
    }
    let (mut coords, angle) = unfold(surface, patch, bfs);
    shift_to_origin(&mut coords);
    (coords, angle)
}

/// A seed's flattening, reused when its patch shrinks: a smaller BFS
/// ball from the same seed is part of the larger one.
pub(super) struct Flattening {
    /// (texel, coordinate), sorted by texel.
    pub(super) coords: Vec<(u32, [f64; 2])>,
    pub(super) angle: f64,
}

impl Flattening {
    /// The work image of a smaller patch from the cached coordinates.
    pub(super) fn work_image(&self, inputs: &WorkInputs, patch: &WorkPatch) -> Option<WorkImage> {
        let (surface, bfs) = (inputs.surface, inputs.bfs);
        let coords: Vec<[f64; 2]> = patch
            .texels
            .iter()
            .map(|t| {
                self.coords
                    .binary_search_by_key(t, |e| e.0)
                    .ok()
                    .map(|k| self.coords[k].1)
            })
            .collect::<Option<_>>()?;
        let (tris, _, _) = patch_triangles(surface, patch, bfs, inputs.zipper_triangles);
        raster_work_image(
            inputs.sample,
            inputs.state,
            patch,
            &tris,
            coords,
            self.angle,
            surface.r,
        )
    }
}

/// Cross-chart work image without flattening: each chart's part of the patch keeps
/// its atlas layout (no resampling inside a chart) and is turned rigidly so
/// that the vector field agrees across the zipper it was entered through.
/// Used when the patch's triangulation cannot be flattened within T_d.
pub(super) fn unfolded_work_image(
    surface: &Surface,
    sample: &Sample,
    state: &State,
    patch: &WorkPatch,
    bfs: &Bfs,
) -> WorkImage {
    let (mut coords, angle) = unfold(surface, patch, bfs);
    let (w, h) = shift_to_origin(&mut coords);
    let n = state.n;
    let mut work = WorkImage::blank(w, h, state, coords, angle);
    for (i, &t) in patch.texels.iter().enumerate() {
        if state.synthesized(t) {
            let c = work.coords[i];
            let (x, y) = (c[0].round() as usize, c[1].round() as usize);
            let p = (y.min(h - 1)) * w + x.min(w - 1);
            if work.known[p] == 0.0 {
                work.known[p] = 1.0;
                state.feature_into(sample, t, &mut work.features[p * n..(p + 1) * n]);
                if let Some(m0) = state.target(t) {
                    work.constraint[p] = m0;
                }
            }
        }
    }
    work
}

/// The rigid unfolding of a patch: each chart's part keeps its atlas layout,
/// turned so the vector field agrees across the zipper it was entered
/// through. Work coordinates per patch vertex and the mean field angle.
fn unfold(surface: &Surface, patch: &WorkPatch, bfs: &Bfs) -> (Vec<[f64; 2]>, f64) {
    let r = surface.r;
    let m = patch.texels.len();
    let atlas = |t: u32| [(t as usize % r) as f64, (t as usize / r) as f64];
    // per chart: (rotation φ, work origin, atlas origin, sin φ, cos φ)
    let mut frames: std::collections::BTreeMap<u32, (f64, [f64; 2], [f64; 2], f64, f64)> = Default::default();
    let v = patch.texels[0];
    let charts: Vec<u32> = patch.texels.iter().map(|&t| surface.chart(t)).collect();
    let framed = |phi: f64, wo: [f64; 2], ao: [f64; 2]| {
        let (s, co) = math::sin_cos(phi);
        (phi, wo, ao, s, co)
    };
    frames.insert(charts[0], framed(0.0, [0.0, 0.0], atlas(v)));
    let mut coords = vec![[0f64; 2]; m];
    for i in 0..m {
        let t = patch.texels[i];
        let c = charts[i];
        if !frames.contains_key(&c) {
            // entered through a zipper from an earlier texel of a known chart
            let mut entry = None;
            surface.for_each_neighbour(t, |nb, zipper| {
                if entry.is_none() && zipper {
                    if let Some(k) = bfs.contains(nb) {
                        if k < i && frames.contains_key(&charts[k]) {
                            entry = Some((nb, k));
                        }
                    }
                }
            });
            let (phi, origin) = match entry {
                Some((p, k)) => {
                    let pf = frames[&charts[k]].0;
                    (pf + surface.texel_angle(p) - surface.texel_angle(t), coords[k])
                }
                None => (0.0, [0.0, 0.0]),
            };
            frames.insert(c, framed(phi, origin, atlas(t)));
        }
        let (_, wo, ao, s, co) = frames[&c];
        let a = atlas(t);
        let d = [a[0] - ao[0], a[1] - ao[1]];
        coords[i] = [wo[0] + co * d[0] - s * d[1], wo[1] + s * d[0] + co * d[1]];
    }
    let angle = mean_angle(
        patch
            .texels
            .iter()
            .zip(&charts)
            .map(|(&t, c)| surface.texel_angle(t) + frames[c].0),
    );
    (coords, angle)
}

/// Rotation index (5° steps for 72 copies) closest to an angle.
pub(super) fn rotation_index(angle: f64, rotations: usize) -> usize {
    let step = std::f64::consts::TAU / rotations as f64;
    ((angle.rem_euclid(std::f64::consts::TAU) / step).round() as usize) % rotations
}

#[cfg(test)]
mod tests;
