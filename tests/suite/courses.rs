//! Courses across seams (`evaluate`'s `courses`): a brick wall tiled on a
//! flat square keeps its courses; a sample without rows reports none; the
//! field of a flat square forces no course end.

use std::path::Path;

use crate::common::{btfquilt, fails_clearly, ok, s, square_obj};

#[test]
fn courses_run_on_across_the_seams_of_a_flat_wall() {
    let dir = tempfile::tempdir().unwrap();
    let gim = dir.path().join("square.gim");
    crate::common::atlas(&square_obj(dir.path()), 160, &gim);
    let data = Path::new(env!("CARGO_MANIFEST_DIR")).join("data");
    let tile = |sample: &str, out: &str| {
        let (sample, quilt) = (data.join(sample), dir.path().join(out));
        crate::common::tile(&gim, &sample, &quilt);
        quilt
    };
    let wall = tile("brick_wall.png", "wall.quilt");
    let doc: serde_json::Value = serde_json::from_str(&ok(&["evaluate", s(&wall), "--forced-ends"])).unwrap();
    let c = &doc["courses"];
    // the wall has ten courses of 19.2 pixels on average
    assert_eq!(c["courses_in_sample"].as_u64(), Some(10), "{c}");
    assert!((c["period_px"].as_f64().unwrap() - 19.2).abs() < 1e-9, "{c}");
    assert!(c["seam_edges"].as_u64().unwrap() > 1000, "{c}");
    // matching over translations lines the courses up where patches meet
    assert!(c["offset_share"].as_f64().unwrap() < 0.02, "{c}");
    assert_eq!(c["ends"].as_u64(), Some(0), "{c}");
    // a constant field on a plane lets every course run on
    assert_eq!(c["forced_ends"].as_u64(), Some(0), "{c}");
    // without the flag the same figures, without the stripe solve
    let plain: serde_json::Value = serde_json::from_str(&ok(&["evaluate", s(&wall)])).unwrap();
    assert!(plain["courses"].get("forced_ends").is_none());
    assert_eq!(plain["courses"]["ends"], c["ends"]);
    assert_eq!(plain["courses"]["offset_share"], c["offset_share"]);
    // the solve refuses a budget it does not fit in, and says what to do
    let said = fails_clearly(
        &btfquilt(&["evaluate", s(&wall), "--forced-ends", "--memory", "4MiB"]),
        &["of --memory 4MiB: give --memory"],
    );
    let enough = enough_memory(&said);
    let again: serde_json::Value =
        serde_json::from_str(&ok(&["evaluate", s(&wall), "--forced-ends", "--memory", &enough])).unwrap();
    assert_eq!(
        again["courses"]["forced_ends"], c["forced_ends"],
        "--memory {enough}"
    );
    // plaster has no rows
    let plaster = tile("plaster_cracks.png", "plaster.quilt");
    let doc: serde_json::Value =
        serde_json::from_str(&ok(&["evaluate", s(&plaster), "--forced-ends"])).unwrap();
    assert!(doc.get("courses").is_none(), "{doc}");
}

