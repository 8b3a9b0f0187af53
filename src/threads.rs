//! rayon's global pool with each worker pinned to a CPU of its own, for a process whose job is
//! dermis's solves (the `dermis` command-line tool builds it so).
//!
//! A relaxation runs its loops on a team of rayon workers that stay awake between loops,
//! spinning (see the solver's `team` module): it assumes its members run at the same time on
//! different CPUs. Linux's scheduler does not always keep them apart: a worker woken by a
//! thread on another CPU may be queued on that CPU, and two workers sharing one CPU take
//! turns there for milliseconds while another CPU idles. A loop then waits for a member that
//! is not running: on session 29's two-CPU machine the helper was missing from ~13 % of a
//! 10k-vertex frame's loops, and pinning the two workers to the two CPUs removed every one of
//! those absences (`benches/README.md`, session 29).
//!
//! Pinning trades that for the scheduler's freedom to move a worker away from a CPU another
//! program is busy on: it suits a process that has the machine to itself (a render farm's
//! export, a benchmark). It is skipped when the pool has more workers than the process may
//! use CPUs, and nothing is pinned off Linux, Windows and the BSDs. Results never depend on
//! it: a solve gives the same bits on any number of threads, pinned or not.
//!
//! ```no_run
//! // At the start of `main`, before anything runs on rayon's global pool.
//! let pool = dermis::threads::build_global_pool(true).expect("no pool built yet");
//! println!("{} workers, pinned to {:?}", pool.threads, pool.cpus);
//! ```

use thiserror::Error;

/// The global pool [`build_global_pool`] built.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct GlobalPool {
    /// Its workers: `RAYON_NUM_THREADS` when set to a positive number, else the CPUs the
    /// process may use (rayon's own default).
    pub threads: usize,
    /// The CPU each worker was pinned to, worker `i` to `cpus[i]` (empty: none pinned).
    pub cpus: Vec<usize>,
}

/// Why [`build_global_pool`] built no pool.
#[derive(Debug, Error)]
pub enum ThreadsError {
    /// rayon's global pool exists already (something ran on it first, or it was built).
    #[error("could not build rayon's global thread pool: {0}")]
    Build(#[from] rayon::ThreadPoolBuildError),
}

/// Builds rayon's global pool with rayon's default number of workers, each pinned to a CPU
/// of its own when `pin` holds and the process may use at least as many CPUs as there are
/// workers (the CPUs it may use, in increasing order: worker `i` to the `i`-th). A worker whose
/// pinning fails runs unpinned. Call it before anything uses the global pool.
pub fn build_global_pool(pin: bool) -> Result<GlobalPool, ThreadsError> {
    let allowed = core_affinity::get_core_ids().unwrap_or_default();
    let threads = std::env::var("RAYON_NUM_THREADS")
        .ok()
        .and_then(|v| v.trim().parse::<usize>().ok())
        .filter(|&t| t > 0)
        .unwrap_or_else(|| {
            std::thread::available_parallelism().map_or(allowed.len().max(1), |n| n.get())
        });
    let cpus: Vec<core_affinity::CoreId> = if pin && threads > 1 && allowed.len() >= threads {
        allowed[..threads].to_vec()
    } else {
        Vec::new()
    };
    let ids = cpus.clone();
    let mut builder = rayon::ThreadPoolBuilder::new().num_threads(threads);
    if !ids.is_empty() {
        builder = builder.start_handler(move |i| {
            if let Some(&cpu) = ids.get(i) {
                core_affinity::set_for_current(cpu);
            }
        });
    }
    builder.build_global()?;
    let cpus: Vec<usize> = cpus.iter().map(|c| c.id).collect();
    // Only the first build succeeds, so this is set once.
    let _ = PINNED.set(cpus.clone());
    Ok(GlobalPool { threads, cpus })
}

/// The CPUs [`build_global_pool`] pinned the global pool's workers to (empty: it did not build
/// the pool, or pinned none).
pub fn pinned_cpus() -> &'static [usize] {
    PINNED.get().map_or(&[], Vec::as_slice)
}

static PINNED: std::sync::OnceLock<Vec<usize>> = std::sync::OnceLock::new();
