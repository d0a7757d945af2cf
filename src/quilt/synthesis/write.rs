//! Writing the `.quilt` artifact ([`crate::artifact::quilt`]): the synthesis
//! state, the seams it left, and the files it depends on.

use std::path::Path;

use rayon::prelude::*;

use super::{sample_role, Synthesis};
use crate::artifact::gim::{Gim, EMPTY, TILE};
use crate::artifact::quilt::{KIND, SEAM_X, SEAM_Y, SEAM_ZIPPER};
use crate::container::codec::EncodedChunk;
use crate::container::{codec, ArrayId, ArraySpec, ContainerWriter, DType, Param};
use crate::quilt::config::{TileConfig, TileReport};
use crate::quilt::state::{State, Surface};
use crate::Result;

/// Writes the synthesis state as a `.quilt`; `paint_log` (a JSON array of
/// strokes) when the surface was painted.
pub(in crate::quilt) fn write_quilt(
    out: &Path,
    cfg: &TileConfig,
    gim: &Gim,
    gim_path: &Path,
    syn: &Synthesis,
    paint_log: Option<&str>,
    report: &TileReport,
) -> Result<()> {
    // the loop's caches are not read again: their memory goes to writing
    syn.release_caches();
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
    if syn.locks_courses() || syn.base_locked_courses {
        w.set_param("courses", Param::Text("locked".into()));
    }
    // the pattern the courses are locked to, for strokes painted later
    let pattern = match (syn.surface.lock.as_deref(), &syn.kept_pattern) {
        (Some(lock), _) => Some((
            lock.pattern.period(),
            lock.pattern.psi().iter().map(|&x| x as f32).collect(),
        )),
        (None, Some(kept)) => Some((kept.period, kept.psi.clone())),
        (None, None) => None,
    };
    if let Some((period, psi)) = pattern {
        let n = psi.len() as u64;
        w.set_param("stripe_period", Param::Float(period));
        let id = w.add_array(ArraySpec::new("stripe_psi", DType::F32, &[n], &[n.min(1 << 16)])?)?;
        w.write_array::<f32>(id, &psi)?;
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
    // in the resampled sample's, for the texels of the active sample)
    let active = state.active;
    let [sx, sy] = syn.scale;
    let scaled = syn.scale != [1.0, 1.0];
    let grid = syn.surface.grid();
    let planar = |name: &str, dtype| ArraySpec::new(name, dtype, &[r, r], &[t, t]);
    let vector = |name: &str, c| ArraySpec::new(name, DType::F32, &[r, r, c], &[t, t, c]);
    let ids = Planes {
        coord: w.add_array(vector("coord", 2)?)?,
        jacobian: w.add_array(vector("jacobian", 4)?)?,
        rotation: w.add_array(planar("rotation", DType::U8)?)?,
        patch: w.add_array(planar("patch", DType::U32)?)?,
        sample: (paths.len() > 1)
            .then(|| w.add_array(planar("sample", DType::U8)?))
            .transpose()?,
        seam: w.add_array(planar("seam", DType::U8)?)?,
        region: matches!((state.constrained, paint_log), (true, Some(_)))
            .then(|| w.add_array(planar("region", DType::F32)?))
            .transpose()?,
    };
    let zippers = gim.zipper_links()?;
    let mut zipper_flag: std::collections::HashMap<u32, u8> = Default::default();
    for &[a, b] in &zippers {
        if state.patch(a) != state.patch(b) {
            zipper_flag.insert(a, SEAM_ZIPPER);
            zipper_flag.insert(b, SEAM_ZIPPER);
        }
    }
    let surface = &syn.surface;
    // each state tile read once (the state pages them) for all its arrays,
    // a batch of tiles at a time compressed in parallel and written in
    // order: the same bytes for any budget and thread count
    let tiles: Vec<usize> = (0..grid.tiles()).collect();
    for batch in tiles.chunks(WRITE_BATCH) {
        let values: Vec<TileValues> = batch
            .iter()
            .map(|&k| {
                let (x0, y0, tw, th) = grid.region(k);
                let mut v = TileValues::with_capacity(tw * th);
                state.tile(k, |s| {
                    for y in 0..th {
                        for x in 0..tw {
                            let i = y * TILE + x;
                            let (c, j) = (s.coord[i], s.jacobian[i]);
                            if scaled && s.source[i] == active {
                                v.coord
                                    .extend([(c[0] as f64 * sx) as f32, (c[1] as f64 * sy) as f32]);
                                v.jacobian.extend([
                                    (j[0] as f64 * sx) as f32,
                                    (j[1] as f64 * sy) as f32,
                                    (j[2] as f64 * sx) as f32,
                                    (j[3] as f64 * sy) as f32,
                                ]);
                            } else {
                                v.coord.extend(c);
                                v.jacobian.extend(j);
                            }
                            v.rotation.push(s.rotation[i]);
                            v.patch.push(s.patch[i]);
                            v.sample.push(s.source[i]);
                            v.region.push(s.target[i]);
                        }
                    }
                });
                // (the patch ids of +x/+y neighbours may sit in the next tiles)
                for y in 0..th {
                    for x in 0..tw {
                        let texel = ((y0 + y) * grid.r + x0 + x) as u32;
                        v.seam.push(
                            seam_flags_at(surface, v.patch[y * tw + x], texel, grid.r, state)
                                | zipper_flag.get(&texel).copied().unwrap_or(0),
                        );
                    }
                }
                v
            })
            .collect();
        let level = w.level();
        let encoded: Vec<Vec<(ArrayId, EncodedChunk)>> =
            values.par_iter().map(|v| v.encode(&ids, level)).collect();
        for (&k, chunks) in batch.iter().zip(encoded) {
            for (id, e) in chunks {
                w.write_encoded(id, k as u64, e)?;
            }
        }
    }
    w.finish()
}

/// The per-texel arrays of a `.quilt` (`sample` and `region` only where
/// they are written).
struct Planes {
    coord: ArrayId,
    jacobian: ArrayId,
    rotation: ArrayId,
    patch: ArrayId,
    sample: Option<ArrayId>,
    seam: ArrayId,
    region: Option<ArrayId>,
}

/// The values of one atlas tile for each of [`Planes`], row-major over the
/// tile's region.
struct TileValues {
    coord: Vec<f32>,
    jacobian: Vec<f32>,
    rotation: Vec<u8>,
    patch: Vec<u32>,
    sample: Vec<u8>,
    seam: Vec<u8>,
    region: Vec<f32>,
}

impl TileValues {
    fn with_capacity(n: usize) -> TileValues {
        TileValues {
            coord: Vec::with_capacity(2 * n),
            jacobian: Vec::with_capacity(4 * n),
            rotation: Vec::with_capacity(n),
            patch: Vec::with_capacity(n),
            sample: Vec::with_capacity(n),
            seam: Vec::with_capacity(n),
            region: Vec::with_capacity(n),
        }
    }

    /// The tile's chunk of each array, in the order the arrays were declared.
    fn encode(&self, ids: &Planes, level: i32) -> Vec<(ArrayId, EncodedChunk)> {
        let mut out = vec![
            (ids.coord, codec::encode(&self.coord, level)),
            (ids.jacobian, codec::encode(&self.jacobian, level)),
            (ids.rotation, codec::encode(&self.rotation, level)),
            (ids.patch, codec::encode(&self.patch, level)),
        ];
        if let Some(id) = ids.sample {
            out.push((id, codec::encode(&self.sample, level)));
        }
        out.push((ids.seam, codec::encode(&self.seam, level)));
        if let Some(id) = ids.region {
            out.push((id, codec::encode(&self.region, level)));
        }
        out
    }
}

/// Records a file the quilt at `out` depends on under `role` (a parameter of
/// that name): its path relative to the quilt's folder (so the quilt and its
/// inputs can move together, and be read from any working directory), its
/// length (`ROLE_bytes`) and its content hash (an input of that name).
fn record_dependency(w: &mut ContainerWriter, out: &Path, role: &str, path: &Path) -> Result<()> {
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

/// Atlas tiles gathered before compressing them in parallel.
const WRITE_BATCH: usize = 64;
