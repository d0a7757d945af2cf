//! Runs one parsed command: each arm calls a library stage and prints what
//! it made.

use anyhow::{bail, Context, Result};

use btfquilt::artifact::btf::{self, Btf};
use btfquilt::artifact::gim::Gim;
use btfquilt::artifact::svd::SvdArtifact;
use btfquilt::atlas::{self, AtlasConfig};
use btfquilt::batch;
use btfquilt::container::Container;
use btfquilt::factorize;
use btfquilt::generate;
use btfquilt::ingest::{self, IngestConfig};
use btfquilt::mesh::io::LoadOptions;
use btfquilt::output::render::RenderConfig;
use btfquilt::paint::PaintConfig;
use btfquilt::quilt;
use btfquilt::studio::ServeConfig;
use btfquilt::{
    output::bake, output::compare, output::evaluate, output::export, output::render, output::show,
};

use super::args::{Cli, Command, LISTED_SINGULARITIES};
use super::bars::Bars;

/// Prints quality figures as pretty JSON on stdout.
fn print_json(figures: &impl serde::Serialize) -> Result<()> {
    say!(
        "{}",
        serde_json::to_string_pretty(figures).context("writing the figures as JSON")?
    );
    Ok(())
}

pub(crate) fn run(cli: Cli) -> Result<()> {
    match cli.command {
        Command::Info { file, verify, res } => {
            let (memory, _) = res.apply()?;
            let c = Container::open(&file, memory)?;
            say!("{}", c.describe().trim_end());
            if c.metadata().kind == btf::KIND {
                let b = Btf::open(&file, memory)?;
                let l = b.layout();
                say!(
                    "btf:       {}×{} texels, {} views × {} lights = {} pairs, tile {}, band {}",
                    l.width,
                    l.height,
                    l.views.len(),
                    l.lights.len(),
                    l.pairs(),
                    l.tile,
                    l.band
                );
            }
            if verify {
                c.verify()?;
                say!("verify:    every chunk decodes and matches its checksum");
            }
        }
        Command::GenerateBtf {
            generating,
            output,
            res,
        } => {
            let (memory, bars) = res.apply()?;
            let cfg = generating.generate_config(memory);
            let report = generate::generate_btf(&cfg, &output, &bars)?;
            say!("wrote {} ({})", output.display(), report);
        }
        Command::Ingest { input, output, res } => {
            let (memory, bars) = res.apply()?;
            let cfg = IngestConfig {
                memory,
                ..IngestConfig::default()
            };
            let r = ingest::ingest(&input, &output, &cfg, &bars)?;
            say!(
                "wrote {}: {}×{} texels, {} views × {} lights",
                output.display(),
                r.width,
                r.height,
                r.views,
                r.lights
            );
        }
        Command::ExportBtf {
            file,
            view,
            light,
            output,
            all,
            format,
            res,
        } => {
            let (memory, bars) = res.apply()?;
            let b = Btf::open(&file, memory)?;
            match (all, output) {
                (Some(dir), None) => {
                    let n = ingest::export_all(&b, &dir, format, memory, &bars)?;
                    say!("wrote {n} images and manifest.csv into {}", dir.display());
                }
                (None, Some(out)) => {
                    btfquilt::io::staging::check_output(&out, &[("the BTF", file.as_path())])?;
                    let view = view.context("--view θ,φ is required with -o")?;
                    let light = light.context("--light θ,φ is required with -o")?;
                    let img = ingest::pair_image(&b, view, light)?;
                    btfquilt::io::imageio::write_rgb(&out, &img)?;
                    say!("wrote {}", out.display());
                }
                _ => bail!("give either -o IMAGE (with --view and --light) or --all DIR"),
            }
        }
        Command::Factorize {
            input,
            factorizing,
            output,
            res,
        } => {
            let (memory, bars) = res.apply()?;
            let cfg = factorizing.factorize_config(memory);
            let report = factorize::factorize(&input, &output, &cfg, &bars)?;
            say!("wrote {}: {report}", output.display());
        }
        Command::Reconstruct {
            file,
            view,
            light,
            original,
            output,
            res,
        } => {
            let (memory, _) = res.apply()?;
            let mut inputs = vec![("the factorization", file.as_path())];
            if let Some(o) = &original {
                inputs.push(("the original", o.as_path()));
            }
            btfquilt::io::staging::check_output(&output, &inputs)?;
            let svd = SvdArtifact::open(&file, memory)?;
            let pair = svd.find_pair(view, light)?;
            let img = svd.reconstruct_pair(pair)?;
            btfquilt::io::imageio::write_rgb(&output, &img)?;
            say!("wrote {}", output.display());
            match svd.original_pair(pair, original.as_deref(), memory)? {
                Some(orig) => say!("PSNR {:.2} dB against the original", factorize::psnr(&orig, &img)),
                None => say!("PSNR: the original is not available (give --original FILE)"),
            }
        }
        Command::Atlas {
            mesh,
            resolution,
            gutter,
            field,
            field_exposure,
            weld,
            max_stretch,
            max_area_distortion,
            max_linf_stretch,
            compact,
            output,
            res,
        } => {
            let (_, bars) = res.apply()?;
            let mut cfg = AtlasConfig {
                resolution,
                gutter,
                field_keys: field,
                field_exposure,
                load: LoadOptions { weld_tolerance: weld },
                ..AtlasConfig::default()
            };
            cfg.charts.max_stretch = max_stretch;
            cfg.charts.max_area_distortion = max_area_distortion;
            cfg.charts.max_linf_stretch = max_linf_stretch;
            cfg.charts.compact = compact;
            cfg.validate()?;
            let report = atlas::build_gim(&mesh, &output, &cfg, &bars)?;
            say!("{}: {}", mesh.display(), report.repair);
            say!("wrote {}: {report}", output.display());
            // the most exposed first: the ones a viewer sees
            let mut listed: Vec<_> = report.singularities.iter().collect();
            listed.sort_by(|a, b| b.exposure.total_cmp(&a.exposure).then(a.vertex.cmp(&b.vertex)));
            for s in listed.iter().take(LISTED_SINGULARITIES) {
                let [x, y, z] = s.position;
                say!(
                    "  singularity of index {:+} at vertex {} ({x:.4}, {y:.4}, {z:.4}), exposure {:.2}",
                    s.index,
                    s.vertex,
                    s.exposure
                );
            }
            if listed.len() > LISTED_SINGULARITIES {
                say!(
                    "  … and {} less exposed (`show --what field` rings them all)",
                    listed.len() - LISTED_SINGULARITIES
                );
            }
        }
        Command::Show {
            file,
            what,
            output,
            res,
        } => {
            let (memory, _) = res.apply()?;
            let g = Gim::open(&file, memory)?;
            show::show(&g, what, &output)?;
            say!("wrote {}", output.display());
        }
        Command::Export {
            file,
            format,
            output,
            btf,
            sample,
            res,
        } => {
            let (memory, _) = res.apply()?;
            if output.is_none() && format.is_some() {
                bail!("--format needs -o DIR (the folder for the mesh)");
            }
            let format = format.unwrap_or_default();
            let opts = export::ExportOptions {
                mesh: output.map(|dir| (format, dir)),
                btf,
                sample,
                budget: memory,
            };
            for path in export::export(&file, &opts)? {
                say!("wrote {}", path.display());
            }
        }
        Command::Tile {
            gim,
            sample,
            quilting,
            tiling,
            output,
            res,
        } => {
            let (memory, bars) = res.apply()?;
            let cfg = tiling.tile_config(quilting.tile_config(memory));
            let report = quilt::tile(&gim, &sample, &output, &cfg, &bars)?;
            say!("wrote {}: {report}", output.display());
        }
        Command::Batch {
            plan,
            output,
            shard,
            job,
            stages,
            list,
            json,
            manifest,
            workers,
            res,
        } => {
            let (memory, bars) = res.apply()?;
            if workers == 0 {
                bail!("--workers must be at least 1");
            }
            // one progress bar cannot follow several jobs: their lines only
            let bars = if workers > 1 { Bars::new(true) } else { bars };
            let plan = batch::Plan::load(&plan)?;
            let cfg = batch::BatchConfig {
                shard,
                jobs: job,
                stages,
                manifest,
                memory,
                workers,
            };
            if list && stages == batch::Stages::Shared {
                for (stage, status) in batch::selected_shared(&plan, &output, &cfg) {
                    let status = serde_json::to_value(status)?;
                    let status = status.as_str().unwrap_or_default();
                    if json {
                        let line = serde_json::json!({
                            "shared": stage.key().to_string(),
                            "status": status,
                            "file": stage.file(),
                        });
                        say!("{line}");
                    } else {
                        say!("{}  {status:4}  {}", stage.key(), stage.file());
                    }
                }
                return Ok(());
            }
            if list {
                for (job, status) in batch::selected_jobs(&plan, &output, &cfg)? {
                    let what = job.describe(&plan);
                    if json {
                        let line = serde_json::json!({
                            "job": job.key.to_string(),
                            "status": status,
                            "folder": job.dir(),
                            "what": what,
                        });
                        say!("{line}");
                    } else {
                        let status = serde_json::to_value(status)?;
                        say!("{}  {:4}  {what}", job.key, status.as_str().unwrap_or_default());
                    }
                }
                return Ok(());
            }
            let report = batch::run(&plan, &output, &cfg, &bars)?;
            say!("{}: {report}", output.display());
            if !report.failed.is_empty() {
                for (key, why) in &report.failed {
                    eprintln!("failed: {key}: {why}");
                }
                bail!(
                    "{} of the batch's jobs or shared stages failed (see {})",
                    report.failed.len(),
                    cfg.manifest
                        .unwrap_or_else(|| output.join("manifest.jsonl"))
                        .display()
                );
            }
        }
        Command::Serve {
            file,
            port,
            bind,
            workers,
            sample,
            sample_mask,
            res,
        } => {
            let (memory, _) = res.apply()?;
            if !sample_mask.is_empty() && sample_mask.len() != sample.len() {
                anyhow::bail!(
                    "{} --sample-mask for {} --sample: give one mask per sample, or none",
                    sample_mask.len(),
                    sample.len()
                );
            }
            let mut masks = sample_mask.into_iter().map(Some);
            let samples = sample.into_iter().map(|s| (s, masks.next().flatten())).collect();
            let cfg = ServeConfig {
                bind,
                port,
                workers,
                memory,
                samples,
            };
            let server = btfquilt::studio::Studio::start(&file, &cfg)?;
            stop_on_signal(server.stop_handle())?;
            println!("studio for {} at {}", file.display(), server.url());
            server.wait();
            eprintln!("studio stopped; its work files are removed");
        }
        Command::Paint {
            file,
            sample,
            sample_mask,
            region,
            transition,
            verbatim,
            at,
            angle,
            preview,
            courses,
            quilting,
            output,
            res,
        } => {
            let (memory, bars) = res.apply()?;
            let verbatim = if verbatim {
                let at = at.ok_or_else(|| anyhow::anyhow!("--verbatim needs --at x,y,z"))?;
                Some(btfquilt::paint::Verbatim { at, angle })
            } else {
                if at.is_some() {
                    anyhow::bail!("--at is for --verbatim");
                }
                None
            };
            if output.is_none() && preview.is_none() {
                anyhow::bail!("give -o OUTPUT.quilt (or --preview IMAGE with --verbatim)");
            }
            let cfg = PaintConfig {
                sample,
                sample_mask,
                region,
                transition,
                verbatim,
                preview: preview.clone(),
                courses,
                tile: quilting.tile_config(memory),
            };
            if let Some(p) = &preview {
                let t = std::time::Instant::now();
                let report = btfquilt::paint::preview(&file, &cfg, &bars)?;
                say!(
                    "wrote {} ({} foreground texels; projection {:.1} ms, {:.0} ms with opening the artifacts)",
                    p.display(),
                    report.region_texels,
                    report.projection_seconds * 1e3,
                    t.elapsed().as_secs_f64() * 1e3
                );
            }
            if let Some(out) = output {
                let cfg = PaintConfig { preview: None, ..cfg };
                let report = btfquilt::paint::paint(&file, &out, &cfg, &bars)?;
                say!("wrote {}: {report}", out.display());
            }
        }
        Command::Replay { file, output, res } => {
            let (memory, bars) = res.apply()?;
            let report = btfquilt::paint::replay(&file, &output, memory, &bars)?;
            say!("wrote {}: {report}", output.display());
        }
        Command::Bake {
            file,
            sample,
            output,
            res,
        } => {
            let (memory, _) = res.apply()?;
            bake::bake(&file, sample.as_deref(), &output, memory)?;
            say!("wrote {}", output.display());
        }
        Command::Evaluate {
            file,
            gim,
            sample,
            windows,
            forced_ends,
            res,
        } => {
            let (memory, _) = res.apply()?;
            let cfg = evaluate::EvaluateConfig {
                memory,
                windows,
                forced_ends,
            };
            print_json(&evaluate::evaluate_with(
                &file,
                gim.as_deref(),
                sample.as_deref(),
                &cfg,
            )?)?;
        }
        Command::Compare { image, sample, res } => {
            let (memory, _) = res.apply()?;
            print_json(&compare::compare(&image, &sample, memory)?)?;
        }
        Command::Render {
            file,
            camera,
            light,
            point_light,
            orbit_light,
            exposure,
            width,
            height,
            output,
            res,
        } => {
            let (memory, _bars) = res.apply()?;
            let mut lights = light;
            lights.extend(point_light);
            if lights.is_empty() {
                lights = RenderConfig::default().lights;
            }
            let cfg = RenderConfig {
                camera,
                lights,
                width,
                height,
                exposure,
            };
            match orbit_light {
                Some(frames) => {
                    for p in render::render_frames(&file, &cfg, frames, &output, memory)? {
                        say!("wrote {}", p.display());
                    }
                }
                None => {
                    render::render(&file, &cfg, &output, memory)?;
                    say!("wrote {}", output.display());
                }
            }
        }
        Command::Demo { output, res } => {
            let (memory, bars) = res.apply()?;
            let report = btfquilt::demo::run(&output, memory, &bars)?;
            say!("{report}");
        }
    }
    Ok(())
}

/// Ctrl-C (SIGINT), SIGTERM or SIGHUP stops the studio the way its own stop
/// does: requests being answered finish and the work files beside the
/// surface go. A second signal ends the process at once (its work files
/// are then removed by the next studio on that surface).
#[cfg(unix)]
fn stop_on_signal(handle: btfquilt::studio::StopHandle) -> Result<()> {
    use signal_hook::consts::{SIGHUP, SIGINT, SIGTERM};
    let mut signals =
        signal_hook::iterator::Signals::new([SIGINT, SIGTERM, SIGHUP]).context("cannot watch for Ctrl-C")?;
    std::thread::spawn(move || {
        let mut received = signals.forever();
        if received.next().is_some() {
            eprintln!("stopping the studio (again to quit at once)");
            handle.stop();
        }
        if received.next().is_some() {
            std::process::exit(130);
        }
    });
    Ok(())
}

/// (Elsewhere the process ends as the system ends it; the next studio on
/// the surface removes the work files.)
#[cfg(not(unix))]
fn stop_on_signal(_: btfquilt::studio::StopHandle) -> Result<()> {
    Ok(())
}
