//! Locked courses (`--courses locked`): the work image of a patch bent so
//! that its rows follow one stripe pattern over the whole surface
//! ([`crate::field::StripePattern`]). The work coordinate along the rows
//! (their mean direction over the patch, [`rows_angle`]) stays that of the
//! chart layout, flattening or unfolding; the coordinate across them
//! becomes the pattern's phase, unwrapped over the patch, in course
//! periods. Every patch whose sample rows are then locked to that
//! phase ([`crate::quilt::placement::lock_courses`], [`Courses::lock_rows`])
//! shows the same course at the same place: courses run on across every
//! seam and end only where the pattern ends them.
//!
//! [`Courses::lock_rows`]: crate::quilt::courses::Courses::lock_rows

use std::f64::consts::TAU;

use super::*;
use crate::math;

/// The orientation of the pattern's phase in a work image: the phase grows
/// along n = N × f (N the surface normal, f the field), which an
/// orientation-preserving chart map draws as the field direction turned by
/// −90° in the image's y-down frame: against the work image's across axis
/// (−sin θ, cos θ) of a field at angle θ.
const ACROSS: f64 = -1.0;

/// The work image of `patch` with its courses locked to the surface's
/// stripe pattern: the coordinates of [`work_coords`], their component
/// across the field (at the rows' rotation step, the copy matching
/// uses) replaced by the pattern's phase × period / 2π. `None` without a
/// lock, or if the patch flattened implausibly large.
pub(in crate::quilt) fn locked_work_image(inputs: &WorkInputs, patch: &WorkPatch) -> Option<WorkImage> {
    let WorkInputs {
        surface,
        sample,
        state,
        bfs,
        zipper_triangles,
        max_distortion,
    } = *inputs;
    let lock = surface.lock.as_ref()?;
    let (tris, _, grid_count) = patch_triangles(surface, patch, bfs, zipper_triangles);
    let (mut coords, angle) = if patch.crosses_charts {
        coords_over(surface, patch, bfs, &tris[..grid_count], max_distortion)
    } else {
        chart_coords(surface, patch)
    };
    let phase = unwrapped_phase(surface, patch, bfs);
    let per_radian = ACROSS * lock.period / TAU;
    let angle = rows_angle(&coords, &phase, per_radian, angle);
    let theta = rotation_index(angle, sample.rotations) as f64 * TAU / sample.rotations as f64;
    let (s, c) = math::sin_cos(theta);
    for (w, &ph) in coords.iter_mut().zip(&phase) {
        let along = c * w[0] + s * w[1];
        let across = ph * per_radian;
        *w = [along * c - across * s, along * s + across * c];
    }
    let mut work = raster_work_image(sample, state, patch, &tris, coords, angle, surface.r)?;
    work.course_phase = phase.iter().map(|&p| ACROSS * p).collect();
    Some(work)
}

/// How far the copy may turn from the field to follow the pattern's rows
/// ([`rows_angle`]), in radians: a patch whose rows seem to turn further
/// holds one of the pattern's ends, where its mean direction means little.
const MAX_ROWS_TURN: f64 = 0.6;

/// The direction of the pattern's rows over a patch: the work-image angle
/// θ whose across axis (−sin θ, cos θ) runs along the least-squares
/// gradient of the across coordinate (`phase` × `per_radian`) over the
/// work coordinates `coords`. The rows turn from the field where its
/// lines converge or bend; a copy matched at the rows' direction is
/// sheared less by the phase coordinate. The field's `angle` for a
/// degenerate patch, or one whose rows seem to turn more than
/// [`MAX_ROWS_TURN`] from it.
fn rows_angle(coords: &[[f64; 2]], phase: &[f64], per_radian: f64, angle: f64) -> f64 {
    let m = coords.len() as f64;
    let mean = coords.iter().zip(phase).fold([0.0; 3], |a, (w, &p)| {
        [a[0] + w[0] / m, a[1] + w[1] / m, a[2] + p * per_radian / m]
    });
    // normal equations of across ≈ g · (w − mean)
    let (mut xx, mut xy, mut yy, mut xa, mut ya) = (0.0, 0.0, 0.0, 0.0, 0.0);
    for (w, &p) in coords.iter().zip(phase) {
        let (x, y, a) = (w[0] - mean[0], w[1] - mean[1], p * per_radian - mean[2]);
        (xx, xy, yy, xa, ya) = (xx + x * x, xy + x * y, yy + y * y, xa + x * a, ya + y * a);
    }
    let det = xx * yy - xy * xy;
    if !(det > 0.0) {
        return angle;
    }
    let g = [(yy * xa - xy * ya) / det, (xx * ya - xy * xa) / det];
    let rows = math::atan2(-g[0], g[1]);
    if crate::field::wrap_angle(rows - angle).abs() < MAX_ROWS_TURN {
        rows
    } else {
        angle
    }
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

#[cfg(test)]
mod tests {
    use super::*;

    /// Work coordinates on a grid and the phase of rows whose across axis
    /// is at angle `rows` (phase in radians, `per_radian` pixels each).
    fn plane_rows(rows: f64, per_radian: f64) -> (Vec<[f64; 2]>, Vec<f64>) {
        let coords: Vec<[f64; 2]> = (0..15 * 11)
            .map(|i| [(i % 15) as f64 * 1.5, (i / 15) as f64])
            .collect();
        let across = [-math::sin(rows), math::cos(rows)];
        let phase = coords
            .iter()
            .map(|w| (across[0] * w[0] + across[1] * w[1]) / per_radian + 0.7)
            .collect();
        (coords, phase)
    }

    #[test]
    fn the_copy_turns_to_the_rows_within_its_limit() {
        for per_radian in [3.0, -3.0] {
            for (field, rows) in [(0.2, 0.45), (-1.0, -1.3), (3.0, 3.3 - TAU)] {
                let (coords, phase) = plane_rows(rows, per_radian);
                let got = rows_angle(&coords, &phase, per_radian, field);
                assert!(
                    crate::field::wrap_angle(got - rows).abs() < 1e-9,
                    "{field} {rows}: {got}"
                );
            }
            // rows turned further than the limit, or no rows to fit: the field's
            let (coords, phase) = plane_rows(0.2 + MAX_ROWS_TURN + 0.1, per_radian);
            assert_eq!(rows_angle(&coords, &phase, per_radian, 0.2), 0.2);
            let line: Vec<[f64; 2]> = (0..9).map(|i| [i as f64, 2.0 * i as f64]).collect();
            assert_eq!(rows_angle(&line, &[0.0; 9], per_radian, 0.2), 0.2);
        }
    }
}
