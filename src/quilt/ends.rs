//! Features that end at seams around a work patch: the seam edges where one
//! side's patch, continued one texel across, differs from what the other
//! side shows by more than a limit (a mortar line or a strand that stops at
//! the seam; Kwatra et al. 2003's "old patch value across a seam"), and for
//! a sample in rows those where the course is offset
//! ([`super::courses::course_offset`]): two offset brick bodies are grey
//! against grey, but the course phase sees the step. Seam
//! refinement counts them before and after a candidate cut, to choose a cut
//! that ends fewer features than the seams it replaces.

use super::courses::course_offset;
use super::fit::{jacobian_from, Fit};
use super::sample::{dist, Sample};
use super::state::{Bfs, State, Surface, WorkPatch};

/// One side of a seam edge: the patch it shows and how to continue it.
#[derive(Clone, Copy)]
struct Side {
    /// Patch id; `u32::MAX` for the candidate's new patch.
    id: u32,
    /// Sample coordinate and Jacobian (per atlas +x, +y), for the new patch.
    new: Option<([f32; 2], [f32; 4])>,
}

const NEW: u32 = u32::MAX;

/// The grid step from `t` to its neighbour `nb` in an `r`-wide atlas, or
/// `None` for a zipper link (no common step).
pub(super) fn step(t: u32, nb: u32, r: usize, zipper: bool) -> Option<(f64, f64)> {
    let r = r as u32;
    match () {
        _ if zipper => None,
        _ if nb == t + 1 => Some((1.0, 0.0)),
        _ if nb + 1 == t => Some((-1.0, 0.0)),
        _ if nb == t + r => Some((0.0, 1.0)),
        _ if nb + r == t => Some((0.0, -1.0)),
        _ => None,
    }
}

/// How far a feature ends at the seam edge between sides a and b: the larger
/// of each side continued one step across (`continued_a`, `continued_b`,
/// false outside the sample) against what the other side shows (`fb`,
/// `fa`). `fc` is scratch.
pub(super) fn gap(
    fa: &[f32],
    fb: &[f32],
    fc: &mut [f32],
    continued_a: impl FnOnce(&mut [f32]) -> bool,
    continued_b: impl FnOnce(&mut [f32]) -> bool,
) -> f64 {
    let mut ends = 0f64;
    if continued_a(fc) {
        ends = ends.max(dist(fc, fb));
    }
    if continued_b(fc) {
        ends = ends.max(dist(fc, fa));
    }
    ends
}

/// Broken continuations on the seam edges that touch `patch`'s texels:
/// with `fit`, as they would be once it is accepted (its taken texels show
/// the new patch); without, as the surface is now. `bfs` holds `patch`
/// (its local index per texel); `limit` is in feature units.
pub(super) fn broken_around(
    sample: &Sample,
    state: &State,
    surface: &Surface,
    bfs: &Bfs,
    patch: &WorkPatch,
    fit: Option<&Fit>,
    limit: f64,
) -> usize {
    let n = state.n;
    let r = state.r;
    let (mut fa, mut fb, mut fc) = (vec![0f32; n], vec![0f32; n], vec![0f32; n]);
    let taken = |t: u32| -> Option<usize> {
        let i = bfs.contains(t)?;
        fit.filter(|f| f.take[i]).map(|_| i)
    };
    // the new patch's coordinate as it would be stored
    let stored = |i: usize| {
        let c = fit.expect("a taken texel has a fit").coord[i];
        [c[0] as f32, c[1] as f32]
    };
    // the new patch's coordinate and Jacobian per taken texel, once
    let new: Vec<Option<([f32; 2], [f32; 4])>> = match fit {
        None => Vec::new(),
        Some(fit) => (0..patch.texels.len())
            .map(|i| {
                fit.take[i].then(|| {
                    let t = patch.texels[i];
                    let chart = surface.chart(t);
                    let (x, y) = (t as usize % r, t as usize / r);
                    let same = |nx: isize, ny: isize| -> Option<[f32; 2]> {
                        if nx < 0 || ny < 0 || nx >= r as isize || ny >= r as isize {
                            return None;
                        }
                        let nb = (ny as usize * r + nx as usize) as u32;
                        taken(nb).filter(|_| surface.chart(nb) == chart).map(stored)
                    };
                    let c = stored(i);
                    (c, jacobian_from(c, x, y, same).unwrap_or(fit.jacobian))
                })
            })
            .collect(),
    };
    let side = |t: u32| -> Side {
        match taken(t) {
            Some(i) => Side { id: NEW, new: new[i] },
            None => Side {
                id: state.patch(t),
                new: None,
            },
        }
    };
    let features = |t: u32, s: Side, out: &mut [f32]| match s.new {
        Some((c, _)) => {
            if !sample.lookup([c[0] as f64, c[1] as f64], out) {
                out.fill(0.0);
            }
        }
        None => state.feature_into(sample, t, out),
    };
    let continued = |t: u32, s: Side, d: (f64, f64), out: &mut [f32]| match s.new {
        Some((c, j)) => {
            let moved = [
                c[0] as f64 + j[0] as f64 * d.0 + j[2] as f64 * d.1,
                c[1] as f64 + j[1] as f64 * d.0 + j[3] as f64 * d.1,
            ];
            sample.lookup(moved, out)
        }
        None => state.continued(sample, t, d, out),
    };
    // a side's sample coordinate and Jacobian, for the course phase
    let coord_jac = |t: u32, s: Side| -> ([f32; 2], [f32; 4]) {
        match s.new {
            Some(cj) => cj,
            None => state.coord_jacobian(t),
        }
    };
    let mut edges: Vec<(u32, (f64, f64))> = Vec::with_capacity(8);
    let mut broken = 0;
    for &t in &patch.texels {
        if !(state.synthesized(t) || taken(t).is_some()) {
            continue;
        }
        edges.clear();
        surface.for_each_neighbour(t, |nb, zipper| {
            // each edge once: inside the patch from its lower texel
            if bfs.contains(nb).is_some() && nb < t {
                return;
            }
            if let Some(d) = step(t, nb, r, zipper) {
                edges.push((nb, d));
            }
        });
        if edges.is_empty() {
            continue;
        }
        let a = side(t);
        let mut shown = false;
        for &(nb, d) in &edges {
            if !(state.synthesized(nb) || taken(nb).is_some()) {
                continue;
            }
            let b = side(nb);
            if a.id == b.id {
                continue;
            }
            if !shown {
                features(t, a, &mut fa);
                shown = true;
            }
            features(nb, b, &mut fb);
            let ends = gap(
                &fa,
                &fb,
                &mut fc,
                |out| continued(t, a, d, out),
                |out| continued(nb, b, (-d.0, -d.1), out),
            );
            let offset = || {
                sample
                    .courses
                    .as_ref()
                    .is_some_and(|c| course_offset(c, coord_jac(t, a), coord_jac(nb, b), d))
            };
            if ends > limit || offset() {
                broken += 1;
            }
        }
    }
    broken
}
