//! Adaptive binary range coder and the residual coder built on it (patch blobs `MWP3`,
//! `docs/FORMAT.md` "Range coding").
//!
//! The binary coder is LZMA's (Igor Pavlov; the same arithmetic as in the LZMA SDK's
//! `LzmaEnc.c`/`LzmaDec.c`): a 32-bit range renormalised bytewise below 2^24, carries
//! propagated through a cached byte; its probabilities here have 15 bits and adapt at a rate
//! that slows as they learn ([`Bit`]). Every step is an integer operation on values below
//! 2^32, so the browser's decoder (`static/js/lod/rangecoder.js`) gets the same bits with
//! doubles.
//!
//! Residuals (signed integers) are zigzag-mapped, then coded as Elias-gamma-like pairs, as
//! LZMA codes match distances and Draco its prediction residuals: the bit length `k` through a
//! 6-bit adaptive bit tree, the four bits below the leading one adaptively (per `k`), the rest
//! as direct (equiprobable) bits. Each kind of value has its own [`Channel`] of probabilities.
//! A patch has a few thousand values per channel, so every extra context must be learnt from
//! scratch in each patch: on the dragon, conditioning the bit length on the previous one cost
//! 7% more bytes than this single context.

/// Probability scale: probabilities of a 0 bit are in `1..2^15`.
const PROB_BITS: u32 = 15;
const PROB_ONE: u32 = 1 << PROB_BITS;
/// Slowest adaptation: a shift of 5 (about the last 32 bits). The statistics drift as the
/// traversal crosses a patch: on the dragon a shift of 7 cost 3% more bytes, 8 cost 4%.
const MAX_RATE: u8 = 5;

/// An adaptive bit probability. It adapts by a shift that grows with the bits seen (3 for
/// the first, then 4 from the third bit, up to `MAX_RATE`), learning fast while little is
/// known and then tracking, as AV1's and Daala's adaptive CDFs do: a patch codes only a few
/// thousand values per channel, so how fast a probability is learnt matters.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Bit {
    p: u16,
    seen: u8,
}

impl Default for Bit {
    fn default() -> Self {
        Bit {
            p: (PROB_ONE / 2) as u16,
            seen: 0,
        }
    }
}

/// The adaptation shift after `seen` bits: 1 + the bit length of `seen + 2`, capped at
/// `MAX_RATE` (reached at the seventh bit; [`Bit::update`] stops counting at the eighth).
const RATES: [u8; 8] = {
    let mut rates = [0u8; 8];
    let mut seen = 0;
    while seen < rates.len() {
        let rate = 1 + u32::BITS - (seen as u32 + 2).leading_zeros();
        rates[seen] = if rate < MAX_RATE as u32 {
            rate as u8
        } else {
            MAX_RATE
        };
        seen += 1;
    }
    assert!(rates[rates.len() - 1] == MAX_RATE);
    rates
};

/// `if_one` where `mask` is all ones, `if_zero` where it is zero: a choice on a coded bit
/// without a branch (`mask` is `0u32.wrapping_sub(bit as u32)`).
#[inline(always)]
fn select(mask: u32, if_one: u32, if_zero: u32) -> u32 {
    (if_one & mask) | (if_zero & !mask)
}

impl Bit {
    /// Moves the probability towards `bit`. Without branches: the coded bits are what the
    /// coder cannot predict, so a branch on them is mispredicted about as often as they carry
    /// information (this and [`Encoder::bit`] were 8% of a build's time).
    #[inline(always)]
    fn update(&mut self, bit: bool) {
        let rate = RATES[self.seen as usize & 7] as u32;
        let p = self.p as u32;
        let up = p + ((PROB_ONE - p) >> rate);
        let down = p - (p >> rate);
        let one = 0u32.wrapping_sub(bit as u32);
        self.p = select(one, down, up) as u16;
        self.seen += (self.seen < 7) as u8;
    }
}

/// Renormalise below this range.
const TOP: u32 = 1 << 24;
/// Largest bit length of a zigzag-mapped residual a decoder accepts: grid coordinates and ids
/// are below 2^32, so valid residuals (a + b - c of them) stay below 2^34.
pub const MAX_RESIDUAL_BITS: u32 = 40;
/// Bit lengths are coded in a 6-bit tree (0..=63).
const LENGTH_TREE_BITS: u32 = 6;
/// Bits below the leading one coded adaptively.
const ADAPTIVE_MANTISSA: u32 = 4;

/// Range encoder writing to a byte vector.
pub struct Encoder {
    low: u64,
    range: u32,
    cache: u8,
    cache_size: u64,
    out: Vec<u8>,
}

impl Default for Encoder {
    fn default() -> Self {
        Self::new()
    }
}

impl Encoder {
    pub fn new() -> Self {
        Encoder {
            low: 0,
            range: u32::MAX,
            cache: 0,
            cache_size: 1,
            out: Vec::new(),
        }
    }

