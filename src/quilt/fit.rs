//! Patch fitting (section III-B, step 5): the graphcut between the old
//! values and the new patch over P(v), with seam nodes on old seams, and
//! applying the result to the state.

use super::flatten::WorkImage;
use super::maxflow::{Graph, Segment};
use super::occurrence::Occurrence;
use super::placement::{placed_on_sample, PlacementChoice, Turn};
use super::sample::{dist, Sample};
use super::state::{State, Surface, WorkPatch};
use crate::progress::Progress;

/// The outcome of a graphcut fitting.
pub(super) struct Fit {
    /// Per patch vertex: take the new patch B? with its sample coordinate.
    pub(super) take: Vec<bool>,
    pub(super) coord: Vec<[f64; 2]>,
    /// m_P at B's coordinate per patch vertex (empty without a mask).
    pub(super) new_mask: Vec<f32>,
    pub(super) rotation: usize,
    pub(super) jacobian: [f32; 4],
    pub(super) seam_cost: f64,
    pub(super) seam_edges: usize,
    pub(super) taken: usize,
    pub(super) taken_new_synth: usize,
    /// The min-cut's cost, and what keeping every old value would cost (the
    /// old seams inside the patch).
    pub(super) flow: f64,
    pub(super) baseline: f64,
    /// Seam refinement by structure: features ending at the seams around
    /// the patch before and after this cut ([`super::ends`]).
    pub(super) ends: Option<(usize, usize)>,
}

pub(super) const INFINITE: f64 = 1e30;

