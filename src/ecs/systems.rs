//! The dermis systems: stiffness, spring rebuild, relaxation with the non-finite guard.

use bevy_ecs::prelude::*;
use glam::Vec3;
use rayon::prelude::*;

use super::SkinError;
use super::components::*;
use crate::solver::{Loads, RelaxConfig, RelaxReport, SolverError, SpringSystem, StopReason};

/// The strain the characteristic force of a skin is measured at (10 %): see [`force_scale_n`].
pub const REFERENCE_STRAIN: f32 = 0.1;

/// Recomputes [`EdgeStiffness`] for the skins whose [`RestGeometry`] or [`SkinMaterial`] changed
/// since this system last ran (every skin on its first frame). Skins that did not change are not
/// visited at all. Errors (a bad modulus, say) are recorded in
/// [`RelaxDiagnostics::stiffness_error`] and leave the previous stiffness in place.
#[expect(
    clippy::type_complexity,
    reason = "the query is spelled out so the reader sees what the system touches"
)]
pub fn compute_edge_stiffness(
    mut skins: Query<
        (
            &RestGeometry,
            &SkinMaterial,
            &mut EdgeStiffness,
            &mut RelaxDiagnostics,
        ),
        Or<(Changed<RestGeometry>, Changed<SkinMaterial>)>,
    >,
) {
    for (rest, material, mut stiffness, mut diagnostics) in &mut skins {
        match material
            .stiffness_rule
            .edge_stiffness(rest.mesh(), &material.youngs_2d_n_per_m)
        {
            Ok(k) => {
                // Unchanged values do not trigger a spring rebuild.
                if stiffness.k_n_per_m != k {
                    stiffness.k_n_per_m = k;
                }
                diagnostics.stiffness_updates += 1;
                diagnostics.stiffness_error = None;
            }
            Err(e) => diagnostics.stiffness_error = Some(e.into()),
        }
    }
}

/// Rebuilds the cached [`SkinSprings`] of the skins whose [`EdgeStiffness`] or
/// [`RestGeometry`] changed (and of newly spawned skins). When only the stiffness changed, the
/// system keeps its vertex order ([`SpringSystem::with_stiffness`]: the same result, without
/// ordering the mesh again). A failure keeps the previous springs and is recorded in
/// [`RelaxDiagnostics::springs_error`].
#[expect(
    clippy::type_complexity,
    reason = "the query is spelled out so the reader sees what the system touches"
)]
pub fn rebuild_springs(
    mut skins: Query<
        (
            Ref<RestGeometry>,
            &EdgeStiffness,
            &mut SkinSprings,
            &mut RelaxDiagnostics,
        ),
        Or<(
            Changed<EdgeStiffness>,
            Changed<RestGeometry>,
            Added<SkinSprings>,
        )>,
    >,
) {
    for (rest, stiffness, mut springs, mut diagnostics) in &mut skins {
        let k = &stiffness.k_n_per_m;
        let edges = rest.mesh().topology().edges();
        // The system's order is the current rest geometry's unless that changed since (now, or
        // in a frame whose rebuild failed and kept the older system).
        let current = springs.order_is_current && !rest.is_changed();
        let built = match &springs.system {
            Some(system) if current => system.with_stiffness(edges, k, rest.edge_lengths_m()),
            _ => SpringSystem::new(rest.positions(), edges, k, rest.edge_lengths_m()),
        };
        springs.order_is_current = current;
        match built {
            Ok(system) => {
                springs.system = Some(system);
                springs.order_is_current = true;
                springs.spring_scale_sq = k.iter().map(|&k| f64::from(k).powi(2)).sum();
                let mut vertex_k = vec![0.0f64; rest.positions().len()];
                for (&[a, b], &k) in rest.mesh().topology().edges().iter().zip(k) {
                    vertex_k[a as usize] += f64::from(k);
                    vertex_k[b as usize] += f64::from(k);
                }
                springs.vertex_k = vertex_k;
                diagnostics.spring_rebuilds += 1;
                diagnostics.springs_error = None;
            }
            Err(e) => diagnostics.springs_error = Some(e.into()),
        }
    }
}

