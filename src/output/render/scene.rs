//! The scene: the mesh, its texel lookups and shading, and rendering
//! one frame into a G-buffer and an image.

use super::*;
use crate::math;

/// A decorated mesh loaded for rendering: mesh, atlas uv, normals and the
/// samples' shading data. Open once, render many frames.
pub struct Scene {
    pub(crate) mesh: Mesh,
    pub(crate) corner_uv: Vec<[f32; 2]>,
    pub(crate) normals: Vec<[f32; 3]>,
    pub(crate) resolution: usize,
    centre: [f32; 3],
    pub(crate) shading: Shading,
    /// The power of two the mesh's positions are multiplied by (1 but for a
    /// mesh of extreme size, which f32 shading would overflow or underflow);
    /// cameras and point lights given in the user's units are scaled alike.
    pub(crate) unit: f32,
}

/// Per corner: the atlas→3D derivatives ∂P/∂X, ∂P/∂Y averaged over the
/// faces around the corner's vertex that share its atlas uv (the same
/// chart), so that, interpolated over a face, the sample frame turns
/// smoothly across the face edges inside a chart instead of stepping at
/// every edge. `None` where every such face is degenerate.
fn corner_maps(mesh: &Mesh, corner_uv: &[[f32; 2]], r: f32) -> Vec<Option<[[f32; 3]; 2]>> {
    let faces = face_maps(mesh, corner_uv, r);
    // wedge key: vertex and uv bits; sums accumulated in face order
    let mut wedges: std::collections::HashMap<(u32, u32, u32), ([Vec3; 2], u32)> =
        std::collections::HashMap::new();
    let key = |c: usize, v: u32| (v, corner_uv[c][0].to_bits(), corner_uv[c][1].to_bits());
    for (f, tri) in mesh.triangles.iter().enumerate() {
        let Some(m) = faces[f] else { continue };
        for (k, &v) in tri.iter().enumerate() {
            let e = wedges.entry(key(f * 3 + k, v)).or_insert(([Vec3::ZERO; 2], 0));
            for (a, b) in e.0.iter_mut().zip(m) {
                *a += Vec3::from(b);
            }
            e.1 += 1;
        }
    }
    let mut out = Vec::with_capacity(mesh.triangles.len() * 3);
    for (f, tri) in mesh.triangles.iter().enumerate() {
        for (k, &v) in tri.iter().enumerate() {
            out.push(
                wedges
                    .get(&key(f * 3 + k, v))
                    .map(|(sum, n)| sum.map(|a| (a / *n as f32).to_array()))
                    .or(faces[f]),
            );
        }
    }
    out
}

/// Per face: the atlas→3D derivatives ∂P/∂X, ∂P/∂Y in 3D units per atlas
/// texel, from the corners' positions and atlas uv (constant on a face).
fn face_maps(mesh: &Mesh, corner_uv: &[[f32; 2]], r: f32) -> Vec<Option<[[f32; 3]; 2]>> {
    (0..mesh.triangles.len())
        .map(|f| {
            let [p0, p1, p2] = mesh.corners(f).map(Vec3::from);
            let (e1, e2) = (p1 - p0, p2 - p0);
            let (u0, u1, u2) = (corner_uv[f * 3], corner_uv[f * 3 + 1], corner_uv[f * 3 + 2]);
            let a = [(u1[0] - u0[0]) * r, (u1[1] - u0[1]) * r];
            let b = [(u2[0] - u0[0]) * r, (u2[1] - u0[1]) * r];
            let det = a[0] * b[1] - a[1] * b[0];
            if !(det.abs() > 1e-12) {
                return None;
            }
            // [e1 e2] = [dX dY] [a b]  ⇒  [dX dY] = [e1 e2] [a b]⁻¹
            let (i00, i01, i10, i11) = (b[1] / det, -b[0] / det, -a[1] / det, a[0] / det);
            let (dx, dy) = (e1 * i00 + e2 * i10, e1 * i01 + e2 * i11);
            Some([dx.to_array(), dy.to_array()])
        })
        .collect()
}

