//! Rotated and resampled copies of a factorization: the geometry maps
//! turned for each of the field-aligned rotations, and resized to a scale.

use super::maps::Maps;
use super::*;
use crate::math;

/// Writes `src` (whose geometry maps `maps` the caller has read) resampled
/// to `width`×`height` texels as the `.svd` `out`: the geometry maps and the
/// preview resampled
/// ([`crate::io::imageio::resample`]), the appearance functions, singular
/// values and directions unchanged (the BTF's columns do not depend on the
/// texel grid), and `rotations` rotated copies made from the resampled maps
/// (within `memory`). Quilting uses it to give a sample its size on the
/// surface.
pub fn resample_svd(
    src: &SvdArtifact,
    maps: &[f32],
    out: &Path,
    (width, height): (usize, usize),
    rotations: usize,
    memory: MemoryBudget,
    progress: &dyn Progress,
) -> Result<()> {
    let (w0, h0, terms) = (src.width, src.height, src.terms);
    let g = crate::io::imageio::resample(maps, w0, h0, terms, width, height);
    let preview = crate::io::imageio::resample(&src.preview()?.data, w0, h0, 3, width, height);
    let meta = src.container().metadata();
    let cfg = FactorizeConfig {
        rotations,
        tileable: src.tileable(),
        seed: meta.seed.unwrap_or(FactorizeConfig::default().seed),
        memory,
        ..FactorizeConfig::default()
    };
    let (w, h, t) = (width as u64, height as u64, SVD_TILE);
    let mut c = ContainerWriter::create(out, KIND)?;
    c.set_level(cfg.level);
    c.set_seed(cfg.seed);
    c.add_input(
        &src.container().path().display().to_string(),
        src.container().content_hash(),
    );
    for (name, value) in &meta.params {
        let value = match name.as_str() {
            "width" => Param::Int(w as i64),
            "height" => Param::Int(h as i64),
            "rotations" => Param::Int(rotations as i64),
            _ => value.clone(),
        };
        c.set_param(name, value);
    }
    c.set_param("resampled_from", Param::Text(format!("{w0}x{h0}")));
    for name in ["view_dirs", "light_dirs", "singular_values"] {
        let id = src.container().array(name)?;
        let spec = src.container().spec(id).clone();
        let values: Vec<f32> = src.container().read_array(id)?;
        let id = c.add_array(spec)?;
        c.write_array(id, &values)?;
    }
    let id = c.add_array(ArraySpec::new(
        "geometry_maps",
        DType::F32,
        &[h, w, terms as u64],
        &[t, t, terms as u64],
    )?)?;
    c.write_array(id, &g)?;
    let id = src.container().array("appearance")?;
    let spec = src.container().spec(id).clone();
    let appearance: Vec<f32> = src.container().read_array(id)?;
    let id = c.add_array(spec)?;
    c.write_array(id, &appearance)?;
    let id = c.add_array(ArraySpec::new("preview", DType::F32, &[h, w, 3], &[t, t, 3])?)?;
    c.write_array(id, &preview)?;
    if rotations > 0 {
        write_rotations(&mut c, &cfg, width, height, terms, Maps::Whole(&g), progress)?;
    }
    c.finish()
}

/// Bilinear rotation of multi-channel maps about the sample centre: copy r
/// shows the sample turned by r·360°/R (output texel x reads the input at
/// R(−θ)(x − c) + c). Invalid where that point leaves the sample (unless
/// `tileable`, which wraps).
pub fn rotate_maps(
    maps: &[f32],
    width: usize,
    height: usize,
    channels: usize,
    degrees: f64,
    tileable: bool,
) -> (Vec<f32>, Vec<u8>) {
    rotate_region(
        maps,
        width,
        height,
        channels,
        degrees,
        tileable,
        (0, 0, width, height),
    )
}

/// [`rotate_maps`] for the texels of `region` only (`x0`, `y0`, `w` × `h`;
/// the output `[y][x][c]` within it): each output texel depends on its
/// position alone, so a copy made region by region is the same as the
/// whole.
pub(super) fn rotate_region(
    maps: &[f32],
    width: usize,
    height: usize,
    channels: usize,
    degrees: f64,
    tileable: bool,
    region: (usize, usize, usize, usize),
) -> (Vec<f32>, Vec<u8>) {
    let texel = |x: usize, y: usize| &maps[(y * width + x) * channels..(y * width + x + 1) * channels];
    rotate_from(texel, width, height, channels, degrees, tileable, region)
}