/// The force (N) a skin's residual is measured against when [`RelaxSettings::force_scale_n`]
/// is `None`: `max(primary, ε · |x|max · |K| / tolerance)`.
///
/// - `primary` is the norm of the external forces on free vertices when there are any (the
///   pure solver's convention), else the skin's characteristic force
///   `REFERENCE_STRAIN · L̄ · sqrt(Σ_edges k² + Σ_vertices max(k_normal, k_tangent)²)`: the norm
///   of the spring and anchor forces a displacement of 10 % of the mean edge length `L̄`
///   produces. A relative tolerance `tol` then stops when the leftover force is that of a strain
///   of about `0.1 · tol`, whatever the anchors did this frame: a still frame takes no
///   iteration, and a small motion is not polished to round-off.
/// - The second term is the f32 floor. Positions carry a rounding error of about
///   `ε·|x|max / 2` (`ε = 1.19e-7`), which leaves a force noise of about that times `|K|`, the
///   norm over vertices of the summed spring and anchor stiffness at each vertex. The scale is
///   never so small that `tolerance · scale` falls under twice that noise, so convergence stays
///   reachable instead of every frame spending its whole budget.
pub fn force_scale_n(
    springs: &SkinSprings,
    rest: &RestGeometry,
    positions: &[Vec3],
    anchors: Option<&SkinAnchors>,
    loads: Option<&ExternalLoads>,
    tolerance: f32,
) -> f32 {
    let anchor_k = |v: usize| {
        anchors
            .and_then(|a| a.get(v))
            .map_or(0.0, |a| f64::from(a.k_normal.max(a.k_tangent)))
    };
    let anchor_sq: f64 = (0..springs.vertex_k.len())
        .map(|v| anchor_k(v).powi(2))
        .sum();
    let external: f64 = loads.map_or(0.0, |l| {
        l.forces_n
            .iter()
            .enumerate()
            .filter(|&(i, _)| !l.pinned.get(i).copied().unwrap_or(false))
            .map(|(_, f)| f.as_dvec3().length_squared())
            .sum::<f64>()
            .sqrt()
    });
    let primary = if external > 0.0 {
        external
    } else {
        f64::from(REFERENCE_STRAIN * rest.mean_edge_length_m())
            * (springs.spring_scale_sq + anchor_sq).sqrt()
    };
    let k_norm = springs
        .vertex_k
        .iter()
        .enumerate()
        .map(|(v, &k)| (k + anchor_k(v)).powi(2))
        .sum::<f64>()
        .sqrt();
    primary.max(f32_force_floor_n(positions, k_norm, tolerance)) as f32
}

/// The smallest force scale a relative `tolerance` can be met at with f32 positions: forces
/// carry round-off of about `ε·|x|max·|K|` (`k_norm`: the norm of the per-vertex stiffness sums),
/// so the threshold `tolerance · scale` must stay above it.
pub(crate) fn f32_force_floor_n(positions: &[Vec3], k_norm: f64, tolerance: f32) -> f64 {
    let x_max = positions
        .iter()
        .map(|p| p.abs().max_element())
        .fold(0.0f32, f32::max);
    f64::from(f32::EPSILON * x_max) * k_norm / f64::from(tolerance.max(f32::MIN_POSITIVE))
}

/// The query item of [`relax_skins`].
type RelaxItem<'a> = (
    Entity,
    Ref<'a, SkinSprings>,
    Ref<'a, RestGeometry>,
    Mut<'a, SkinPositions>,
    Mut<'a, LastValidPositions>,
    Option<Ref<'a, SkinAnchors>>,
    Option<Ref<'a, ExternalLoads>>,
    Option<Ref<'a, RelaxSettings>>,
    Mut<'a, RelaxDiagnostics>,
    Option<Mut<'a, SkinContact>>,
    Option<Mut<'a, SolvedAnchors>>,
);

