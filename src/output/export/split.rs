//! A mesh split where its texture coordinates are discontinuous, with
//! per-vertex normals: what OBJ and glTF need.

use super::*;
use crate::math;

/// A mesh as glTF wants it: one uv per vertex, so mesh vertices whose corners
/// carry different atlas uvs (chart seams) are split.
#[derive(Clone, Debug, PartialEq)]
pub struct SplitMesh {
    pub positions: Vec<[f32; 3]>,
    /// Unit normals (area-weighted smooth normals of the input mesh, so both
    /// copies of a split vertex have the same one).
    pub normals: Vec<[f32; 3]>,
    /// Atlas uv, origin top left, v down (glTF's and the atlas's convention).
    pub uvs: Vec<[f32; 2]>,
    pub triangles: Vec<[u32; 3]>,
    /// The input vertex of each output vertex.
    pub source: Vec<u32>,
}

/// Splits `mesh`'s vertices wherever its corners have different uvs; output
/// vertices are numbered in order of first use (triangle by triangle, corner
/// by corner), so the result is deterministic.
pub fn split_by_uv(mesh: &Mesh, corner_uv: &[[f32; 2]]) -> std::result::Result<SplitMesh, String> {
    let (nv, nf) = (mesh.positions.len(), mesh.triangles.len());
    if nf == 0 {
        return Err("the mesh has no triangles".into());
    }
    if corner_uv.len() != 3 * nf {
        return Err(format!("{} corner uvs for {nf} triangles", corner_uv.len()));
    }
    if let Some(p) = mesh
        .positions
        .iter()
        .position(|p| p.iter().any(|c| !c.is_finite()))
    {
        return Err(format!("vertex {p} is not finite"));
    }
    if let Some(i) = corner_uv.iter().position(|p| p.iter().any(|c| !c.is_finite())) {
        return Err(format!("corner uv {i} is not finite"));
    }
    let normals = mesh.vertex_normals();
    let mut map: HashMap<(u32, u32, u32), u32> = HashMap::new();
    let mut out = SplitMesh {
        positions: Vec::new(),
        normals: Vec::new(),
        uvs: Vec::new(),
        triangles: Vec::with_capacity(nf),
        source: Vec::new(),
    };
    for (f, tri) in mesh.triangles.iter().enumerate() {
        let mut t = [0u32; 3];
        for k in 0..3 {
            let v = tri[k];
            if v as usize >= nv {
                return Err(format!("triangle {f} refers to vertex {v} of {nv}"));
            }
            // +0.0 folds -0.0 into 0.0, so equal uvs have equal bits
            let uv = [corner_uv[3 * f + k][0] + 0.0, corner_uv[3 * f + k][1] + 0.0];
            let key = (v, uv[0].to_bits(), uv[1].to_bits());
            let next = out.positions.len() as u32;
            let id = *map.entry(key).or_insert(next);
            if id == next {
                out.positions.push(mesh.positions[v as usize]);
                out.normals.push(unit_normal(mesh, &normals, v as usize, f));
                out.uvs.push(uv);
                out.source.push(v);
            }
            t[k] = id;
        }
        out.triangles.push(t);
    }
    Ok(out)
}

/// The smooth normal of vertex `v`, or the normal of face `f` (or +z) where
/// the smooth one vanishes; unit length in f32.
fn unit_normal(mesh: &Mesh, normals: &[[f32; 3]], v: usize, f: usize) -> [f32; 3] {
    let unit = |n: [f32; 3]| {
        let l = math::hypot(math::hypot(n[0] as f64, n[1] as f64), n[2] as f64);
        (l > 1e-20 && l.is_finite()).then(|| n.map(|c| (c as f64 / l) as f32))
    };
    unit(normals[v])
        .or_else(|| {
            let [a, b, c] = mesh.triangles[f].map(|i| mesh.positions[i as usize]);
            let (e1, e2) = (
                [b[0] - a[0], b[1] - a[1], b[2] - a[2]],
                [c[0] - a[0], c[1] - a[1], c[2] - a[2]],
            );
            unit([
                e1[1] * e2[2] - e1[2] * e2[1],
                e1[2] * e2[0] - e1[0] * e2[2],
                e1[0] * e2[1] - e1[1] * e2[0],
            ])
        })
        .unwrap_or([0.0, 0.0, 1.0])
}
