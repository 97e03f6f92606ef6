//! A tracked blob's rows of one run each, in a window of 8-bit pixels up to 256 wide, with AVX2
//! (the commonest rows of a tracking step), summed with as little work a row as the sums allow;
//! and a blob's edge ring (`ring::add_edge_ring`) read the same way.
//! Each row's run is taken from its foreground mask; its binary moments (Eq. 3.33–3.40) from
//! tables of `Σi^p` over the window's columns `i` and added into running sums — `C₀ += S`,
//! `C₁ += C₀`, … — that weigh each row by `u`, `u(u+1)/2`, … (`u` the rows from it to the
//! block's end) with no multiplication; its grey-level weights (Eq. 3.1, `min(pixel −
//! background, cap)`) are summed in vectors lane by lane, the lane's column multiplied in
//! per lane and the rows weighed by the same running sums, and added across the lanes only
//! every [`FLUSH_ROWS`] rows. The running sums become moments in frame coordinates at the end
//! (`y = Y + n − u` expanded binomially, then `x = X + i`). Same exact integers as the
//! row-by-row path (`Scratch::scan_with`'s block loop, `ring::add_edge_ring`'s rows), which
//! takes every other case (16-bit pixels, SSE2, windows wider than 256 pixels and ring boxes
//! wider than 128, or too near the frame's right edge for whole 32-pixel reads). Part of
//! `extract` (module docs there).

use super::*;
#[cfg(target_arch = "x86_64")]
use std::arch::x86_64::*;
use std::num::Wrapping;

/// Rows summed in the vector lanes between two additions across them: the 32-bit lane sums
/// stay below 2³² (at 128 columns, `Σw·i²` over 32 rows is at most 32 · 4 · 2 · 255 · (127² +
/// 126²) ≈ 2.09 · 10⁹, and `Σu·w·i` at most 32 · 32 · 4 · 2 · 255 · 127 ≈ 2.7 · 10⁸).
#[cfg(target_arch = "x86_64")]
const FLUSH_ROWS: u32 = 32;

/// `POWER_SUMS[p][j] = Σ_{i<j} i^p` for the columns `i` of a window of up to 256 (the largest,
/// `Σi³` below 256, is 1 065 369 600).
const POWER_SUMS: [[u32; 257]; 4] = {
    let mut t = [[0u32; 257]; 4];
    let mut j = 1;
    while j <= 256 {
        let i = (j - 1) as u32;
        t[0][j] = t[0][j - 1] + 1;
        t[1][j] = t[1][j - 1] + i;
        t[2][j] = t[2][j - 1] + i * i;
        t[3][j] = t[3][j - 1] + i * i * i;
        j += 1;
    }
    t
};

/// `INSIDE[32 − k..][..32]`: the first `k` lanes of a vector set.
static INSIDE: [u8; 64] = {
    let mut t = [0u8; 64];
    let mut i = 0;
    while i < 32 {
        t[i] = 0xFF;
        i += 1;
    }
    t
};

/// The bytes 0, 1, …, 31: each lane's index.
static LANES: [u8; 32] = {
    let mut t = [0u8; 32];
    let mut i = 0;
    while i < 32 {
        t[i] = i as u8;
        i += 1;
    }
    t
};

/// Each lane's column `i` from the segment's first (`COLUMNS[0]`) and its square
/// (`COLUMNS[1]`), as 16-bit words in the order the byte-to-word unpacking of vector `j`
/// leaves them: row `2j` its low words (pixels `32j` + 0–7 and 16–23), row `2j + 1` its high
/// words (+ 8–15 and 24–31).
static COLUMNS: [[[i16; 16]; 8]; 2] = {
    let mut t = [[[0i16; 16]; 8]; 2];
    let mut j = 0;
    while j < 4 {
        let mut l = 0;
        while l < 16 {
            let lo = (32 * j + (l % 8) + 16 * (l / 8)) as i16;
            let hi = lo + 8;
            t[0][2 * j][l] = lo;
            t[0][2 * j + 1][l] = hi;
            t[1][2 * j][l] = lo * lo;
            t[1][2 * j + 1][l] = hi * hi;
            l += 1;
        }
        j += 1;
    }
    t
};