/// `tile --courses locked` on a curved surface (Spot at 256², the wall 1.4
/// mesh units wide, about 8 texels a course): courses run on across the
/// seams and end only where the field forces them (`evaluate
/// --forced-ends`), where free placement offsets a fifth of the seam edges
/// and ends about twice as many; the patches are bent, never mirrored; the
/// quilt is the same for any thread count or budget; a sample without rows
/// and a budget too small for the pattern are refused before anything is
/// written.
#[test]
fn locked_courses_end_only_where_the_field_forces_them() {
    let dir = tempfile::tempdir().unwrap();
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("data");
    let gim = dir.path().join("spot.gim");
    crate::common::atlas(&root.join("spot_5.8k.obj"), 256, &gim);
    let wall = root.join("brick_wall.png");
    let tile = |mode: &str, name: &str, extra: &[&str]| {
        let quilt = dir.path().join(name);
        let mut args = vec![
            "tile",
            "--gim",
            s(&gim),
            "--sample",
            s(&wall),
            "--sample-width",
            "1.4",
            "--courses",
            mode,
            "-q",
            "-o",
            s(&quilt),
        ];
        args.extend_from_slice(extra);
        let report = ok(&args);
        (quilt, report)
    };
    let courses = |quilt: &Path| {
        let doc: serde_json::Value =
            serde_json::from_str(&ok(&["evaluate", s(quilt), "--forced-ends", "-q"])).unwrap();
        let c = &doc["courses"];
        let f = |k: &str| c[k].as_f64().unwrap_or_else(|| panic!("{k} in {c}"));
        (f("offset_share"), f("ends"), f("forced_ends"))
    };
    // what locking does alone: refinement where features end, which mends
    // free courses' offsets too, off on both sides
    let alone = ["--refine-broken", "0"];
    let (locked, report) = tile("locked", "locked.quilt", &alone);
    let (offset, ends, forced) = courses(&locked);
    // the report names the pattern's ends: those of `--forced-ends` at the
    // period tile measured (evaluate measures it on the quilt)
    let said: f64 = report
        .split("stripe pattern that ends ")
        .nth(1)
        .and_then(|r| r.split_whitespace().next())
        .and_then(|n| n.parse().ok())
        .unwrap_or_else(|| panic!("no pattern ends in: {report}"));
    assert!(
        (said - forced).abs() <= 0.1 * forced,
        "the report says {said}, evaluate {forced}"
    );
    assert!(forced > 20.0, "Spot's field must end some courses: {forced}");
    assert!(
        offset < 0.02,
        "locked: {:.1} % of seam edges offset",
        100.0 * offset
    );
    assert!(
        ends <= 1.1 * forced,
        "locked: {ends} ends against {forced} forced"
    );
    let (free, report) = tile("free", "free.quilt", &alone);
    assert!(!report.contains("stripe pattern"), "{report}");
    let (free_offset, free_ends, _) = courses(&free);
    assert!(
        free_offset > 10.0 * offset.max(0.001),
        "free {free_offset} against locked {offset}"
    );
    assert!(
        free_ends > 1.5 * ends,
        "free {free_ends} ends against locked {ends}"
    );
    // bent, not mirrored: the sample's rows turn with the atlas (the
    // Jacobian's determinant keeps its sign but where a patch's phase is
    // cut around one of the pattern's ends)
    let budget = btfquilt::container::MemoryBudget::default();
    let jacobians = btfquilt::artifact::quilt::Quilt::open(&locked, budget)
        .unwrap()
        .jacobians()
        .unwrap();
    let dets: Vec<f32> = jacobians
        .iter()
        .map(|j| j[0] * j[3] - j[1] * j[2])
        .filter(|d| *d != 0.0)
        .collect();
    let mirrored = dets.iter().filter(|&&d| d < 0.0).count();
    assert!(dets.len() > 30_000, "{} texels", dets.len());
    assert!(
        mirrored * 50 < dets.len(),
        "{mirrored} of {} texels mirrored",
        dets.len()
    );
    // the recipe, not the machine: one thread or a small budget
    let bytes = std::fs::read(&locked).unwrap();
    let (one, _) = tile("locked", "one.quilt", &["--threads", "1", alone[0], alone[1]]);
    assert!(
        std::fs::read(one).unwrap() == bytes,
        "--threads 1 changed the quilt"
    );
    let (small, _) = tile(
        "locked",
        "small.quilt",
        &["--memory", "48MiB", alone[0], alone[1]],
    );
    assert!(
        std::fs::read(small).unwrap() == bytes,
        "--memory 48MiB changed the quilt"
    );
    // refused: a sample without rows, a budget the pattern's solve exceeds
    let refused = dir.path().join("refused.quilt");
    let plaster = root.join("plaster_cracks.png");
    let args = |sample: &Path, memory: &str| -> Vec<String> {
        [
            "tile",
            "--gim",
            s(&gim),
            "--sample",
            s(sample),
            "--sample-width",
            "1.4",
            "--courses",
            "locked",
            alone[0],
            alone[1],
            "--memory",
            memory,
            "-q",
            "-o",
            s(&refused),
        ]
        .map(String::from)
        .to_vec()
    };
    let run = |a: Vec<String>| btfquilt(&a.iter().map(String::as_str).collect::<Vec<_>>());
    fails_clearly(
        &run(args(&plaster, "1GiB")),
        &["plaster_cracks.png", "has no courses", "--courses locked"],
    );
    let said = fails_clearly(
        &run(args(&wall, "8MiB")),
        &["locking the courses", "of --memory 8MiB: give --memory"],
    );
    assert!(!refused.exists());
    // the --memory it names is enough, and gives the same quilt
    let enough = enough_memory(&said);
    assert!(run(args(&wall, &enough)).status.success(), "--memory {enough}");
    assert!(
        std::fs::read(&refused).unwrap() == bytes,
        "--memory {enough} changed the quilt"
    );
}

