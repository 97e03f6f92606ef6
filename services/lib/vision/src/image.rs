//! Grey images as borrowed views with a stride, and an owned buffer.
//!
//! Pixel coordinates follow `docs/conventions.md`: x to the right, y down, the centre of pixel
//! `(x, y)` at integer coordinates `(x, y)`, so pixel `(x, y)` covers `[x-½, x+½] × [y-½, y+½]`.
//!
//! A [`GrayView`] borrows pixels it does not own (a frame in shared memory is never copied);
//! rows may be padded, so each row starts `stride` pixels after the previous one.

use crate::error::VisionError;

/// Largest frame side the engine accepts. Moment sums are exact integers up to this size
/// (see `moments.rs` for the bounds).
pub const MAX_SIDE_PX: u32 = 8192;

/// A grey pixel type: 8-bit (`u8`) or 16-bit (`u16`, Y16 cameras).
pub trait Pixel: Copy + Default + Send + Sync + PartialOrd + std::fmt::Debug + 'static {
    /// Largest value this pixel type can hold.
    const MAX_VALUE: u32;
    /// Number of bits, for messages.
    const BITS: u32;
    /// The value widened to `u32`.
    fn value(self) -> u32;
    /// A pixel from a `u32`, saturating at [`Pixel::MAX_VALUE`].
    fn from_u32_saturating(v: u32) -> Self;

    /// Bit `i` set where `chunk[i] >= threshold`, for the first 64 pixels of `chunk`
    /// (which must hold at least 64). The hot loop of blob extraction.
    #[inline(always)]
    fn foreground_mask64(chunk: &[Self], threshold: u32) -> u64 {
        let chunk = &chunk[..64];
        let mut mask = 0u64;
        for (i, p) in chunk.iter().enumerate() {
            mask |= ((p.value() >= threshold) as u64) << i;
        }
        mask
    }

    /// Whether any of the first 64 pixels of `chunk` is `>= threshold`.
    #[inline(always)]
    fn any_foreground64(chunk: &[Self], threshold: u32) -> bool {
        Self::foreground_mask64(chunk, threshold) != 0
    }

    /// Whether any of the first 64 pixels of any of four chunks is `>= threshold`: the test
    /// that skips empty rows of a narrow window four at a time.
    #[inline(always)]
    fn any_foreground64x4(chunks: [&[Self]; 4], threshold: u32) -> bool {
        chunks.iter().any(|c| Self::any_foreground64(c, threshold))
    }

    /// [`Pixel::foreground_mask64`] with 256-bit vectors where the type has them.
    ///
    /// # Safety
    /// The CPU must support AVX2 (`is_x86_feature_detected!("avx2")`); the caller is compiled
    /// with it enabled for the vector instructions to be inlined.
    #[inline(always)]
    unsafe fn foreground_mask64_avx2(chunk: &[Self], threshold: u32) -> u64 {
        Self::foreground_mask64(chunk, threshold)
    }

    /// [`Pixel::any_foreground64x4`] with 256-bit vectors where the type has them.
    ///
    /// # Safety
    /// As [`Pixel::foreground_mask64_avx2`].
    #[inline(always)]
    unsafe fn any_foreground64x4_avx2(chunks: [&[Self]; 4], threshold: u32) -> bool {
        Self::any_foreground64x4(chunks, threshold)
    }

    /// The pixels as bytes, for 8-bit pixels (the byte-wise vector paths); `None` otherwise.
    #[inline(always)]
    fn as_bytes(row: &[Self]) -> Option<&[u8]> {
        let _ = row;
        None
    }

    /// A run's weight sums `(Σw, Σw·x, Σw·x²)` over `row[a..b]`, `w = min(pixel − bg, cap)`
    /// (Eq. 3.1 weights), `x` the pixel's index in `row` (`crate::weights`).
    #[inline(always)]
    fn weight_sums(row: &[Self], a: usize, b: usize, bg: u32, cap: u32) -> (u64, u64, u64) {
        crate::weights::scalar(row, a, b, bg, cap)
    }

    /// [`Pixel::weight_sums`] with 256-bit vectors where the type has them.
    ///
    /// # Safety
    /// As [`Pixel::foreground_mask64_avx2`].
    #[inline(always)]
    unsafe fn weight_sums_avx2(
        row: &[Self],
        a: usize,
        b: usize,
        bg: u32,
        cap: u32,
    ) -> (u64, u64, u64) {
        Self::weight_sums(row, a, b, bg, cap)
    }
}