/// Graphcut between the old values A and the new patch B over the work
/// patch's vertices, with seam nodes on old seams (Kwatra et al. 2003, §3).
/// With `keep_outside_target` (region painting) texels where m0 = 0 keep
/// their old values, so a stroke changes nothing outside F and its
/// transition zone; synthesized texels less than `core` hops from the seed
/// must take the new values (seam refinement). With `align` > 0 the new
/// patch is first bent by up to that share of the patch's radius to meet
/// the old texels of the overlap ([`super::align`]; `reference` is the
/// sample's mean neighbour difference).
#[allow(clippy::too_many_arguments)]
pub(super) fn fit_patch(
    sample: &Sample,
    state: &State,
    surface: &Surface,
    patch: &WorkPatch,
    work: &WorkImage,
    placement: &PlacementChoice,
    data_weight: f64,
    keep_outside_target: bool,
    core: u16,
    (align, reference): (f64, f64),
) -> Fit {
    let n = state.n;
    let r = state.r;
    let m = patch.texels.len();
    let turn = Turn::new(sample, placement.rotation);
    let (s, c) = (turn.s, turn.c);
    // B at every patch vertex: unrotated sample coordinate (locked
    // courses: every row on its course phase) and value
    let mut coord = placed_on_sample(sample, placement, &work.coords[..m], &work.course_phase);
    let mut valid = vec![false; m];
    let mut new_features = vec![0f32; m * n];
    // the old values A at the patch's synthesized vertices
    let (synthesized, old_values) = state.features_of(sample, &patch.texels);
    let max_depth = patch.depth.iter().copied().max().unwrap_or(0);
    if align > 0.0 && !keep_outside_target {
        // the largest shift scales with the patch (its BFS radius), at least a pixel
        let shift = (align * max_depth as f64).max(1.0);
        super::align::align_to_overlap(
            &mut coord,
            sample,
            work,
            &synthesized,
            &old_values,
            n,
            shift,
            reference,
        );
    }
    for (i, (v, c)) in valid.iter_mut().zip(&coord).enumerate() {
        *v = sample.lookup(*c, &mut new_features[i * n..(i + 1) * n]);
    }
    // the Jacobian (sample offset per atlas +x / +y) for in-chart patches
    let j = work.atlas_to_work.map(|a| {
        [
            c * a[0] + s * a[2],
            -s * a[0] + c * a[2],
            c * a[1] + s * a[3],
            -s * a[1] + c * a[3],
        ]
    });
    let jacobian = j
        .map(|v| v.map(|x| x as f32))
        .unwrap_or([c as f32, -s as f32, s as f32, c as f32]);

    // nodes: one per patch vertex, plus seam nodes; Source = keep A, Sink = take B
    let mut g = Graph::new(m, m * 3);
    let mut take = vec![false; m];
    let mut order: Vec<(u32, u32)> = patch
        .texels
        .iter()
        .enumerate()
        .map(|(i, &t)| (t, i as u32))
        .collect();
    order.sort_unstable();
    let find = |t: u32| {
        order
            .binary_search_by_key(&t, |e| e.0)
            .ok()
            .map(|k| order[k].1 as usize)
    };
    let mut new_mask = vec![0f32; if sample.mask.is_some() { m } else { 0 }];
    for i in 0..new_mask.len() {
        new_mask[i] = sample.mask_at(coord[i]);
    }
    for i in 0..m {
        let t = patch.texels[i];
        let (synth, old_mask, m0) = state.texel(t, |s, i| (s.synthesized[i], s.mask[i], s.target[i]));
        let m0 = state.constrained.then_some(m0);
        // the data term of constrained synthesis (§IV): D_p(σ) = |m_σ(p) −
        // m0(p)| on the t-links — keeping A costs D_p(A) (the sink edge is
        // cut), taking B costs D_p(B)
        if let (Some(m0), false, true) = (m0, new_mask.is_empty(), synth && valid[i]) {
            let d_a = (old_mask - m0).abs() as f64;
            let d_b = (new_mask[i] - m0).abs() as f64;
            g.add_tweights(i as u32, data_weight * d_b, data_weight * d_a);
        }
        let outside = keep_outside_target && m0.is_some_and(|m0| m0 <= 0.0);
        if valid[i] && synth && patch.depth[i] < core {
            // refinement: the core around the seed takes the new patch
            g.fix(i as u32, Segment::Sink);
        } else if !valid[i] || (synth && outside) {
            // B cannot reach here, or region painting keeps everything
            // outside F and its transition zone: keep A (or stay
            // unsynthesized)
            g.fix(i as u32, Segment::Source);
        } else if !synth {
            g.fix(i as u32, Segment::Sink);
        } else if patch.depth[i] == max_depth && max_depth > 0 {
            g.fix(i as u32, Segment::Source);
        }
    }
    let a_at = |i: usize| &old_values[i * n..(i + 1) * n];
    let b_at = |i: usize| &new_features[i * n..(i + 1) * n];
    let mut tmp_a = vec![0f32; n];
    let mut tmp_b = vec![0f32; n];
    let mut edges: Vec<(usize, usize, f64)> = Vec::new();
    let mut neighbours: Vec<(u32, Option<(f64, f64)>)> = Vec::with_capacity(8);
    // the cost of the old seams inside the patch: what keeping every old
    // value would cost (refinement compares the cut with it)
    let mut baseline = 0.0;
    for i in 0..m {
        let t = patch.texels[i];
        neighbours.clear();
        surface.for_each_neighbour(t, |nb, zipper| {
            if zipper {
                if nb > t {
                    neighbours.push((nb, None));
                }
            } else if nb == t + 1 {
                neighbours.push((nb, Some((1.0, 0.0))));
            } else if nb == t + r as u32 {
                neighbours.push((nb, Some((0.0, 1.0))));
            }
        });
        for &(nb, step) in &neighbours {
            let Some(k) = find(nb) else { continue };
            if !valid[i] || !valid[k] {
                continue;
            }
            let (si, sk) = (synthesized[i], synthesized[k]);
            let d_s = if si { dist(a_at(i), b_at(i)) } else { 0.0 };
            let d_t = if sk { dist(a_at(k), b_at(k)) } else { 0.0 };
            let weight = match (si, sk) {
                (true, true) => d_s + d_t,
                (true, false) => 2.0 * d_s,
                (false, true) => 2.0 * d_t,
                (false, false) => 0.0,
            };
            let old_seam = si && sk && state.patch(t) != state.patch(nb);
            match (old_seam, step) {
                (true, Some(st)) => {
                    // seam node (Kwatra et al. 2003): s–n = M(A_s, B), n–t = M(A_t, B), n–sink = M(A_s, A_t)
                    let ok_a = state.continued(sample, t, st, &mut tmp_a); // A_s at nb
                    let ok_b = state.continued(sample, nb, (-st.0, -st.1), &mut tmp_b); // A_t at t
                    if ok_a && ok_b {
                        let m_s = dist(a_at(i), b_at(i)) + dist(&tmp_a, b_at(k));
                        let m_t = dist(&tmp_b, b_at(i)) + dist(a_at(k), b_at(k));
                        let old = dist(a_at(i), &tmp_b) + dist(&tmp_a, a_at(k));
                        baseline += old;
                        let node = g.add_node();
                        g.add_edge(i as u32, node, m_s, m_s);
                        g.add_edge(node, k as u32, m_t, m_t);
                        g.add_tweights(node, 0.0, old);
                        edges.push((i, k, weight));
                        continue;
                    }
                    g.add_edge(i as u32, k as u32, weight, weight);
                    edges.push((i, k, weight));
                }
                _ => {
                    g.add_edge(i as u32, k as u32, weight, weight);
                    edges.push((i, k, weight));
                }
            }
        }
    }
    let flow = g.maxflow();
    if std::env::var_os("BTFQUILT_TRACE").is_some() && !synthesized[0] {
        eprintln!(
            "seed valid {} segment {:?} coord {:?} work {:?}",
            valid[0],
            g.segment(0),
            coord[0],
            work.coords[0]
        );
    }
    let mut taken = 0;
    let mut taken_new_synth = 0;
    for i in 0..m {
        take[i] = valid[i] && g.segment(i as u32) == Segment::Sink;
        if take[i] {
            taken += 1;
            taken_new_synth += synthesized[i] as usize;
        }
    }
    // the seam: edges whose ends took different sides, both synthesized after
    let (mut seam_cost, mut seam_edges) = (0.0, 0usize);
    for &(i, k, w) in &edges {
        let ti = synthesized[i] || take[i];
        let tk = synthesized[k] || take[k];
        if take[i] != take[k] && ti && tk {
            seam_cost += w;
            seam_edges += 1;
        }
    }
    Fit {
        take,
        coord,
        new_mask,
        rotation: placement.rotation,
        jacobian,
        seam_cost,
        seam_edges,
        taken,
        taken_new_synth,
        flow,
        baseline,
        ends: None,
    }
}

