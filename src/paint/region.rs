//! Where paint goes: regions from masks, strokes or a point, and the
//! constraint function over them (§IV: a weight per texel, falling off over
//! the transition zone).

use super::*;

/// The foreground's centroid (sample pixels) and its largest distance from
/// it.
pub(super) fn foreground_extent(syn: &Synthesis) -> ([f64; 2], f64) {
    let (w, mask) = syn.sample_mask();
    let (mut sx, mut sy, mut n) = (0.0, 0.0, 0usize);
    for (i, &m) in mask.iter().enumerate() {
        if m >= 0.5 {
            sx += (i % w) as f64;
            sy += (i / w) as f64;
            n += 1;
        }
    }
    let c = [sx / n.max(1) as f64, sy / n.max(1) as f64];
    let extent = mask
        .iter()
        .enumerate()
        .filter(|(_, &m)| m >= 0.5)
        .map(|(i, _)| (((i % w) as f64 - c[0]).powi(2) + ((i / w) as f64 - c[1]).powi(2)).sqrt())
        .fold(0.0, f64::max);
    (c, extent)
}

/// The dense vertex nearest to a 3D point (lowest id among equals),
/// computed in f64 so that far points compare correctly. Refuses, with the
/// reason, a point that is not finite or that lies farther from the surface
/// than the surface's own size (its bounding-box diagonal): such a point was
/// meant for another mesh or other units, and its "nearest vertex" would be
/// an arbitrary one.
fn nearest_vertex(syn: &Synthesis, p: [f64; 3]) -> std::result::Result<u32, String> {
    let show = |p: [f64; 3]| format!("({}, {}, {})", short(p[0]), short(p[1]), short(p[2]));
    if !p.iter().all(|c| c.is_finite()) {
        return Err(format!("point {} is not a finite position", show(p)));
    }
    let r = syn.resolution();
    let mut best: Option<(f64, u32)> = None;
    let mut lo = [f64::INFINITY; 3];
    let mut hi = [f64::NEG_INFINITY; 3];
    for t in 0..(r * r) as u32 {
        if syn.chart(t) == EMPTY {
            continue;
        }
        let q = syn.position(t).map(|c| c as f64);
        if !q.iter().all(|c| c.is_finite()) {
            continue;
        }
        for k in 0..3 {
            lo[k] = lo[k].min(q[k]);
            hi[k] = hi[k].max(q[k]);
        }
        let d = (0..3).map(|k| (q[k] - p[k]).powi(2)).sum::<f64>();
        if best.map_or(true, |(b, _)| d < b) {
            best = Some((d, t));
        }
    }
    let Some((d2, t)) = best else {
        return Err("the surface has no dense vertex to place it on".into());
    };
    let diag = (0..3).map(|k| (hi[k] - lo[k]).powi(2)).sum::<f64>().sqrt();
    let d = d2.sqrt();
    if !d.is_finite() || d > diag {
        return Err(format!(
            "point {} is {} from the surface, farther than the surface's size \
             (bounding-box diagonal {}): give a point on or near the mesh, in its units",
            show(p),
            short(d),
            short(diag)
        ));
    }
    Ok(t)
}

/// A number for a message: 4 decimals in ordinary ranges, else scientific.
fn short(x: f64) -> String {
    if x != 0.0 && x.is_finite() && !(1e-3..1e6).contains(&x.abs()) {
        format!("{x:.3e}")
    } else {
        format!("{}", (x * 1e4).round() / 1e4)
    }
}

/// Checks a verbatim copy's numbers: a finite point and a finite angle.
pub(super) fn check_verbatim(v: &Verbatim) -> Result<()> {
    if !v.at.iter().all(|c| c.is_finite()) {
        return Err(Error::Config(format!(
            "--at {},{},{}: each coordinate must be a finite number",
            v.at[0], v.at[1], v.at[2]
        )));
    }
    if !v.angle.is_finite() {
        return Err(Error::Config(format!(
            "--angle {}: must be a finite number of degrees",
            v.angle
        )));
    }
    Ok(())
}

/// The dense vertex for a verbatim copy at `v.at`.
pub(super) fn verbatim_vertex(syn: &Synthesis, v: &Verbatim) -> Result<u32> {
    check_verbatim(v)?;
    nearest_vertex(syn, v.at.map(|c| c as f64)).map_err(|why| Error::Config(format!("--at: {why}")))
}

/// Checks stroke `k` of the strokes file `path` after parsing: a finite
/// point and a finite radius > 0; the error names the file and the stroke.
fn check_stroke(path: &Path, k: usize, point: [f64; 3], radius: f64) -> Result<()> {
    if !point.iter().all(|c| c.is_finite()) {
        return Err(Error::input(
            path,
            format!(
                "stroke {k}: \"point\" [{}, {}, {}] is not a finite position",
                point[0], point[1], point[2]
            ),
        ));
    }
    if !(radius.is_finite() && radius > 0.0) {
        return Err(Error::input(
            path,
            format!("stroke {k}: \"radius\" {radius} must be a finite number > 0"),
        ));
    }
    Ok(())
}