impl Pixel for u8 {
    const MAX_VALUE: u32 = u8::MAX as u32;
    const BITS: u32 = 8;
    #[inline(always)]
    fn value(self) -> u32 {
        self as u32
    }
    #[inline(always)]
    fn from_u32_saturating(v: u32) -> Self {
        v.min(255) as u8
    }
    #[inline(always)]
    fn as_bytes(row: &[Self]) -> Option<&[u8]> {
        Some(row)
    }

    #[cfg(target_arch = "x86_64")]
    #[inline(always)]
    fn foreground_mask64(chunk: &[Self], threshold: u32) -> u64 {
        use std::arch::x86_64::*;
        let chunk = &chunk[..64];
        // SAFETY: `chunk` holds 64 bytes (sliced above), so each 16-byte load at 16k is in
        // bounds; unaligned loads are allowed; SSE2 is part of the x86_64 baseline.
        unsafe {
            let t = _mm_set1_epi8(threshold.min(255) as u8 as i8);
            let mut mask = 0u64;
            for k in 0..4 {
                let v = _mm_loadu_si128(chunk.as_ptr().add(16 * k) as *const __m128i);
                let ge = _mm_cmpeq_epi8(_mm_max_epu8(v, t), v);
                mask |= (_mm_movemask_epi8(ge) as u16 as u64) << (16 * k);
            }
            mask
        }
    }

    #[cfg(target_arch = "x86_64")]
    #[inline(always)]
    fn any_foreground64(chunk: &[Self], threshold: u32) -> bool {
        use std::arch::x86_64::*;
        let chunk = &chunk[..64];
        // SAFETY: as above, four 16-byte loads inside the 64-byte slice; SSE2 is baseline.
        unsafe {
            let p = chunk.as_ptr() as *const __m128i;
            let (a, b) = (_mm_loadu_si128(p), _mm_loadu_si128(p.add(1)));
            let (c, d) = (_mm_loadu_si128(p.add(2)), _mm_loadu_si128(p.add(3)));
            let m = _mm_max_epu8(_mm_max_epu8(a, b), _mm_max_epu8(c, d));
            let t = _mm_set1_epi8(threshold.min(255) as u8 as i8);
            let ge = _mm_cmpeq_epi8(_mm_max_epu8(m, t), m);
            _mm_movemask_epi8(ge) != 0
        }
    }

    #[cfg(target_arch = "x86_64")]
    #[inline(always)]
    fn any_foreground64x4(chunks: [&[Self]; 4], threshold: u32) -> bool {
        use std::arch::x86_64::*;
        let chunks = chunks.map(|c| &c[..64]);
        // SAFETY: each chunk holds 64 bytes (sliced above): four 16-byte loads inside each;
        // SSE2 is baseline on x86_64.
        unsafe {
            let mut m = _mm_setzero_si128();
            for c in chunks {
                let p = c.as_ptr() as *const __m128i;
                let ab = _mm_max_epu8(_mm_loadu_si128(p), _mm_loadu_si128(p.add(1)));
                let cd = _mm_max_epu8(_mm_loadu_si128(p.add(2)), _mm_loadu_si128(p.add(3)));
                m = _mm_max_epu8(m, _mm_max_epu8(ab, cd));
            }
            let t = _mm_set1_epi8(threshold.min(255) as u8 as i8);
            let ge = _mm_cmpeq_epi8(_mm_max_epu8(m, t), m);
            _mm_movemask_epi8(ge) != 0
        }
    }

