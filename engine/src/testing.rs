//! Helpers shared by the engine's unit tests.

/// A deterministic stream of pseudo-random numbers (Marsaglia's xorshift32) from `seed`
/// (not 0).
pub(crate) fn xorshift(seed: u32) -> impl FnMut() -> u32 {
    let mut state = seed;
    move || {
        state ^= state << 13;
        state ^= state >> 17;
        state ^= state << 5;
        state
    }
}