/// What [`narrow_block_avx2`] took: rows `y..end_y` of one blob, each one run continuing the
/// one above.
#[derive(Debug)]
pub(super) struct NarrowBlock {
    /// The first row not taken.
    pub(super) end_y: u32,
    /// The rows' binary moments.
    pub(super) moments: RawMoments,
    /// The columns the runs span.
    pub(super) x_span: (u32, u32),
    /// The last row's run.
    pub(super) last: (u32, u32),
    /// The rows' grey-level moments (zero without weights).
    pub(super) weighted: WeightedMoments,
}

/// Whether [`narrow_block_avx2`] can read the segment: at most 256 pixels, whole 32-pixel
/// vectors from its first column inside the row.
pub(super) fn narrow_block_fits(seg: &Seg, width: u32) -> bool {
    let n = seg.x1 - seg.x0 + 1;
    n <= 256 && seg.x0 + 32 * n.div_ceil(32) <= width
}

/// The rows from `y` of the blob whose run on row `y` is the segment's only run: row `y` and
/// each next row below `stop` while it holds one run in the segment joining the one above
/// (touching within `k` columns), with weights `min(pixel − bg, cap)` when `levels` is
/// `Some((bg, cap))`.
///
/// # Safety
/// The CPU must support AVX2; `narrow_block_fits(seg, img.width())`; `y < height` and
/// `stop <= height`; row `y` holds exactly one run of `pixel >= seg.threshold` in the
/// segment.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
#[inline(never)]
pub(super) unsafe fn narrow_block_avx2(
    img: &GrayView<'_, u8>,
    seg: &Seg,
    y: u32,
    stop: u32,
    k: u32,
    levels: Option<(u32, u32)>,
) -> NarrowBlock {
    let vectors = (seg.x1 - seg.x0 + 1).div_ceil(32);
    // SAFETY: the caller's contract, passed on.
    unsafe {
        let args = (img, seg, y, stop, k, levels);
        match (vectors, levels.is_some()) {
            (1, false) => block::<1, 0, false>(args),
            (1, true) => block::<1, 0, true>(args),
            (2, false) => block::<2, 0, false>(args),
            (2, true) => block::<2, 0, true>(args),
            (3, false) => block::<3, 0, false>(args),
            (3, true) => block::<3, 0, true>(args),
            (4, false) => block::<4, 0, false>(args),
            (4, true) => block::<4, 0, true>(args),
            (5, false) => block::<4, 1, false>(args),
            (5, true) => block::<4, 1, true>(args),
            (6, false) => block::<4, 2, false>(args),
            (6, true) => block::<4, 2, true>(args),
            (7, false) => block::<4, 3, false>(args),
            (7, true) => block::<4, 3, true>(args),
            (_, false) => block::<4, 4, false>(args),
            (_, true) => block::<4, 4, true>(args),
        }
    }
}

/// Running sums of a row quantity `S` over rows `0..n`: after each row `c[0] += S`, then
/// `c[q] += c[q − 1]`, so `c[0] = ΣS`, `c[1] = Σu·S`, `c[2] = Σu(u+1)/2·S`, `c[3] =
/// Σu(u+1)(u+2)/6·S` with `u = n − dy` the rows from a row to the end (row `dy` included).
/// Returns `[ΣS, Σy·S, Σy²·S, Σy³·S]` for rows `y = y0 + dy`, i.e. `y = z − u` with
/// `z = y0 + n`, from the first `Q + 1` of them (the rest zero). In wrapping `u64`: every
/// sum the rows of a block make fits (`x, y < 2¹³`, at most 2²⁰ pixels: `Σx³ < 2⁵⁹`), so
/// the differences of larger terms come out exact.
#[inline(always)]
fn weigh_rows<const Q: usize>(c: [u64; 4], z: u64) -> [u64; 4] {
    let [c0, c1, c2, c3] = c.map(Wrapping);
    let z = Wrapping(z);
    let (two, three, six) = (Wrapping(2), Wrapping(3), Wrapping(6));
    let u1 = c1;
    let u2 = two * c2 - c1;
    let u3 = six * c3 - three * u2 - two * u1;
    let mut out = [c0.0, 0, 0, 0];
    if Q >= 1 {
        out[1] = (z * c0 - u1).0;
    }
    if Q >= 2 {
        out[2] = (z * z * c0 - two * z * u1 + u2).0;
    }
    if Q >= 3 {
        out[3] = (z * z * z * c0 - three * z * z * u1 + three * z * u2 - u3).0;
    }
    out
}