    #[cfg(target_arch = "x86_64")]
    #[inline(always)]
    unsafe fn foreground_mask64_avx2(chunk: &[Self], threshold: u32) -> u64 {
        use std::arch::x86_64::*;
        let chunk = &chunk[..64];
        // SAFETY: two 32-byte loads inside the 64-byte slice; the caller guarantees AVX2.
        unsafe {
            let t = _mm256_set1_epi8(threshold.min(255) as u8 as i8);
            let p = chunk.as_ptr() as *const __m256i;
            let (a, b) = (_mm256_loadu_si256(p), _mm256_loadu_si256(p.add(1)));
            let ga = _mm256_cmpeq_epi8(_mm256_max_epu8(a, t), a);
            let gb = _mm256_cmpeq_epi8(_mm256_max_epu8(b, t), b);
            (_mm256_movemask_epi8(ga) as u32 as u64)
                | ((_mm256_movemask_epi8(gb) as u32 as u64) << 32)
        }
    }

    #[cfg(target_arch = "x86_64")]
    #[inline(always)]
    unsafe fn any_foreground64x4_avx2(chunks: [&[Self]; 4], threshold: u32) -> bool {
        use std::arch::x86_64::*;
        let chunks = chunks.map(|c| &c[..64]);
        // SAFETY: two 32-byte loads inside each 64-byte chunk; the caller guarantees AVX2.
        unsafe {
            let mut m = _mm256_setzero_si256();
            for c in chunks {
                let p = c.as_ptr() as *const __m256i;
                m = _mm256_max_epu8(
                    m,
                    _mm256_max_epu8(_mm256_loadu_si256(p), _mm256_loadu_si256(p.add(1))),
                );
            }
            let t = _mm256_set1_epi8(threshold.min(255) as u8 as i8);
            _mm256_movemask_epi8(_mm256_cmpeq_epi8(_mm256_max_epu8(m, t), m)) != 0
        }
    }

    #[cfg(target_arch = "x86_64")]
    #[inline(always)]
    fn weight_sums(row: &[Self], a: usize, b: usize, bg: u32, cap: u32) -> (u64, u64, u64) {
        // SAFETY: 16-byte vectors are SSE2, the x86-64 baseline.
        unsafe { crate::weights::u8_sums::<std::arch::x86_64::__m128i>(row, a, b, bg, cap) }
    }

    #[cfg(target_arch = "x86_64")]
    #[inline(always)]
    unsafe fn weight_sums_avx2(
        row: &[Self],
        a: usize,
        b: usize,
        bg: u32,
        cap: u32,
    ) -> (u64, u64, u64) {
        // SAFETY: the caller guarantees AVX2.
        unsafe { crate::weights::u8_sums::<std::arch::x86_64::__m256i>(row, a, b, bg, cap) }
    }
}

impl Pixel for u16 {
    const MAX_VALUE: u32 = u16::MAX as u32;
    const BITS: u32 = 16;
    #[inline(always)]
    fn value(self) -> u32 {
        self as u32
    }
    #[inline(always)]
    fn from_u32_saturating(v: u32) -> Self {
        v.min(65535) as u16
    }