/// Painting a surface tiled with locked courses (Spot at 256², the wall
/// 1.4 mesh units wide) with the tiling's sample locks the stroke to the
/// same stripe pattern: the painted region's seams offset no more courses
/// than the tiling's, where a free stroke offsets many; the painted quilt
/// keeps the lock and the pattern for later strokes, replays byte for
/// byte and is the same for any thread count or budget; `--courses
/// locked` is refused where there is no pattern to lock to, and a stored
/// pattern that does not fit the atlas is refused naming the quilt.
#[test]
fn painting_a_locked_surface_keeps_its_courses() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("data");
    let gim = d.join("spot.gim");
    crate::common::atlas(&root.join("spot_5.8k.obj"), 256, &gim);
    let wall = root.join("brick_wall.png");
    let tile = |mode: &str, name: &str| {
        let quilt = d.join(name);
        #[rustfmt::skip]
        ok(&["tile", "--gim", s(&gim), "--sample", s(&wall), "--sample-width", "1.4",
             "--courses", mode, "-q", "-o", s(&quilt)]);
        quilt
    };
    let base = tile("locked", "base.quilt");
    // the foreground: the sample's left half; the region: a disk on the flank
    let mask = d.join("mask.png");
    crate::common::write_mask_png(&mask, 192, 192, |x, _| x < 96);
    let region = d.join("flank.json");
    std::fs::write(&region, r#"[{"point": [0.35, 0.0, 0.45], "radius": 0.4}]"#).unwrap();
    let paint = |name: &str, extra: &[&str]| {
        let out = d.join(name);
        #[rustfmt::skip]
        let mut args = vec!["paint", s(&base), "--sample-mask", s(&mask), "-q", "-o", s(&out)];
        args.extend_from_slice(extra);
        (out.clone(), btfquilt(&args))
    };
    let offsets = |quilt: &Path| {
        let doc: serde_json::Value = serde_json::from_str(&ok(&["evaluate", s(quilt), "-q"])).unwrap();
        let c = &doc["courses"];
        let f = |k: &str| c[k].as_f64().unwrap_or_else(|| panic!("{k} in {c}"));
        f("offset_share") * f("seam_edges")
    };
    let at_region = ["--region", s(&region)];
    let (locked, run) = paint("locked.quilt", &at_region);
    let report = String::from_utf8_lossy(&run.stdout).to_string();
    assert!(run.status.success(), "{}", String::from_utf8_lossy(&run.stderr));
    assert!(report.contains("courses locked"), "{report}");
    let (free, run) = paint("free.quilt", &[&at_region[..], &["--courses", "free"]].concat());
    assert!(run.status.success(), "{}", String::from_utf8_lossy(&run.stderr));
    assert!(!String::from_utf8_lossy(&run.stdout).contains("courses locked"));
    let (before, after_locked, after_free) = (offsets(&base), offsets(&locked), offsets(&free));
    eprintln!("offset seam edges: base {before}, painted locked {after_locked}, free {after_free}");
    assert!(
        after_free > before + 20.0,
        "a free stroke must offset courses here: {before} → {after_free}"
    );
    assert!(
        after_locked - before <= 0.2 * (after_free - before),
        "locked stroke: {before} → {after_locked} offset seam edges (free: {after_free})"
    );
    // a verbatim copy along the field is locked too; a free one offsets
    let copy = ["--verbatim", "--at", "0.35,0,0.45"];
    let (copied, run) = paint("copy.quilt", &copy);
    assert!(
        String::from_utf8_lossy(&run.stdout).contains("courses locked"),
        "{run:?}"
    );
    let (copied_free, run) = paint("copy_free.quilt", &[&copy[..], &["--courses", "free"]].concat());
    assert!(run.status.success(), "{}", String::from_utf8_lossy(&run.stderr));
    let (copy_locked, copy_free) = (offsets(&copied), offsets(&copied_free));
    eprintln!("verbatim: base {before}, locked {copy_locked}, free {copy_free}");
    assert!(
        copy_free > before + 20.0 && copy_locked - before <= 0.2 * (copy_free - before),
        "verbatim copy: {before} → {copy_locked} locked, {copy_free} free"
    );
    // another sample whose courses fit the stored pattern (the wall with
    // a box of bricks darkened, at the tiling's width by default: it has
    // the wall's pixel size) locks to it too; `evaluate` counts its texels
    // in its own courses
    let twin = d.join("twin.png");
    let mut image = btfquilt::io::imageio::read_rgb(&wall).unwrap();
    for y in 50..140 {
        for x in 40..150 {
            let i = (y * image.width + x) * 3;
            image.data[i..i + 3].iter_mut().for_each(|v| *v *= 0.7);
        }
    }
    btfquilt::io::imageio::write_png(&twin, &image, btfquilt::io::imageio::PngDepth::Eight).unwrap();
    let with_twin = |name: &str, extra: &[&str]| {
        let (painted, run) = paint(name, &[&at_region[..], &["--sample", s(&twin)], extra].concat());
        assert!(run.status.success(), "{}", String::from_utf8_lossy(&run.stderr));
        (
            offsets(&painted),
            String::from_utf8_lossy(&run.stdout).contains("courses locked"),
        )
    };
    let ((twin_locked, said_locked), (twin_free, said_free)) = (
        with_twin("twin.quilt", &[]),
        with_twin("twin_free.quilt", &["--courses", "free"]),
    );
    eprintln!("another sample: base {before}, locked {twin_locked}, free {twin_free}");
    assert!(said_locked && !said_free);
    let (given, run) = paint(
        "twin_given.quilt",
        &[&at_region[..], &["--sample", s(&twin), "--sample-width", "1.4"]].concat(),
    );
    assert!(run.status.success(), "{}", String::from_utf8_lossy(&run.stderr));
    assert!(
        std::fs::read(&given).unwrap() == std::fs::read(d.join("twin.quilt")).unwrap(),
        "a twin without --sample-width takes the tiling's width"
    );
    assert!(
        twin_free > before + 20.0 && twin_locked - before <= 0.2 * (twin_free - before),
        "another sample: {before} → {twin_locked} locked, {twin_free} free"
    );
    // at a width whose courses do not fit the pattern: free by default,
    // refused locked
    let (_, run) = paint(
        "twin_wide.quilt",
        &[&at_region[..], &["--sample", s(&twin), "--sample-width", "1.6"]].concat(),
    );
    assert!(run.status.success() && !String::from_utf8_lossy(&run.stdout).contains("courses locked"));
    // a copy turned from the field keeps its own rows: refused locked
    let (turned, run) = paint(
        "turned.quilt",
        &[&copy[..], &["--angle", "30", "--courses", "locked"]].concat(),
    );
    fails_clearly(&run, &["--angle", "--courses free"]);
    assert!(!turned.exists());
    // the painted surface keeps the lock and its stored pattern, whatever
    // the stroke's courses
    let budget = btfquilt::container::MemoryBudget::default();
    let open = |q: &Path| btfquilt::artifact::quilt::Quilt::open(q, budget).unwrap();
    let pattern = open(&base)
        .stripe_pattern()
        .unwrap()
        .expect("a locked tiling stores its pattern");
    for q in [&locked, &free] {
        assert!(open(q).locked_courses(), "{}", q.display());
        assert!(
            open(q).stripe_pattern().unwrap() == Some(pattern.clone()),
            "{}",
            q.display()
        );
    }
    // the recipe, not the machine; and the paint log replays it
    let bytes = std::fs::read(&locked).unwrap();
    let (one, run) = paint(
        "one.quilt",
        &[&at_region[..], &["--threads", "1", "--memory", "64MiB"]].concat(),
    );
    assert!(run.status.success(), "{}", String::from_utf8_lossy(&run.stderr));
    assert!(
        std::fs::read(one).unwrap() == bytes,
        "--threads 1 --memory 64MiB changed the stroke"
    );
    let replayed = d.join("replayed.quilt");
    ok(&["replay", s(&locked), "-q", "-o", s(&replayed)]);
    assert!(std::fs::read(&replayed).unwrap() == bytes, "the replay differs");
    // refused: another width (another pattern), a surface tiled free
    let (refused, run) = paint(
        "refused.quilt",
        &[&at_region[..], &["--courses", "locked", "--sample-width", "1.3"]].concat(),
    );
    fails_clearly(
        &run,
        &["brick_wall.png", "off the stripe pattern", "--courses free"],
    );
    let free_base = tile("free", "free_base.quilt");
    #[rustfmt::skip]
    let run = btfquilt(&["paint", s(&free_base), "--region", s(&region), "--sample-mask", s(&mask),
                         "--courses", "locked", "-q", "-o", s(&refused)]);
    fails_clearly(&run, &["free_base.quilt", "was not tiled with --courses locked"]);
    // a stored pattern that does not fit the atlas (a damaged quilt)
    let damaged = d.join("damaged.quilt");
    shorten_stripe_pattern(&base, &damaged);
    #[rustfmt::skip]
    let run = btfquilt(&["paint", s(&damaged), "--region", s(&region), "--sample-mask", s(&mask),
                         "-q", "-o", s(&refused)]);
    fails_clearly(
        &run,
        &["damaged.quilt", "stripe pattern", "does not fit its atlas"],
    );
    assert!(!refused.exists());
}

