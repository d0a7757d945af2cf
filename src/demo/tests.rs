use super::*;

#[test]
fn lights_from_camera_keep_their_angle_to_the_view_axis() {
    for (_, _, angle, azimuth) in BTF_LIGHTS {
        let l = light_from_camera(&SPOT_CAMERA, angle, azimuth);
        let l = Vec3::from(l);
        assert!((l.length_squared() - 1.0).abs() < 1e-5);
        let a = l
            .dot(SPOT_CAMERA.axis().into())
            .clamp(-1.0, 1.0)
            .acos()
            .to_degrees();
        assert!((a - angle).abs() < 0.01, "{a} vs {angle}");
    }
    // azimuth 90° is towards the image top: positive world y for this camera
    assert!(light_from_camera(&SPOT_CAMERA, 75.0, 90.0)[1] > 0.9);
}

#[test]
fn dilation_is_a_disk_that_wraps_around() {
    // one foreground pixel in the corner of a 9×7 periodic sample
    let mut m = vec![0f32; 63];
    m[0] = 0.7;
    let d = dilate_wrapping(&m, 9, 7, 2);
    // the 13 lattice points of a radius-2 disk, split over the four corners
    assert_eq!(d.iter().filter(|&&v| v == 1.0).count(), 13);
    for (x, y) in [(0, 0), (2, 0), (7, 0), (0, 2), (0, 5), (8, 6), (1, 1)] {
        assert_eq!(d[y * 9 + x], 1.0, "({x}, {y})");
    }
    assert_eq!(d[6 * 9 + 7], 0.0);
    assert!(dilate_wrapping(&vec![0.49; 63], 9, 7, 3)
        .iter()
        .all(|&v| v == 0.0));
}
