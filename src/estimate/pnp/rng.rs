//! SplitMix64: a few lines, statistically fine for drawing samples, and reproducible across
//! platforms and crate versions (a `rand` dependency would be neither needed nor pinned).

#[derive(Clone, Debug)]
pub(crate) struct SplitMix64(u64);

impl SplitMix64 {
    pub(crate) fn new(seed: u64) -> Self {
        Self(seed)
    }

    pub(crate) fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    /// Uniform in `0..n` (n > 0) by a widening multiply: no modulo, bias below 2⁻⁵⁴ for any
    /// realistic n.
    pub(crate) fn below(&mut self, n: usize) -> usize {
        ((self.next_u64() as u128 * n as u128) >> 64) as usize
    }

    /// Uniform in [0, 1).
    #[cfg(test)]
    pub(crate) fn unit(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 * (1.0 / (1u64 << 53) as f64)
    }

    /// A uniformly random order of `0..n` (Fisher–Yates).
    pub(crate) fn permutation(&mut self, n: usize) -> Vec<u32> {
        let mut order: Vec<u32> = (0..n as u32).collect();
        for i in (1..n).rev() {
            order.swap(i, self.below(i + 1));
        }
        order
    }

    /// `K` distinct indices in `0..n` (n ≥ K), by rejection: cheap while K ≪ n.
    pub(crate) fn distinct<const K: usize>(&mut self, n: usize) -> [usize; K] {
        debug_assert!(n >= K);
        let mut out = [0; K];
        let mut filled = 0;
        while filled < K {
            let i = self.below(n);
            if !out[..filled].contains(&i) {
                out[filled] = i;
                filled += 1;
            }
        }
        out
    }
}