/// The region F (its texels, ascending), from a mask PNG, a mesh with
/// vertex paint, or JSON strokes (by extension).
pub(super) fn read_region(syn: &Synthesis, gim: &Gim, path: &Path) -> Result<Vec<u32>> {
    let ext = path
        .extension()
        .map(|e| e.to_string_lossy().to_ascii_lowercase())
        .unwrap_or_default();
    let r = syn.resolution();
    match ext.as_str() {
        _ if crate::io::imageio::is_image_path(path) => {
            let mut marked =
                crate::io::imageio::read_mask_marked(path, r, r, "a region mask must be the atlas size")?;
            marked.retain(|&t| syn.chart(t) != EMPTY);
            Ok(marked)
        }
        "ply" | "obj" => vertex_paint_region(gim, path),
        "json" => strokes_region(syn, path),
        _ => Err(Error::input(
            path,
            "is not a region: give a mask .png, a .ply/.obj with vertex paint, or .json strokes",
        )),
    }
}

/// F from per-vertex paint on the input mesh: a vertex is in F when its
/// weight (PLY `quality`/`weight`/`value`) is ≥ ½, or, for vertex colours,
/// when its colour differs from the mesh's dominant (unpainted) colour by
/// ≥ ½ in some channel. Per texel the corner weights are interpolated with
/// the texel's barycentrics on its face. The atlas is read in bands of
/// rows.
fn vertex_paint_region(gim: &Gim, path: &Path) -> Result<Vec<u32>> {
    let (painted, _) = crate::mesh::io::load(path, &crate::mesh::io::LoadOptions::default())?;
    let weights: Vec<f32> = if let Some(w) = &painted.vertex_weights {
        w.clone()
    } else if let Some(c) = &painted.vertex_colors {
        let q = |c: &[f32; 3]| c.map(|v| (v * 15.0).round() as u8);
        let mut counts: std::collections::BTreeMap<[u8; 3], usize> = Default::default();
        for col in c {
            *counts.entry(q(col)).or_default() += 1;
        }
        let dominant = counts
            .iter()
            .max_by_key(|(k, n)| (**n, std::cmp::Reverse(**k)))
            .map(|(k, _)| k.map(|v| v as f32 / 15.0))
            .unwrap_or([0.0; 3]);
        c.iter()
            .map(|col| (0..3).map(|k| (col[k] - dominant[k]).abs()).fold(0f32, f32::max))
            .collect()
    } else {
        return Err(Error::input(
            path,
            "has no vertex paint (no quality/weight property and no vertex colours)",
        ));
    };
    let mesh = gim.mesh()?;
    // each mesh vertex's weight: the painted vertex at the same position
    // (both went through the same repair), else the nearest one
    let key = |p: [f32; 3]| p.map(|c| c.to_bits());
    let mut by_pos: std::collections::HashMap<[u32; 3], usize> = Default::default();
    for (i, &p) in painted.positions.iter().enumerate() {
        by_pos.entry(key(p)).or_insert(i);
    }
    let vertex_weight: Vec<f32> = mesh
        .positions
        .iter()
        .map(|&p| {
            let i = by_pos.get(&key(p)).copied().unwrap_or_else(|| {
                let d = |q: [f32; 3]| (0..3).map(|k| (q[k] - p[k]).powi(2)).sum::<f32>();
                (0..painted.positions.len())
                    .min_by(|&a, &b| d(painted.positions[a]).total_cmp(&d(painted.positions[b])))
                    .unwrap_or(0)
            });
            weights.get(i).copied().unwrap_or(0.0)
        })
        .collect();
    if !vertex_weight.iter().any(|&w| w >= 0.5) {
        return Err(Error::input(path, "paints no vertex (no weight ≥ ½)"));
    }
    let r = gim.resolution;
    let c = gim.container();
    let mut region = Vec::new();
    for y0 in (0..r).step_by(crate::artifact::gim::TILE) {
        let h = crate::artifact::gim::TILE.min(r - y0);
        let (chart, face) = gim.chart_face_region(0, y0, r, h)?;
        let bary: Vec<f32> = c.read_region(c.array("bary")?, &[y0 as u64, 0, 0], &[h as u64, r as u64, 2])?;
        for i in 0..chart.len() {
            if chart[i] == EMPTY {
                continue;
            }
            let tri = mesh.triangles[face[i] as usize];
            let (b1, b2) = (bary[i * 2], bary[i * 2 + 1]);
            let w = (1.0 - b1 - b2) * vertex_weight[tri[0] as usize]
                + b1 * vertex_weight[tri[1] as usize]
                + b2 * vertex_weight[tri[2] as usize];
            if w >= 0.5 {
                region.push((y0 * r + i) as u32);
            }
        }
    }
    Ok(region)
}

