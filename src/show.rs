//! `show`: debug pictures of a geometry image in atlas space: the chart map,
//! the normal map, and the vector field drawn as short strokes.

use std::path::Path;
use std::str::FromStr;

use crate::gim::{Gim, EMPTY};
use crate::imageio::{self, srgb_to_linear, PngDepth, RgbImage};
use crate::{Error, Result};

/// What to draw.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ShowWhat {
    Charts,
    Normals,
    Field,
}

impl FromStr for ShowWhat {
    type Err = Error;
    fn from_str(s: &str) -> Result<Self> {
        match s {
            "charts" => Ok(ShowWhat::Charts),
            "normals" => Ok(ShowWhat::Normals),
            "field" => Ok(ShowWhat::Field),
            _ => Err(Error::Config(format!(
                "--what '{s}': expected charts, normals or field"
            ))),
        }
    }
}

/// A distinct, stable colour per chart (golden-angle hues), display-encoded.
pub fn chart_colour(c: u32) -> [f32; 3] {
    let h = (c as f32 * 0.618_034).fract() * 6.0;
    let s = 0.55 + 0.35 * ((c * 7 % 5) as f32 / 4.0);
    let v = 0.95 - 0.25 * ((c * 3 % 4) as f32 / 3.0);
    let f = h.fract();
    let (p, q, t) = (v * (1.0 - s), v * (1.0 - s * f), v * (1.0 - s * (1.0 - f)));
    match h as u32 {
        0 => [v, t, p],
        1 => [q, v, p],
        2 => [p, v, t],
        3 => [p, q, v],
        4 => [t, p, v],
        _ => [v, p, q],
    }
}

/// Draws `what` for the whole atlas into a PNG at `out`.
pub fn show(gim: &Gim, what: ShowWhat, out: &Path) -> Result<()> {
    let r = gim.resolution;
    let chart: Vec<u32> = gim.read("chart")?;
    let normal: Vec<f32> = gim.read("normal")?;
    let mut display = vec![0.08f32; r * r * 3];
    for t in 0..r * r {
        if chart[t] == EMPTY {
            continue;
        }
        let n = &normal[t * 3..t * 3 + 3];
        let c = match what {
            ShowWhat::Normals => [n[0] * 0.5 + 0.5, n[1] * 0.5 + 0.5, n[2] * 0.5 + 0.5],
            ShowWhat::Charts => chart_colour(chart[t]),
            ShowWhat::Field => {
                // dimmed chart colours, shaded by a light from the front
                let shade = 0.35 + 0.35 * (n[2].max(0.0) + 0.5 * n[1].max(0.0));
                chart_colour(chart[t]).map(|v| v * shade)
            }
        };
        display[t * 3..t * 3 + 3].copy_from_slice(&c);
    }
    if what == ShowWhat::Field {
        draw_field(gim, &chart, &mut display)?;
    }
    let img = RgbImage {
        width: r,
        height: r,
        // write_png encodes linear to sRGB: hand it the linear values of these display colours
        data: display
            .iter()
            .map(|&v| srgb_to_linear(v.clamp(0.0, 1.0)))
            .collect(),
    };
    imageio::write_png(out, &img, PngDepth::Eight)
}

/// Strokes along the field's direction in atlas space, every 12 texels: the
/// 3D tangent mapped through each face's inverse parameterisation.
fn draw_field(gim: &Gim, chart: &[u32], display: &mut [f32]) -> Result<()> {
    let r = gim.resolution;
    let mesh = gim.mesh()?;
    let uv = gim.corner_uv()?;
    let face: Vec<u32> = gim.read("face")?;
    let tangent: Vec<f32> = gim.read("tangent")?;
    let step = (r / 80).max(8);
    for y in (step / 2..r).step_by(step) {
        for x in (step / 2..r).step_by(step) {
            let t = y * r + x;
            if chart[t] == EMPTY {
                continue;
            }
            let f = face[t] as usize;
            let [p0, p1, p2] = mesh.corners(f);
            let (u0, u1, u2) = (uv[f * 3], uv[f * 3 + 1], uv[f * 3 + 2]);
            // J = [dP/ds dP/dt] from (ds, dt) = atlas texels; solve J d = tangent (least squares)
            let e1 = [p1[0] - p0[0], p1[1] - p0[1], p1[2] - p0[2]];
            let e2 = [p2[0] - p0[0], p2[1] - p0[1], p2[2] - p0[2]];
            let (a, b) = ([u1[0] - u0[0], u1[1] - u0[1]], [u2[0] - u0[0], u2[1] - u0[1]]);
            let det = a[0] * b[1] - a[1] * b[0];
            if det.abs() < 1e-12 {
                continue;
            }
            // dP/du, dP/dv from the 2×2 inverse
            let (i00, i01, i10, i11) = (b[1] / det, -b[0] / det, -a[1] / det, a[0] / det);
            let du: Vec<f32> = (0..3).map(|k| e1[k] * i00 + e2[k] * i10).collect();
            let dv: Vec<f32> = (0..3).map(|k| e1[k] * i01 + e2[k] * i11).collect();
            let tan = &tangent[t * 3..t * 3 + 3];
            let (g00, g01, g11) = (dot3(&du, &du), dot3(&du, &dv), dot3(&dv, &dv));
            let (h0, h1) = (dot3(&du, tan), dot3(&dv, tan));
            let gdet = g00 * g11 - g01 * g01;
            if gdet.abs() < 1e-20 {
                continue;
            }
            let d = [(g11 * h0 - g01 * h1) / gdet, (g00 * h1 - g01 * h0) / gdet];
            let len = (d[0] * d[0] + d[1] * d[1]).sqrt();
            if len == 0.0 {
                continue;
            }
            let d = [d[0] / len, d[1] / len];
            let length = step as f32 * 0.8;
            let n = (length * 2.0) as usize;
            for i in 0..=n {
                let s = i as f32 / n as f32;
                let (px, py) = (
                    x as f32 + 0.5 + d[0] * length * s,
                    y as f32 + 0.5 + d[1] * length * s,
                );
                if px < 0.0 || py < 0.0 || px >= r as f32 || py >= r as f32 {
                    break;
                }
                let p = (py as usize * r + px as usize) * 3;
                // dark tail, bright head: the direction is readable
                let c = if s > 0.7 {
                    [1.0, 0.95, 0.3]
                } else {
                    [0.02, 0.02, 0.02]
                };
                display[p..p + 3].copy_from_slice(&c);
            }
        }
    }
    Ok(())
}

fn dot3(a: &[f32], b: &[f32]) -> f32 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}
