//! The hasher of geometry fingerprints (a mesh's arrays, a medium's density grid), which cache
//! keys hold: FNV-1a over explicit little-endian bytes, so a fingerprint depends on the values
//! hashed alone, never on the Rust release, the platform or `std`'s randomly seeded hashers.
//! Cache keys themselves are derived from serialized input structs ([`crate::cache`]).

/// FNV-1a, 64 bits. Feed values with the typed helpers (each writes a fixed byte layout) and
/// read the result with [`Fnv64::finish`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Fnv64(u64);

impl Fnv64 {
    const OFFSET: u64 = 0xcbf2_9ce4_8422_2325;
    const PRIME: u64 = 0x0100_0000_01b3;

    pub const fn new() -> Fnv64 {
        Fnv64(Fnv64::OFFSET)
    }

    pub fn bytes(&mut self, b: &[u8]) {
        for &x in b {
            self.0 ^= x as u64;
            self.0 = self.0.wrapping_mul(Fnv64::PRIME);
        }
    }

    /// Four bytes, little-endian.
    pub fn u32(&mut self, v: u32) {
        self.bytes(&v.to_le_bytes());
    }

    /// Eight bytes, little-endian.
    pub fn u64(&mut self, v: u64) {
        self.bytes(&v.to_le_bytes());
    }

    /// The bit pattern: `0.0` and `-0.0` differ, every NaN payload is its own value.
    pub fn f32(&mut self, v: f32) {
        self.u32(v.to_bits());
    }

    /// The bit pattern, as [`Fnv64::f32`].
    pub fn f64(&mut self, v: f64) {
        self.u64(v.to_bits());
    }

    /// Length-prefixed, so `("ab", "c")` and `("a", "bc")` differ.
    pub fn str(&mut self, s: &str) {
        self.u64(s.len() as u64);
        self.bytes(s.as_bytes());
    }

    pub fn finish(&self) -> u64 {
        self.0
    }
}

impl Default for Fnv64 {
    fn default() -> Self {
        Fnv64::new()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn of(b: &[u8]) -> u64 {
        let mut h = Fnv64::new();
        h.bytes(b);
        h.finish()
    }

    #[test]
    fn published_fnv1a_64_vectors() {
        // From the FNV reference test suite (Noll).
        assert_eq!(of(b""), 0xcbf2_9ce4_8422_2325);
        assert_eq!(of(b"a"), 0xaf63_dc4c_8601_ec8c);
        assert_eq!(of(b"foobar"), 0x8594_4171_f739_67e8);
    }

    #[test]
    fn typed_helpers_are_their_little_endian_bytes() {
        let mut a = Fnv64::new();
        a.u32(0x0403_0201);
        a.f64(1.5);
        a.str("ab");
        let mut b = Fnv64::new();
        b.bytes(&[1, 2, 3, 4]);
        b.bytes(&1.5f64.to_bits().to_le_bytes());
        b.bytes(&2u64.to_le_bytes());
        b.bytes(b"ab");
        assert_eq!(a.finish(), b.finish());
        let (mut x, mut y) = (Fnv64::new(), Fnv64::new());
        x.str("ab");
        x.str("c");
        y.str("a");
        y.str("bc");
        assert_ne!(x.finish(), y.finish());
        let (mut p, mut n) = (Fnv64::new(), Fnv64::new());
        p.f32(0.0);
        n.f32(-0.0);
        assert_ne!(p.finish(), n.finish());
    }
}
