//! Issue 8's performance targets, checked against a `dermis bench` run.
//!
//! The targets were set for the 2-core reference machine on the full workloads
//! ([`Plan::FULL`](super::Plan::FULL)); a `--quick` run has other sizes and is not checked. Each
//! check reports its *attainment*: measured / target for a floor (`at_least`), target /
//! measured for a ceiling (`at_most`), so 1 or more means met, and 0.5 means half-way in
//! either direction.

use serde::Serialize;

use super::WorkloadReport;

/// Which side of its target a figure must be on.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Goal {
    /// At least the target (a throughput, a scaling).
    AtLeast,
    /// At most the target (a time, a size).
    AtMost,
}

/// One target: a figure of one workload of [`WorkloadReport`], by its JSON field name.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Target {
    /// The workload's name (`tube-10k`, `tube-100k`, `relax-1m`).
    pub workload: &'static str,
    /// The figure, as named in the report.
    pub metric: &'static str,
    /// Which side of `value` it must be on.
    pub goal: Goal,
    /// The target value, in the figure's unit (per 50,000 collider triangles when
    /// `per_50k_triangles`).
    pub value: f64,
    /// The target scales with the workload's collider (the refit's time per 50k triangles).
    pub per_50k_triangles: bool,
}

/// Issue 8's targets (2 threads, the reference machine).
pub const TARGETS: [Target; 15] = {
    const fn t(workload: &'static str, metric: &'static str, goal: Goal, value: f64) -> Target {
        Target {
            workload,
            metric,
            goal,
            value,
            per_50k_triangles: false,
        }
    }
    use Goal::{AtLeast, AtMost};
    [
        t("tube-10k", "relax_vertex_iterations_per_s", AtLeast, 250e6),
        t("tube-100k", "relax_vertex_iterations_per_s", AtLeast, 330e6),
        t("relax-1m", "relax_vertex_iterations_per_s", AtLeast, 180e6),
        t("tube-100k", "thread_scaling_2_over_1", AtLeast, 1.7),
        t("relax-1m", "thread_scaling_2_over_1", AtLeast, 1.7),
        t("tube-10k", "shuffled_over_ordered", AtMost, 1.1),
        t("tube-100k", "shuffled_over_ordered", AtMost, 1.1),
        t("tube-10k", "collision_us_per_vertex", AtMost, 0.3),
        t("tube-100k", "collision_us_per_vertex", AtMost, 0.3),
        Target {
            per_50k_triangles: true,
            ..t("tube-10k", "collider_refresh_ms", AtMost, 1.0)
        },
        t("tube-10k", "frame_ms_median", AtMost, 4.0),
        t("tube-10k", "frame_ms_p99", AtMost, 6.0),
        t("tube-100k", "frame_ms_median", AtMost, 33.0),
        t("tube-10k", "bytes_per_vertex", AtMost, 96.0),
        t("relax-1m", "bytes_per_vertex", AtMost, 96.0),
    ]
};

/// A target checked against one run.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct TargetCheck {
    /// The workload's name.
    pub workload: &'static str,
    /// The figure's name in the report.
    pub metric: &'static str,
    /// Which side of the target it must be on.
    pub goal: Goal,
    /// The target, in the figure's unit (scaled to the workload's collider for the refresh).
    pub target: f64,
    /// What this run measured.
    pub measured: f64,
    /// measured / target (`at_least`) or target / measured (`at_most`): met at 1 or more.
    pub attainment: f64,
    /// The target is met.
    pub met: bool,
}

/// The figure `metric` of `w` (`None` when the workload has no such figure).
fn figure(w: &WorkloadReport, metric: &str) -> Option<f64> {
    Some(match metric {
        "relax_vertex_iterations_per_s" => w.relax_vertex_iterations_per_s,
        "thread_scaling_2_over_1" => w.thread_scaling_2_over_1,
        "shuffled_over_ordered" => w.shuffled_over_ordered?,
        "collision_us_per_vertex" => w.collision_us_per_vertex?,
        "collider_refresh_ms" => w.collider_refresh_ms?,
        "frame_ms_median" => w.frame_ms_median,
        "frame_ms_p99" => w.frame_ms_p99,
        "bytes_per_vertex" => w.bytes_per_vertex,
        _ => return None,
    })
}