/// [`rotate_region`] reading the maps' texel (x, y) from `texel`.
pub(super) fn rotate_from<'a>(
    texel: impl Fn(usize, usize) -> &'a [f32],
    width: usize,
    height: usize,
    channels: usize,
    degrees: f64,
    tileable: bool,
    (rx, ry, rw, rh): (usize, usize, usize, usize),
) -> (Vec<f32>, Vec<u8>) {
    let (sin, cos) = math::sin_cos(degrees.to_radians());
    let (cx, cy) = ((width as f64 - 1.0) / 2.0, (height as f64 - 1.0) / 2.0);
    let mut out = vec![0f32; rw * rh * channels];
    let mut valid = vec![0u8; rw * rh];
    for y in ry..ry + rh {
        for x in rx..rx + rw {
            let (dx, dy) = (x as f64 - cx, y as f64 - cy);
            let mut sx = cos * dx + sin * dy + cx;
            let mut sy = -sin * dx + cos * dy + cy;
            if tileable {
                sx = sx.rem_euclid(width as f64);
                sy = sy.rem_euclid(height as f64);
            } else {
                // snap rounding noise (e.g. at 90°) back onto the sample
                let snap = |v: f64, hi: f64| {
                    if v < 0.0 && v > -1e-9 {
                        0.0
                    } else if v > hi && v < hi + 1e-9 {
                        hi
                    } else {
                        v
                    }
                };
                sx = snap(sx, width as f64 - 1.0);
                sy = snap(sy, height as f64 - 1.0);
                if !(0.0..=width as f64 - 1.0).contains(&sx) || !(0.0..=height as f64 - 1.0).contains(&sy) {
                    continue;
                }
            }
            // sx, sy ≥ 0 here, so truncation is the floor (and no libm call)
            let (x0, y0) = (sx as usize, sy as usize);
            let (fx, fy) = ((sx - x0 as f64) as f32, (sy - y0 as f64) as f32);
            let (x0, y0) = (x0.min(width - 1), y0.min(height - 1));
            let x1 = if tileable {
                (x0 + 1) % width
            } else {
                (x0 + 1).min(width - 1)
            };
            let y1 = if tileable {
                (y0 + 1) % height
            } else {
                (y0 + 1).min(height - 1)
            };
            let (a, b, c, d) = (texel(x0, y0), texel(x1, y0), texel(x0, y1), texel(x1, y1));
            let at = (y - ry) * rw + x - rx;
            let o = &mut out[at * channels..(at + 1) * channels];
            for i in 0..channels {
                let top = a[i] + (b[i] - a[i]) * fx;
                let bottom = c[i] + (d[i] - c[i]) * fx;
                o[i] = top + (bottom - top) * fy;
            }
            valid[at] = 1;
        }
    }
    (out, valid)
}

/// Writes the `rotated_maps` (f16) and `rotated_valid` arrays of `g`'s
/// copies turned by [`rotate_region`], chunk by chunk: a batch of chunks is
/// rotated and encoded at once, sized to an eighth of `cfg.memory` (at
/// least one per thread), and written in the arrays' order, so the file is
/// the same for any budget and thread count. Maps kept as chunks are read a
/// window per turned chunk, by the thread that turns it (through the
/// chunks' shared cache).
pub(super) fn write_rotations(
    c: &mut ContainerWriter,
    cfg: &FactorizeConfig,
    width: usize,
    height: usize,
    terms: usize,
    g: Maps,
    progress: &dyn Progress,
) -> Result<()> {
    let r = cfg.rotations as u64;
    let (w, h, t) = (width as u64, height as u64, SVD_TILE);
    let maps = c.add_array(ArraySpec::new(
        "rotated_maps",
        DType::F16,
        &[r, h, w, terms as u64],
        &[1, t, t, terms as u64],
    )?)?;
    let valid = c.add_array(ArraySpec::new(
        "rotated_valid",
        DType::U8,
        &[r, h, w],
        &[1, t, t],
    )?)?;
    let maps_spec = c.spec(maps).clone();
    let per_rotation = maps_spec.chunk_count() / r;
    // a chunk in flight: its f32 and f16 texels, its validity and encodings,
    // and the window it reads when the maps are kept as chunks
    let window = (t as f64 * std::f64::consts::SQRT_2).ceil() as usize + 6;
    let chunk_bytes = (t * t) as usize * (terms * 8 + 2)
        + matches!(g, Maps::Chunks(_)) as usize * window * window * terms * 4;
    let batch = (cfg.memory.bytes() as usize / 8 / chunk_bytes)
        .max(rayon::current_num_threads())
        .min(per_rotation as usize) as u64;
    progress.begin("rotations", r);
    let level = c.level();
    for ri in 0..cfg.rotations as u64 {
        let degrees = 360.0 * ri as f64 / cfg.rotations as f64;
        // the validity chunks are written after the rotation's maps (they
        // compress to a few bytes each)
        let mut valid_chunks = Vec::with_capacity(per_rotation as usize);
        for k0 in (0..per_rotation).step_by(batch as usize) {
            let region = |k: u64| {
                let (o, e) = maps_spec.chunk_region(ri * per_rotation + k);
                (o[2] as usize, o[1] as usize, e[2] as usize, e[1] as usize)
            };
            let ks = k0..(k0 + batch).min(per_rotation);
            let encoded: Vec<(codec::EncodedChunk, codec::EncodedChunk)> = ks
                .into_par_iter()
                .map(|k| {
                    let (rot, ok) = match &g {
                        Maps::Whole(g) => {
                            rotate_region(g, width, height, terms, degrees, cfg.tileable, region(k))
                        }
                        Maps::Chunks(m) => {
                            let win = m.window(degrees, cfg.tileable, region(k))?;
                            let texel = |x, y| win.texel(x, y);
                            rotate_from(texel, width, height, terms, degrees, cfg.tileable, region(k))
                        }
                    };
                    let mut rot16 = vec![f16::ZERO; rot.len()];
                    rot16.convert_from_f32_slice(&rot);
                    Ok((codec::encode(&rot16, level), codec::encode(&ok, level)))
                })
                .collect::<Result<_>>()?;
            for (k, (mc, vc)) in (k0..).zip(encoded) {
                c.write_encoded(maps, ri * per_rotation + k, mc)?;
                valid_chunks.push(vc);
            }
        }
        for (k, vc) in valid_chunks.into_iter().enumerate() {
            c.write_encoded(valid, ri * per_rotation + k as u64, vc)?;
        }
        progress.advance(1);
    }
    progress.end();
    Ok(())
}
