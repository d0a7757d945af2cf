//! Loading a quilt into the synthesis state (a painted surface starts from
//! its base) and writing the state back as a quilt.

use super::*;

impl Synthesis {
    /// Starts from a decorated surface: its coordinates, rotations, patch
    /// ids, Jacobians and sample indices. The features are looked up in each
    /// texel's own sample; texels of another sample than the one opened
    /// (painting with a new sample) are projected into its basis, g ↦ P_aᵀ
    /// P_k g (both appearance bases orthonormal, so this is the closest
    /// vector of the active rank-n space to the texel's value), and count as
    /// background (m_σ = 0). The opened sample joins the surface's list if
    /// it is new.
    pub(crate) fn load(&mut self, quilt: &Quilt, progress: &dyn Progress) -> Result<()> {
        let r = self.surface.r;
        if quilt.resolution != r {
            return Err(Error::input(
                quilt.container().path(),
                format!("is {}² but its geometry image is {r}²", quilt.resolution),
            ));
        }
        let mut paths = quilt.samples.clone();
        let active = match paths.iter().position(|p| same_file(p, &self.sample_path)) {
            Some(k) => k,
            None if paths.len() < MAX_SAMPLES => {
                paths.push(self.sample_path.clone());
                paths.len() - 1
            }
            None => {
                return Err(Error::input(
                    quilt.container().path(),
                    format!("already draws from {MAX_SAMPLES} samples, the most one surface can"),
                ))
            }
        };
        let grid = self.surface.grid();
        let mut used = vec![false; paths.len()];
        let [sx, sy] = self.scale;
        let scaled = self.scale != [1.0, 1.0];
        self.state.active = active as u8;
        self.state.remaining = 0;
        let mut next = 0u32;
        for k in 0..grid.tiles() {
            let (x0, y0, w, h) = grid.region(k);
            let q = quilt.texel_region(x0, y0, w, h)?;
            let chart = self.surface.chart_tile(k);
            let (sample, st, used) = (&self.sample, &mut self.state, &mut used);
            let loaded = st.tile_mut(k, |s| -> Result<()> {
                for y in 0..h {
                    for x in 0..w {
                        let (i, j) = (y * TILE + x, y * w + x);
                        if chart[i] == EMPTY {
                            continue;
                        }
                        if q.patch[j] == NO_PATCH {
                            return Err(Error::input(
                                quilt.container().path(),
                                "is not fully decorated (texels without a patch)",
                            ));
                        }
                        s.synthesized[i] = true;
                        s.coord[i] = q.coord[j];
                        s.rotation[i] = q.rotation[j];
                        s.patch[i] = q.patch[j];
                        s.jacobian[i] = q.jacobian[j];
                        if q.sample[j] as usize == active && scaled {
                            // the file holds original sample pixels; the loop
                            // works in the resampled sample's
                            let (c, jc) = (q.coord[j], q.jacobian[j]);
                            s.coord[i] = [(c[0] as f64 / sx) as f32, (c[1] as f64 / sy) as f32];
                            s.jacobian[i] = [
                                (jc[0] as f64 / sx) as f32,
                                (jc[1] as f64 / sy) as f32,
                                (jc[2] as f64 / sx) as f32,
                                (jc[3] as f64 / sy) as f32,
                            ];
                        }
                        s.source[i] = q.sample[j];
                        used[q.sample[j] as usize] = true;
                        next = next.max(q.patch[j] + 1);
                        s.mask[i] = if q.sample[j] as usize != active {
                            0.0
                        } else {
                            sample.mask_at([s.coord[i][0] as f64, s.coord[i][1] as f64])
                        };
                    }
                }
                Ok(())
            });
            loaded?;
            self.state.refresh_frontier(&self.surface, &[k]);
        }
        // the other samples the surface shows, with their projections into
        // the active basis
        let mut others: Vec<Option<ForeignSample>> = (0..paths.len()).map(|_| None).collect();
        let mut previews = vec![None; paths.len()];
        let active_p = self.sample.svd.appearance()?;
        for k in (0..paths.len()).filter(|&k| used[k] && k != active) {
            let (svd_path, _tmp) = sample_svd(quilt.sample_file(k)?, false, self.cfg.memory, progress)?;
            // (its arrays are read whole, once: no chunk is worth caching)
            let svd = SvdArtifact::open(&svd_path, MemoryBudget(0))?;
            crate::artifact::svd::same_directions(&self.sample.svd, &svd)?;
            let projection =
                basis_projection(&active_p, self.sample.svd.terms, &svd.appearance()?, svd.terms);
            previews[k] = Some(svd.preview()?);
            // only their unrotated maps are read: no rotated copy is cached
            others[k] = Some(ForeignSample {
                sample: Sample::from_svd(svd, MemoryBudget(0))?,
                projection,
            });
        }
        let st = &mut self.state;
        st.foreign = std::sync::Arc::new(others);
        st.next_patch = next;
        self.sample_spans = (0..paths.len()).map(|k| quilt.sample_span(k)).collect();
        self.sample_paths = paths;
        self.other_previews = previews;
        Ok(())
    }

    /// Writes the state as a `.quilt` (see [`tile`](crate::quilt::tile)); `paint_log` for a
    /// painted surface.
    pub(crate) fn write(
        &mut self,
        out: &Path,
        gim: &Gim,
        gim_path: &Path,
        paint_log: Option<&str>,
        start: Instant,
    ) -> Result<TileReport> {
        self.finish_report(start);
        let report = self.report.clone();
        write_quilt(out, &self.cfg, gim, gim_path, self, paint_log, &report)?;
        Ok(report)
    }
}
