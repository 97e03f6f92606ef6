//! A small deterministic random generator for reproducible scenes, noise and tests. Not a
//! thesis algorithm.

/// A small deterministic generator (SplitMix64): reproducible scenes from a seed.
#[derive(Debug, Clone)]
pub struct SplitMix64 {
    state: u64,
}

impl SplitMix64 {
    #[inline]
    pub fn new(seed: u64) -> Self {
        SplitMix64 { state: seed }
    }

    #[inline]
    pub fn next_u64(&mut self) -> u64 {
        self.state = self.state.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.state;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    /// Uniform in [0, 1).
    #[inline]
    pub fn uniform(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 / (1u64 << 53) as f64
    }

    /// Uniform in [lo, hi).
    #[inline]
    pub fn range(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * self.uniform()
    }

    /// Standard normal (Box–Muller).
    #[inline]
    pub fn normal(&mut self) -> f64 {
        self.normal_pair().0
    }

    /// Two independent standard normals (both halves of Box–Muller).
    pub fn normal_pair(&mut self) -> (f64, f64) {
        let u1 = self.uniform().max(1e-300);
        let u2 = self.uniform();
        let r = (-2.0 * u1.ln()).sqrt();
        let (s, c) = (2.0 * std::f64::consts::PI * u2).sin_cos();
        (r * c, r * s)
    }
}

/// Hostile inputs for the decoders' property tests: from a valid encoding, `n` variants that
/// are cut short, have bits flipped, bytes inserted, removed or repeated, or are random bytes
/// of the same length — deterministic for a seed, so a failure reproduces.
pub fn mutations(valid: &[u8], n: usize, seed: u64) -> Vec<Vec<u8>> {
    let mut rng = SplitMix64::new(seed);
    let mut pick = |k: usize| (rng.next_u64() % k.max(1) as u64) as usize;
    (0..n)
        .map(|i| {
            let mut b = valid.to_vec();
            match i % 6 {
                0 => b.truncate(pick(valid.len() + 1)),
                1 => {
                    for _ in 0..1 + pick(8) {
                        let at = pick(b.len());
                        if let Some(x) = b.get_mut(at) {
                            *x ^= 1 << pick(8);
                        }
                    }
                }
                2 => {
                    let at = pick(b.len() + 1);
                    let byte = pick(256) as u8;
                    b.insert(at, byte);
                }
                3 => {
                    if !b.is_empty() {
                        let at = pick(b.len());
                        let len = pick(b.len() - at + 1);
                        b.drain(at..at + len);
                    }
                }
                4 => {
                    let at = pick(b.len() + 1);
                    let tail = b[at..].to_vec();
                    b.extend_from_slice(&tail);
                }
                _ => {
                    for x in b.iter_mut() {
                        *x = pick(256) as u8;
                    }
                }
            }
            b
        })
        .collect()
}