impl Scene {
    /// Opens the quilt, its geometry image and its samples.
    pub fn open(quilt_path: &Path, budget: MemoryBudget) -> Result<Scene> {
        // a quarter each for the quilt's and the geometry image's decoded
        // chunks, half for the shading tiles
        let [quilt_budget, gim_budget, tile_budget] =
            budget.less(crate::output::PROGRAM_BYTES).split([1, 1, 2]);
        let quilt = Quilt::open(quilt_path, quilt_budget)?;
        let gim = quilt.open_gim(None, gim_budget)?;
        if gim.resolution != quilt.resolution {
            return Err(Error::input(
                quilt_path,
                format!(
                    "its atlas is {}² but its geometry image {} is {}²",
                    quilt.resolution,
                    quilt.gim.display(),
                    gim.resolution
                ),
            ));
        }
        for (k, path) in quilt.samples.iter().enumerate() {
            if !path.exists() {
                let which = if k == 0 {
                    String::new()
                } else {
                    format!(" (painted in, 'sample_{k}')")
                };
                return Err(Error::input(
                    quilt_path,
                    format!("its sample {}{which} is gone", path.display()),
                ));
            }
        }
        let opened = open_samples(&quilt, None, [gim_budget, budget])?;
        let svd0 = &opened[0].svd;
        let mut mesh = gim.mesh()?;
        let unit = (1.0 / mesh.normalize_extreme_scale()) as f32;
        let corner_uv = gim.corner_uv()?;
        if corner_uv.len() != mesh.triangles.len() * 3
            || mesh
                .triangles
                .iter()
                .flatten()
                .any(|&v| v as usize >= mesh.positions.len())
        {
            return Err(Error::input(&quilt.gim, "mesh and corner uv disagree"));
        }
        let normals = mesh.vertex_normals();
        let r = quilt.resolution;
        // open_samples checked that every sample has sample 0's directions
        let pairs = svd0.views.len() * svd0.lights.len();
        let quilt = std::sync::Arc::new(quilt);
        let shading = if pairs <= 1 {
            let previews = opened
                .iter()
                .map(|s| s.svd.preview())
                .collect::<Result<Vec<_>>>()?;
            // what dilation leaves empty gets the whole atlas's mean: a first pass
            let mut mean = CoveredMean::default();
            for y0 in (0..r).step_by(BAND_ROWS) {
                let (colour, covered) = colour_rows(&quilt, &previews, y0, (y0 + BAND_ROWS).min(r))?;
                mean.add(&colour, &covered);
            }
            let tiles = colour_tiles(
                quilt.clone(),
                previews,
                TEXTURE_DILATION,
                mean.colour(),
                tile_budget,
            );
            tiles.probe()?;
            Shading::Colour(tiles)
        } else {
            let steps = opened.iter().map(|s| s.svd.rotations).collect();
            let tiles = btf_tiles(quilt.clone(), steps, tile_budget);
            tiles.probe()?;
            let mut samples = Vec::with_capacity(opened.len());
            let mut offset = 0;
            for s in &opened {
                let svd = &s.svd;
                let (geometry, appearance) = (svd.geometry_maps()?, svd.appearance()?);
                let n = svd.terms;
                if geometry.len() != svd.width * svd.height * n
                    || appearance.len() != pairs * 3 * n
                    || geometry.is_empty()
                {
                    return Err(Error::input(
                        svd.container().path(),
                        "geometry maps and appearance disagree",
                    ));
                }
                samples.push(Basis {
                    width: svd.width,
                    height: svd.height,
                    terms: n,
                    offset,
                    geometry,
                    appearance,
                });
                offset += n;
            }
            Shading::Btf(Box::new(BtfShading {
                samples,
                total_terms: offset,
                views: Directions::new(&svd0.views),
                lights: Directions::new(&svd0.lights),
                n_lights: svd0.lights.len(),
                tiles,
                corner_maps: corner_maps(&mesh, &corner_uv, r as f32),
            }))
        };
        let (centre, _) = bounds(&mesh.positions);
        Ok(Scene {
            mesh,
            corner_uv,
            normals,
            resolution: r,
            centre,
            shading,
            unit,
        })
    }