    fn shift_low(&mut self) {
        if (self.low as u32) < 0xFF00_0000 || (self.low >> 32) != 0 {
            let carry = (self.low >> 32) as u8;
            let mut temp = self.cache;
            loop {
                self.out.push(temp.wrapping_add(carry));
                temp = 0xFF;
                self.cache_size -= 1;
                if self.cache_size == 0 {
                    break;
                }
            }
            self.cache = ((self.low >> 24) & 0xFF) as u8;
        }
        self.cache_size += 1;
        self.low = (self.low & 0x00FF_FFFF) << 8;
    }

    /// Codes `bit` with the adaptive probability `p` (of a 0), updating it. Inlined into the
    /// coders' loops, without a branch on the bit; renormalising (one bit in several) is out
    /// of line.
    #[inline(always)]
    pub fn bit(&mut self, p: &mut Bit, bit: bool) {
        let bound = (self.range >> PROB_BITS) * p.p as u32;
        let one = 0u32.wrapping_sub(bit as u32);
        self.low += (bound & one) as u64;
        self.range = select(one, self.range - bound, bound);
        p.update(bit);
        if self.range < TOP {
            self.normalize();
        }
    }

    #[cold]
    #[inline(never)]
    fn normalize(&mut self) {
        while self.range < TOP {
            self.range <<= 8;
            self.shift_low();
        }
    }

    /// Codes the `count` low bits of `value`, most significant first, each with probability ½.
    pub fn direct(&mut self, value: u64, count: u32) {
        for i in (0..count).rev() {
            self.range >>= 1;
            self.low += (self.range & 0u32.wrapping_sub(((value >> i) & 1) as u32)) as u64;
            if self.range < TOP {
                self.normalize();
            }
        }
    }

    /// Codes the `bits` low bits of `value` through a bit tree of adaptive probabilities
    /// (`probs` has `2^bits` entries; entry 0 is unused).
    pub fn tree(&mut self, probs: &mut [Bit], bits: u32, value: u32) {
        let mut node = 1usize;
        for i in (0..bits).rev() {
            let bit = (value >> i) & 1 == 1;
            self.bit(&mut probs[node], bit);
            node = (node << 1) | bit as usize;
        }
    }

    /// The coded bytes.
    pub fn finish(mut self) -> Vec<u8> {
        for _ in 0..5 {
            self.shift_low();
        }
        self.out
    }
}

/// Range decoder over a byte slice. Reading past the end yields zero bytes; callers bound
/// the work by the counts the blob declares and check what they decode.
pub struct Decoder<'a> {
    bytes: &'a [u8],
    at: usize,
    range: u32,
    code: u32,
}

impl<'a> Decoder<'a> {
    pub fn new(bytes: &'a [u8]) -> Self {
        let mut d = Decoder {
            bytes,
            at: 0,
            range: u32::MAX,
            code: 0,
        };
        for _ in 0..5 {
            d.code = (d.code << 8) | d.next_byte() as u32;
        }
        d
    }

    fn next_byte(&mut self) -> u8 {
        let b = self.bytes.get(self.at).copied().unwrap_or(0);
        self.at += 1;
        b
    }

    /// Whether the decoder has read more bytes than the stream holds (a truncated stream; a
    /// complete one ends exactly where the encoder's five flush bytes do, or before).
    pub fn overrun(&self) -> bool {
        self.at > self.bytes.len()
    }

    #[cold]
    #[inline(never)]
    fn normalize(&mut self) {
        while self.range < TOP {
            self.range <<= 8;
            self.code = (self.code << 8) | self.next_byte() as u32;
        }
    }

    /// Decodes a bit with the adaptive probability `p` (of a 0), updating it; without a
    /// branch on the bit, as [`Encoder::bit`].
    #[inline(always)]
    pub fn bit(&mut self, p: &mut Bit) -> bool {
        let bound = (self.range >> PROB_BITS) * p.p as u32;
        let bit = self.code >= bound;
        let one = 0u32.wrapping_sub(bit as u32);
        self.code -= bound & one;
        self.range = select(one, self.range - bound, bound);
        p.update(bit);
        if self.range < TOP {
            self.normalize();
        }
        bit
    }

    pub fn direct(&mut self, count: u32) -> u64 {
        let mut value = 0u64;
        for _ in 0..count {
            self.range >>= 1;
            let bit = self.code >= self.range;
            self.code -= self.range & 0u32.wrapping_sub(bit as u32);
            value = (value << 1) | bit as u64;
            if self.range < TOP {
                self.normalize();
            }
        }
        value
    }

    pub fn tree(&mut self, probs: &mut [Bit], bits: u32) -> u32 {
        let mut node = 1usize;
        for _ in 0..bits {
            node = (node << 1) | self.bit(&mut probs[node]) as usize;
        }
        (node - (1 << bits)) as u32
    }
}

/// The adaptive probabilities of one kind of residual.
#[derive(Clone)]
pub struct Channel {
    lengths: [Bit; 1 << LENGTH_TREE_BITS],
    mantissa: Vec<[Bit; 1 << ADAPTIVE_MANTISSA]>,
}

impl Default for Channel {
    fn default() -> Self {
        Self::new()
    }
}

