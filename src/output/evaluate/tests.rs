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
