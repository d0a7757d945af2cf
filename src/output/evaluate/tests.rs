use super::*;

#[test]
fn median_of_a_stream_is_the_sorted_middle() {
    // many equal values, a spread, zeros and an infinity: the select must
    // narrow through several passes and agree with sorting
    for n in [0usize, 1, 2, 7, 100_000, 300_001] {
        let values: Vec<f64> = (0..n)
            .map(|i| match crate::rng::mix64(i as u64) % 5 {
                0 => 1.0,
                1 => 0.0,
                2 if i % 1000 == 0 => f64::INFINITY,
                _ => (crate::rng::mix64(i as u64 + 7) % 1_000_000) as f64 * 1e-3,
            })
            .collect();
        let mut passes = 0;
        let got = median_of(|f| {
            passes += 1;
            values.iter().for_each(|&v| f(v));
            Ok(())
        })
        .unwrap();
        let mut sorted = values.clone();
        sorted.sort_by(f64::total_cmp);
        let want = sorted.get(n / 2).copied().unwrap_or(0.0);
        assert_eq!(got, (n, want), "{n} values");
        assert!(passes <= 5, "{passes} passes");
    }
}

/// A `w`×`h` preview of smooth random colour (sums of a few waves), so
/// that bilinear reads at different sub-pixel positions differ.
fn waves(w: usize, h: usize, seed: u64) -> RgbImage {
    let r = |k: u64| (crate::rng::mix64(seed * 64 + k) % 1000) as f32 / 1000.0;
    let data = (0..w * h * 3)
        .map(|i| {
            let (x, y, c) = ((i / 3 % w) as f32, (i / 3 / w) as f32, (i % 3) as u64);
            (0..3u64)
                .map(|k| {
                    let j = c * 3 + k;
                    (r(j) * 2.0 + 0.3)
                        * ((x * (0.2 + r(j + 9)) + y * (0.3 - r(j + 18) * 0.5)) + r(j + 27) * 6.0).sin()
                })
                .sum::<f32>()
                / 9.0
                + 0.5
        })
        .collect();
    RgbImage {
        width: w,
        height: h,
        data,
    }
}

/// The window whose texel (dx, dy) reads `p` at `at(dx, dy)`.
fn window_at(p: &RgbImage, at: impl Fn(f64, f64) -> [f64; 2]) -> Vec<f32> {
    (0..25)
        .flat_map(|i| {
            let q = at((i % 5) as f64 - 2.0, (i / 5) as f64 - 2.0);
            crate::io::imageio::bilinear(p, q[0] as f32, q[1] as f32)
        })
        .collect()
}

#[test]
fn a_window_read_in_its_own_frame_is_at_distance_zero_at_any_phase_turn_or_scale() {
    let p = waves(48, 40, 1);
    for (k, (degrees, scale, mirrored)) in [
        (0.0, 1.0, false),
        (33.0, 1.0, false),
        (-71.0, 1.31, false),
        (124.0, 0.77, true),
    ]
    .into_iter()
    .enumerate()
    {
        let (s, c) = (degrees as f64).to_radians().sin_cos();
        let m = if mirrored { -1.0 } else { 1.0 };
        // atlas +X → (c, s)·scale, atlas +Y → m·(−s, c)·scale
        let jacobian = [c * scale, s * scale, -s * scale * m, c * scale * m];
        let centre = [17.37 + k as f64 * 1.13, 20.81 - k as f64 * 0.71];
        let frame = Frame {
            centre: centre.map(|v| v as f32),
            jacobian: jacobian.map(|v| v as f32),
        };
        let window = window_at(&p, |dx, dy| {
            [
                centre[0] + jacobian[0] * dx + jacobian[2] * dy,
                centre[1] + jacobian[1] * dx + jacobian[3] * dy,
            ]
        });
        let d = framed_distance(&p, &window, frame).unwrap();
        assert!(d < 1e-5, "{degrees}° × {scale}, mirrored {mirrored}: {d}");
        // the same window in a frame half a pixel off is not
        let off = Frame {
            centre: [frame.centre[0] + 0.5, frame.centre[1]],
            ..frame
        };
        assert!(framed_distance(&p, &window, off).unwrap() > 1e-3);
    }
}

#[test]
fn framed_distance_is_the_brute_force_nearest_whole_pixel_move() {
    // a window across a seam: its left two columns from one place, the
    // rest from another, in a turned frame; the oracle tries every whole
    // pixel move with the image reader
    let p = waves(30, 26, 2);
    let (s, c) = 0.4f64.sin_cos();
    let jacobian = [c, s, -s, c];
    let centre = [12.3, 11.6];
    let at = |dx: f64, dy: f64| [centre[0] + c * dx - s * dy, centre[1] + s * dx + c * dy];
    let window = window_at(&p, |dx, dy| {
        let q = at(dx, dy);
        if dx < 0.0 {
            [q[0] + 5.4, q[1] - 3.2]
        } else {
            q
        }
    });
    let frame = Frame {
        centre: centre.map(|v| v as f32),
        jacobian: jacobian.map(|v| v as f32),
    };
    let got = framed_distance(&p, &window, frame).unwrap();
    let mut best = f64::INFINITY;
    for ty in -30i64..30 {
        for tx in -30i64..30 {
            let reads: Vec<[f64; 2]> = (0..25)
                .map(|i| {
                    let q = at((i % 5) as f64 - 2.0, (i / 5) as f64 - 2.0);
                    [q[0] + tx as f64, q[1] + ty as f64]
                })
                .collect();
            // (every read and its right and lower neighbour inside)
            if reads
                .iter()
                .any(|q| q[0] < 0.0 || q[1] < 0.0 || q[0].floor() + 1.0 > 29.0 || q[1].floor() + 1.0 > 25.0)
            {
                continue;
            }
            let ssd: f64 = reads
                .iter()
                .enumerate()
                .map(|(i, q)| {
                    let v = crate::io::imageio::bilinear(&p, q[0] as f32, q[1] as f32);
                    (0..3)
                        .map(|k| ((v[k] - window[i * 3 + k]) as f64).powi(2))
                        .sum::<f64>()
                })
                .sum();
            best = best.min(ssd);
        }
    }
    let want = (best / 25.0).sqrt();
    assert!(want > 1e-2, "the seam shows: {want}");
    assert!((got - want).abs() < 1e-4, "{got} against the oracle's {want}");
}

#[test]
fn a_degenerate_or_oversized_frame_has_no_framed_distance() {
    let p = waves(12, 12, 3);
    let window = vec![0.5f32; 75];
    let flat = Frame {
        centre: [6.0, 6.0],
        jacobian: [1.0, 2.0, 0.5, 1.0],
    };
    assert_eq!(framed_distance(&p, &window, flat), None);
    let huge = Frame {
        centre: [6.0, 6.0],
        jacobian: [4.0, 0.0, 0.0, 4.0],
    };
    assert_eq!(framed_distance(&p, &window, huge), None);
    let nan = Frame {
        centre: [f32::NAN, 6.0],
        jacobian: [1.0, 0.0, 0.0, 1.0],
    };
    assert_eq!(framed_distance(&p, &window, nan), None);
}
