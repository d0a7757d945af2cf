//! Verbatim copy (§IV): the sample pasted as it is, without a cut, at a
//! point of the surface; the fast preview of painting.

use super::*;

impl Synthesis {
    /// Verbatim copy (§IV): the sample's foreground, its point `centre`
    /// (unrotated sample pixels) put on dense vertex `v`, turned by `angle`
    /// (radians) from the field direction, over a work patch of `radius`.
    /// On a surface with locked courses a copy along the field (`angle`
    /// 0) is locked like a tiling patch: moved across the rows by under
    /// half a course (or a course more, [`lock_courses`]) and its rows put
    /// on their phase; a turned copy is placed as given. With `preview`,
    /// only computes the direct projection (no graphcut: the
    /// foreground pasted over the old colours in the patch's atlas box) and
    /// returns it; otherwise merges it with a graphcut seam: foreground
    /// texels are forced to the copy, the rest chooses by the smoothness
    /// term. Returns the foreground texels the copy covers.
    pub(crate) fn verbatim(
        &mut self,
        v: u32,
        radius: usize,
        angle: f64,
        centre: [f64; 2],
        preview: bool,
        progress: &dyn Progress,
    ) -> Result<(usize, Option<Projection>)> {
        let t0 = Instant::now();
        let trace = |what: &str| crate::progress::trace(progress, t0, &format!("verbatim {what}"));
        let patch = self.bfs.patch(&self.surface, v, radius);
        trace("work patch");
        let locked = angle == 0.0 && self.surface.lock.is_some();
        // (a free preview reads only the work coordinates)
        let (work, coords, field) = if preview && !locked {
            let (coords, field) = crate::quilt::flatten::work_coords(
                &self.surface,
                &patch,
                &self.bfs,
                &self.zipper_triangles,
                self.cfg.max_distortion,
            );
            (None, coords, field)
        } else {
            let (mut work, _) = self.worker().work_image(&patch, &mut None);
            if !locked {
                // a turned copy keeps its own rows
                work.course_phase.clear();
            }
            let (coords, field) = (work.coords.clone(), work.angle);
            (Some(work), coords, field)
        };
        trace("work image");
        let rotations = self.sample.rotations;
        let rotation = rotation_index(field + angle, rotations);
        let turn = Turn::new(&self.sample, rotation);
        let [dx, dy] = turn.placing(coords[0], centre);
        let mut placement = PlacementChoice { rotation, dx, dy };
        // (a work image keeps its course phase only when locked)
        let course_phase: &[f64] = work.as_ref().map_or(&[], |w| &w.course_phase);
        if let Some(work) = &work {
            placement = lock_courses(&self.sample, work, &placement).unwrap_or(placement);
        }
        let placed = placed_on_sample(&self.sample, &placement, &coords, course_phase);
        let fg: Vec<f32> = placed.iter().map(|&c| self.sample.mask_at(c)).collect();
        trace("placed");
        if preview {
            let colours = self.sample.svd.preview()?;
            let r = self.surface.r;
            let (x0, y0, w, h) = patch.atlas_box(r);
            let mut data = vec![0f32; w * h * 3];
            let mut covered = vec![false; w * h];
            // the surface as it is, a state tile at a time
            let grid = self.surface.grid();
            let (ty0, ty1) = (y0 / TILE, (y0 + h - 1) / TILE);
            let (tx0, tx1) = (x0 / TILE, (x0 + w - 1) / TILE);
            for k in (ty0..=ty1).flat_map(|ty| (tx0..=tx1).map(move |tx| ty * grid.across + tx)) {
                let (kx, ky, kw, kh) = grid.region(k);
                let (ax0, ax1) = (kx.max(x0), (kx + kw).min(x0 + w));
                let (ay0, ay1) = (ky.max(y0), (ky + kh).min(y0 + h));
                self.state.tile(k, |s| {
                    for ay in ay0..ay1 {
                        for ax in ax0..ax1 {
                            let i = (ay - ky) * TILE + (ax - kx);
                            if !s.synthesized[i] {
                                continue;
                            }
                            let c = s.coord[i];
                            let from = self.other_previews.get(s.source[i] as usize);
                            let col = crate::io::imageio::bilinear(
                                from.and_then(Option::as_ref).unwrap_or(&colours),
                                c[0],
                                c[1],
                            );
                            let o = (ay - y0) * w + ax - x0;
                            data[o * 3..o * 3 + 3].copy_from_slice(&col);
                            covered[o] = true;
                        }
                    }
                });
            }
            for (i, &t) in patch.texels.iter().enumerate() {
                if fg[i] >= 0.5 {
                    let (x, y) = (t as usize % r - x0, t as usize / r - y0);
                    let col =
                        crate::io::imageio::bilinear(&colours, placed[i][0] as f32, placed[i][1] as f32);
                    data[(y * w + x) * 3..(y * w + x) * 3 + 3].copy_from_slice(&col);
                    covered[y * w + x] = true;
                }
            }
            trace("projected");
            let image = crate::io::imageio::RgbImage {
                width: w,
                height: h,
                data,
            };
            let taken = fg.iter().filter(|&&m| m >= 0.5).count();
            return Ok((
                taken,
                Some(Projection {
                    x0,
                    y0,
                    image,
                    covered,
                }),
            ));
        }
        // m0 = the placed foreground on the patch, 0 elsewhere
        self.state.constrain_everywhere(0.0);
        for (i, &t) in patch.texels.iter().enumerate() {
            self.state.texel_mut(t, |s, k| s.target[k] = fg[i]);
        }
        let work = work.expect("a merge has its work image");
        let t = Instant::now();
        let fit = fit_patch(
            &self.sample,
            &self.state,
            &self.surface,
            &patch,
            &work,
            &placement,
            INFINITE.sqrt(),
            false,
            0,
            (0.0, self.reference),
        );
        self.report.graphcut_seconds += t.elapsed().as_secs_f64();
        self.accept(&patch, &fit, progress);
        Ok((fit.taken, None))
    }
}
