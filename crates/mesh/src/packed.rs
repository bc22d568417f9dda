//! Bit-packed index arrays: each index takes as many bits as the largest
//! one needs, so the compact mesh's per-corner vertex and opposite indices
//! take about 16 and 18 bits on a mesh like `bunny00.off` instead of 32.

/// A read-only array of `u32` indices stored with a fixed number of bits
/// each; `u32::MAX` (the handles' invalid sentinel) is kept as the all-ones
/// pattern, which no stored index uses.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct PackedIndices {
    /// The packed bits, low bits first, and one spare word so that a read
    /// may always look at the word after the one it starts in.
    words: Vec<u64>,
    len: usize,
    bits: u32,
    mask: u64,
}

impl PackedIndices {
    /// Packs `values` (which may contain `u32::MAX` as a sentinel) with the
    /// fewest bits that hold the largest other value and still leave the
    /// all-ones pattern free.
    #[must_use]
    pub fn new(values: &[u32]) -> Self {
        let largest = values
            .iter()
            .copied()
            .filter(|&v| v != u32::MAX)
            .max()
            .map_or(0, u64::from);
        // Values 0..=largest plus the sentinel: largest + 2 patterns.
        let bits = (64 - (largest + 1).leading_zeros()).max(1);
        let mask = (1u64 << bits) - 1;
        let mut words = vec![0u64; (values.len() * bits as usize).div_ceil(64) + 1];
        for (i, &v) in values.iter().enumerate() {
            let v = if v == u32::MAX { mask } else { u64::from(v) };
            let bit = i * bits as usize;
            let (w, off) = (bit / 64, (bit % 64) as u32);
            words[w] |= v << off;
            if off + bits > 64 {
                words[w + 1] |= v >> (64 - off);
            }
        }
        Self {
            words,
            len: values.len(),
            bits,
            mask,
        }
    }

    /// The `i`-th index.
    ///
    /// # Panics
    /// If `i` is out of range.
    #[inline(always)]
    #[must_use]
    pub fn get(&self, i: usize) -> u32 {
        assert!(
            i < self.len,
            "index {i} out of range for {} indices",
            self.len
        );
        let bit = i * self.bits as usize;
        let (w, off) = (bit / 64, (bit % 64) as u32);
        // The next word's bits shifted in: by 64 - off, done in two steps
        // so that off = 0 shifts them all out instead of overflowing.
        let v = ((self.words[w] >> off) | ((self.words[w + 1] << 1) << (63 - off))) & self.mask;
        if v == self.mask {
            u32::MAX
        } else {
            v as u32
        }
    }

    /// Number of indices.
    #[inline]
    #[must_use]
    pub fn len(&self) -> usize {
        self.len
    }

    /// Whether there are no indices.
    #[inline]
    #[must_use]
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// Bits per index.
    #[must_use]
    pub fn bits(&self) -> u32 {
        self.bits
    }

    /// Bytes of storage.
    #[must_use]
    pub fn memory_bytes(&self) -> usize {
        self.words.len() * 8
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn widths_follow_the_largest_index() {
        assert_eq!(PackedIndices::new(&[]).bits(), 1);
        assert_eq!(PackedIndices::new(&[0, 0]).bits(), 1);
        assert_eq!(
            PackedIndices::new(&[1]).bits(),
            2,
            "1 and the sentinel need two bits"
        );
        assert_eq!(PackedIndices::new(&[2, u32::MAX]).bits(), 2);
        assert_eq!(PackedIndices::new(&[3]).bits(), 3);
        assert_eq!(PackedIndices::new(&[65_534]).bits(), 16);
        assert_eq!(PackedIndices::new(&[65_535]).bits(), 17);
        assert_eq!(PackedIndices::new(&[u32::MAX - 1]).bits(), 32);
        let p = PackedIndices::new(&[u32::MAX - 1, u32::MAX, 0]);
        assert_eq!((p.get(0), p.get(1), p.get(2)), (u32::MAX - 1, u32::MAX, 0));
    }

    #[test]
    #[should_panic(expected = "out of range")]
    fn reads_past_the_end_panic() {
        let _ = PackedIndices::new(&[1, 2, 3]).get(3);
    }

    proptest! {
        /// Every value comes back, sentinels included, at every width and
        /// across word boundaries.
        #[test]
        fn values_round_trip(bits in 1u32..=32, raw in proptest::collection::vec(any::<u32>(), 0..300), holes in proptest::collection::vec(any::<bool>(), 300)) {
            let top = if bits == 32 { u32::MAX - 1 } else { (1u32 << bits) - 2 };
            let values: Vec<u32> = raw
                .iter()
                .zip(&holes)
                .map(|(&v, &hole)| if hole { u32::MAX } else { v % (top.saturating_add(1)).max(1) })
                .collect();
            let p = PackedIndices::new(&values);
            prop_assert!(p.bits() <= bits.max(1));
            prop_assert_eq!(p.len(), values.len());
            for (i, &v) in values.iter().enumerate() {
                prop_assert_eq!(p.get(i), v, "index {} of {:?}", i, values);
            }
            prop_assert!(p.memory_bytes() <= (values.len() * p.bits() as usize).div_ceil(64) * 8 + 8);
        }
    }
}