/// Relaxes every skin to equilibrium under its anchors and loads, warm-started from its current
/// [`SkinPositions`], with the budget of its [`RelaxSettings`] (else [`DermisConfig::relax`]).
///
/// Skins are independent and solved in parallel (rayon); each solve is itself bit-identical for
/// any thread count, so the result is too. Non-finite positions, anchors or forces, or a
/// non-finite result, quarantine the skin: it is rolled back to its [`LastValidPositions`], the
/// event goes to its [`RelaxDiagnostics`] and to [`Messages<SkinQuarantined>`], and the other
/// skins are unaffected.
///
/// A skin whose last solve converged and whose inputs (positions, anchors, loads, springs, rest
/// geometry, settings, [`DermisConfig`]) have not changed since is not solved again: the solve
/// would stop at once with the same answer. Its diagnostics keep the last solve's figures, with
/// `iterations == 0`.
#[expect(
    clippy::type_complexity,
    reason = "the query is spelled out so the reader sees what the system touches"
)]
pub fn relax_skins(
    config: Res<DermisConfig>,
    mut skins: Query<(
        Entity,
        Ref<SkinSprings>,
        Ref<RestGeometry>,
        &mut SkinPositions,
        &mut LastValidPositions,
        Option<Ref<SkinAnchors>>,
        Option<Ref<ExternalLoads>>,
        Option<Ref<RelaxSettings>>,
        &mut RelaxDiagnostics,
        Option<&mut SkinContact>,
        Option<&mut SolvedAnchors>,
    )>,
    mut quarantined: MessageWriter<SkinQuarantined>,
) {
    let default = config.relax;
    let config_changed = config.is_changed();
    let mut items: Vec<RelaxItem<'_>> = skins.iter_mut().collect();
    let events: Vec<Vec<SkinQuarantined>> = items
        .par_iter_mut()
        .map(|item| relax_one(item, &default, config_changed))
        .collect();
    quarantined.write_batch(events.into_iter().flatten());
}

fn changed<T>(c: &Option<Ref<'_, T>>) -> bool {
    c.as_ref().is_some_and(|c| c.is_changed())
}

fn first_non_finite(x: &[Vec3]) -> Option<usize> {
    x.iter().position(|p| !p.is_finite())
}

fn relax_one(
    item: &mut RelaxItem<'_>,
    default: &RelaxSettings,
    config_changed: bool,
) -> Vec<SkinQuarantined> {
    let (
        entity,
        springs,
        rest,
        positions,
        last_valid,
        anchors,
        loads,
        settings,
        diagnostics,
        contact,
        solved_anchors,
    ) = item;
    let diagnostics = &mut **diagnostics;
    diagnostics.frames += 1;
    diagnostics.quarantined.clear();
    // Which optional inputs exist: removing one is a change that change detection cannot see.
    let present = [anchors.is_some(), loads.is_some(), settings.is_some()];
    let still = !(config_changed
        || springs.is_changed()
        || rest.is_changed()
        || positions.is_changed()
        || changed(anchors)
        || changed(loads)
        || changed(settings))
        && present == diagnostics.present;
    diagnostics.present = present;
    if still && diagnostics.stop == Some(StopReason::Converged) {
        diagnostics.iterations = 0;
        // A still frame ends the motion: the next start is the anchors' motion alone.
        if let Some(solved) = solved_anchors.as_mut() {
            solved.bypass_change_detection().1.clear();
        }
        return Vec::new();
    }
    diagnostics.stop = None;
    diagnostics.iterations = 0;
    let frame = diagnostics.frames;
    let mut events = Vec::new();
    let mut quarantine = |input, vertex, diagnostics: &mut RelaxDiagnostics| {
        let event = SkinQuarantined {
            skin: *entity,
            vertex,
            input,
            frame,
        };
        diagnostics.quarantined.push(event);
        diagnostics.quarantine_total += 1;
        events.push(event);
    };

    // The chokepoint: nothing non-finite reaches the solver.
    if let Some(v) = first_non_finite(positions) {
        if positions.len() == last_valid.len() {
            positions.copy_from_slice(last_valid);
        }
        quarantine(NonFiniteInput::Position, v, diagnostics);
    }
    let bad_anchor = anchors.and_then(|a| a.iter().position(|a| !a.is_finite()));
    // Positions were rolled back above and can be solved from; bad anchors or forces cannot.
    let mut blocked = false;
    if let Some(v) = bad_anchor {
        quarantine(NonFiniteInput::Anchor, v, diagnostics);
        blocked = true;
    }
    if let Some(v) = loads.and_then(|l| first_non_finite(&l.forces_n)) {
        quarantine(NonFiniteInput::Force, v, diagnostics);
        blocked = true;
    }
    let Some(system) = springs.system().filter(|_| !blocked) else {
        return events;
    };

    let settings = settings.as_deref().copied().unwrap_or(*default);
    let config = RelaxConfig {
        max_iterations: settings.max_iterations,
        tolerance: settings.tolerance,
        force_scale: Some(settings.force_scale_n.unwrap_or_else(|| {
            force_scale_n(
                springs,
                rest,
                positions,
                anchors.as_deref(),
                loads.as_deref(),
                settings.tolerance,
            )
        })),
        ..RelaxConfig::DEFAULT
    };
    let loads = loads.as_deref();
    let solver_loads = Loads {
        forces: loads
            .filter(|l| !l.forces_n.is_empty())
            .map(|l| l.forces_n.as_slice()),
        pinned: loads
            .filter(|l| !l.pinned.is_empty())
            .map(|l| l.pinned.as_slice()),
        anchors: anchors
            .as_deref()
            .filter(|a| !a.is_empty())
            .map(|a| &a.0[..]),
    };
    let x = &mut positions.bypass_change_detection().0;
    // Warm start: the skin carried by its anchors' motion since the last solve, its
    // deviation from them extrapolated.
    let mut predicted = false;
    if let (Some(solved), Some(anchors)) = (solved_anchors.as_mut(), solver_loads.anchors) {
        let solved = solved.bypass_change_detection();
        if solved.0.len() == anchors.len() && solved.0 != anchors {
            crate::collision::predict_from_motion(
                x,
                &mut solved.1,
                &solved.0,
                anchors,
                rest.mesh().topology().edges(),
                &crate::collision::MotionPrediction::DEFAULT,
            );
            predicted = true;
        } else {
            solved.1.clear();
        }
        solved.0.clear();
        solved.0.extend_from_slice(anchors);
    }
    let result = match contact.as_mut() {
        None => system
            .relax(x, &solver_loads, &config)
            .map_err(SkinError::from),
        Some(contact) => {
            let contact = contact.bypass_change_detection();
            let result = relax_with_contact(system, x, &solver_loads, &config, contact);
            diagnostics.contact = Some(contact.collision.diagnostics().clone());
            result
        }
    };
    match result {
        Ok(report) => {
            if let Some(v) = first_non_finite(x) {
                x.copy_from_slice(last_valid);
                quarantine(NonFiniteInput::Result, v, diagnostics);
                if let Some(solved) = solved_anchors.as_mut() {
                    solved.bypass_change_detection().1.clear();
                }
            } else {
                last_valid.0.copy_from_slice(x);
                diagnostics.iterations = report.iterations;
                diagnostics.residual = report.residual;
                diagnostics.force_scale_n = report.force_scale;
                diagnostics.energy_j = report.energy;
                diagnostics.stop = Some(report.stop);
                diagnostics.solve_error = None;
            }
            if report.iterations > 0 || predicted || !diagnostics.quarantined.is_empty() {
                positions.set_changed();
            }
        }
        Err(SkinError::Solver(SolverError::NonFinite { what, vertex })) => {
            let input = match what {
                "anchor" => NonFiniteInput::Anchor,
                "force" => NonFiniteInput::Force,
                _ => NonFiniteInput::Position,
            };
            quarantine(input, vertex, diagnostics);
        }
        Err(e) => diagnostics.solve_error = Some(e),
    }
    events
}

