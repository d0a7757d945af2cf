//! Writing the `.quilt` artifact ([`crate::artifact::quilt`]): the synthesis
//! state, the seams it left, and the files it depends on.

use std::path::Path;

use super::synthesis::{sample_role, Synthesis};
use super::{TileConfig, TileReport};
use crate::artifact::gim::{Gim, EMPTY, TILE};
use crate::artifact::quilt::{KIND, SEAM_X, SEAM_Y, SEAM_ZIPPER};
use crate::container::{ArraySpec, ContainerWriter, DType, Param};
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
    w.set_param("terms", Param::Int(sample.n as i64));
    w.set_param("rotations", Param::Int(sample.rotations as i64));
    w.set_param("patches", Param::Int(state.next_patch as i64));
    w.set_param("mean_seam_cost", Param::Float(report.mean_seam_cost));
    // coordinates and Jacobians in original sample pixels (the loop works
    // in the resampled sample's, for the texels of the active sample)
    let active = state.active;
    let [sx, sy] = syn.scale;
    let scaled = syn.scale != [1.0, 1.0];
    let coord: Vec<f32> = if scaled {
        (state.coord.iter().zip(&state.source))
            .flat_map(|(c, &k)| {
                if k == active {
                    [(c[0] as f64 * sx) as f32, (c[1] as f64 * sy) as f32]
                } else {
                    *c
                }
            })
            .collect()
    } else {
        state.coord.iter().flatten().copied().collect()
    };
    let id = w.add_array(ArraySpec::new("coord", DType::F32, &[r, r, 2], &[t, t, 2])?)?;
    w.write_array(id, &coord)?;
    let jacobian: Vec<f32> = if scaled {
        (state.jacobian.iter().zip(&state.source))
            .flat_map(|(j, &k)| {
                if k == active {
                    [
                        (j[0] as f64 * sx) as f32,
                        (j[1] as f64 * sy) as f32,
                        (j[2] as f64 * sx) as f32,
                        (j[3] as f64 * sy) as f32,
                    ]
                } else {
                    *j
                }
            })
            .collect()
    } else {
        state.jacobian.iter().flatten().copied().collect()
    };
    let id = w.add_array(ArraySpec::new("jacobian", DType::F32, &[r, r, 4], &[t, t, 4])?)?;
    w.write_array(id, &jacobian)?;
    let id = w.add_array(ArraySpec::new("rotation", DType::U8, &[r, r], &[t, t])?)?;
    w.write_array(id, &state.rotation)?;
    let id = w.add_array(ArraySpec::new("patch", DType::U32, &[r, r], &[t, t])?)?;
    w.write_array(id, &state.patch)?;
    if paths.len() > 1 {
        let id = w.add_array(ArraySpec::new("sample", DType::U8, &[r, r], &[t, t])?)?;
        w.write_array(id, &state.source)?;
    }
    let seams = seam_flags(&state.patch, &state.chart, gim.resolution, &gim.zipper_links()?);
    let id = w.add_array(ArraySpec::new("seam", DType::U8, &[r, r], &[t, t])?)?;
    w.write_array(id, &seams)?;
    if let (Some(m0), Some(_)) = (&state.target, paint_log) {
        let id = w.add_array(ArraySpec::new("region", DType::F32, &[r, r], &[t, t])?)?;
        w.write_array(id, m0)?;
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

/// Per texel: which of its mesh edges the patches meet across (the seams
/// the graphcut left), as [`SEAM_X`] | [`SEAM_Y`] | [`SEAM_ZIPPER`].
pub(super) fn seam_flags(patch: &[u32], chart: &[u32], r: usize, zipper_links: &[[u32; 2]]) -> Vec<u8> {
    let mut flags = vec![0u8; r * r];
    let seam = |a: usize, b: usize| chart[a] == chart[b] && chart[a] != EMPTY && patch[a] != patch[b];
    for y in 0..r {
        for x in 0..r {
            let t = y * r + x;
            if x + 1 < r && seam(t, t + 1) {
                flags[t] |= SEAM_X;
            }
            if y + 1 < r && seam(t, t + r) {
                flags[t] |= SEAM_Y;
            }
        }
    }
    for &[a, b] in zipper_links {
        let (a, b) = (a as usize, b as usize);
        if patch[a] != patch[b] {
            flags[a] |= SEAM_ZIPPER;
            flags[b] |= SEAM_ZIPPER;
        }
    }
    flags
}