    /// True if the samples are BTFs (more than one direction pair).
    pub fn is_btf(&self) -> bool {
        matches!(self.shading, Shading::Btf(_))
    }

    /// The default camera: a three-quarter view framing the mesh (in the
    /// mesh's units).
    pub fn default_camera(&self) -> Camera {
        let c = Camera::framing(&self.mesh.positions);
        if self.unit == 1.0 {
            return c;
        }
        Camera {
            eye: c.eye.map(|v| v / self.unit),
            target: c.target.map(|v| v / self.unit),
            ..c
        }
    }

    /// A camera in the mesh's units as the scene's positions see it.
    fn in_scene_units(&self, c: Camera) -> Camera {
        if self.unit == 1.0 {
            return c;
        }
        Camera {
            eye: c.eye.map(|v| v * self.unit),
            target: c.target.map(|v| v * self.unit),
            ..c
        }
    }

    /// Renders one frame (linear RGB).
    pub fn render_image(&self, cfg: &RenderConfig) -> Result<RgbImage> {
        cfg.validate()?;
        let cam = self.in_scene_units(cfg.camera.unwrap_or_else(|| self.default_camera()));
        let (width, height) = (cfg.width, cfg.height);
        let g = self.rasterize(&cam, width, height);
        let scale = math::exp2(cfg.exposure);
        let mut data = vec![0f32; width * height * 3];
        data.par_chunks_mut(width * 3).enumerate().for_each(|(y, row)| {
            let mut scratch = Vec::new();
            let mut view = match &self.shading {
                Shading::Colour(tiles) => Lookup::Colour(tiles.view()),
                Shading::Btf(btf) => Lookup::Btf(btf.tiles.view()),
            };
            let mut lights = Vec::with_capacity(cfg.lights.len());
            for (x, px) in row.chunks_exact_mut(3).enumerate() {
                let i = y * width + x;
                let face = g.face[i];
                if face == u32::MAX {
                    px.copy_from_slice(&BACKGROUND);
                    continue;
                }
                let f = face as usize;
                let tri = self.mesh.triangles[f];
                let b = [g.bary[i][0], g.bary[i][1], 1.0 - g.bary[i][0] - g.bary[i][1]];
                let mut pos = Vec3::ZERO;
                let mut n = Vec3::ZERO;
                let mut uv = [0f32; 2];
                for k in 0..3 {
                    pos += b[k] * Vec3::from(self.mesh.positions[tri[k] as usize]);
                    n += b[k] * Vec3::from(self.normals[tri[k] as usize]);
                    uv[0] += b[k] * self.corner_uv[f * 3 + k][0];
                    uv[1] += b[k] * self.corner_uv[f * 3 + k][1];
                }
                let mut n = unit_or(n, Vec3::ZERO);
                if n.length_squared() < 0.5 {
                    n = self.mesh.face_normal(f).into();
                }
                lights.clear();
                lights.extend(cfg.lights.iter().map(|l| self.light_at(l, pos)));
                let c = match (&self.shading, &mut view) {
                    (Shading::Colour(_), Lookup::Colour(texture)) => {
                        let r = self.resolution;
                        let texel = |x: usize, y: usize| {
                            texture
                                .with(y * r + x, |tile, i| {
                                    [tile.0[i * 3], tile.0[i * 3 + 1], tile.0[i * 3 + 2]]
                                })
                                .unwrap_or([0.0; 3])
                        };
                        let rf = r as f32;
                        let colour = bilinear_with(r, r, uv[0] * rf - 0.5, uv[1] * rf - 0.5, texel);
                        let e: f32 = lights.iter().map(|&(l, e)| e * n.dot(l).max(0.0)).sum();
                        let shade = 0.18 + 0.82 * e;
                        colour.map(|v| v * shade)
                    }
                    (Shading::Btf(btf), Lookup::Btf(texels)) => {
                        let view = unit_or(Vec3::from(cam.eye) - pos, Vec3::ZERO);
                        self.shade_btf(btf, texels, f, b, n, uv, view, &lights, &mut scratch)
                    }
                    _ => unreachable!("the lookup is made from the shading"),
                };
                for k in 0..3 {
                    px[k] = c[k] * scale;
                }
            }
        });
        match &self.shading {
            Shading::Colour(tiles) => tiles.check()?,
            Shading::Btf(btf) => btf.tiles.check()?,
        }
        Ok(RgbImage { width, height, data })
    }