/// Checks `targets` against the workloads of a full run; a target whose workload or figure is
/// missing is left out.
///
/// ```
/// use dermis::bench::targets::{Goal, Target, check};
/// // An empty run checks nothing.
/// let t = Target {
///     workload: "tube-10k",
///     metric: "frame_ms_median",
///     goal: Goal::AtMost,
///     value: 4.0,
///     per_50k_triangles: false,
/// };
/// assert!(check(&[t], &[]).is_empty());
/// ```
pub fn check(targets: &[Target], workloads: &[WorkloadReport]) -> Vec<TargetCheck> {
    targets
        .iter()
        .filter_map(|t| {
            let w = workloads.iter().find(|w| w.name == t.workload)?;
            let measured = figure(w, t.metric)?;
            let target = if t.per_50k_triangles {
                t.value * w.collider_triangles as f64 / 50_000.0
            } else {
                t.value
            };
            let (attainment, met) = match t.goal {
                Goal::AtLeast => (measured / target, measured >= target),
                Goal::AtMost => (target / measured, measured <= target),
            };
            Some(TargetCheck {
                workload: t.workload,
                metric: t.metric,
                goal: t.goal,
                target,
                measured,
                attainment,
                met,
            })
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A workload report with every figure set: `frame_ms` median (p99 twice it), 150 M
    /// vertex-iterations/s, collision and refresh figures only for the arm tubes.
    fn report(name: &'static str, triangles: usize, frame_ms: f64) -> WorkloadReport {
        let arm = name != "relax-1m";
        WorkloadReport {
            name,
            skin_vertices: 10_000,
            collider_triangles: triangles,
            frames: 10,
            frame_ms: vec![frame_ms; 10],
            frame_iterations: vec![70; 10],
            frames_converged: 10,
            frame_ms_median: frame_ms,
            frame_ms_p99: 2.0 * frame_ms,
            iterations_per_frame_mean: 70.0,
            substeps_per_frame_mean: arm.then_some(3.0),
            collision_passes_per_frame_mean: arm.then_some(73.0),
            relax_vertex_iterations_per_s: 150e6,
            relax_fraction_of_floor: 0.5,
            relax_setup_ms: 0.2,
            relax_ns_per_vertex_iteration: crate::bench::RelaxLoops {
                curvature_gather: 2.0,
                force_gather: 4.0,
                step: 0.3,
                direction: 0.3,
                other: 0.07,
            },
            collision_us_per_vertex: arm.then_some(0.6),
            collision_plan_us_per_vertex: arm.then_some(0.05),
            collision_passes_us_per_vertex: arm.then_some(0.15),
            collision_projections_us_per_vertex: arm.then_some(0.4),
            collision_naive_us_per_vertex_pass: arm.then_some(5.0),
            collision_speedup_vs_naive: arm.then_some(15.0),
            collider_refresh_ms: arm.then_some(1.5),
            collider_deferred_refit_ms: arm.then_some(0.3),
            collider_parts_refitted_per_frame: arm.then_some(10.0),
            collider_parts: arm.then_some(64),
            min_clearance_m: arm.then_some(0.002),
            unresolved_max: arm.then_some(0),
            bytes_per_vertex: 90.0,
            thread_scaling_2_over_1: 1.8,
            shuffled_over_ordered: arm.then_some(1.0),
            shuffled_energy_after_30: arm.then_some(1.0),
            relax_speedup_vs_previous: 5.0,
            previous_energy_after_30: 1.0,
            relax_speedup_vs_naive_scatter: 1.0,
            energy_after_30: 1.0,
        }
    }

    #[test]
    fn every_target_names_a_figure_of_its_workload() {
        let run = [
            report("tube-10k", 50_000, 8.0),
            report("tube-100k", 50_000, 100.0),
            report("relax-1m", 0, 2000.0),
        ];
        let checks = check(&TARGETS, &run);
        assert_eq!(checks.len(), TARGETS.len());
        for (c, t) in checks.iter().zip(&TARGETS) {
            assert_eq!(
                (c.workload, c.metric, c.goal),
                (t.workload, t.metric, t.goal)
            );
        }
    }

    #[test]
    fn attainment_is_the_ratio_on_the_targets_side() {
        let run = [
            report("tube-10k", 100_000, 8.0),
            report("relax-1m", 0, 2000.0),
        ];
        let checks = check(&TARGETS, &run);
        let get = |w: &str, m: &str| {
            checks
                .iter()
                .find(|c| c.workload == w && c.metric == m)
                .unwrap_or_else(|| panic!("{w} {m} checked"))
        };
        // A floor: 150 M against 250 M is 0.6 of it; 180 M at 1M: 150 / 180.
        let relax = get("tube-10k", "relax_vertex_iterations_per_s");
        assert_eq!((relax.attainment, relax.met), (0.6, false));
        let relax_1m = get("relax-1m", "relax_vertex_iterations_per_s");
        assert!((relax_1m.attainment - 150.0 / 180.0).abs() < 1e-12);
        // A ceiling: 8 ms against 4 ms is half-way; 16 ms p99 against 6 ms is 6 / 16.
        let median = get("tube-10k", "frame_ms_median");
        assert_eq!((median.attainment, median.met), (0.5, false));
        assert_eq!(get("tube-10k", "frame_ms_p99").attainment, 6.0 / 16.0);
        // Met: scaling 1.8 >= 1.7, 90 B <= 96 B.
        let scaling = get("relax-1m", "thread_scaling_2_over_1");
        assert!(scaling.met && (scaling.attainment - 1.8 / 1.7).abs() < 1e-12);
        assert!(get("relax-1m", "bytes_per_vertex").met);
        // The refresh target is per 50k triangles: 2 ms for this 100k-triangle collider, so
        // 1.5 ms meets it.
        let refresh = get("tube-10k", "collider_refresh_ms");
        assert_eq!((refresh.target, refresh.met), (2.0, true));
        assert!((refresh.attainment - 2.0 / 1.5).abs() < 1e-12);
        // Workloads missing from the run are left out.
        assert!(checks.iter().all(|c| c.workload != "tube-100k"));
    }

    #[test]
    fn a_target_exactly_reached_is_met() {
        let mut w = report("tube-10k", 50_000, 4.0);
        w.relax_vertex_iterations_per_s = 250e6;
        let checks = check(&TARGETS, &[w]);
        for m in ["frame_ms_median", "relax_vertex_iterations_per_s"] {
            let c = checks.iter().find(|c| c.metric == m).unwrap();
            assert!(c.met && c.attainment == 1.0, "{c:?}");
        }
    }
}
