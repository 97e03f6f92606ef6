//! A run's grey-level weight sums (thesis Eq. 3.1, the weights `w = min(pixel − bg, cap)`, 0
//! at or below `bg`): `(Σw, Σw·x, Σw·x²)` over the pixels `row[a..b]`, `x` the pixel's column.
//! They make a blob's weighted moments (Eq. 3.33–3.40 with weights) one row at a time.
//!
//! Every path gives the same exact integers:
//! - [`scalar`], any pixel type: summed in `u32` relative to each piece's start — pieces short
//!   enough that `Σw·i²` cannot overflow (256 pixels of 8 bits, 32 of 16) — and moved to `x` in
//!   `u64` per piece;
//! - [`u8_sums`], 8-bit pixels on x86-64, 16 (SSE2) or 32 (AVX2) pixels a step: the weights by
//!   saturating byte arithmetic, `Σw` by `psadbw`, `Σw·i` and `Σw·i²` by 16-bit multiply-adds
//!   (`pmaddwd`) with `i` the index in a piece of 128 pixels (`i² < 2¹⁵`), moved to `x` in
//!   `u64` per piece. A run shorter than one step, or a run's last partial step, is read as the
//!   whole step inside the row with the pixels outside the run masked to weight 0 (no scalar
//!   tail).

use crate::image::Pixel;

/// `(Σw, Σw·x, Σw·x²)` over `row[a..b]`, pixel by pixel (see the module docs).
#[inline(always)]
pub(crate) fn scalar<P: Pixel>(
    row: &[P],
    a: usize,
    b: usize,
    bg: u32,
    cap: u32,
) -> (u64, u64, u64) {
    let cap = cap.min(P::MAX_VALUE);
    let piece = if P::BITS <= 8 { 256 } else { 32 };
    let (mut sw, mut swx, mut swxx) = (0u64, 0u64, 0u64);
    for (c, chunk) in row[a..b].chunks(piece).enumerate() {
        let (mut s0, mut s1, mut s2) = (0u32, 0u32, 0u32);
        for (i, p) in chunk.iter().enumerate() {
            let w = p.value().saturating_sub(bg).min(cap);
            let i = i as u32;
            s0 += w;
            s1 += w * i;
            s2 += w * i * i;
        }
        let base = (a + c * piece) as u64;
        move_to_x(
            (s0 as u64, s1 as u64, s2 as u64),
            base,
            (&mut sw, &mut swx, &mut swxx),
        );
    }
    (sw, swx, swxx)
}

/// Adds a piece's sums relative to its start `base` to the sums in `x`:
/// `Σw·(base+i) = base·Σw + Σw·i`, `Σw·(base+i)² = base²·Σw + 2·base·Σw·i + Σw·i²`.
#[inline(always)]
fn move_to_x(
    (s0, s1, s2): (u64, u64, u64),
    base: u64,
    (sw, swx, swxx): (&mut u64, &mut u64, &mut u64),
) {
    *sw += s0;
    *swx += base * s0 + s1;
    *swxx += base * base * s0 + 2 * base * s1 + s2;
}

#[cfg(target_arch = "x86_64")]
pub(crate) use simd::{sum_u64_lanes, u8_sums};

#[cfg(target_arch = "x86_64")]
mod simd {
    use super::move_to_x;
    use std::arch::x86_64::*;

    /// The four 64-bit lanes of `v` added (wrapping).
    ///
    /// # Safety
    /// The CPU must have AVX2; the caller is compiled with it for this to be inlined.
    #[inline(always)]
    pub(crate) unsafe fn sum_u64_lanes(v: __m256i) -> u64 {
        // SAFETY: the caller's contract.
        unsafe {
            let s = _mm_add_epi64(_mm256_castsi256_si128(v), _mm256_extracti128_si256(v, 1));
            (_mm_cvtsi128_si64(s) as u64).wrapping_add(_mm_extract_epi64(s, 1) as u64)
        }
    }

    /// Pixels in a piece: `i < 128`, so `i²` fits a signed 16-bit lane and a piece's `Σw·i²`
    /// per 32-bit lane stays below 2³¹ (at most 8 steps of two multiply-adds of 2·255·127²).
    const PIECE: usize = 128;

    /// The vector operations of [`u8_sums`], at 16 bytes (SSE2, the x86-64 baseline) or 32
    /// (AVX2).
    ///
    /// # Safety
    /// The AVX2 implementation's functions may be called only on a CPU with AVX2, from code
    /// compiled with it enabled (for them to be inlined).
    pub(crate) trait Vector: Copy {
        /// Bytes (pixels) per vector.
        const BYTES: usize;
        /// The weights of the `BYTES` pixels at `p`: `min(pixel − bg, cap)` per byte, 0 in the
        /// lanes outside `lo..hi`.
        unsafe fn weights(p: *const u8, bg: u8, cap: u8, lo: usize, hi: usize) -> Self;
        /// Adds `Σw` (64-bit lanes), `Σw·i` and `Σw·i²` (32-bit lanes) of weights `w` whose
        /// lane `l` is at piece index `base + l` to `acc`.
        unsafe fn accumulate(w: Self, base: i16, acc: &mut [Self; 3]);
        /// The lanes of `acc` summed: `(Σw, Σw·i, Σw·i²)`.
        unsafe fn reduce(acc: [Self; 3]) -> (u64, u64, u64);
        /// Three zero accumulators.
        unsafe fn zeros() -> [Self; 3];
    }