    /// Unit direction towards the light and its irradiance scale at `pos`.
    fn light_at(&self, light: &Light, pos: Vec3) -> (Vec3, f32) {
        match *light {
            Light::Directional { direction, intensity } => (unit_or(direction.into(), Vec3::ZERO), intensity),
            Light::Point { position, intensity } => {
                let position = Vec3::from(position) * self.unit;
                let d = position - pos;
                let d2 = d.length_squared().max(1e-20);
                let c = position - Vec3::from(self.centre);
                let c2 = c.length_squared().max(1e-20);
                (unit_or(d, Vec3::ZERO), intensity * c2 / d2)
            }
        }
    }

    /// BTF value of a surface point: see the module documentation.
    #[allow(clippy::too_many_arguments)]
    fn shade_btf(
        &self,
        btf: &BtfShading,
        texels: &mut TileView<'_, BtfTile>,
        face: usize,
        bary: [f32; 3],
        n: Vec3,
        uv: [f32; 2],
        view: Vec3,
        lights: &[(Vec3, f32)],
        scratch: &mut Vec<f32>,
    ) -> [f32; 3] {
        let r = self.resolution;
        let (xa, ya) = (uv[0] * r as f32 - 0.5, uv[1] * r as f32 - 0.5);
        // (coordinate, Jacobian, sample) of a covered texel
        let mut at = |t: usize| {
            texels
                .with(t, |tile, i| {
                    tile.covered[i].then(|| (tile.coord[i], tile.jacobian[i], tile.sample[i]))
                })
                .flatten()
        };
        let Some((t, dx, dy)) = nearest_covered(|t| at(t).is_some(), r, xa, ya) else {
            return [0.0; 3];
        };
        let Some((c, j, sample_t)) = at(t) else {
            return [0.0; 3];
        };
        let sx = c[0] + j[0] * dx + j[2] * dy;
        let sy = c[1] + j[1] * dx + j[3] * dy;
        // local frame: sample +x and +y on the surface
        let det = j[0] * j[3] - j[1] * j[2];
        let ax = [j[3] / det, -j[1] / det]; // J⁻¹·(1, 0)
        let ay = [-j[2] / det, j[0] / det]; // J⁻¹·(0, 1)
                                            // ∂P/∂X, ∂P/∂Y at the pixel: the corners' wedge averages interpolated
        let corners = &btf.corner_maps[face * 3..face * 3 + 3];
        let maps = corners.iter().all(Option::is_some).then(|| {
            let mut m = [Vec3::ZERO; 2];
            for (c, w) in corners.iter().zip(bary) {
                let c = c.expect("checked");
                for a in 0..2 {
                    m[a] += w * Vec3::from(c[a]);
                }
            }
            m
        });
        let (x3, y3) = match maps {
            Some([dpx, dpy]) => (ax[0] * dpx + ax[1] * dpy, ay[0] * dpx + ay[1] * dpy),
            None => (Vec3::ZERO, Vec3::ZERO),
        };
        let mut xh = unit_or(x3 - n * x3.dot(n), Vec3::ZERO);
        if xh.length_squared() < 0.5 {
            let other = if n.x.abs() < 0.9 { Vec3::X } else { Vec3::Y };
            xh = unit_or(n.cross(other), Vec3::ZERO);
        }
        let mut yh = n.cross(xh);
        if yh.dot(y3) < 0.0 {
            yh = -yh;
        }
        let local = |d: Vec3| Vec3::new(d.dot(xh), d.dot(yh), d.dot(n));

        // geometry maps: each of the (up to) four texels around the pixel's
        // atlas position continues its own patch to that position through
        // its Jacobian; their g vectors are blended bilinearly, so a patch
        // seam is a one-texel blend instead of a step (inside a patch the
        // four continuations agree). Texels of different samples blend in
        // separate segments of `scratch` (each sample's terms at its
        // offset), since g vectors of different bases must not be mixed.
        let mut active = [0usize; 4];
        let mut n_active = 0;
        if scratch.len() != btf.total_terms {
            scratch.clear();
            scratch.resize(btf.total_terms, 0.0);
        }
        let mut activate = |k: usize, scratch: &mut [f32]| {
            if !active[..n_active].contains(&k) {
                let b = &btf.samples[k];
                scratch[b.offset..b.offset + b.terms].fill(0.0);
                active[n_active] = k;
                n_active += 1;
            }
        };
        let (bx, by) = (xa.floor(), ya.floor());
        let (fxa, fya) = (xa - bx, ya - by);
        let mut total = 0f32;
        for (ox, oy, wgt) in [
            (0.0, 0.0, (1.0 - fxa) * (1.0 - fya)),
            (1.0, 0.0, fxa * (1.0 - fya)),
            (0.0, 1.0, (1.0 - fxa) * fya),
            (1.0, 1.0, fxa * fya),
        ] {
            let (cx, cy) = (bx + ox, by + oy);
            if wgt <= 0.0 || cx < 0.0 || cy < 0.0 || cx >= r as f32 || cy >= r as f32 {
                continue;
            }
            let k = cy as usize * r + cx as usize;
            let Some((ck, jk, sk)) = at(k) else {
                continue;
            };
            let (ddx, ddy) = (xa - cx, ya - cy);
            let px = ck[0] + jk[0] * ddx + jk[2] * ddy;
            let py = ck[1] + jk[1] * ddx + jk[3] * ddy;
            let sk = sk as usize;
            activate(sk, scratch);
            add_geometry(&btf.samples[sk], px, py, wgt, scratch);
            total += wgt;
        }
        if total > 0.0 {
            // each sample's share of the blend stays in its segment's scale
            for &k in &active[..n_active] {
                let b = &btf.samples[k];
                for a in scratch[b.offset..b.offset + b.terms].iter_mut() {
                    *a /= total;
                }
            }
        } else {
            let sk = sample_t as usize;
            activate(sk, scratch);
            add_geometry(&btf.samples[sk], sx, sy, 1.0, scratch);
        }
        let active = &active[..n_active];

        let (vdirs, vcount) = btf.views.nearest(btf.views.clamp(local(view)));
        let mut acc = [0f32; 3];
        for &(l, e) in lights {
            let ll = local(l);
            if ll.z <= 0.0 || e <= 0.0 {
                continue;
            }
            let fade = if ll.z < btf.lights.cos_max {
                ll.z / btf.lights.cos_max.max(1e-3)
            } else {
                1.0
            };
            let (ldirs, lcount) = btf.lights.nearest(btf.lights.clamp(ll));
            for &(vi, vw) in &vdirs[..vcount] {
                for &(li, lw) in &ldirs[..lcount] {
                    let wgt = vw * lw * e * fade;
                    let pair = vi as usize * btf.n_lights + li as usize;
                    // Σ over the samples present, each its own g · p
                    for &k in active {
                        let b = &btf.samples[k];
                        let nt = b.terms;
                        let g = &scratch[b.offset..b.offset + nt];
                        let p = &b.appearance[pair * 3 * nt..(pair + 1) * 3 * nt];
                        for (ch, a) in acc.iter_mut().enumerate() {
                            *a += wgt * dot_n(g, &p[ch * nt..(ch + 1) * nt]);
                        }
                    }
                }
            }
        }
        acc
    }

