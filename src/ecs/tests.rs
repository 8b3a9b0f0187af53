use approx::assert_relative_eq;
use glam::Vec3;

use super::*;
use crate::mesh::TriMesh;
use crate::stiffness::{Modulus, StiffnessRule};

/// A right isosceles triangle with legs of length 1: Eq. 29 with `E2 = 100` gives
/// k = 50, 50, 25 N/m for edges (0,1), (0,2), (1,2).
fn triangle() -> TriMesh {
    TriMesh::new(vec![Vec3::ZERO, Vec3::X, Vec3::Y], vec![[0, 1, 2]]).unwrap()
}

fn spawn_and_run(builder: SkinBuilder) -> (World, Entity) {
    let mut world = World::new();
    let mut schedule = DermisPlugin.build_schedule(&mut world);
    let skin = builder.spawn(&mut world).unwrap();
    schedule.run(&mut world);
    (world, skin)
}

fn scale(world: &World, skin: Entity, tolerance: f32) -> f32 {
    let e = world.entity(skin);
    force_scale_n(
        e.get::<SkinSprings>().unwrap(),
        e.get::<RestGeometry>().unwrap(),
        e.get::<SkinPositions>().unwrap(),
        e.get::<SkinAnchors>(),
        e.get::<ExternalLoads>(),
        tolerance,
    )
}

#[test]
fn anchors_only_force_scale_is_the_force_of_a_ten_percent_strain() {
    let material = SkinMaterial::default().with_youngs_2d(Modulus::Uniform(100.0));
    let (world, skin) =
        spawn_and_run(SkinBuilder::new(triangle(), material).with_rest_anchors(10.0, 4.0));
    let mean_length = (2.0 + 2f64.sqrt()) / 3.0;
    let stiffness = (50f64.powi(2) * 2.0 + 25f64.powi(2) + 3.0 * 10f64.powi(2)).sqrt();
    assert_relative_eq!(
        f64::from(scale(&world, skin, 1e-4)),
        0.1 * mean_length * stiffness,
        max_relative = 1e-5
    );
}

#[test]
fn external_forces_on_free_vertices_set_the_force_scale() {
    let forces = vec![
        Vec3::new(100.0, 0.0, 0.0),
        Vec3::new(0.0, 3.0, 0.0),
        Vec3::new(0.0, 0.0, 4.0),
    ];
    let (world, skin) = spawn_and_run(
        SkinBuilder::new(triangle(), SkinMaterial::default())
            .with_forces(forces)
            .with_pinned([0]),
    );
    // Vertex 0 is pinned, so its 100 N do not count: |(0,3,0), (0,0,4)| = 5 N.
    assert_relative_eq!(scale(&world, skin, 1e-4), 5.0, max_relative = 1e-6);
}

#[test]
fn force_scale_never_asks_for_less_than_f32_round_off() {
    let material = SkinMaterial::default().with_youngs_2d(Modulus::Uniform(100.0));
    let (world, skin) = spawn_and_run(SkinBuilder::new(triangle(), material));
    // Summed stiffness per vertex: v0 = 50 + 50, v1 = 50 + 25, v2 = 50 + 25; |x|max = 1.
    let k_norm = (100f64.powi(2) + 2.0 * 75f64.powi(2)).sqrt();
    let tolerance = 1e-12;
    assert_relative_eq!(
        f64::from(scale(&world, skin, tolerance)),
        f64::from(f32::EPSILON) * k_norm / tolerance as f64,
        max_relative = 1e-5
    );
}

#[test]
fn flat_mesh_normals_point_along_z() {
    for n in vertex_normals(&triangle()) {
        assert_eq!(n, Vec3::Z);
    }
}

#[test]
fn rest_geometry_update_checks_the_vertex_count_and_recomputes_lengths() {
    let mut rest = RestGeometry::new(triangle());
    assert!(matches!(
        rest.set_positions(vec![Vec3::ZERO; 2]),
        Err(SkinError::Length {
            given: 2,
            expected: 3,
            ..
        })
    ));
    rest.set_positions(vec![Vec3::ZERO, 2.0 * Vec3::X, 2.0 * Vec3::Y])
        .unwrap();
    assert_eq!(rest.edge_lengths_m()[0], 2.0);
    assert_eq!(rest.triangle_areas_m2(), &[2.0]);
}

#[test]
fn poisson_ratio_and_rule_stay_in_step() {
    let m = SkinMaterial::default()
        .with_stiffness_rule(StiffnessRule::poisson(0.2))
        .with_poisson_ratio(0.35);
    assert_eq!(m.poisson_ratio, 0.35);
    assert!(matches!(m.stiffness_rule, StiffnessRule::Poisson { nu, .. } if nu == 0.35));
}

#[test]
fn pinned_vertices_stay_where_they_start() {
    let mut forces = vec![Vec3::ZERO; 3];
    forces[1] = Vec3::new(1.0, 1.0, 1.0);
    let start = vec![Vec3::new(0.0, 0.0, 0.5), Vec3::X, Vec3::Y];
    let (world, skin) = spawn_and_run(
        SkinBuilder::new(triangle(), SkinMaterial::default())
            .with_positions(start.clone())
            .with_forces(forces)
            .with_pinned([0, 2]),
    );
    let x = skin_positions(&world, skin).unwrap();
    assert_eq!((x[0], x[2]), (start[0], start[2]));
    assert!(x[1].y > 0.0, "vertex 1 follows its force");
}
