//! Writing the `.quilt` artifact ([`crate::artifact::quilt`]): the synthesis
//! state, the seams it left, and the files it depends on.

use std::path::Path;

use rayon::prelude::*;

use super::state::{State, StateTile, Surface};
use super::synthesis::{sample_role, Synthesis};
use super::{TileConfig, TileReport};
use crate::artifact::gim::{Gim, EMPTY, TILE};
use crate::artifact::quilt::{KIND, SEAM_X, SEAM_Y, SEAM_ZIPPER};
use crate::container::{codec, ArraySpec, ContainerWriter, DType, Element, Param};
use crate::Result;

/// Writes the synthesis state as a `.quilt`; `paint_log` (a JSON array of
/// strokes) when the surface was painted.
pub(super) fn write_quilt(
    out: &Path,
    cfg: &TileConfig,
    gim: &Gim,
    gim_path: &Path,
    syn: &Synthesis,
    paint_log: Option<&str>,
    report: &TileReport,
) -> Result<()> {
    let (sample, state) = (&syn.sample, &syn.state);
    let r = gim.resolution as u64;
    let t = TILE as u64;
    let mut w = ContainerWriter::create(out, KIND)?;
    w.set_level(cfg.level);
    w.set_seed(cfg.seed);
    record_dependency(&mut w, out, "gim", gim_path)?;
    let paths = &syn.sample_paths;
    record_dependency(&mut w, out, "sample", &paths[0])?;
    if paths.len() > 1 {
        w.set_param("sample_count", Param::Int(paths.len() as i64));
        for (k, p) in paths.iter().enumerate().skip(1) {
            record_dependency(&mut w, out, &format!("sample_{k}"), p)?;
        }
    }
    if let Some(mask) = &cfg.sample_mask {
        record_dependency(&mut w, out, "sample_mask", mask)?;
        if state.active > 0 {
            w.set_param("mask_sample", Param::Int(state.active as i64));
        }
    }
    if let Some(log) = paint_log {
        w.set_param("paint_log", Param::Text(log.to_string()));
    }
    w.set_param("resolution", Param::Int(r as i64));
    let [width, height] = syn.original_size;
    w.set_param("sample_width", Param::Int(width as i64));
    w.set_param("sample_height", Param::Int(height as i64));
    for k in 0..paths.len() {
        let span = if k == state.active as usize {
            syn.active_span
        } else {
            syn.sample_spans.get(k).copied().flatten()
        };
        if let Some(units) = span {
            w.set_param(&format!("{}_span", sample_role(k)), Param::Float(units));
        }
    }
    w.set_param("terms", Param::Int(sample.svd.terms as i64));
    w.set_param("rotations", Param::Int(sample.rotations as i64));
    w.set_param("patches", Param::Int(state.next_patch as i64));
    w.set_param("mean_seam_cost", Param::Float(report.mean_seam_cost));
    // coordinates and Jacobians in original sample pixels (the loop works
    // in the resampled sample's, for the texels of the active sample);
    // written tile by tile, array after array
    let active = state.active;
    let [sx, sy] = syn.scale;
    let scaled = syn.scale != [1.0, 1.0];
    write_plane(
        &mut w,
        state,
        &syn.surface,
        "coord",
        2,
        |s, i, _, buf: &mut Vec<f32>| {
            let c = s.coord[i];
            if scaled && s.source[i] == active {
                buf.extend_from_slice(&[(c[0] as f64 * sx) as f32, (c[1] as f64 * sy) as f32]);
            } else {
                buf.extend_from_slice(&c);
            }
        },
    )?;
    write_plane(
        &mut w,
        state,
        &syn.surface,
        "jacobian",
        4,
        |s, i, _, buf: &mut Vec<f32>| {
            let j = s.jacobian[i];
            if scaled && s.source[i] == active {
                buf.extend_from_slice(&[
                    (j[0] as f64 * sx) as f32,
                    (j[1] as f64 * sy) as f32,
                    (j[2] as f64 * sx) as f32,
                    (j[3] as f64 * sy) as f32,
                ]);
            } else {
                buf.extend_from_slice(&j);
            }
        },
    )?;
    write_plane(
        &mut w,
        state,
        &syn.surface,
        "rotation",
        1,
        |s, i, _, buf: &mut Vec<u8>| buf.push(s.rotation[i]),
    )?;
    write_plane(
        &mut w,
        state,
        &syn.surface,
        "patch",
        1,
        |s, i, _, buf: &mut Vec<u32>| buf.push(s.patch[i]),
    )?;
    if paths.len() > 1 {
        write_plane(
            &mut w,
            state,
            &syn.surface,
            "sample",
            1,
            |s, i, _, buf: &mut Vec<u8>| buf.push(s.source[i]),
        )?;
    }
    let zippers = gim.zipper_links()?;
    let mut zipper_flag: std::collections::HashMap<u32, u8> = Default::default();
    for &[a, b] in &zippers {
        if state.patch(a) != state.patch(b) {
            zipper_flag.insert(a, SEAM_ZIPPER);
            zipper_flag.insert(b, SEAM_ZIPPER);
        }
    }
    let surface = &syn.surface;
    // (the patch ids of +x/+y neighbours may sit in the next tiles)
    let grid = syn.surface.grid();
    let id = w.add_array(ArraySpec::new("seam", DType::U8, &[r, r], &[t, t])?)?;
    for k in 0..grid.tiles() {
        let (x0, y0, tw, th) = grid.region(k);
        let patches = state.tile(k, |s| s.patch.clone());
        let mut flags = Vec::with_capacity(tw * th);
        for y in 0..th {
            for x in 0..tw {
                let texel = ((y0 + y) * grid.r + x0 + x) as u32;
                let own = patches[y * TILE + x];
                flags.push(
                    seam_flags_at(surface, own, texel, grid.r, state)
                        | zipper_flag.get(&texel).copied().unwrap_or(0),
                );
            }
        }
        w.write_chunk(id, k as u64, &flags)?;
    }
    if let (true, Some(_)) = (state.constrained, paint_log) {
        write_plane(
            &mut w,
            state,
            &syn.surface,
            "region",
            1,
            |s, i, _, buf: &mut Vec<f32>| buf.push(s.target[i]),
        )?;
    }
    w.finish()
}