/// The lane sums of [`block`]'s weights since the last flush (`i` the column from the
/// segment's first, `u` as in [`weigh_rows`]).
#[cfg(target_arch = "x86_64")]
#[derive(Clone, Copy)]
struct LaneSums {
    /// Σw, Σu·w, Σu(u+1)/2·w (64-bit lanes).
    w: [__m256i; 3],
    /// Σw·i, Σu·w·i (32-bit lanes).
    wi: [__m256i; 2],
    /// Σw·i² (32-bit lanes).
    wii: __m256i,
}

#[cfg(target_arch = "x86_64")]
impl LaneSums {
    #[inline(always)]
    fn zero() -> Self {
        // SAFETY: AVX (part of AVX2, which every caller is compiled with).
        let z = unsafe { _mm256_setzero_si256() };
        LaneSums {
            w: [z; 3],
            wi: [z; 2],
            wii: z,
        }
    }

    /// Adds a row's lane sums `Σw` (64-bit lanes), `Σw·i` and `Σw·i²` (32-bit lanes) and
    /// carries the running sums on (`weigh_rows`).
    #[inline(always)]
    unsafe fn add_row(&mut self, s0: __m256i, s1: __m256i, s2: __m256i) {
        // SAFETY: AVX2, as every caller is compiled with.
        unsafe {
            self.w[0] = _mm256_add_epi64(self.w[0], s0);
            self.w[1] = _mm256_add_epi64(self.w[1], self.w[0]);
            self.w[2] = _mm256_add_epi64(self.w[2], self.w[1]);
            self.wi[0] = _mm256_add_epi32(self.wi[0], s1);
            self.wi[1] = _mm256_add_epi32(self.wi[1], self.wi[0]);
            self.wii = _mm256_add_epi32(self.wii, s2);
        }
    }

    /// Adds the lanes up and moves the sums of rows `y0..y0 + n` to frame coordinates
    /// (`x = x0 + i`) in `wm`.
    #[inline(always)]
    unsafe fn flush(&mut self, x0: u32, y0: u32, n: u32, wm: &mut WeightedMoments) {
        // SAFETY: AVX2, as every caller is compiled with.
        let [w0, w1, w2, wi0, wi1, wii] = unsafe {
            [
                sum64(self.w[0]),
                sum64(self.w[1]),
                sum64(self.w[2]),
                sum32(self.wi[0]),
                sum32(self.wi[1]),
                sum32(self.wii),
            ]
        };
        *self = LaneSums::zero();
        let z = y0 as u64 + n as u64;
        let [s, sy, syy, _] = weigh_rows::<2>([w0, w1, w2, 0], z).map(Wrapping);
        let [si, siy, _, _] = weigh_rows::<1>([wi0, wi1, 0, 0], z).map(Wrapping);
        let (x, two, wii) = (Wrapping(x0 as u64), Wrapping(2), Wrapping(wii));
        // Each sum fits `u64` (`weigh_rows`; weights below 2⁸), so the wrapping is exact.
        wm.w00 += s.0 as u128;
        wm.w10 += (x * s + si).0 as u128;
        wm.w20 += (x * x * s + two * x * si + wii).0 as u128;
        wm.w01 += sy.0 as u128;
        wm.w11 += (x * sy + siy).0 as u128;
        wm.w02 += syy.0 as u128;
    }
}

#[cfg(target_arch = "x86_64")]
use crate::weights::sum_u64_lanes as sum64;

/// The eight 32-bit lanes of `v`, read as unsigned, added in 64 bits.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
unsafe fn sum32(v: __m256i) -> u64 {
    // SAFETY: AVX2, as every caller is compiled with.
    unsafe {
        let z = _mm256_setzero_si256();
        sum64(_mm256_add_epi64(
            _mm256_unpacklo_epi32(v, z),
            _mm256_unpackhi_epi32(v, z),
        ))
    }
}

