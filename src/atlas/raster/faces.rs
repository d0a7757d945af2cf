//! Rasterizing chart triangles into atlas tiles: which face covers each
//! texel, its barycentric position, and the chart-border texels.

use super::*;

/// Per-face data the rasterizer needs.
pub(super) struct FaceRaster<'a> {
    pub(super) mesh: &'a Mesh,
    pub(super) face_chart: Vec<u32>,
    /// Texel-space corners of each face.
    pub(super) corner_texel: Vec<[[f64; 2]; 3]>,
    pub(super) vertex_normals: Vec<[f32; 3]>,
    pub(super) field: Vec<[f32; 3]>,
    pub(super) resolution: usize,
    /// Maps the (possibly rescaled, see [`Mesh::normalize_extreme_scale`])
    /// mesh positions back to the user's units; 1.0 for ordinary meshes.
    pub(super) unscale: f64,
}

/// The best triangle found for one texel.
#[derive(Clone, Copy)]
pub(super) struct Cover {
    dist: f64,
    pub(super) face: u32,
    pub(super) bary: [f64; 3],
}

const NO_COVER: Cover = Cover {
    dist: f64::INFINITY,
    face: NO_FACE,
    bary: [0.0; 3],
};

/// One rasterized tile plus a one-texel margin.
pub(super) struct TileRaster {
    x0: usize,
    pub(super) y0: usize,
    pub(super) w: usize,
    pub(super) h: usize,
    /// (w + 2) × (h + 2) covers, margin included.
    cover: Vec<Cover>,
    /// Per texel of the tile (w × h), how many triangles hold its centre
    /// strictly inside (saturating): above one where charts overlap.
    inside: Vec<u8>,
}

impl TileRaster {
    pub(super) fn at(&self, x: isize, y: isize) -> &Cover {
        // x, y relative to the tile origin, -1..=w
        &self.cover[((y + 1) as usize) * (self.w + 2) + (x + 1) as usize]
    }
}

/// A boundary texel, for zippering.
#[derive(Clone, Copy, Debug)]
pub(super) struct BoundaryTexel {
    pub(super) texel: u32,
    pub(super) chart: u32,
    pub(super) face: u32,
    pub(super) position: [f32; 3],
}

impl FaceRaster<'_> {
    fn chart_of(&self, c: &Cover) -> u32 {
        if c.face == NO_FACE {
            EMPTY
        } else {
            self.face_chart[c.face as usize]
        }
    }

    pub(super) fn rasterize(&self, tx: usize, ty: usize, bucket: &[u32]) -> TileRaster {
        let r = self.resolution;
        let (x0, y0) = (tx * TILE, ty * TILE);
        let (w, h) = (TILE.min(r - x0), TILE.min(r - y0));
        let mut cover = vec![NO_COVER; (w + 2) * (h + 2)];
        let mut inside = vec![0u8; w * h];
        // region in absolute texels: [x0 - 1, x0 + w + 1)
        let (rx0, ry0) = (x0 as isize - 1, y0 as isize - 1);
        let (rx1, ry1) = ((x0 + w + 1) as isize, (y0 + h + 1) as isize);
        for &f in bucket {
            let p = &self.corner_texel[f as usize];
            let lo_x = p.iter().map(|c| c[0]).fold(f64::INFINITY, f64::min) - COVER_RADIUS - 0.5;
            let hi_x = p.iter().map(|c| c[0]).fold(f64::NEG_INFINITY, f64::max) + COVER_RADIUS - 0.5;
            let lo_y = p.iter().map(|c| c[1]).fold(f64::INFINITY, f64::min) - COVER_RADIUS - 0.5;
            let hi_y = p.iter().map(|c| c[1]).fold(f64::NEG_INFINITY, f64::max) + COVER_RADIUS - 0.5;
            let xa = (lo_x.ceil() as isize).max(rx0).max(0);
            let xb = (hi_x.floor() as isize + 1).min(rx1).min(r as isize);
            let ya = (lo_y.ceil() as isize).max(ry0).max(0);
            let yb = (hi_y.floor() as isize + 1).min(ry1).min(r as isize);
            for y in ya..yb {
                for x in xa..xb {
                    let q = [x as f64 + 0.5, y as f64 + 0.5];
                    let Some((dist, bary)) = closest_on_triangle(p, q) else {
                        continue;
                    };
                    if dist > COVER_RADIUS {
                        continue;
                    }
                    let core = (x as usize).wrapping_sub(x0) < w && (y as usize).wrapping_sub(y0) < h;
                    if core && bary.iter().all(|&l| l > 0.0) {
                        let n = &mut inside[(y as usize - y0) * w + x as usize - x0];
                        *n = n.saturating_add(1);
                    }
                    let slot = &mut cover[((y - ry0) as usize) * (w + 2) + (x - rx0) as usize];
                    if dist < slot.dist - 1e-12 || (dist <= slot.dist + 1e-12 && f < slot.face) {
                        *slot = Cover { dist, face: f, bary };
                    }
                }
            }
        }
        TileRaster {
            x0,
            y0,
            w,
            h,
            cover,
            inside,
        }
    }

    /// The attributes of a covered texel: position, normal, tangent.
    fn attributes(&self, c: &Cover) -> ([f32; 3], [f32; 3], [f32; 3]) {
        let t = self.mesh.triangles[c.face as usize];
        let mut pos = DVec3::ZERO;
        let mut nrm = Vec3::ZERO;
        for k in 0..3 {
            let p = Vec3::from(self.mesh.positions[t[k] as usize]);
            let n = Vec3::from(self.vertex_normals[t[k] as usize]);
            pos += c.bary[k] * p.as_dvec3();
            nrm += c.bary[k] as f32 * n;
        }
        let mut n = unit_or(nrm, Vec3::ZERO);
        if n.length_squared() < 0.5 {
            n = self.mesh.face_normal(c.face as usize).into();
        }
        let f = Vec3::from(self.field[c.face as usize]);
        let mut t = unit_or(f - f.dot(n) * n, Vec3::ZERO);
        if t.length_squared() < 0.5 {
            let other = if n.x.abs() < 0.9 { Vec3::X } else { Vec3::Y };
            t = unit_or(n.cross(other), Vec3::ZERO);
        }
        (pos.as_vec3().to_array(), n.to_array(), t.to_array())
    }
}