    impl Vector for __m128i {
        const BYTES: usize = 16;
        #[inline(always)]
        unsafe fn weights(p: *const u8, bg: u8, cap: u8, lo: usize, hi: usize) -> Self {
            // SAFETY: the caller reads 16 bytes inside the row; SSE2 is baseline on x86-64.
            unsafe {
                let v = _mm_loadu_si128(p as *const __m128i);
                let w = _mm_min_epu8(
                    _mm_subs_epu8(v, _mm_set1_epi8(bg as i8)),
                    _mm_set1_epi8(cap as i8),
                );
                if lo == 0 && hi == 16 {
                    return w;
                }
                let lane = _mm_setr_epi8(0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15);
                let keep = _mm_and_si128(
                    _mm_cmpgt_epi8(lane, _mm_set1_epi8(lo as i8 - 1)),
                    _mm_cmpgt_epi8(_mm_set1_epi8(hi as i8), lane),
                );
                _mm_and_si128(w, keep)
            }
        }
        #[inline(always)]
        unsafe fn accumulate(w: Self, base: i16, acc: &mut [Self; 3]) {
            // SAFETY: SSE2 only.
            unsafe {
                let zero = _mm_setzero_si128();
                acc[0] = _mm_add_epi64(acc[0], _mm_sad_epu8(w, zero));
                let b = _mm_set1_epi16(base);
                let il = _mm_add_epi16(_mm_setr_epi16(0, 1, 2, 3, 4, 5, 6, 7), b);
                let ih = _mm_add_epi16(_mm_setr_epi16(8, 9, 10, 11, 12, 13, 14, 15), b);
                let (wl, wh) = (_mm_unpacklo_epi8(w, zero), _mm_unpackhi_epi8(w, zero));
                acc[1] = _mm_add_epi32(
                    acc[1],
                    _mm_add_epi32(_mm_madd_epi16(wl, il), _mm_madd_epi16(wh, ih)),
                );
                acc[2] = _mm_add_epi32(
                    acc[2],
                    _mm_add_epi32(
                        _mm_madd_epi16(wl, _mm_mullo_epi16(il, il)),
                        _mm_madd_epi16(wh, _mm_mullo_epi16(ih, ih)),
                    ),
                );
            }
        }
        #[inline(always)]
        unsafe fn reduce(acc: [Self; 3]) -> (u64, u64, u64) {
            // SAFETY: SSE2 only.
            unsafe {
                let s0 = _mm_add_epi64(acc[0], _mm_unpackhi_epi64(acc[0], acc[0]));
                let sum32 = |v: __m128i| {
                    let v = _mm_add_epi32(v, _mm_shuffle_epi32(v, 0b01_00_11_10));
                    let v = _mm_add_epi32(v, _mm_shuffle_epi32(v, 0b10_11_00_01));
                    _mm_cvtsi128_si32(v) as u32 as u64
                };
                (_mm_cvtsi128_si64(s0) as u64, sum32(acc[1]), sum32(acc[2]))
            }
        }
        #[inline(always)]
        unsafe fn zeros() -> [Self; 3] {
            // SAFETY: SSE2 only.
            unsafe { [_mm_setzero_si128(); 3] }
        }
    }