/// The binary moments of rows `y0..y0 + n` in frame coordinates (`x = x0 + i`) from the
/// running sums of each row's `Σi^p` over its run (`c[p]`, as in [`weigh_rows`]).
#[inline(always)]
fn binary_moments(c: [[u64; 4]; 4], x0: u32, y0: u32, n: u32) -> RawMoments {
    let z = y0 as u64 + n as u64;
    // `s[p][q] = Σ i^p y^q` over the rows' pixels.
    let s = [
        weigh_rows::<3>(c[0], z),
        weigh_rows::<2>(c[1], z),
        weigh_rows::<1>(c[2], z),
        weigh_rows::<0>(c[3], z),
    ]
    .map(|r| r.map(Wrapping));
    let (x, two, three) = (Wrapping(x0 as u64), Wrapping(2u64), Wrapping(3u64));
    // Each moment fits `u64` (`weigh_rows`), so the wrapping is exact.
    RawMoments {
        m00: s[0][0].0,
        m10: (x * s[0][0] + s[1][0]).0,
        m01: s[0][1].0,
        m20: (x * x * s[0][0] + two * x * s[1][0] + s[2][0]).0,
        m11: (x * s[0][1] + s[1][1]).0,
        m02: s[0][2].0,
        m30: (x * x * x * s[0][0] + three * x * x * s[1][0] + three * x * s[2][0] + s[3][0]).0
            as u128,
        m21: (x * x * s[0][1] + two * x * s[1][1] + s[2][1]).0 as u128,
        m12: (x * s[0][2] + s[1][2]).0 as u128,
        m03: s[0][3].0 as u128,
    }
}

/// The columns of a window `n <= 32·NV` pixels wide read as `NV` vectors of 32 pixels.
#[cfg(target_arch = "x86_64")]
struct Columns<const NV: usize> {
    /// Each vector's lanes inside the window (the last vector may reach past its end).
    inside: [__m256i; NV],
    /// Each lane's column `i` from the window's first, and its square, as 16-bit words in the
    /// order the byte-to-word unpacking leaves them ([`COLUMNS`]).
    i_lo: [__m256i; NV],
    i_hi: [__m256i; NV],
    ii_lo: [__m256i; NV],
    ii_hi: [__m256i; NV],
}

#[cfg(target_arch = "x86_64")]
impl<const NV: usize> Columns<NV> {
    #[inline(always)]
    unsafe fn new(n: u32) -> Self {
        let load = |p: *const u8| {
            // SAFETY: `p` is the start of 32 bytes of a static table (below); AVX2, as every
            // caller is compiled with.
            unsafe { _mm256_loadu_si256(p as *const __m256i) }
        };
        let cols = |t: usize, j: usize, half: usize| load(COLUMNS[t][2 * j + half].as_ptr() as _);
        Columns {
            inside: std::array::from_fn(|j| {
                let left = (n as usize).saturating_sub(32 * j).min(32);
                // SAFETY: `32 − left <= 32`: the 32 bytes from there lie in the 64 of INSIDE.
                load(unsafe { INSIDE.as_ptr().add(32 - left) })
            }),
            i_lo: std::array::from_fn(|j| cols(0, j, 0)),
            i_hi: std::array::from_fn(|j| cols(0, j, 1)),
            ii_lo: std::array::from_fn(|j| cols(1, j, 0)),
            ii_hi: std::array::from_fn(|j| cols(1, j, 1)),
        }
    }

    /// The row's `NV` vectors from `p`, the lanes inside the window `>= level` (all ones),
    /// and those lanes as bits (bit `i` of the 128 for column `i`).
    ///
    /// # Safety
    /// `p` points at `32·NV` readable bytes; AVX2, as every caller is compiled with.
    #[inline(always)]
    unsafe fn read(
        &self,
        p: *const u8,
        level: __m256i,
    ) -> ([__m256i; NV], [__m256i; NV], [u64; 2]) {
        // SAFETY: the caller's contract.
        unsafe {
            // Loops, not `array::from_fn`: its closures are not always inlined, and one not
            // inlined is compiled without AVX2 (each intrinsic a call).
            let zero = _mm256_setzero_si256();
            let (mut v, mut at_or_above) = ([zero; NV], [zero; NV]);
            let mut bits = [0u64; 2];
            for j in 0..NV {
                v[j] = _mm256_loadu_si256(p.add(32 * j) as *const __m256i);
                at_or_above[j] = _mm256_and_si256(
                    _mm256_cmpeq_epi8(_mm256_max_epu8(v[j], level), v[j]),
                    self.inside[j],
                );
                bits[j / 2] |=
                    (_mm256_movemask_epi8(at_or_above[j]) as u32 as u64) << (32 * (j % 2));
            }
            (v, at_or_above, bits)
        }
    }