/// A copy of the quilt `src` at `out` whose stored stripe pattern lacks
/// its last vertex; everything else as it is.
fn shorten_stripe_pattern(src: &Path, out: &Path) {
    use btfquilt::container::{Container, ContainerWriter, DType, MemoryBudget};
    let c = Container::open(src, MemoryBudget::default()).unwrap();
    let m = c.metadata();
    let mut w = ContainerWriter::create(out, &m.kind).unwrap();
    if let Some(seed) = m.seed {
        w.set_seed(seed);
    }
    for i in &m.inputs {
        w.add_input(&i.name, i.hash);
    }
    for (k, v) in &m.params {
        w.set_param(k, v.clone());
    }
    for spec in &m.arrays {
        let id = c.array(&spec.name).unwrap();
        let mut spec = spec.clone();
        if spec.name == "stripe_psi" {
            spec.shape[0] -= 2;
            spec.chunk_shape[0] = spec.chunk_shape[0].min(spec.shape[0]);
        }
        let to = w.add_array(spec.clone()).unwrap();
        match spec.dtype {
            DType::F32 => {
                let mut v = c.read_array::<f32>(id).unwrap();
                v.truncate(spec.shape[0] as usize * spec.shape[1..].iter().product::<u64>() as usize);
                w.write_array(to, &v).unwrap()
            }
            DType::U32 => w.write_array(to, &c.read_array::<u32>(id).unwrap()).unwrap(),
            DType::U8 => w.write_array(to, &c.read_array::<u8>(id).unwrap()).unwrap(),
            DType::F16 => panic!("a quilt holds no f16 array ('{}')", spec.name),
        }
    }
    w.finish().unwrap();
}

/// The budget a refusal names ("give --memory 184MiB or more").
fn enough_memory(said: &str) -> String {
    let after = said
        .split("give --memory ")
        .nth(1)
        .unwrap_or_else(|| panic!("no budget named: {said}"));
    after.split_whitespace().next().unwrap().to_string()
}