    /// The G-buffer: per pixel the nearest face and perspective-correct
    /// barycentrics of its first two corners.
    pub(super) fn rasterize(&self, cam: &Camera, width: usize, height: usize) -> GBuffer {
        let eye = Vec3::from(cam.eye);
        let f = unit_or(Vec3::from(cam.target) - eye, Vec3::ZERO);
        let s = unit_or(f.cross(cam.up.into()), Vec3::ZERO);
        let u = s.cross(f);
        let focal = 0.5 * height as f32 / math::tan(0.5 * cam.fov.to_radians());
        // (pixel x, pixel y, depth)
        let proj: Vec<[f32; 3]> = self
            .mesh
            .positions
            .iter()
            .map(|&p| {
                let d = Vec3::from(p) - eye;
                let (x, y, z) = (d.dot(s), d.dot(u), d.dot(f));
                [
                    width as f32 / 2.0 + focal * x / z,
                    height as f32 / 2.0 - focal * y / z,
                    z,
                ]
            })
            .collect();
        let mut depth = vec![f32::INFINITY; width * height];
        let mut g = GBuffer {
            face: vec![u32::MAX; width * height],
            bary: vec![[0.0; 2]; width * height],
        };
        for (fi, tri) in self.mesh.triangles.iter().enumerate() {
            let p = [
                proj[tri[0] as usize],
                proj[tri[1] as usize],
                proj[tri[2] as usize],
            ];
            if p.iter()
                .any(|q| !(q[2] > 1e-6) || !q[0].is_finite() || !q[1].is_finite())
            {
                continue;
            }
            let area = (p[1][0] - p[0][0]) * (p[2][1] - p[0][1]) - (p[2][0] - p[0][0]) * (p[1][1] - p[0][1]);
            if !(area.abs() >= 1e-12) {
                continue;
            }
            // the triangle's pixel span along axis k, clipped to [0, size]
            let span = |k: usize, size: usize| {
                let (lo, hi) = p.iter().fold((f32::INFINITY, f32::NEG_INFINITY), |(lo, hi), q| {
                    (lo.min(q[k]), hi.max(q[k]))
                });
                (lo.floor().max(0.0), hi.ceil().min(size as f32))
            };
            let ((lo_x, hi_x), (lo_y, hi_y)) = (span(0, width), span(1, height));
            if !(lo_x < hi_x && lo_y < hi_y) {
                continue;
            }
            let (x0, x1, y0, y1) = (lo_x as usize, hi_x as usize, lo_y as usize, hi_y as usize);
            for y in y0..y1 {
                for x in x0..x1 {
                    let (qx, qy) = (x as f32 + 0.5, y as f32 + 0.5);
                    let w0 = ((p[1][0] - qx) * (p[2][1] - qy) - (p[2][0] - qx) * (p[1][1] - qy)) / area;
                    let w1 = ((p[2][0] - qx) * (p[0][1] - qy) - (p[0][0] - qx) * (p[2][1] - qy)) / area;
                    let w2 = 1.0 - w0 - w1;
                    if w0 < 0.0 || w1 < 0.0 || w2 < 0.0 {
                        continue;
                    }
                    // perspective-correct weights
                    let b = [w0 / p[0][2], w1 / p[1][2], w2 / p[2][2]];
                    let z = 1.0 / (b[0] + b[1] + b[2]);
                    let i = y * width + x;
                    if z >= depth[i] {
                        continue;
                    }
                    depth[i] = z;
                    g.face[i] = fi as u32;
                    g.bary[i] = [b[0] * z, b[1] * z];
                }
            }
        }
        g
    }
}