    // Sixteen-bit masks: `pixel >= t` is `t -sat pixel == 0` (unsigned saturating subtract,
    // SSE2 has no unsigned 16-bit compare), each lane's 0 / 0xFFFF packed to bytes for the
    // byte movemask. A threshold above 65535 takes no pixel.
    #[cfg(target_arch = "x86_64")]
    #[inline(always)]
    fn foreground_mask64(chunk: &[Self], threshold: u32) -> u64 {
        use std::arch::x86_64::*;
        let chunk = &chunk[..64];
        if threshold > 65535 {
            return 0;
        }
        // SAFETY: `chunk` holds 64 pixels (sliced above), so each 8-pixel load at 8k is in
        // bounds; unaligned loads are allowed; SSE2 is part of the x86_64 baseline.
        unsafe {
            let t = _mm_set1_epi16(threshold as u16 as i16);
            let zero = _mm_setzero_si128();
            let p = chunk.as_ptr() as *const __m128i;
            let ge = |k: usize| _mm_cmpeq_epi16(_mm_subs_epu16(t, _mm_loadu_si128(p.add(k))), zero);
            let mut mask = 0u64;
            for k in 0..4 {
                let bytes = _mm_packs_epi16(ge(2 * k), ge(2 * k + 1));
                mask |= (_mm_movemask_epi8(bytes) as u16 as u64) << (16 * k);
            }
            mask
        }
    }

    #[cfg(target_arch = "x86_64")]
    #[inline(always)]
    unsafe fn foreground_mask64_avx2(chunk: &[Self], threshold: u32) -> u64 {
        use std::arch::x86_64::*;
        let chunk = &chunk[..64];
        if threshold > 65535 {
            return 0;
        }
        // SAFETY: four 32-byte loads inside the 128-byte slice; the caller guarantees AVX2.
        unsafe {
            let t = _mm256_set1_epi16(threshold as u16 as i16);
            let zero = _mm256_setzero_si256();
            let p = chunk.as_ptr() as *const __m256i;
            let mut mask = 0u64;
            for k in 0..2 {
                let a = _mm256_loadu_si256(p.add(2 * k));
                let b = _mm256_loadu_si256(p.add(2 * k + 1));
                let ga = _mm256_cmpeq_epi16(_mm256_subs_epu16(t, a), zero);
                let gb = _mm256_cmpeq_epi16(_mm256_subs_epu16(t, b), zero);
                // The pack works within 128-bit lanes: a0 b0 a1 b1 → a0 a1 b0 b1.
                let bytes = _mm256_permute4x64_epi64(_mm256_packs_epi16(ga, gb), 0b11_01_10_00);
                mask |= (_mm256_movemask_epi8(bytes) as u32 as u64) << (32 * k);
            }
            mask
        }
    }
}

/// A rectangle of whole pixels, both corners inclusive: it covers the pixels
/// `x0..=x1` × `y0..=y1`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct PixelRect {
    pub x0: u32,
    pub y0: u32,
    pub x1: u32,
    pub y1: u32,
}

impl PixelRect {
    /// The rectangle covering a whole `width` × `height` frame. Both must be at least 1.
    pub fn full(width: u32, height: u32) -> Self {
        PixelRect {
            x0: 0,
            y0: 0,
            x1: width.saturating_sub(1),
            y1: height.saturating_sub(1),
        }
    }

    pub fn width(&self) -> u32 {
        self.x1 - self.x0 + 1
    }

    pub fn height(&self) -> u32 {
        self.y1 - self.y0 + 1
    }

    pub fn area(&self) -> u64 {
        self.width() as u64 * self.height() as u64
    }

    pub fn contains(&self, x: f64, y: f64) -> bool {
        // Pixel (x1, y1) covers up to x1 + ½.
        x >= self.x0 as f64 - 0.5
            && x <= self.x1 as f64 + 0.5
            && y >= self.y0 as f64 - 0.5
            && y <= self.y1 as f64 + 0.5
    }
}

/// A borrowed grey image: `height` rows of `width` pixels, row `y` starting at `y * stride`.
#[derive(Debug, Clone, Copy)]
pub struct GrayView<'a, P: Pixel> {
    data: &'a [P],
    width: u32,
    height: u32,
    stride: usize,
}