/// One frame of a skin in contact: the collision frame plan, then per substep a contact pass
/// and a relaxation with the contact as the projection. The iteration budget of `config` is
/// shared by the substeps: half of it spread over the intermediate ones (at least one iteration
/// each; they only hold the skin together while the colliders sweep through), the rest for the
/// last one, whose result is the frame's. The report sums the iterations and keeps the last
/// substep's residual, energy and stop reason.
///
/// The last frame's pass state is forgotten first
/// ([`crate::collision::SkinCollision::clear_frame_state`]); the query cache carries over (see
/// [`SkinContact`] for how checkpoints stay exact), and the friction anchors (each vertex's
/// last contact) carry friction along a collider over many frames.
fn relax_with_contact(
    system: &SpringSystem,
    x: &mut [Vec3],
    loads: &Loads<'_>,
    config: &RelaxConfig,
    contact: &mut SkinContact,
) -> Result<RelaxReport, SkinError> {
    use crate::collision::{FrameError, FrameSchedule, relax_frame};
    match relax_frame(
        system,
        &mut contact.collision,
        x,
        loads,
        config,
        &FrameSchedule::DEFAULT,
    ) {
        Ok(frame) => Ok(frame.report),
        Err(FrameError::Collision(e)) => Err(e.into()),
        Err(FrameError::Solver(e)) => Err(e.into()),
    }
}

/// Swaps the [`Messages<SkinQuarantined>`] buffers once a frame. Only used on a standalone
/// `World` ([`DermisPlugin::add_to`](super::DermisPlugin::add_to)); a Bevy `App` does this in
/// its own `First` schedule.
pub fn update_skin_messages(mut messages: ResMut<Messages<SkinQuarantined>>) {
    messages.update();
}