pub(super) struct GBuffer {
    /// Face per pixel, `u32::MAX` where empty.
    pub(super) face: Vec<u32>,
    pub(super) bary: Vec<[f32; 2]>,
}

/// Dot product in eight lanes (vectorises; fixed summation order).
#[inline]
fn dot_n(a: &[f32], b: &[f32]) -> f32 {
    let mut acc = [0f32; 8];
    let (ca, cb) = (a.chunks_exact(8), b.chunks_exact(8));
    let (ra, rb) = (ca.remainder(), cb.remainder());
    for (x, y) in ca.zip(cb) {
        for k in 0..8 {
            acc[k] += x[k] * y[k];
        }
    }
    let mut s = ((acc[0] + acc[4]) + (acc[1] + acc[5])) + ((acc[2] + acc[6]) + (acc[3] + acc[7]));
    for (x, y) in ra.iter().zip(rb) {
        s += x * y;
    }
    s
}

/// The covered texel nearest to the continuous texel position `(xa, ya)`
/// (texel centres at integers): the texel under it, else the nearest in up to
/// [`TEXEL_SEARCH`] rings around it; with the offset from its centre.
pub(crate) fn nearest_covered(
    mut covered: impl FnMut(usize) -> bool,
    r: usize,
    xa: f32,
    ya: f32,
) -> Option<(usize, f32, f32)> {
    let last = (r - 1) as f32;
    let tx = xa.round().clamp(0.0, last) as isize;
    let ty = ya.round().clamp(0.0, last) as isize;
    let t = ty as usize * r + tx as usize;
    if covered(t) {
        return Some((t, xa - tx as f32, ya - ty as f32));
    }
    for ring in 1..=TEXEL_SEARCH {
        let mut best: Option<(f32, usize, f32, f32)> = None;
        for y in ty - ring..=ty + ring {
            for x in tx - ring..=tx + ring {
                if (x - tx).abs().max((y - ty).abs()) != ring
                    || x < 0
                    || y < 0
                    || x >= r as isize
                    || y >= r as isize
                {
                    continue;
                }
                let t = y as usize * r + x as usize;
                if !covered(t) {
                    continue;
                }
                let (dx, dy) = (xa - x as f32, ya - y as f32);
                let d = dx * dx + dy * dy;
                if best.map_or(true, |b| d < b.0) {
                    best = Some((d, t, dx, dy));
                }
            }
        }
        if let Some((_, t, dx, dy)) = best {
            return Some((t, dx, dy));
        }
    }
    None
}

