//! Support code of the `raymesh` tool that the benchmark crate shares: the
//! numpy ray and hit files of `../shared/BENCH.md`, and its ray workloads.

pub mod npy;
pub mod workload;