/// Records the vertices that took the new patch, and recounts the
/// frontier of the tiles it touched.
pub(super) fn apply(
    state: &mut State,
    sample: &Sample,
    surface: &Surface,
    patch: &WorkPatch,
    fit: &Fit,
    id: u32,
    mut occurrence: Option<&mut Occurrence>,
    progress: &dyn Progress,
) {
    let mut newly = 0u64;
    let grid = surface.grid();
    let mut touched: Vec<usize> = Vec::new();
    let active = state.active;
    let masked = sample.mask.is_some();
    let mut neighbours: Vec<u32> = Vec::with_capacity(8);
    for (i, &t) in patch.texels.iter().enumerate() {
        if !fit.take[i] {
            continue;
        }
        touched.push(grid.locate(t).0);
        let stored = [fit.coord[i][0] as f32, fit.coord[i][1] as f32];
        let (was, old) = state.texel_mut(t, |s, k| {
            let old = (s.synthesized[k] && s.source[k] == active).then_some(s.coord[k]);
            s.coord[k] = stored;
            s.jacobian[k] = fit.jacobian;
            s.rotation[k] = fit.rotation as u8;
            s.patch[k] = id;
            s.source[k] = active;
            if masked {
                s.mask[k] = fit.new_mask[i];
            }
            (std::mem::replace(&mut s.synthesized[k], true), old)
        });
        if let Some(occ) = occurrence.as_deref_mut() {
            if let Some(c) = old {
                occ.add([c[0] as f64, c[1] as f64], -1.0);
            }
            // the coordinate as stored, so a later replacement takes back
            // exactly this count
            occ.add([stored[0] as f64, stored[1] as f64], 1.0);
        }
        if !was {
            state.remaining -= 1;
            newly += 1;
            neighbours.clear();
            surface.for_each_neighbour(t, |nb, _| neighbours.push(nb));
            for &nb in &neighbours {
                let counted = state.texel_mut(nb, |s, k| {
                    if !s.synthesized[k] {
                        s.count[k] = s.count[k].saturating_add(1);
                    }
                    !s.synthesized[k]
                });
                if counted {
                    touched.push(grid.locate(nb).0);
                }
            }
        }
    }
    touched.sort_unstable();
    touched.dedup();
    state.refresh_frontier(surface, &touched);
    // the Jacobian per taken texel from finite differences of the sample
    // coordinates over atlas neighbours of the same patch and chart (exact
    // for flattened patches, whose map to the sample varies per chart);
    // the patch-wide estimate where a texel has no such neighbour
    for (i, &t) in patch.texels.iter().enumerate() {
        if fit.take[i] {
            let j = local_jacobian(state, surface, t, id).unwrap_or(fit.jacobian);
            state.texel_mut(t, |s, k| s.jacobian[k] = j);
        }
    }
    progress.advance(newly);
}

/// Sample offset per atlas +x and +y step at `t`, from the coordinates of
/// its grid neighbours that belong to patch `id` in the same chart.
pub(super) fn local_jacobian(state: &State, surface: &Surface, t: u32, id: u32) -> Option<[f32; 4]> {
    let r = state.r;
    let chart = surface.chart(t);
    let (x, y) = (t as usize % r, t as usize / r);
    let same = |nx: isize, ny: isize| -> Option<[f32; 2]> {
        if nx < 0 || ny < 0 || nx >= r as isize || ny >= r as isize {
            return None;
        }
        let n = ny as usize * r + nx as usize;
        let n = n as u32;
        (state.patch(n) == id && surface.chart(n) == chart).then(|| state.coord(n))
    };
    jacobian_from(state.coord(t), x, y, same)
}

/// Sample offset per atlas +x and +y step at texel (`x`, `y`) with sample
/// coordinate `c`, from `same`: the coordinate at an atlas position when
/// that texel belongs to the same patch and chart. Central differences
/// where both neighbours do, one-sided where one does.
pub(super) fn jacobian_from(
    c: [f32; 2],
    x: usize,
    y: usize,
    same: impl Fn(isize, isize) -> Option<[f32; 2]>,
) -> Option<[f32; 4]> {
    let axis = |dx: isize, dy: isize| -> Option<[f32; 2]> {
        let (x, y) = (x as isize, y as isize);
        match (same(x + dx, y + dy), same(x - dx, y - dy)) {
            (Some(a), Some(b)) => Some([(a[0] - b[0]) / 2.0, (a[1] - b[1]) / 2.0]),
            (Some(a), None) => Some([a[0] - c[0], a[1] - c[1]]),
            (None, Some(b)) => Some([c[0] - b[0], c[1] - b[1]]),
            (None, None) => None,
        }
    };
    let (ax, ay) = (axis(1, 0)?, axis(0, 1)?);
    Some([ax[0], ax[1], ay[0], ay[1]])
}
