use super::*;

fn ang(theta: f32, phi: f32) -> Angles {
    Angles { theta, phi }
}

fn pair(name: &str, view: Angles, light: Angles) -> PairFile {
    PairFile {
        path: PathBuf::from(name),
        view,
        light,
    }
}

#[test]
fn parses_bonn_names() {
    let (v, l) = parse_pair_name("bricks_tl015_pl000_tv030_pv045.png").unwrap();
    assert_eq!((v, l), (ang(30.0, 45.0), ang(15.0, 0.0)));
    let (v, l) = parse_pair_name("tl15.5_pl0_tv30_pv45.exr").unwrap();
    assert_eq!((v, l), (ang(30.0, 45.0), ang(15.5, 0.0)));
    let (v, l) = parse_pair_name("plaster_TV75_PV0_TL60_PL120.5.JPG").unwrap();
    assert_eq!((v, l), (ang(75.0, 0.0), ang(60.0, 120.5)));
    // No extension, fractional last angle.
    let (v, _) = parse_pair_name("tl1_pl2_tv3_pv4.25").unwrap();
    assert_eq!(v, ang(3.0, 4.25));
}

#[test]
fn name_errors_say_what_is_wrong() {
    let e = parse_pair_name("x_tl015_pl000_tv030.png").unwrap_err();
    assert!(e.contains("missing pv"), "{e}");
    let e = parse_pair_name("x.png").unwrap_err();
    assert!(e.contains("missing tl, pl, tv, pv"), "{e}");
    let e = parse_pair_name("tl1_tl2_pl0_tv3_pv4.png").unwrap_err();
    assert!(e.contains("tl appears more than once"), "{e}");
    let e = parse_pair_name("tl-1_pl0_tv3_pv4.png").unwrap_err();
    assert!(e.contains("not a non-negative decimal"), "{e}");
    let e = parse_pair_name("tl1.2.3_pl0_tv3_pv4.png").unwrap_err();
    assert!(e.contains("tl1.2.3"), "{e}");
    let e = parse_pair_name("tl1e3_pl0_tv3_pv4.png").unwrap_err();
    assert!(e.contains("1e3"), "{e}");
}

#[test]
fn format_parse_round_trip_exact() {
    assert_eq!(
        format_pair_name("bricks", ang(30.0, 45.0), ang(15.0, 0.0), "png"),
        "bricks_tl015_pl000_tv030_pv045.png"
    );
    assert_eq!(
        format_pair_name("", ang(0.0, 360.0 - 0.5), ang(7.5, 0.125), ".exr"),
        "tl007.5_pl000.125_tv000_pv359.5.exr"
    );
    // Every angle with at most 3 decimals in [0, 360) at a stride of 0.001
    // (thinned), plus all integers.
    let mut checked = 0;
    let mut k: u32 = 0;
    while k < 360_000 {
        let s = format!("{}.{:03}", k / 1000, k % 1000);
        let a: f32 = s.parse().unwrap();
        let b: f32 = format!("{}", (359_999 - k) as f32 / 1000.0).parse().unwrap();
        let name = format_pair_name("p", ang(a, b), ang(b, a), "png");
        let (v, l) = parse_pair_name(&name).unwrap();
        assert_eq!(v.theta.to_bits(), a.to_bits(), "{name}");
        assert_eq!(v.phi.to_bits(), b.to_bits(), "{name}");
        assert_eq!((l.theta, l.phi), (b, a), "{name}");
        checked += 1;
        k += 7;
    }
    assert!(checked > 50_000);
}

#[test]
fn scan_folder_finds_and_sorts() {
    let dir = tempfile::tempdir().unwrap();
    for name in [
        "m_tl000_pl000_tv030_pv000.png",
        "m_tl000_pl000_tv000_pv000.PNG",
        "readme.txt",
        ".hidden_tl1.png",
    ] {
        std::fs::write(dir.path().join(name), b"x").unwrap();
    }
    std::fs::create_dir(dir.path().join("sub.png")).unwrap();
    let files = scan_folder(dir.path()).unwrap();
    assert_eq!(files.len(), 2);
    assert!(files[0].path.ends_with("m_tl000_pl000_tv000_pv000.PNG"));
    assert_eq!(files[1].view, ang(30.0, 0.0));
    // An image that does not parse is an error naming it.
    std::fs::write(dir.path().join("cover.jpg"), b"x").unwrap();
    let e = scan_folder(dir.path()).unwrap_err().to_string();
    assert!(e.contains("cover.jpg") && e.contains("missing"), "{e}");
    // Empty folder.
    let empty = tempfile::tempdir().unwrap();
    let e = scan_folder(empty.path()).unwrap_err();
    assert!(matches!(e, Error::Input { .. }) && e.to_string().contains("no BTF images"));
    // Missing folder.
    let e = scan_folder(&empty.path().join("gone")).unwrap_err();
    assert!(matches!(e, Error::Io { .. }));
}