/// The atlas arrays of one tile, ready to encode.
pub(super) struct TileArrays {
    pub(super) chart: Vec<u32>,
    pub(super) face: Vec<u32>,
    pub(super) bary: Vec<f32>,
    pub(super) position: Vec<f32>,
    pub(super) normal: Vec<f32>,
    pub(super) tangent: Vec<f32>,
    pub(super) boundary: Vec<BoundaryTexel>,
    pub(super) covered: usize,
    /// Texels whose centre lies inside two triangles or more.
    pub(super) overlapping: usize,
}

pub(super) fn tile_arrays(fr: &FaceRaster, t: &TileRaster) -> TileArrays {
    let n = t.w * t.h;
    let mut a = TileArrays {
        chart: vec![EMPTY; n],
        face: vec![NO_FACE; n],
        bary: vec![0.0; n * 2],
        position: vec![0.0; n * 3],
        normal: vec![0.0; n * 3],
        tangent: vec![0.0; n * 3],
        boundary: Vec::new(),
        covered: 0,
        overlapping: t.inside.iter().filter(|&&n| n > 1).count(),
    };
    for y in 0..t.h {
        for x in 0..t.w {
            let c = t.at(x as isize, y as isize);
            let chart = fr.chart_of(c);
            if chart == EMPTY {
                continue;
            }
            let i = y * t.w + x;
            a.covered += 1;
            a.chart[i] = chart;
            a.face[i] = c.face;
            a.bary[i * 2] = c.bary[1] as f32;
            a.bary[i * 2 + 1] = c.bary[2] as f32;
            let (p, nrm, tan) = fr.attributes(c);
            let user = if fr.unscale == 1.0 {
                p
            } else {
                p.map(|x| (x as f64 * fr.unscale) as f32)
            };
            a.position[i * 3..i * 3 + 3].copy_from_slice(&user);
            a.normal[i * 3..i * 3 + 3].copy_from_slice(&nrm);
            a.tangent[i * 3..i * 3 + 3].copy_from_slice(&tan);
            let (xi, yi) = (x as isize, y as isize);
            let on_border = [(-1, 0), (1, 0), (0, -1), (0, 1)]
                .iter()
                .any(|&(dx, dy)| fr.chart_of(t.at(xi + dx, yi + dy)) != chart);
            if on_border {
                a.boundary.push(BoundaryTexel {
                    texel: ((t.y0 + y) * fr.resolution + t.x0 + x) as u32,
                    chart,
                    face: c.face,
                    position: p,
                });
            }
        }
    }
    a
}