    /// Adds a row's weights `w` (bytes, one a column) to the lane sums: `Σw`, `Σw·i`, `Σw·i²`.
    #[inline(always)]
    unsafe fn add_row(&self, w: [__m256i; NV], lanes: &mut LaneSums) {
        // SAFETY: AVX2, as every caller is compiled with.
        unsafe {
            let zero = _mm256_setzero_si256();
            let (mut s0, mut s1, mut s2) = (zero, zero, zero);
            for (j, w) in w.into_iter().enumerate() {
                s0 = _mm256_add_epi64(s0, _mm256_sad_epu8(w, zero));
                let (lo, hi) = (_mm256_unpacklo_epi8(w, zero), _mm256_unpackhi_epi8(w, zero));
                s1 = _mm256_add_epi32(
                    s1,
                    _mm256_add_epi32(
                        _mm256_madd_epi16(lo, self.i_lo[j]),
                        _mm256_madd_epi16(hi, self.i_hi[j]),
                    ),
                );
                s2 = _mm256_add_epi32(
                    s2,
                    _mm256_add_epi32(
                        _mm256_madd_epi16(lo, self.ii_lo[j]),
                        _mm256_madd_epi16(hi, self.ii_hi[j]),
                    ),
                );
            }
            lanes.add_row(s0, s1, s2);
        }
    }
}

/// A row's one run in a segment of up to 256 columns held as two 128-column masks: columns
/// `t..e` from the segment's first, or `None` when the row holds no run or several (a run of
/// ones shifted down is one less than a power of two).
#[inline(always)]
fn one_run(m0: u128, m1: u128) -> Option<(u32, u32)> {
    let ones_from_bit_0 = |r: u128| r & r.wrapping_add(1) == 0;
    if m0 != 0 {
        let t = m0.trailing_zeros();
        let r = m0 >> t;
        if !ones_from_bit_0(r) {
            return None;
        }
        let e = t + r.wrapping_add(1).trailing_zeros();
        if e < 128 {
            return (m1 == 0).then_some((t, e));
        }
        // The run reaches the first mask's last column: it goes on through the second's first
        // columns, if any, and nothing after.
        ones_from_bit_0(m1).then(|| (t, 128 + m1.wrapping_add(1).trailing_zeros()))
    } else if m1 != 0 {
        let t = m1.trailing_zeros();
        let r = m1 >> t;
        ones_from_bit_0(r).then(|| (128 + t, 128 + t + r.wrapping_add(1).trailing_zeros()))
    } else {
        None
    }
}

/// The weights `min(pixel − bg, cap)` of the foreground lanes `fg` of the row's vectors `v`,
/// 0 elsewhere.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
unsafe fn capped_weights<const N: usize>(
    v: [__m256i; N],
    fg: [__m256i; N],
    (bg, cap): (__m256i, __m256i),
) -> [__m256i; N] {
    let mut w = fg;
    for j in 0..N {
        // SAFETY: AVX2, as every caller is compiled with.
        w[j] = unsafe { _mm256_and_si256(_mm256_min_epu8(_mm256_subs_epu8(v[j], bg), cap), fg[j]) };
    }
    w
}

/// [`narrow_block_avx2`]'s arguments, passed on.
type BlockArgs<'v, 'a> = (
    &'a GrayView<'v, u8>,
    &'a Seg,
    u32,
    u32,
    u32,
    Option<(u32, u32)>,
);