#[test]
fn manifest_round_trip_and_parsing() {
    let dir = tempfile::tempdir().unwrap();
    let m = dir.path().join("btf.csv");
    let files = vec![
        pair("a.png", ang(0.0, 0.0), ang(15.5, 0.1)),
        pair("sub/b, \"c\".exr", ang(89.999, 359.75), ang(1.0 / 3.0, 7.0)),
    ];
    let files: Vec<PairFile> = files
        .into_iter()
        .map(|mut f| {
            f.path = dir.path().join(&f.path);
            f
        })
        .collect();
    write_manifest(&m, &files).unwrap();
    let text = std::fs::read_to_string(&m).unwrap();
    assert!(
        text.starts_with("file,theta_v,phi_v,theta_l,phi_l\na.png,"),
        "{text}"
    );
    assert_eq!(read_manifest(&m).unwrap(), files);

    std::fs::write(
        &m,
        "\u{feff}# comment\n\n file , theta_v,phi_v , theta_l,phi_l\n  x.png , 10 , 20.5, 30,40 \n",
    )
    .unwrap();
    let got = read_manifest(&m).unwrap();
    assert_eq!(
        got,
        vec![PairFile {
            path: dir.path().join("x.png"),
            view: ang(10.0, 20.5),
            light: ang(30.0, 40.0)
        }]
    );
}

