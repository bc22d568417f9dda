//! The side-by-side benchmarks' engines and reports, shared by the
//! `raymesh-peers` and `raymesh-mesh-peers` binaries: raymesh and each
//! peer behind one [`engines::Engine`] interface, Embree's wrapping (with
//! `--features embree`), the chart, and the records a run reports.
//!
//! A library of its own so that the engines (every peer's generic code)
//! compile once: as modules of a binary they compiled twice, for the
//! binary and again for its unit tests. Never a dependency of raymesh's
//! libraries: the peers stay here.

pub mod chart;
#[cfg(feature = "embree")]
pub mod embree_peer;
pub mod engines;
pub mod thread_list;

use raymesh_accel::AccelKind;
use serde::Serialize;

/// One engine's pass over one workload.
#[derive(Serialize)]
pub struct Trace {
    /// Always `trace` (beside the build records in `--json`'s output).
    pub kind: &'static str,
    /// The mesh's file name.
    pub mesh: String,
    /// The workload's name (BENCH.md), or the rays' file.
    pub workload: String,
    /// Threads the pass ran on.
    pub threads: usize,
    /// `closest` or `any-hit`.
    pub query: &'static str,
    /// The engine's name (`raymesh`, `embree`, `obvhs`, ...).
    pub engine: &'static str,
    /// The raymesh structure, for raymesh's engines.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub accel: Option<&'static str>,
    /// Millions of rays a second, the best of the repeats.
    pub mrays_per_s: f64,
    /// raymesh's Mrays/s over this engine's.
    pub raymesh_ratio: f64,
    /// Share of rays whose answer matches the reference engine's.
    pub agree: f64,
    /// The engine the hits are compared with: the run's first (Embree
    /// where built in and asked for, raymesh otherwise).
    pub agree_with: &'static str,
}

impl Trace {
    /// `engine`'s pass over `workload` (`any`: any-hit queries) at `threads`
    /// threads (over raymesh structure `accel`, for raymesh's engines),
    /// its hits agreeing with `agree_with`'s on a fraction `agree` of the
    /// rays; raymesh's ratio is filled in once every engine has run.
    #[allow(clippy::too_many_arguments)]
    pub fn new(
        mesh: &str,
        workload: &str,
        threads: usize,
        any: bool,
        engine: &'static str,
        accel: Option<AccelKind>,
        mrays_per_s: f64,
        agree: f64,
        agree_with: &'static str,
    ) -> Self {
        Self {
            kind: "trace",
            mesh: mesh.to_string(),
            workload: workload.to_string(),
            threads,
            query: if any { "any-hit" } else { "closest" },
            engine,
            accel: accel.map(AccelKind::name),
            mrays_per_s,
            raymesh_ratio: f64::NAN,
            agree,
            agree_with,
        }
    }

    /// Whether `other` measured the same case (mesh, workload, thread
    /// count and query), whatever the engine.
    pub fn same_case(&self, other: &Trace) -> bool {
        self.mesh == other.mesh
            && self.workload == other.workload
            && self.threads == other.threads
            && self.query == other.query
    }
}