/// One stroke of a strokes file.
#[derive(serde::Deserialize)]
struct StrokeSpec {
    point: [f64; 3],
    radius: f64,
}

/// F from JSON strokes `[{"point": [x, y, z], "radius": r}, …]`: the union
/// of geodesic disks on the dense mesh (Dijkstra over its edges with their
/// 3D lengths, from the vertex nearest each point).
fn strokes_region(syn: &Synthesis, path: &Path) -> Result<Vec<u32>> {
    let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
    let bad = |why: &str| Error::input(path, format!("is not a stroke list ({why})"));
    let strokes: Vec<StrokeSpec> = serde_json::from_slice(&bytes)
        .map_err(|e| bad(&format!("[{{\"point\": [x, y, z], \"radius\": r}}, …]: {e}")))?;
    if strokes.is_empty() {
        return Err(bad("the list is empty"));
    }
    let r = syn.resolution();
    let mut region = std::collections::BTreeSet::new();
    // geodesic distance of the texels the current disk reached
    let mut dist: std::collections::HashMap<u32, f32> = Default::default();
    for (k, s) in strokes.iter().enumerate() {
        let (point, radius) = (s.point, s.radius);
        if !(radius > 0.0 && radius.is_finite()) {
            return Err(bad(&format!("stroke {k} has no positive \"radius\"")));
        }
        check_stroke(path, k, point, radius)?;
        let source =
            nearest_vertex(syn, point).map_err(|why| Error::input(path, format!("stroke {k}: {why}")))?;
        // Dijkstra bounded by the radius
        dist.clear();
        dist.insert(source, 0.0);
        let mut heap = BinaryHeap::new();
        heap.push((std::cmp::Reverse(OrdF32(0.0)), source));
        while let Some((std::cmp::Reverse(OrdF32(d)), t)) = heap.pop() {
            if d > dist[&t] {
                continue;
            }
            region.insert(t);
            let p = syn.position(t);
            let mut relax = |nb: u32| {
                let q = syn.position(nb);
                let nd = d + ((p[0] - q[0]).powi(2) + (p[1] - q[1]).powi(2) + (p[2] - q[2]).powi(2)).sqrt();
                let old = dist.entry(nb).or_insert(f32::INFINITY);
                if nd <= radius as f32 && nd < *old {
                    *old = nd;
                    heap.push((std::cmp::Reverse(OrdF32(nd)), nb));
                }
            };
            syn.for_each_neighbour(t, |nb, _| relax(nb));
            // diagonal grid neighbours too, so the disk is round (8-neighbour
            // paths are within 8 % of the geodesic distance)
            let (x, y) = ((t as usize % r) as isize, (t as usize / r) as isize);
            for (dx, dy) in [(-1, -1), (1, -1), (-1, 1), (1, 1)] {
                let (nx, ny) = (x + dx, y + dy);
                if nx >= 0 && ny >= 0 && (nx as usize) < r && (ny as usize) < r {
                    let nb = ny as usize * r + nx as usize;
                    if syn.chart(nb as u32) == syn.chart(t) {
                        relax(nb as u32);
                    }
                }
            }
        }
    }
    Ok(region.into_iter().collect())
}

/// A totally ordered f32 for the Dijkstra heap.
#[derive(Clone, Copy, PartialEq)]
struct OrdF32(f32);

impl Eq for OrdF32 {}

impl PartialOrd for OrdF32 {
    fn partial_cmp(&self, other: &Self) -> Option<std::cmp::Ordering> {
        Some(self.cmp(other))
    }
}

impl Ord for OrdF32 {
    fn cmp(&self, other: &Self) -> std::cmp::Ordering {
        self.0.total_cmp(&other.0)
    }
}

/// The constraint function m0 (§IV): 1 on F (`region`, its texels), falling
/// linearly to 0 over `transition` texels of hop distance outside F on the
/// dense mesh. Returns the zone where m0 > 0, `(texel, m0)` by texel.
pub(super) fn constraint_function(syn: &Synthesis, region: &[u32], transition: usize) -> Vec<(u32, f32)> {
    let mut hops: std::collections::HashMap<u32, u32> = region.iter().map(|&t| (t, 0)).collect();
    let mut queue: VecDeque<u32> = region.iter().copied().collect();
    while let Some(t) = queue.pop_front() {
        let d = hops[&t];
        if d as usize >= transition {
            continue;
        }
        syn.for_each_neighbour(t, |nb, _| {
            if let std::collections::hash_map::Entry::Vacant(e) = hops.entry(nb) {
                e.insert(d + 1);
                queue.push_back(nb);
            }
        });
    }
    let mut zone: Vec<(u32, f32)> = hops
        .into_iter()
        .map(|(t, d)| (t, (1.0 - d as f32 / (transition as f32 + 1.0)).max(0.0)))
        .filter(|&(_, m)| m > 0.0)
        .collect();
    zone.sort_unstable_by_key(|e| e.0);
    zone
}