impl Channel {
    pub fn new() -> Self {
        Channel {
            lengths: [Bit::default(); 1 << LENGTH_TREE_BITS],
            mantissa: vec![
                [Bit::default(); 1 << ADAPTIVE_MANTISSA];
                MAX_RESIDUAL_BITS as usize + 1
            ],
        }
    }

    /// Codes a signed residual.
    pub fn put(&mut self, enc: &mut Encoder, value: i64) {
        let z = ((value << 1) ^ (value >> 63)) as u64;
        let k = 64 - z.leading_zeros();
        enc.tree(&mut self.lengths, LENGTH_TREE_BITS, k);
        if k > 1 {
            let below = k - 1;
            let adaptive = below.min(ADAPTIVE_MANTISSA);
            let rest = below - adaptive;
            let probs = &mut self.mantissa[(k as usize).min(MAX_RESIDUAL_BITS as usize)];
            enc.tree(
                probs,
                adaptive,
                ((z >> rest) & ((1 << adaptive) - 1)) as u32,
            );
            enc.direct(z, rest);
        }
    }

    /// Decodes a signed residual; `None` when its bit length is beyond
    /// [`MAX_RESIDUAL_BITS`] (no valid blob has one).
    pub fn get(&mut self, dec: &mut Decoder<'_>) -> Option<i64> {
        let k = dec.tree(&mut self.lengths, LENGTH_TREE_BITS);
        if k > MAX_RESIDUAL_BITS {
            return None;
        }
        let z = if k == 0 {
            0
        } else if k == 1 {
            1
        } else {
            let below = k - 1;
            let adaptive = below.min(ADAPTIVE_MANTISSA);
            let rest = below - adaptive;
            let top = dec.tree(&mut self.mantissa[k as usize], adaptive) as u64;
            let low = dec.direct(rest);
            (1u64 << below) | (top << rest) | low
        };
        Some(((z >> 1) as i64) ^ -((z & 1) as i64))
    }
}

/// Adaptive probabilities for a small alphabet (`2^bits` symbols), one tree per context.
#[derive(Clone)]
pub struct Symbols {
    trees: Vec<Vec<Bit>>,
    bits: u32,
}

impl Symbols {
    pub fn new(bits: u32, contexts: usize) -> Self {
        Symbols {
            trees: vec![vec![Bit::default(); 1 << bits]; contexts],
            bits,
        }
    }

    pub fn put(&mut self, enc: &mut Encoder, context: usize, symbol: u32) {
        enc.tree(&mut self.trees[context], self.bits, symbol);
    }

    pub fn get(&mut self, dec: &mut Decoder<'_>, context: usize) -> u32 {
        dec.tree(&mut self.trees[context], self.bits)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn residuals_bits_and_symbols_roundtrip() {
        let mut state = 0x9E37_79B9_7F4A_7C15u64;
        let mut next = move || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            state
        };
        let values: Vec<i64> = (0..20_000)
            .map(|i| {
                let r = next();
                match i % 5 {
                    0 => 0,
                    1 => (r % 7) as i64 - 3,
                    2 => (r % 1000) as i64 - 500,
                    3 => (r >> 30) as i64 - (1 << 33),
                    _ => -((r % (1 << 33)) as i64),
                }
            })
            .collect();
        let bits: Vec<bool> = (0..5000).map(|_| next() % 10 == 0).collect();
        let symbols: Vec<u32> = (0..5000).map(|_| (next() % 6) as u32).collect();
        let mut enc = Encoder::new();
        let (mut ch, mut p, mut sy) = (Channel::new(), Bit::default(), Symbols::new(3, 2));
        for &v in &values {
            ch.put(&mut enc, v);
        }
        for &b in &bits {
            enc.bit(&mut p, b);
        }
        for (i, &s) in symbols.iter().enumerate() {
            sy.put(&mut enc, i % 2, s);
        }
        enc.direct(0x1234_5678_9abc, 48);
        let bytes = enc.finish();
        let mut dec = Decoder::new(&bytes);
        let (mut ch, mut p, mut sy) = (Channel::new(), Bit::default(), Symbols::new(3, 2));
        for &v in &values {
            assert_eq!(ch.get(&mut dec), Some(v));
        }
        for &b in &bits {
            assert_eq!(dec.bit(&mut p), b);
        }
        for (i, &s) in symbols.iter().enumerate() {
            assert_eq!(sy.get(&mut dec, i % 2), s);
        }
        assert_eq!(dec.direct(48), 0x1234_5678_9abc);
        assert!(!dec.overrun());
        // Skewed bits cost well under a bit each.
        let mut enc = Encoder::new();
        let mut p = Bit::default();
        for &b in &bits {
            enc.bit(&mut p, b);
        }
        assert!(enc.finish().len() * 8 < bits.len() / 2);
    }

    #[test]
    fn hostile_streams_decode_to_bounded_values() {
        for fill in [0u8, 0xFF, 0x55] {
            let bytes = vec![fill; 64];
            let mut dec = Decoder::new(&bytes);
            let mut ch = Channel::new();
            for _ in 0..1000 {
                if let Some(v) = ch.get(&mut dec) {
                    assert!(v.unsigned_abs() < 1 << MAX_RESIDUAL_BITS);
                }
            }
        }
    }
}
