use super::*;

/// The interpolation weights over the measured directions as a dense
/// vector.
fn weights(dirs: &Directions, d: Vec3) -> Vec<f32> {
    let mut w = vec![0f32; dirs.dirs.len()];
    let (near, count) = dirs.nearest(d);
    for &(i, x) in &near[..count] {
        w[i as usize] += x;
    }
    w
}

/// The largest L1 change of the weights between consecutive points of
/// a sweep over the hemisphere in steps of `step` radians.
fn largest_jump(dirs: &Directions, step: f32) -> f32 {
    let (mut prev, mut worst) = (None::<Vec<f32>>, 0f32);
    let mut t = 0f32;
    while t < 2.6 {
        let (theta, phi) = (0.05 + 0.65 * t.sin().abs(), 0.3 + t);
        let d = Vec3::new(theta.sin() * phi.cos(), theta.sin() * phi.sin(), theta.cos());
        let w = weights(dirs, d);
        assert!((w.iter().sum::<f32>() - 1.0).abs() < 1e-5);
        if let Some(p) = &prev {
            worst = worst.max(w.iter().zip(p).map(|(a, b)| (a - b).abs()).sum());
        }
        prev = Some(w);
        t += step;
    }
    worst
}

#[test]
fn direction_weights_turn_continuously_and_hit_measured_directions() {
    let dirs = Directions::new(&crate::artifact::btf::default_grid());
    // continuous: the largest change between neighbouring points of a
    // sweep shrinks with the step (with plain inverse-angle weights over
    // the three nearest it stays at 0.64 whatever the step: the weight
    // of the third nearest is not zero where it changes)
    let (coarse, fine) = (largest_jump(&dirs, 0.002), largest_jump(&dirs, 0.0002));
    assert!(
        fine < 0.2 * coarse,
        "weights jump: {coarse} at 0.002 rad steps, {fine} at 0.0002"
    );
    // on a measured direction, that direction alone
    for (i, m) in dirs.dirs.iter().enumerate() {
        let w = weights(&dirs, *m);
        assert_eq!(w[i], 1.0, "direction {i}");
    }
}
