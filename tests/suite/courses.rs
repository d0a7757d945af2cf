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
    fails_clearly(
        &btfquilt(&["evaluate", s(&wall), "--forced-ends", "--memory", "4MiB"]),
        &["raise --memory"],
    );
    // plaster has no rows
    let plaster = tile("plaster_cracks.png", "plaster.quilt");
    let doc: serde_json::Value =
        serde_json::from_str(&ok(&["evaluate", s(&plaster), "--forced-ends"])).unwrap();
    assert!(doc.get("courses").is_none(), "{doc}");
}
