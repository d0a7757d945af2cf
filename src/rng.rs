//! Seeded, counter-based randomness: every random value is a pure function of
//! (seed, index), so results never depend on thread scheduling.

/// The golden-ratio increment of splitmix64.
pub(crate) const GOLDEN: u64 = 0x9e37_79b9_7f4a_7c15;

/// splitmix64 finaliser: a bijective 64-bit mixer with good avalanche.
#[inline]
pub(crate) fn mix64(mut z: u64) -> u64 {
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    z ^ (z >> 31)
}

/// Derive an independent sub-seed.
#[inline]
pub(crate) fn derive(seed: u64, salt: u64) -> u64 {
    mix64(seed ^ mix64(salt.wrapping_mul(GOLDEN)))
}

/// A uniform value in (0, 1] from the top 53 bits of a hash.
#[inline]
fn unit_open(h: u64) -> f64 {
    ((h >> 11) as f64 + 1.0) * (1.0 / 9_007_199_254_740_992.0)
}

/// A uniform value in (0, 1], the `index`-th of the stream `seed`.
pub(crate) fn unit(seed: u64, index: u64) -> f64 {
    unit_open(mix64(derive(seed, index)))
}

/// An approximately standard normal value, the `index`-th of the stream
/// `seed`: the sum of twelve uniform values minus six (mean 0 and variance
/// 1 exactly, tails cut at ±6). Only additions, so it is the same on every
/// machine; a transcendental function from the system library could differ
/// in the last bit between CPUs.
pub(crate) fn gaussian(seed: u64, index: u64) -> f64 {
    let stream = derive(seed, index);
    (0..12).map(|i| unit(stream, i)).sum::<f64>() - 6.0
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn gaussian_stream_has_unit_moments() {
        let n = 200_000;
        let v: Vec<f64> = (0..n).map(|i| gaussian(42, i)).collect();
        let mean = v.iter().sum::<f64>() / n as f64;
        let var = v.iter().map(|x| (x - mean) * (x - mean)).sum::<f64>() / n as f64;
        assert!(mean.abs() < 0.01, "{mean}");
        assert!((var - 1.0).abs() < 0.02, "{var}");
        assert_ne!(gaussian(42, 7), gaussian(43, 7));
    }
}
