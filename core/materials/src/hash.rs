//! FNV-1a (Fowler, Noll, Vo): a fixed, documented hash, the same on every platform
//! and Rust version (std's hashers promise neither), for what must stay stable across
//! runs: cache keys, checksums, shard assignment. Not for adversarial input.

const OFFSET_64: u64 = 0xcbf2_9ce4_8422_2325;
const PRIME_64: u64 = 0x0000_0100_0000_01b3;
const OFFSET_128: u128 = 0x6c62_272e_07bb_0142_62b8_2175_6295_c58d;
const PRIME_128: u128 = 0x0000_0000_0100_0000_0000_0000_0000_013b;

/// FNV-1a, 64 bits, fed in pieces.
#[derive(Clone, Copy, Debug)]
pub struct Fnv1a(u64);

impl Default for Fnv1a {
    fn default() -> Self {
        Self(OFFSET_64)
    }
}

impl Fnv1a {
    pub fn bytes(&mut self, b: &[u8]) {
        for &x in b {
            self.0 = (self.0 ^ u64::from(x)).wrapping_mul(PRIME_64);
        }
    }

    /// `w`'s little-endian bytes.
    pub fn word(&mut self, w: u64) {
        self.bytes(&w.to_le_bytes());
    }

    pub fn finish(&self) -> u64 {
        self.0
    }
}

/// FNV-1a, 64 bits, of `bytes`.
pub fn fnv1a64(bytes: &[u8]) -> u64 {
    let mut h = Fnv1a::default();
    h.bytes(bytes);
    h.finish()
}

/// FNV-1a, 128 bits, of the pieces one after the other.
pub fn fnv1a128<'a>(pieces: impl IntoIterator<Item = &'a [u8]>) -> u128 {
    pieces.into_iter().flatten().fold(OFFSET_128, |h, &b| {
        (h ^ u128::from(b)).wrapping_mul(PRIME_128)
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn both_widths_match_the_published_test_vectors() {
        // From the FNV reference (Fowler, Noll, Vo): "", "a" and "foobar".
        assert_eq!(fnv1a64(b""), 0xcbf29ce484222325);
        assert_eq!(fnv1a64(b"a"), 0xaf63dc4c8601ec8c);
        assert_eq!(fnv1a64(b"foobar"), 0x85944171f73967e8);
        assert_eq!(fnv1a128([&b""[..]]), 0x6c62272e07bb014262b821756295c58d);
        assert_eq!(fnv1a128([&b"a"[..]]), 0xd228cb696f1a8caf78912b704e4a8964);
    }

    #[test]
    fn pieces_hash_as_their_concatenation() {
        let mut h = Fnv1a::default();
        h.bytes(b"foo");
        h.word(7);
        let mut whole = b"foo".to_vec();
        whole.extend_from_slice(&7u64.to_le_bytes());
        assert_eq!(h.finish(), fnv1a64(&whole));
        assert_eq!(fnv1a128([&b"fo"[..], b"obar"]), fnv1a128([&b"foobar"[..]]));
    }
}