/// [`narrow_block_avx2`] for a segment of `A` 32-pixel vectors in its first 128 columns and
/// `B` in the next 128, with weights when `W`.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
unsafe fn block<const A: usize, const B: usize, const W: bool>(
    (img, seg, y, stop, k, levels): BlockArgs<'_, '_>,
) -> NarrowBlock {
    let n = seg.x1 - seg.x0 + 1;
    let (bg, cap) = levels.unwrap_or((0, 0));
    // SAFETY: AVX2 (the caller's contract); every load reads the 32·(A + B) pixels from
    // `seg.x0` of a row below the height, inside the row (`narrow_block_fits`).
    unsafe {
        let thr = _mm256_set1_epi8(seg.threshold.min(255) as u8 as i8);
        let bgv = _mm256_set1_epi8(bg.min(255) as u8 as i8);
        let capv = _mm256_set1_epi8(cap.min(255) as u8 as i8);
        // The first 128 columns and the next (none when `B = 0`), each its own lane sums (the
        // lanes' column products fit 16 bits within 128 columns).
        let (c0, c1) = (
            Columns::<A>::new(n.min(128)),
            Columns::<B>::new(n.saturating_sub(128)),
        );
        let (mut l0, mut l1) = (LaneSums::zero(), LaneSums::zero());
        let mut weighted = WeightedMoments::default();
        let mut flush_y = y;
        // Running sums of each row's Σi^p over its run (`weigh_rows`).
        let mut c = [[0u64; 4]; 4];
        let mut span = (u32::MAX, 0u32);
        let mut prev: Option<(u32, u32)> = None;
        let mut yy = y;
        loop {
            let p = img.row(yy).as_ptr().add(seg.x0 as usize);
            let (v0, fg0, b0) = c0.read(p, thr);
            // (No read at all in a piece of no vectors, `B = 0`.)
            let (v1, fg1, b1) = c1.read(p.wrapping_add(128), thr);
            // The row's one run, if it holds exactly one: columns `t..e` from the segment's
            // first.
            let run = if A <= 2 && B == 0 {
                let m = b0[0];
                let t = m.trailing_zeros();
                let r = m >> t.min(63);
                (m != 0 && r & r.wrapping_add(1) == 0)
                    .then(|| (t, t + r.wrapping_add(1).trailing_zeros()))
            } else {
                let m1 = if B == 0 {
                    0
                } else {
                    b1[0] as u128 | (b1[1] as u128) << 64
                };
                one_run(b0[0] as u128 | (b0[1] as u128) << 64, m1)
            };
            let Some((t, e)) = run else {
                break;
            };
            let (a, b) = (seg.x0 + t, seg.x0 + e - 1);
            if let Some((pa, pb)) = prev
                && !(pa <= b + k && pb + k >= a)
            {
                break;
            }
            span = (span.0.min(a), span.1.max(b));
            prev = Some((a, b));
            // Σi^p over the run, from the tables.
            debug_assert!(t < e && e <= n && n <= 256);
            for (q, cq) in c.iter_mut().enumerate() {
                let table = &POWER_SUMS[q];
                // SAFETY: `t < e <= n <= 256` (the masks' bits past the segment's `n` columns
                // are cleared by `inside`), and the tables hold 257 entries.
                let sp =
                    (*table.get_unchecked(e as usize) - *table.get_unchecked(t as usize)) as u64;
                cq[0] += sp;
                for r in 1..4 - q {
                    cq[r] += cq[r - 1];
                }
            }
            if W {
                c0.add_row(capped_weights(v0, fg0, (bgv, capv)), &mut l0);
                if B > 0 {
                    c1.add_row(capped_weights(v1, fg1, (bgv, capv)), &mut l1);
                }
                if yy + 1 - flush_y == FLUSH_ROWS {
                    l0.flush(seg.x0, flush_y, FLUSH_ROWS, &mut weighted);
                    if B > 0 {
                        l1.flush(seg.x0 + 128, flush_y, FLUSH_ROWS, &mut weighted);
                    }
                    flush_y = yy + 1;
                }
            }
            yy += 1;
            if yy >= stop {
                break;
            }
        }
        if W && flush_y < yy {
            l0.flush(seg.x0, flush_y, yy - flush_y, &mut weighted);
            if B > 0 {
                l1.flush(seg.x0 + 128, flush_y, yy - flush_y, &mut weighted);
            }
        }
        NarrowBlock {
            end_y: yy,
            moments: binary_moments(c, seg.x0, y, yy - y),
            x_span: span,
            last: prev.unwrap_or((seg.x0, seg.x0)),
            weighted,
        }
    }
}