/// Records a file the quilt at `out` depends on under `role` (a parameter of
/// that name): its path relative to the quilt's folder (so the quilt and its
/// inputs can move together, and be read from any working directory), its
/// length (`ROLE_bytes`) and its content hash (an input of that name).
pub(super) fn record_dependency(w: &mut ContainerWriter, out: &Path, role: &str, path: &Path) -> Result<()> {
    let (bytes, hash) = crate::container::file_identity(path)?;
    w.add_input(role, hash);
    w.set_param(
        role,
        Param::Text(crate::io::staging::relative_to_folder_of(out, path)),
    );
    w.set_param(&format!("{role}_bytes"), Param::Int(bytes as i64));
    Ok(())
}

/// The seam flags [`SEAM_X`] | [`SEAM_Y`] of texel `t` (patch `patch`):
/// whether the patches meet across its atlas edges to +x and +y.
fn seam_flags_at(surface: &Surface, patch: u32, t: u32, r: usize, state: &State) -> u8 {
    let chart = surface.chart(t);
    if chart == EMPTY {
        return 0;
    }
    let (x, y) = (t as usize % r, t as usize / r);
    let seam = |n: u32| surface.chart(n) == chart && state.patch(n) != patch;
    let mut flags = 0;
    if x + 1 < r && seam(t + 1) {
        flags |= SEAM_X;
    }
    if y + 1 < r && seam(t + r as u32) {
        flags |= SEAM_Y;
    }
    flags
}

/// Writes a per-texel array `name` of `c` values per texel, tile by tile
/// (its chunks): `f` appends the values of a texel of a state tile
/// (`(tile, index in it, texel id, out)`).
fn write_plane<T: Element>(
    w: &mut ContainerWriter,
    state: &State,
    surface: &Surface,
    name: &str,
    c: u64,
    mut f: impl FnMut(&StateTile, usize, u32, &mut Vec<T>),
) -> Result<()> {
    let grid = surface.grid();
    let (r, t) = (grid.r as u64, TILE as u64);
    let (shape, chunk) = if c == 1 {
        (vec![r, r], vec![t, t])
    } else {
        (vec![r, r, c], vec![t, t, c])
    };
    let id = w.add_array(ArraySpec::new(name, T::DTYPE, &shape, &chunk)?)?;
    // tiles read in order (the state pages them), a batch at a time
    // compressed in parallel and written in order: the same bytes
    let tiles: Vec<usize> = (0..grid.tiles()).collect();
    for batch in tiles.chunks(WRITE_BATCH) {
        let values: Vec<Vec<T>> = batch
            .iter()
            .map(|&k| {
                let (x0, y0, tw, th) = grid.region(k);
                let mut buf = Vec::with_capacity(tw * th * c as usize);
                state.tile(k, |s| {
                    for y in 0..th {
                        for x in 0..tw {
                            f(s, y * TILE + x, ((y0 + y) * grid.r + x0 + x) as u32, &mut buf);
                        }
                    }
                });
                buf
            })
            .collect();
        let level = w.level();
        let encoded: Vec<_> = values.par_iter().map(|v| codec::encode(v, level)).collect();
        for (&k, e) in batch.iter().zip(encoded) {
            w.write_encoded(id, k as u64, e)?;
        }
    }
    Ok(())
}

/// Atlas tiles gathered before compressing them in parallel.
const WRITE_BATCH: usize = 64;
