//! Locked courses (`--courses locked`): the work image of a patch bent so
//! that its rows follow one stripe pattern over the whole surface
//! ([`crate::field::StripePattern`]). The work coordinates along the field
//! stay those of the chart layout, flattening or unfolding; the coordinate
//! across it becomes the pattern's phase, unwrapped over the patch, in
//! course periods. Every patch whose sample rows are then locked to that
//! phase ([`crate::quilt::placement::lock_courses`], [`Courses::lock_rows`])
//! shows the same course at the same place: courses run on across every
//! seam and end only where the pattern ends them.
//!
//! [`Courses::lock_rows`]: crate::quilt::courses::Courses::lock_rows

use std::f64::consts::TAU;

use super::*;

/// The orientation of the pattern's phase in a work image: the phase grows
/// along n = N × f (N the surface normal, f the field), which an
/// orientation-preserving chart map draws as the field direction turned by
/// −90° in the image's y-down frame: against the work image's across axis
/// (−sin θ, cos θ) of a field at angle θ.
const ACROSS: f64 = -1.0;

/// The work image of `patch` with its courses locked to the surface's
/// stripe pattern: the coordinates of [`work_coords`], their component
/// across the field (at the field's rotation step, the copy matching
/// uses) replaced by the pattern's phase × period / 2π. `None` without a
/// lock, or if the patch flattened implausibly large.
pub(in crate::quilt) fn locked_work_image(
    surface: &Surface,
    sample: &Sample,
    state: &State,
    patch: &WorkPatch,
    bfs: &Bfs,
    zipper_triangles: &[[u32; 3]],
    max_distortion: f64,
) -> Option<WorkImage> {
    let lock = surface.lock.as_ref()?;
    let (tris, _, grid_count) = patch_triangles(surface, patch, bfs, zipper_triangles);
    let (mut coords, angle) = if patch.crosses_charts {
        coords_over(surface, patch, bfs, &tris[..grid_count], max_distortion)
    } else {
        chart_coords(surface, patch)
    };
    let theta = rotation_index(angle, sample.rotations) as f64 * TAU / sample.rotations as f64;
    let (s, c) = theta.sin_cos();
    let phase = unwrapped_phase(surface, patch, bfs);
    let per_radian = ACROSS * lock.period / TAU;
    for (w, &ph) in coords.iter_mut().zip(&phase) {
        let along = c * w[0] + s * w[1];
        let across = ph * per_radian;
        *w = [along * c - across * s, along * s + across * c];
    }
    let mut work = raster_work_image(sample, state, patch, &tris, coords, angle, surface.r)?;
    work.course_phase = phase.iter().map(|&p| ACROSS * p).collect();
    Some(work)
}

/// The pattern's phase per patch vertex, unwrapped along the patch's BFS
/// tree from the seed (each vertex from its first earlier neighbour). A
/// patch around one of the pattern's ends is cut along a tree edge, where
/// the phase steps by a whole course.
fn unwrapped_phase(surface: &Surface, patch: &WorkPatch, bfs: &Bfs) -> Vec<f64> {
    let m = patch.texels.len();
    let wrapped: Vec<f64> = patch.texels.iter().map(|&t| surface.course_phase(t)).collect();
    let mut phase = vec![0f64; m];
    phase[0] = wrapped[0];
    for i in 1..m {
        let mut from = None;
        surface.for_each_neighbour(patch.texels[i], |nb, _| {
            if from.is_none() {
                from = bfs.contains(nb).filter(|&j| j < i);
            }
        });
        phase[i] = match from {
            Some(j) => phase[j] + crate::field::wrap_angle(wrapped[i] - wrapped[j]),
            None => wrapped[i],
        };
    }
    phase
}