/// Whether [`ring_avx2`] can read columns `a..e`: at most 128 pixels, whole 32-pixel vectors
/// from `a` inside the row.
pub(super) fn ring_fits((a, e): (u32, u32), width: u32) -> bool {
    let n = e - a;
    (1..=128).contains(&n) && a + 32 * n.div_ceil(32) <= width
}

/// The edge ring's grey-level sums (`ring::add_edge_ring`, the same pixels and weights) of
/// rows `y0..=y1` over columns `a..e`, in vectors: on each row the pixels left of its first
/// pixel `>= top` in the columns and right of its last (all of them in a row with none) weigh
/// `pixel − bg` where above `bg`, summed lane by lane as [`narrow_block_avx2`]'s weights.
///
/// # Safety
/// The CPU must support AVX2; `ring_fits((a, e), img.width())`; `y0 <= y1 < height`.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
#[inline(never)]
pub(super) unsafe fn ring_avx2(
    img: &GrayView<'_, u8>,
    columns: (u32, u32),
    rows: (u32, u32),
    top: u32,
    bg: u32,
) -> WeightedMoments {
    // SAFETY: the caller's contract, passed on.
    unsafe {
        match (columns.1 - columns.0).div_ceil(32) {
            1 => ring::<1>(img, columns, rows, top, bg),
            2 => ring::<2>(img, columns, rows, top, bg),
            3 => ring::<3>(img, columns, rows, top, bg),
            _ => ring::<4>(img, columns, rows, top, bg),
        }
    }
}

/// [`ring_avx2`] for `NV` 32-pixel vectors a row.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
unsafe fn ring<const NV: usize>(
    img: &GrayView<'_, u8>,
    (a, e): (u32, u32),
    (y0, y1): (u32, u32),
    top: u32,
    bg: u32,
) -> WeightedMoments {
    let n = e - a;
    // SAFETY: AVX2 (the caller's contract); every load reads the 32·NV pixels from `a` of a
    // row `<= y1 < height`, inside the row (`ring_fits`).
    unsafe {
        let topv = _mm256_set1_epi8(top.min(255) as u8 as i8);
        let bgv = _mm256_set1_epi8(bg.min(255) as u8 as i8);
        let columns = Columns::<NV>::new(n);
        // Each lane's column from `a` as a signed byte (below 128).
        let lane: [__m256i; NV] = std::array::from_fn(|j| {
            _mm256_add_epi8(
                _mm256_loadu_si256(LANES.as_ptr() as *const __m256i),
                _mm256_set1_epi8(32 * j as i8),
            )
        });
        let mut sums = WeightedMoments::default();
        let mut lanes = LaneSums::zero();
        let mut flush_y = y0;
        for y in y0..y1 + 1 {
            let p = img.row(y).as_ptr().add(a as usize);
            let (v, _, bits) = columns.read(p, topv);
            // The first and last bright columns (none: every lane is outside).
            let (first, last) = if NV <= 2 {
                let m = bits[0];
                if m == 0 {
                    (0, -1)
                } else {
                    (m.trailing_zeros() as i32, 63 - m.leading_zeros() as i32)
                }
            } else {
                let m = bits[0] as u128 | (bits[1] as u128) << 64;
                if m == 0 {
                    (0, -1)
                } else {
                    (m.trailing_zeros() as i32, 127 - m.leading_zeros() as i32)
                }
            };
            let (fv, lv) = (_mm256_set1_epi8(first as i8), _mm256_set1_epi8(last as i8));
            let mut w = v;
            for j in 0..NV {
                let outside = _mm256_and_si256(
                    _mm256_or_si256(
                        _mm256_cmpgt_epi8(fv, lane[j]),
                        _mm256_cmpgt_epi8(lane[j], lv),
                    ),
                    columns.inside[j],
                );
                w[j] = _mm256_and_si256(_mm256_subs_epu8(v[j], bgv), outside);
            }
            columns.add_row(w, &mut lanes);
            if y + 1 - flush_y == FLUSH_ROWS {
                lanes.flush(a, flush_y, FLUSH_ROWS, &mut sums);
                flush_y = y + 1;
            }
        }
        if flush_y <= y1 {
            lanes.flush(a, flush_y, y1 + 1 - flush_y, &mut sums);
        }
        sums
    }
}
