//! `render`: a software rasterizer that shows a decorated mesh from a camera
//! (z-buffer, perspective-correct atlas uv, the baked preview colour, Lambert
//! shading under one directional light). BTF shading per view and light
//! direction comes with the BTF decoration stage.

use std::path::Path;

use crate::bake::{atlas_colour, bilinear, dilate, open_sample};
use crate::container::MemoryBudget;
use crate::gim::Gim;
use crate::imageio::{self, PngDepth, RgbImage};
use crate::mesh::{cross, dot, normalize, sub};
use crate::quilt::Quilt;
use crate::{Error, Result};

/// A pinhole camera.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Camera {
    pub eye: [f32; 3],
    pub target: [f32; 3],
    pub up: [f32; 3],
    /// Vertical field of view in degrees.
    pub fov: f32,
}

impl Camera {
    /// Parses `ex,ey,ez,tx,ty,tz,ux,uy,uz,fov`.
    pub fn parse(s: &str) -> Result<Camera> {
        let v: Vec<f32> = s
            .split(',')
            .map(|x| x.trim().parse::<f32>())
            .collect::<std::result::Result<_, _>>()
            .map_err(|_| {
                Error::Config(format!(
                    "--camera '{s}': expected eye,target,up,fov as 10 numbers"
                ))
            })?;
        if v.len() != 10 || !(1.0..179.0).contains(&v[9]) {
            return Err(Error::Config(format!(
                "--camera '{s}': expected eye,target,up,fov as 10 numbers"
            )));
        }
        Ok(Camera {
            eye: [v[0], v[1], v[2]],
            target: [v[3], v[4], v[5]],
            up: [v[6], v[7], v[8]],
            fov: v[9],
        })
    }

    /// A three-quarter view framing the given positions.
    pub fn framing(positions: &[[f32; 3]]) -> Camera {
        let mut lo = [f32::INFINITY; 3];
        let mut hi = [f32::NEG_INFINITY; 3];
        for p in positions {
            for k in 0..3 {
                lo[k] = lo[k].min(p[k]);
                hi[k] = hi[k].max(p[k]);
            }
        }
        let c = [
            (lo[0] + hi[0]) / 2.0,
            (lo[1] + hi[1]) / 2.0,
            (lo[2] + hi[2]) / 2.0,
        ];
        let radius = 0.5 * crate::mesh::length(sub(hi, lo));
        let d = normalize([0.8, 0.45, 1.0]);
        let dist = radius / (20f32.to_radians()).tan();
        Camera {
            eye: [c[0] + d[0] * dist, c[1] + d[1] * dist, c[2] + d[2] * dist],
            target: c,
            up: [0.0, 1.0, 0.0],
            fov: 42.0,
        }
    }
}

/// Renders the quilt's mesh with its baked colour.
pub fn render(
    quilt_path: &Path,
    camera: Option<Camera>,
    light: [f32; 3],
    width: usize,
    height: usize,
    out: &Path,
    budget: MemoryBudget,
) -> Result<()> {
    let quilt = Quilt::open(quilt_path, budget)?;
    let gim = Gim::open(&quilt.gim, budget)?;
    let (svd, _tmp) = open_sample(&quilt, None, budget)?;
    let (mut texture, covered) = atlas_colour(&quilt, &svd.preview()?)?;
    dilate(&mut texture, &covered, 4);
    let mesh = gim.mesh()?;
    let uv = gim.corner_uv()?;
    let normals = mesh.vertex_normals();
    let cam = camera.unwrap_or_else(|| Camera::framing(&mesh.positions));
    let f = normalize(sub(cam.target, cam.eye));
    let s = normalize(cross(f, cam.up));
    let u = cross(s, f);
    let focal = 0.5 * height as f32 / (0.5 * cam.fov.to_radians()).tan();
    let light = normalize(light);
    // project: (pixel x, pixel y, depth)
    let proj: Vec<[f32; 3]> = mesh
        .positions
        .iter()
        .map(|&p| {
            let d = sub(p, cam.eye);
            let (x, y, z) = (dot(d, s), dot(d, u), dot(d, f));
            [
                width as f32 / 2.0 + focal * x / z,
                height as f32 / 2.0 - focal * y / z,
                z,
            ]
        })
        .collect();
    let mut depth = vec![f32::INFINITY; width * height];
    let mut data = vec![0.0f32; width * height * 3];
    for px in data.chunks_exact_mut(3) {
        px.copy_from_slice(&[0.02, 0.02, 0.025]);
    }
    let r = quilt.resolution as f32;
    for (fi, tri) in mesh.triangles.iter().enumerate() {
        let p = [
            proj[tri[0] as usize],
            proj[tri[1] as usize],
            proj[tri[2] as usize],
        ];
        if p.iter().any(|q| q[2] <= 1e-6) {
            continue;
        }
        let area = (p[1][0] - p[0][0]) * (p[2][1] - p[0][1]) - (p[2][0] - p[0][0]) * (p[1][1] - p[0][1]);
        if area.abs() < 1e-12 {
            continue;
        }
        let x0 = p
            .iter()
            .map(|q| q[0])
            .fold(f32::INFINITY, f32::min)
            .floor()
            .max(0.0) as usize;
        let x1 = (p.iter().map(|q| q[0]).fold(f32::NEG_INFINITY, f32::max).ceil() as usize).min(width);
        let y0 = p
            .iter()
            .map(|q| q[1])
            .fold(f32::INFINITY, f32::min)
            .floor()
            .max(0.0) as usize;
        let y1 = (p.iter().map(|q| q[1]).fold(f32::NEG_INFINITY, f32::max).ceil() as usize).min(height);
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
                let b = [b[0] * z, b[1] * z, b[2] * z];
                let mut tu = 0.0;
                let mut tv = 0.0;
                let mut n = [0.0f32; 3];
                for k in 0..3 {
                    tu += b[k] * uv[fi * 3 + k][0];
                    tv += b[k] * uv[fi * 3 + k][1];
                    let vn = normals[tri[k] as usize];
                    for d in 0..3 {
                        n[d] += b[k] * vn[d];
                    }
                }
                let n = normalize(n);
                let colour = bilinear(&texture, tu * r - 0.5, tv * r - 0.5);
                let shade = 0.18 + 0.82 * dot(n, light).max(0.0);
                for c in 0..3 {
                    data[i * 3 + c] = colour[c] * shade;
                }
            }
        }
    }
    let img = RgbImage { width, height, data };
    if out.extension().is_some_and(|e| e.eq_ignore_ascii_case("png")) {
        imageio::write_png(out, &img, PngDepth::Eight)
    } else {
        imageio::write_rgb(out, &img)
    }
}
