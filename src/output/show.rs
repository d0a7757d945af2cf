//! `show`: debug pictures of a geometry image in atlas space: the chart map,
//! the normal map, and the vector field drawn as short strokes with its
//! singularities ringed.

use std::path::Path;
use std::str::FromStr;

use crate::artifact::gim::{atlas_direction, Gim, EMPTY};
use crate::io::imageio::{self, srgb_to_linear, PngDepth, RgbImage};
use crate::math;
use crate::{Error, Result};

/// What to draw (`show --what`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, clap::ValueEnum)]
pub enum ShowWhat {
    /// Each chart in its own colour.
    #[default]
    Charts,
    /// The normal map.
    Normals,
    /// The vector field as short strokes; its singularities ringed (red
    /// index +1, blue −1)
    Field,
}

impl FromStr for ShowWhat {
    type Err = Error;
    /// The names clap accepts: `charts`, `normals`, `field`.
    fn from_str(s: &str) -> Result<Self> {
        <Self as clap::ValueEnum>::from_str(s, false)
            .map_err(|_| Error::Config(format!("--what '{s}': expected charts, normals or field")))
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
    crate::io::staging::check_output(out, &[("the geometry image", gim.container().path())])?;
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
        draw_singularities(gim, &mut display)?;
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
            let tan = &tangent[t * 3..t * 3 + 3];
            let v = [tan[0] as f64, tan[1] as f64, tan[2] as f64];
            let Some(d) = atlas_direction(&mesh, &uv, face[t] as usize, v) else {
                continue;
            };
            let len = (d[0] * d[0] + d[1] * d[1]).sqrt();
            if len == 0.0 {
                continue;
            }
            let d = [(d[0] / len) as f32, (d[1] / len) as f32];
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

/// Rings around the field's singular vertices ([`crate::field::singularities`])
/// at every corner of every face around them (a vertex on a chart border
/// shows in each chart): red for index +1, blue for −1, white otherwise.
fn draw_singularities(gim: &Gim, display: &mut [f32]) -> Result<()> {
    let r = gim.resolution;
    let mesh = gim.mesh()?;
    let uv = gim.corner_uv()?;
    let field = gim.face_field()?;
    let singular = crate::field::singularities(&mesh, &mesh.topology(), &field);
    // each singular vertex's ring colour, found in one pass over the faces
    let mut ring: Vec<Option<[f32; 3]>> = vec![None; mesh.positions.len()];
    for s in &singular {
        ring[s.vertex as usize] = Some(match s.index {
            1 => [1.0, 0.1, 0.1],
            -1 => [0.2, 0.5, 1.0],
            _ => [1.0, 1.0, 1.0],
        });
    }
    let radius = (r as f32 / 128.0).max(4.0);
    let steps = (radius * 8.0) as usize;
    for (f, t) in mesh.triangles.iter().enumerate() {
        for (k, &v) in t.iter().enumerate() {
            let Some(colour) = ring[v as usize] else {
                continue;
            };
            let [u, v] = uv[f * 3 + k];
            let (cx, cy) = (u * r as f32, v * r as f32);
            for i in 0..steps {
                let a = i as f32 / steps as f32 * std::f32::consts::TAU;
                for dr in [-0.5f32, 0.0, 0.5] {
                    let (x, y) = (
                        cx + (radius + dr) * math::cos(a),
                        cy + (radius + dr) * math::sin(a),
                    );
                    if x >= 0.0 && y >= 0.0 && (x as usize) < r && (y as usize) < r {
                        let p = (y as usize * r + x as usize) * 3;
                        display[p..p + 3].copy_from_slice(&colour);
                    }
                }
            }
        }
    }
    Ok(())
}