impl<'a, P: Pixel> GrayView<'a, P> {
    /// Checks the geometry once, so that row access afterwards cannot go out of bounds.
    pub fn new(data: &'a [P], width: u32, height: u32, stride: usize) -> Result<Self, VisionError> {
        if width == 0 || height == 0 {
            return Err(VisionError::EmptyImage { width, height });
        }
        if width > MAX_SIDE_PX || height > MAX_SIDE_PX {
            return Err(VisionError::ImageTooLarge {
                width,
                height,
                max: MAX_SIDE_PX,
            });
        }
        if stride < width as usize {
            return Err(VisionError::StrideTooSmall { stride, width });
        }
        let needed = (height as usize - 1) * stride + width as usize;
        if data.len() < needed {
            return Err(VisionError::BufferTooShort {
                len: data.len(),
                needed,
                width,
                height,
                stride,
            });
        }
        Ok(GrayView {
            data,
            width,
            height,
            stride,
        })
    }

    pub fn width(&self) -> u32 {
        self.width
    }

    pub fn height(&self) -> u32 {
        self.height
    }

    pub fn stride(&self) -> usize {
        self.stride
    }

    /// The same view of 8-bit pixels as bytes (the byte-wise vector paths); `None` for other
    /// pixel types.
    #[inline(always)]
    pub(crate) fn as_u8(&self) -> Option<GrayView<'a, u8>> {
        P::as_bytes(self.data).map(|data| GrayView {
            data,
            width: self.width,
            height: self.height,
            stride: self.stride,
        })
    }

    /// Row `y`, exactly `width` pixels. `y` must be below `height` (checked).
    #[inline(always)]
    pub fn row(&self, y: u32) -> &'a [P] {
        let start = y as usize * self.stride;
        &self.data[start..start + self.width as usize]
    }

    /// The 64 pixels from `(x0, y)` on, without bounds checks: the tracking windows' inner loop
    /// reads one such chunk per row.
    ///
    /// # Safety
    /// `y < height` and `x0 + 64 <= width`.
    #[inline(always)]
    pub(crate) unsafe fn chunk64_unchecked(&self, y: u32, x0: usize) -> &'a [P] {
        debug_assert!(y < self.height && x0 + 64 <= self.width as usize);
        let start = y as usize * self.stride + x0;
        // SAFETY: `new` checked `(height − 1)·stride + width <= data.len()`, and the caller
        // guarantees `y < height` and `x0 + 64 <= width`, so `start + 64 <= data.len()`.
        unsafe { self.data.get_unchecked(start..start + 64) }
    }

    /// Asks the CPU to fetch the pixels of `rect` (the 64-byte lines of each of its rows)
    /// into the cache ahead of a read. The part outside the image is left out; a hint only
    /// elsewhere than x86-64.
    #[inline]
    pub fn prefetch_rect(&self, rect: PixelRect) {
        let (x1, y1) = (
            rect.x1.min(self.width.saturating_sub(1)),
            rect.y1.min(self.height.saturating_sub(1)),
        );
        if rect.x0 > x1 || rect.y0 > y1 {
            return;
        }
        #[cfg(target_arch = "x86_64")]
        {
            use std::arch::x86_64::{_MM_HINT_T0, _mm_prefetch};
            let size = std::mem::size_of::<P>();
            let row = self.row(rect.y0);
            let base = row.as_ptr() as usize;
            let stride_bytes = self.stride * size;
            // The first and last byte of the rect's first row; the same plus a stride a row.
            let (mut a, mut b) = (base + rect.x0 as usize * size, base + x1 as usize * size);
            for _ in rect.y0..=y1 {
                let mut line = a & !63;
                while line <= b {
                    // SAFETY: a prefetch never faults (and these lines hold the image).
                    unsafe { _mm_prefetch::<_MM_HINT_T0>(line as *const i8) };
                    line += 64;
                }
                a += stride_bytes;
                b += stride_bytes;
            }
        }
    }

    /// The pixel at `(x, y)`, or `None` outside the image.
    pub fn get(&self, x: u32, y: u32) -> Option<P> {
        if x < self.width && y < self.height {
            Some(self.row(y)[x as usize])
        } else {
            None
        }
    }

    pub fn full_rect(&self) -> PixelRect {
        PixelRect::full(self.width, self.height)
    }
}