    impl Vector for __m256i {
        const BYTES: usize = 32;
        #[inline(always)]
        unsafe fn weights(p: *const u8, bg: u8, cap: u8, lo: usize, hi: usize) -> Self {
            // SAFETY: the caller reads 32 bytes inside the row, on a CPU with AVX2.
            unsafe {
                let v = _mm256_loadu_si256(p as *const __m256i);
                let w = _mm256_min_epu8(
                    _mm256_subs_epu8(v, _mm256_set1_epi8(bg as i8)),
                    _mm256_set1_epi8(cap as i8),
                );
                if lo == 0 && hi == 32 {
                    return w;
                }
                let lane = _mm256_setr_epi8(
                    0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15, 16, 17, 18, 19, 20, 21,
                    22, 23, 24, 25, 26, 27, 28, 29, 30, 31,
                );
                let keep = _mm256_and_si256(
                    _mm256_cmpgt_epi8(lane, _mm256_set1_epi8(lo as i8 - 1)),
                    _mm256_cmpgt_epi8(_mm256_set1_epi8(hi as i8), lane),
                );
                _mm256_and_si256(w, keep)
            }
        }
        #[inline(always)]
        unsafe fn accumulate(w: Self, base: i16, acc: &mut [Self; 3]) {
            // SAFETY: AVX2, as the trait requires.
            unsafe {
                let zero = _mm256_setzero_si256();
                acc[0] = _mm256_add_epi64(acc[0], _mm256_sad_epu8(w, zero));
                let b = _mm256_set1_epi16(base);
                // unpacklo/hi work within each 128-bit half: the low words are pixels 0–7 and
                // 16–23, the high ones 8–15 and 24–31.
                let il = _mm256_add_epi16(
                    _mm256_setr_epi16(0, 1, 2, 3, 4, 5, 6, 7, 16, 17, 18, 19, 20, 21, 22, 23),
                    b,
                );
                let ih = _mm256_add_epi16(
                    _mm256_setr_epi16(8, 9, 10, 11, 12, 13, 14, 15, 24, 25, 26, 27, 28, 29, 30, 31),
                    b,
                );
                let (wl, wh) = (_mm256_unpacklo_epi8(w, zero), _mm256_unpackhi_epi8(w, zero));
                acc[1] = _mm256_add_epi32(
                    acc[1],
                    _mm256_add_epi32(_mm256_madd_epi16(wl, il), _mm256_madd_epi16(wh, ih)),
                );
                acc[2] = _mm256_add_epi32(
                    acc[2],
                    _mm256_add_epi32(
                        _mm256_madd_epi16(wl, _mm256_mullo_epi16(il, il)),
                        _mm256_madd_epi16(wh, _mm256_mullo_epi16(ih, ih)),
                    ),
                );
            }
        }
        #[inline(always)]
        unsafe fn reduce(acc: [Self; 3]) -> (u64, u64, u64) {
            // SAFETY: AVX2, as the trait requires; the halves are summed as SSE2 vectors.
            unsafe {
                let (a0, a1, a2) = (acc[0], acc[1], acc[2]);
                let s0 = _mm_add_epi64(_mm256_castsi256_si128(a0), _mm256_extracti128_si256(a0, 1));
                let s1 = _mm_add_epi32(_mm256_castsi256_si128(a1), _mm256_extracti128_si256(a1, 1));
                let s2 = _mm_add_epi32(_mm256_castsi256_si128(a2), _mm256_extracti128_si256(a2, 1));
                <__m128i as Vector>::reduce([s0, s1, s2])
            }
        }
        #[inline(always)]
        unsafe fn zeros() -> [Self; 3] {
            // SAFETY: AVX2, as the trait requires.
            unsafe { [_mm256_setzero_si256(); 3] }
        }
    }

    /// `(Σw, Σw·x, Σw·x²)` over `row[a..b]` for 8-bit pixels, `V::BYTES` pixels a step (see
    /// the module docs). A row narrower than one vector is summed by the next smaller path.
    ///
    /// # Safety
    /// As [`Vector`]: with `V = __m256i`, the CPU must have AVX2.
    #[inline(always)]
    pub(crate) unsafe fn u8_sums<V: Vector>(
        row: &[u8],
        a: usize,
        b: usize,
        bg: u32,
        cap: u32,
    ) -> (u64, u64, u64) {
        let n = b - a;
        let step = V::BYTES;
        if n < step && V::BYTES == 32 {
            // SAFETY: SSE2 is baseline.
            return unsafe { u8_sums::<__m128i>(row, a, b, bg, cap) };
        }
        if row.len() < step {
            return super::scalar(row, a, b, bg, cap);
        }
        assert!(a <= b && b <= row.len(), "a run inside its row");
        let (bg8, cap8) = (bg.min(255) as u8, cap.min(255) as u8);
        let (mut sw, mut swx, mut swxx) = (0u64, 0u64, 0u64);
        let ptr = row.as_ptr();
        if n < step {
            // One vector inside the row holding the whole run, the other lanes masked.
            let s = a.min(row.len() - step);
            let lo = a - s;
            // SAFETY: `s + step <= row.len()`; the trait's CPU requirement is the caller's.
            let sums = unsafe {
                let mut acc = V::zeros();
                V::accumulate(
                    V::weights(ptr.add(s), bg8, cap8, lo, lo + n),
                    -(lo as i16),
                    &mut acc,
                );
                V::reduce(acc)
            };
            move_to_x(sums, a as u64, (&mut sw, &mut swx, &mut swxx));
            return (sw, swx, swxx);
        }
        let mut p = a;
        while p < b {
            let m = (b - p).min(PIECE);
            // SAFETY: every load below is `step` bytes starting at or after `a` and ending at
            // or before `b <= row.len()` (the last one ends at `p + m`, and `p + m >= a + step`
            // because `n >= step`); the CPU requirement is the caller's.
            let sums = unsafe {
                let mut acc = V::zeros();
                let mut off = 0;
                while off + step <= m {
                    V::accumulate(
                        V::weights(ptr.add(p + off), bg8, cap8, 0, step),
                        off as i16,
                        &mut acc,
                    );
                    off += step;
                }
                if off < m {
                    // The vector ending at the piece's end; lanes already summed are masked.
                    let start = p + m - step;
                    let base = m as isize - step as isize;
                    let lo = (off as isize - base) as usize;
                    V::accumulate(
                        V::weights(ptr.add(start), bg8, cap8, lo, step),
                        base as i16,
                        &mut acc,
                    );
                }
                V::reduce(acc)
            };
            move_to_x(sums, p as u64, (&mut sw, &mut swx, &mut swxx));
            p += m;
        }
        (sw, swx, swxx)
    }
}
