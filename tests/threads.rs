//! `dermis::threads`: rayon's global pool with its workers pinned (its own test binary: the
//! global pool is built once per process).

use dermis::threads::{build_global_pool, pinned_cpus};

#[test]
fn each_worker_runs_on_the_cpu_it_was_pinned_to() {
    let allowed = core_affinity::get_core_ids().unwrap_or_default();
    let pool = build_global_pool(true).expect("the first build of the global pool");
    assert_eq!(pool.threads, rayon::current_num_threads());
    assert_eq!(pinned_cpus(), pool.cpus.as_slice());
    if pool.threads > 1 && allowed.len() >= pool.threads {
        // Worker `i` pinned to the `i`-th CPU the process may use, and nowhere else.
        let expected: Vec<usize> = allowed[..pool.threads].iter().map(|c| c.id).collect();
        assert_eq!(pool.cpus, expected);
        let seen = rayon::broadcast(|ctx| {
            let mask: Vec<usize> = core_affinity::get_core_ids()
                .unwrap_or_default()
                .iter()
                .map(|c| c.id)
                .collect();
            (ctx.index(), mask)
        });
        for (i, mask) in seen {
            assert_eq!(mask, vec![expected[i]], "worker {i}");
        }
    } else {
        // One worker, or fewer CPUs than workers: nothing pinned.
        assert!(pool.cpus.is_empty());
    }
    // The global pool exists now: a second build is a typed error, not a panic.
    let again = build_global_pool(true).expect_err("built already");
    assert!(again.to_string().contains("global thread pool"), "{again}");
}