/// An owned grey image with rows packed (`stride == width`).
#[derive(Debug, Clone, PartialEq)]
pub struct GrayImage<P: Pixel> {
    data: Vec<P>,
    width: u32,
    height: u32,
}

impl<P: Pixel> GrayImage<P> {
    /// A `width` × `height` image filled with `value`.
    pub fn filled(width: u32, height: u32, value: P) -> Result<Self, VisionError> {
        if width == 0 || height == 0 {
            return Err(VisionError::EmptyImage { width, height });
        }
        if width > MAX_SIDE_PX || height > MAX_SIDE_PX {
            return Err(VisionError::ImageTooLarge {
                width,
                height,
                max: MAX_SIDE_PX,
            });
        }
        Ok(GrayImage {
            data: vec![value; width as usize * height as usize],
            width,
            height,
        })
    }

    /// Wraps packed pixels; `data.len()` must be `width * height`.
    pub fn from_vec(data: Vec<P>, width: u32, height: u32) -> Result<Self, VisionError> {
        GrayView::new(&data, width, height, width as usize)?;
        if data.len() != width as usize * height as usize {
            return Err(VisionError::BufferTooShort {
                len: data.len(),
                needed: width as usize * height as usize,
                width,
                height,
                stride: width as usize,
            });
        }
        Ok(GrayImage {
            data,
            width,
            height,
        })
    }

    pub fn width(&self) -> u32 {
        self.width
    }

    pub fn height(&self) -> u32 {
        self.height
    }

    pub fn as_slice(&self) -> &[P] {
        &self.data
    }

    pub fn as_mut_slice(&mut self) -> &mut [P] {
        &mut self.data
    }

    pub fn into_vec(self) -> Vec<P> {
        self.data
    }

