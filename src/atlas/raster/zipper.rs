//! Zippers: links between border texels of different charts that
//! are neighbours on the surface, and the triangles that stitch them.

use super::*;

/// Faces within two vertex-rings of `f` (sorted).
fn two_ring(mesh: &Mesh, vertex_faces: &[Vec<u32>], f: u32) -> Vec<u32> {
    let mut ring: Vec<u32> = mesh.triangles[f as usize]
        .iter()
        .flat_map(|&v| vertex_faces[v as usize].iter().copied())
        .collect();
    ring.sort_unstable();
    ring.dedup();
    let mut two: Vec<u32> = ring
        .iter()
        .flat_map(|&g| {
            mesh.triangles[g as usize]
                .iter()
                .flat_map(|&v| vertex_faces[v as usize].iter().copied())
        })
        .collect();
    two.sort_unstable();
    two.dedup();
    two
}

/// Links each boundary texel to the nearest boundary texel across its seam:
/// of another chart (or of its own chart but far away in the atlas), within
/// [`MAX_LINK`] texel sizes in 3D, on a face within two vertex-rings. Sorted,
/// deduplicated pairs (lower texel id first).
pub(super) fn zipper_links(mesh: &Mesh, boundary: &[BoundaryTexel], texel: f64, r: usize) -> Vec<[u32; 2]> {
    let mut vertex_faces = vec![Vec::new(); mesh.positions.len()];
    for (f, t) in mesh.triangles.iter().enumerate() {
        for &v in t {
            vertex_faces[v as usize].push(f as u32);
        }
    }
    let cell = MAX_LINK * texel;
    let key = |p: [f32; 3]| -> [i64; 3] {
        [
            (p[0] as f64 / cell).floor() as i64,
            (p[1] as f64 / cell).floor() as i64,
            (p[2] as f64 / cell).floor() as i64,
        ]
    };
    let mut grid: Vec<([i64; 3], u32)> = boundary
        .iter()
        .enumerate()
        .map(|(i, b)| (key(b.position), i as u32))
        .collect();
    grid.sort_unstable();
    // the 2-rings of the boundary faces, computed once per face
    let mut faces: Vec<u32> = boundary.iter().map(|b| b.face).collect();
    faces.sort_unstable();
    faces.dedup();
    let rings: BTreeMap<u32, Vec<u32>> = faces
        .par_iter()
        .map(|&f| (f, two_ring(mesh, &vertex_faces, f)))
        .collect();
    let mut links: Vec<[u32; 2]> = boundary
        .par_iter()
        .filter_map(|a| {
            let k = key(a.position);
            let ring = &rings[&a.face];
            let (ax, ay) = ((a.texel as usize % r) as i64, (a.texel as usize / r) as i64);
            let mut best: Option<(f64, u32)> = None;
            for dz in -1..=1 {
                for dy in -1..=1 {
                    for dx in -1..=1 {
                        let c = [k[0] + dx, k[1] + dy, k[2] + dz];
                        let lo = grid.partition_point(|e| e.0 < c);
                        for e in grid[lo..].iter().take_while(|e| e.0 == c) {
                            let b = &boundary[e.1 as usize];
                            if b.texel == a.texel {
                                continue;
                            }
                            if b.chart == a.chart {
                                let (bx, by) = ((b.texel as usize % r) as i64, (b.texel as usize / r) as i64);
                                if (ax - bx).abs().max((ay - by).abs()) <= 3 {
                                    continue;
                                }
                            }
                            let d = Vec3::from(a.position) - Vec3::from(b.position);
                            let d = (d.length_squared() as f64).sqrt();
                            if d > MAX_LINK * texel || ring.binary_search(&b.face).is_err() {
                                continue;
                            }
                            if best.map_or(true, |(bd, bt)| d < bd || (d == bd && b.texel < bt)) {
                                best = Some((d, b.texel));
                            }
                        }
                    }
                }
            }
            best.map(|(_, t)| [a.texel.min(t), a.texel.max(t)])
        })
        .collect();
    links.sort_unstable();
    links.dedup();
    links
}

/// Stitches zippers into triangle strips: for two boundary texels a, a' that
/// are grid neighbours in one chart and linked to b, b' across the seam, the
/// quad (a, a', b', b) becomes two triangles (one if b = b'). Oriented to
/// agree with the texels' normals is left to the reader; here triangles are
/// sorted triples, deduplicated.
pub(super) fn zipper_triangles(links: &[[u32; 2]], boundary: &[BoundaryTexel], r: usize) -> Vec<[u32; 3]> {
    let chart_of: BTreeMap<u32, u32> = boundary.iter().map(|b| (b.texel, b.chart)).collect();
    let mut partners: BTreeMap<u32, Vec<u32>> = BTreeMap::new();
    for &[a, b] in links {
        partners.entry(a).or_default().push(b);
        partners.entry(b).or_default().push(a);
    }
    let mut tris = Vec::new();
    for (&a, pa) in &partners {
        let (ax, ay) = (a as usize % r, a as usize / r);
        for (nx, ny) in [(ax + 1, ay), (ax, ay + 1)] {
            if nx >= r || ny >= r {
                continue;
            }
            let a2 = (ny * r + nx) as u32;
            if chart_of.get(&a2) != chart_of.get(&a) {
                continue;
            }
            let Some(pa2) = partners.get(&a2) else { continue };
            for &b in pa {
                for &b2 in pa2 {
                    if b == b2 {
                        tris.push(sorted3([a, a2, b]));
                    } else if chart_of.get(&b) == chart_of.get(&b2) {
                        let (bx, by) = (b as i64 % r as i64, b as i64 / r as i64);
                        let (cx, cy) = (b2 as i64 % r as i64, b2 as i64 / r as i64);
                        if (bx - cx).abs() + (by - cy).abs() == 1 {
                            tris.push(sorted3([a, a2, b2]));
                            tris.push(sorted3([a, b2, b]));
                        }
                    }
                }
            }
        }
    }
    tris.sort_unstable();
    tris.dedup();
    tris
}

fn sorted3(mut t: [u32; 3]) -> [u32; 3] {
    t.sort_unstable();
    t
}