#[test]
fn manifest_quoted_fields_with_space_around_them() {
    assert_eq!(
        split_csv(r#" "a, b" , "c""d" ,e f , "#).unwrap(),
        vec!["a, b", "c\"d", "e f", ""]
    );
    assert_eq!(split_csv(r#""  x  ""#).unwrap(), vec!["  x  "]);
    let dir = tempfile::tempdir().unwrap();
    let m = dir.path().join("btf.csv");
    let files = vec![pair("#1.png", ang(1.0, 2.0), ang(3.0, 4.0))]
        .into_iter()
        .map(|mut f| {
            f.path = dir.path().join(&f.path);
            f
        })
        .collect::<Vec<_>>();
    write_manifest(&m, &files).unwrap();
    assert_eq!(read_manifest(&m).unwrap(), files);
}

#[test]
fn manifest_errors_name_file_and_line() {
    let dir = tempfile::tempdir().unwrap();
    let m = dir.path().join("list.csv");
    let h = "file,theta_v,phi_v,theta_l,phi_l\n";
    let cases = [
        ("file,theta,phi\nx.png,1,2,3,4\n", "line 1", "bad header"),
        (&format!("{h}x.png,1,2,3\n"), "line 2", "expected 5 fields"),
        (
            &format!("{h}\n# c\nx.png,1,abc,3,4\n"),
            "line 4",
            "phi_v 'abc' is not a number",
        ),
        (&format!("{h}x.png,1,2,-3,4\n"), "line 2", "negative"),
        (&format!("{h}x.png,1,2,3,inf\n"), "line 2", "not finite"),
        (&format!("{h}x.png,1,2,3,NaN\n"), "line 2", "not finite"),
        (&format!("{h}x.png,91,2,3,4\n"), "line 2", "outside [0, 90]"),
        (&format!("{h}\"x.png,1,2,3,4\n"), "line 2", "unterminated"),
        ("# only a comment\n", "empty manifest", "header"),
        (h, "lists no images", ""),
    ];
    for (text, a, b) in cases {
        std::fs::write(&m, text).unwrap();
        let e = read_manifest(&m).unwrap_err();
        assert!(matches!(e, Error::Input { .. }));
        let e = e.to_string();
        assert!(e.contains("list.csv") && e.contains(a) && e.contains(b), "{e}");
    }
    let e = read_manifest(&dir.path().join("none.csv")).unwrap_err();
    assert!(matches!(e, Error::Io { .. }));
}

#[test]
fn manifest_relative_paths_outside_directory() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::create_dir(dir.path().join("m")).unwrap();
    let m = dir.path().join("m").join("list.csv");
    let f = vec![PairFile {
        path: dir.path().join("imgs").join("a.png"),
        view: ang(0.0, 0.0),
        light: ang(0.0, 0.0),
    }];
    write_manifest(&m, &f).unwrap();
    let text = std::fs::read_to_string(&m).unwrap();
    assert!(text.contains("\n../imgs/a.png,"), "{text}");
    std::fs::create_dir(dir.path().join("imgs")).unwrap();
    let back = read_manifest(&m).unwrap();
    assert_eq!(
        std::fs::canonicalize(back[0].path.parent().unwrap()).unwrap(),
        std::fs::canonicalize(dir.path().join("imgs")).unwrap()
    );
    assert!(back[0].path.ends_with("m/../imgs/a.png"));
}

#[test]
fn organise_two_views_three_lights() {
    let views = [ang(30.0, 90.0), ang(0.0, 0.0)];
    let lights = [ang(45.0, 0.0), ang(15.0, 180.0), ang(15.0, 0.0)];
    let mut files = Vec::new();
    // Shuffled order; the pole view is given with different φ per file.
    for (li, l) in lights.iter().enumerate().rev() {
        for (vi, v) in views.iter().enumerate() {
            let mut v = *v;
            if v.theta == 0.0 {
                v.phi = 10.0 * li as f32;
            }
            files.push(pair(&format!("v{vi}l{li}.png"), v, *l));
        }
    }
    let (vs, ls, grid) = organise_pairs(Path::new("btf"), &files).unwrap();
    assert_eq!(vs.len(), 2);
    assert_eq!(vs[0].theta, 0.0);
    assert_eq!(vs[1], ang(30.0, 90.0));
    assert_eq!(ls, vec![ang(15.0, 0.0), ang(15.0, 180.0), ang(45.0, 0.0)]);
    assert_eq!(grid.len(), 6);
    for v in 0..2 {
        for l in 0..3 {
            let f = &files[grid[v * 3 + l]];
            assert!(same_direction(f.view, vs[v]));
            assert_eq!(f.light, ls[l]);
        }
    }
    // Tiny angle noise and φ wrap-around map to the same direction.
    let mut noisy = files.clone();
    noisy[0].light.theta += 4e-4;
    noisy[1].view.phi = 90.0005;
    let (vs2, ls2, grid2) = organise_pairs(Path::new("btf"), &noisy).unwrap();
    assert_eq!((vs2.len(), ls2.len()), (2, 3));
    assert_eq!(grid2, grid);
    assert!(same_direction(ang(10.0, 359.9995), ang(10.0, 0.0)));
}

#[test]
fn organise_errors() {
    let o = Path::new("folder_x");
    let base = vec![
        pair("a.png", ang(0.0, 0.0), ang(10.0, 0.0)),
        pair("b.png", ang(0.0, 0.0), ang(20.0, 0.0)),
        pair("c.png", ang(30.0, 0.0), ang(10.0, 0.0)),
        pair("d.png", ang(30.0, 0.0), ang(20.0, 0.0)),
    ];
    assert!(organise_pairs(o, &base).is_ok());

    // Duplicate: pole with a different φ is the same view.
    let mut dup = base.clone();
    dup.push(pair("e.png", ang(0.0, 45.0), ang(20.0, 0.0)));
    let e = organise_pairs(o, &dup).unwrap_err().to_string();
    assert!(
        e.contains("e.png") && e.contains("b.png") && e.contains("duplicate"),
        "{e}"
    );

    // Missing pairs: count and examples, naming the origin.
    let mut gap = base.clone();
    gap.remove(3);
    gap.push(pair("f.png", ang(60.0, 0.0), ang(30.0, 0.0)));
    gap.push(pair("h.png", ang(90.0, 0.0), ang(40.0, 0.0)));
    let e = organise_pairs(o, &gap).unwrap_err().to_string();
    assert!(e.starts_with("folder_x"), "{e}");
    assert!(e.contains("11 of the 4 × 4"), "{e}");
    assert!(e.contains("view (θ=30, φ=0) light (θ=20, φ=0)"), "{e}");
    assert_eq!(e.matches("view (").count(), 5, "{e}");

    // Ranges.
    for (f, what) in [
        (pair("g.png", ang(91.0, 0.0), ang(10.0, 0.0)), "view θ"),
        (pair("g.png", ang(0.0, 0.0), ang(10.0, 360.0)), "light φ"),
        (pair("g.png", ang(0.0, -1.0), ang(10.0, 0.0)), "view φ"),
        (pair("g.png", ang(0.0, 0.0), ang(f32::NAN, 0.0)), "light θ"),
    ] {
        let e = organise_pairs(o, &[f]).unwrap_err().to_string();
        assert!(
            e.contains("g.png") && e.contains(what) && e.contains("outside"),
            "{e}"
        );
    }
    assert!(organise_pairs(o, &[]).is_err());
}
