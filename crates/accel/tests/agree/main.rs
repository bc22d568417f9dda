//! Every structure agrees with brute force, and every way of tracing
//! agrees with tracing one ray at a time: one test binary for the three
//! (one link, one copy of the walks' instances, and one pool of test
//! threads that keeps both cores busy to the end, where three binaries
//! compiled the same instances three times and ran one after another).
//! The tests that flip process-wide switches (`avx512.rs`,
//! `scalar_fallback.rs`) stay processes of their own.

#[path = "../common/mod.rs"]
mod common;

/// Closest and any hits, one ray at a time, against brute force.
mod one_ray;
/// Packets of eight rays against the same rays one at a time.
mod packets;
/// Ray streams against the same rays one at a time.
mod stream;