/// Adds `weight` × sample `b`'s geometry-map vector at sample position
/// `(sx, sy)` (bilinear, clamped to the sample) to its segment of `scratch`.
fn add_geometry(b: &Basis, sx: f32, sy: f32, weight: f32, scratch: &mut [f32]) {
    let nt = b.terms;
    let (w, h) = (b.width, b.height);
    let out = &mut scratch[b.offset..b.offset + nt];
    let gx = sx.clamp(0.0, (w - 1) as f32);
    let gy = sy.clamp(0.0, (h - 1) as f32);
    let (x0, y0) = (gx.floor() as usize, gy.floor() as usize);
    let (x1, y1) = ((x0 + 1).min(w - 1), (y0 + 1).min(h - 1));
    let (fx, fy) = (gx - x0 as f32, gy - y0 as f32);
    for (idx, wgt) in [
        (y0 * w + x0, (1.0 - fx) * (1.0 - fy)),
        (y0 * w + x1, fx * (1.0 - fy)),
        (y1 * w + x0, (1.0 - fx) * fy),
        (y1 * w + x1, fx * fy),
    ] {
        let src = &b.geometry[idx * nt..(idx + 1) * nt];
        for (a, &v) in out.iter_mut().zip(src) {
            *a += weight * wgt * v;
        }
    }
}