    pub fn view(&self) -> GrayView<'_, P> {
        GrayView {
            data: &self.data,
            width: self.width,
            height: self.height,
            stride: self.width as usize,
        }
    }

    /// Mutable row `y` (checked).
    pub fn row_mut(&mut self, y: u32) -> &mut [P] {
        let start = y as usize * self.width as usize;
        &mut self.data[start..start + self.width as usize]
    }

    pub fn get(&self, x: u32, y: u32) -> Option<P> {
        self.view().get(x, y)
    }

    pub fn set(&mut self, x: u32, y: u32, value: P) {
        if x < self.width && y < self.height {
            let w = self.width as usize;
            self.data[y as usize * w + x as usize] = value;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A prefetch of a rect in, across or past the image's edges (and of a strided view's)
    /// reads nothing and panics nowhere.
    #[test]
    fn prefetching_a_rect_anywhere_is_harmless() {
        let data = vec![7u16; 100 * 37];
        let img = GrayView::new(&data, 90, 37, 100).unwrap();
        let r = |x0, y0, x1, y1| PixelRect { x0, y0, x1, y1 };
        for rect in [
            r(0, 0, 89, 36),
            r(80, 30, 200, 90),
            r(90, 0, 95, 5),
            r(0, 37, 10, 40),
            r(5, 5, 4, 9),
            r(u32::MAX, u32::MAX, u32::MAX, u32::MAX),
        ] {
            img.prefetch_rect(rect);
        }
        assert_eq!(img.row(36)[89], 7);
    }

    /// Every vector mask (SSE2, and AVX2 where the CPU has it) of both pixel types equals the
    /// definition, bit `i` set where `chunk[i] >= threshold`, for values and thresholds at and
    /// around each other and at both ends of the range (and a threshold past it).
    #[test]
    fn vector_masks_equal_the_definition() {
        fn check<P: Pixel>(chunks: &[Vec<P>], thresholds: &[u32]) {
            for c in chunks {
                for &t in thresholds {
                    let want = c
                        .iter()
                        .enumerate()
                        .fold(0u64, |m, (i, p)| m | ((p.value() >= t) as u64) << i);
                    assert_eq!(P::foreground_mask64(c, t), want, "{t} {c:?}");
                    assert_eq!(P::any_foreground64(c, t), want != 0, "{t}");
                    let four = [&c[..], &c[..], &c[..], &c[..]];
                    assert_eq!(P::any_foreground64x4(four, t), want != 0, "{t}");
                    #[cfg(target_arch = "x86_64")]
                    if std::arch::is_x86_feature_detected!("avx2") {
                        // SAFETY: AVX2 was just detected.
                        unsafe {
                            assert_eq!(P::foreground_mask64_avx2(c, t), want, "avx2 {t}");
                            assert_eq!(P::any_foreground64x4_avx2(four, t), want != 0, "{t}");
                        }
                    }
                }
            }
        }
        let mut rng = stereoscope_numeric::SplitMix64::new(64);
        let mut chunks16: Vec<Vec<u16>> = vec![vec![0; 64], vec![65535; 64]];
        for _ in 0..40 {
            chunks16.push((0..64).map(|_| rng.next_u64() as u16).collect());
            // Levels around 1000 and around the top, to meet the thresholds below.
            chunks16.push((0..64).map(|_| 998 + (rng.next_u64() % 5) as u16).collect());
            chunks16.push(
                (0..64)
                    .map(|_| 65533 + (rng.next_u64() % 3) as u16)
                    .collect(),
            );
        }
        // One bright pixel at each place.
        chunks16.extend((0..64).map(|i| (0..64).map(|j| if i == j { 40000 } else { 7 }).collect()));
        let mut t16 = vec![
            0, 1, 7, 8, 999, 1000, 1001, 32767, 32768, 39999, 40000, 40001,
        ];
        t16.extend([65533, 65534, 65535, 65536, 70000, u32::MAX]);
        t16.extend((0..8).map(|_| rng.next_u64() as u16 as u32));
        check(&chunks16, &t16);
        let chunks8: Vec<Vec<u8>> = chunks16
            .iter()
            .map(|c| c.iter().map(|&v| (v >> 8) as u8 ^ v as u8).collect())
            .collect();
        // (An 8-bit threshold is at most 255: the extractor refuses a larger one first.)
        let t8: Vec<u32> = (0..=255).collect();
        check(&chunks8, &t8);
    }

    #[test]
    fn view_rejects_bad_geometry() {
        let buf = [0u8; 12];
        assert!(matches!(
            GrayView::new(&buf, 0, 3, 4),
            Err(VisionError::EmptyImage { .. })
        ));
        assert!(matches!(
            GrayView::new(&buf, 4, 0, 4),
            Err(VisionError::EmptyImage { .. })
        ));
        assert!(matches!(
            GrayView::new(&buf, 4, 3, 3),
            Err(VisionError::StrideTooSmall {
                stride: 3,
                width: 4
            })
        ));
        assert!(matches!(
            GrayView::new(&buf, 4, 4, 4),
            Err(VisionError::BufferTooShort { .. })
        ));
        assert!(matches!(
            GrayView::new(&buf, 9000, 1, 9000),
            Err(VisionError::ImageTooLarge { .. })
        ));
        // The last row need not be padded.
        let v = GrayView::new(&buf[..10], 2, 3, 4).unwrap();
        assert_eq!(v.row(2).len(), 2);
    }

    #[test]
    fn strided_rows_skip_padding() {
        let buf: Vec<u16> = (0..12).collect();
        let v = GrayView::new(&buf, 3, 3, 4).unwrap();
        assert_eq!(v.row(1), &[4, 5, 6]);
        assert_eq!(v.get(2, 2), Some(10));
        assert_eq!(v.get(3, 0), None);
    }
}
