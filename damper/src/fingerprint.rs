//! A stable hash of a computation's inputs, to key stored results by (the gain cache).

/// FNV-1a, 128 bits: a hash that is the same on every platform and Rust version (unlike
/// `std`'s `DefaultHasher`), for fingerprints and checksums of stored data. Not
/// cryptographic: it tells apart inputs, it does not resist forgery.
#[derive(Debug, Clone, Copy)]
pub struct Fnv128(u128);

impl Default for Fnv128 {
    fn default() -> Self {
        Fnv128(0x6c62_272e_07bb_0142_62b8_2175_6295_c58d)
    }
}

impl Fnv128 {
    pub fn bytes(&mut self, bytes: &[u8]) -> &mut Self {
        for &b in bytes {
            self.0 ^= b as u128;
            self.0 = self
                .0
                .wrapping_mul(0x0000_0000_0100_0000_0000_0000_0000_013b);
        }
        self
    }

    pub fn u64(&mut self, v: u64) -> &mut Self {
        self.bytes(&v.to_le_bytes())
    }

    /// The bits of `v` (so `-0.0` and `0.0`, or two NaNs, differ as the solver's inputs may).
    pub fn f64(&mut self, v: f64) -> &mut Self {
        self.u64(v.to_bits())
    }

    pub fn f64s<'a>(&mut self, vs: impl IntoIterator<Item = &'a f64>) -> &mut Self {
        for v in vs {
            self.f64(*v);
        }
        self
    }

    pub fn finish(&self) -> u128 {
        self.0
    }
}
