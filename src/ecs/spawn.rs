//! Turning a triangle mesh and a material into a skin entity, and reading it back.

use std::sync::Arc;

use bevy_ecs::prelude::*;
use glam::Vec3;

use super::SkinError;
use super::components::*;
use crate::mesh::TriMesh;
use crate::solver::VertexAnchor;
use crate::stiffness::StiffnessRule;

/// Every component of a skin entity except the optional [`RelaxSettings`] override. Made by
/// [`SkinBuilder::build`], already validated.
#[derive(Bundle, Debug, Clone)]
pub struct SkinBundle {
    topology: SkinTopology,
    rest: RestGeometry,
    material: SkinMaterial,
    stiffness: EdgeStiffness,
    springs: SkinSprings,
    positions: SkinPositions,
    last_valid: LastValidPositions,
    anchors: SkinAnchors,
    solved_anchors: SolvedAnchors,
    loads: ExternalLoads,
    diagnostics: RelaxDiagnostics,
}

/// Builds a skin entity from a triangle mesh (its positions are the rest shape) and a material.
///
/// ```
/// use bevy_ecs::prelude::*;
/// use dermis::ecs::{DermisPlugin, SkinBuilder, SkinMaterial, skin_positions};
/// use dermis::mesh::TriMesh;
/// use glam::Vec3;
///
/// let mesh = TriMesh::new(
///     vec![Vec3::ZERO, Vec3::X, Vec3::new(1.0, 1.0, 0.0), Vec3::Y],
///     vec![[0, 1, 2], [0, 2, 3]],
/// )
/// .unwrap();
/// let mut world = World::new();
/// let mut schedule = DermisPlugin.build_schedule(&mut world);
/// // Anchor every vertex where it is, then pull vertex 2 with 1 N along +x.
/// let mut forces = vec![Vec3::ZERO; 4];
/// forces[2] = Vec3::X;
/// let skin = SkinBuilder::new(mesh, SkinMaterial::default())
///     .with_rest_anchors(100.0, 100.0)
///     .with_pinned([0])
///     .with_forces(forces)
///     .spawn(&mut world)
///     .unwrap();
/// schedule.run(&mut world);
/// let x = skin_positions(&world, skin).unwrap();
/// assert_eq!(x[0], Vec3::ZERO); // pinned
/// assert!(x[2].x > 1.0); // pulled
/// ```
#[derive(Debug, Clone)]
pub struct SkinBuilder {
    mesh: TriMesh,
    material: SkinMaterial,
    positions: Option<Vec<Vec3>>,
    anchors: Option<Vec<VertexAnchor>>,
    rest_anchors: Option<(f32, f32)>,
    forces: Vec<Vec3>,
    pinned: Vec<u32>,
    relax: Option<RelaxSettings>,
}

impl SkinBuilder {
    /// A skin at rest in `mesh`'s positions, made of `material`, with no anchors or loads.
    pub fn new(mesh: TriMesh, material: SkinMaterial) -> Self {
        Self {
            mesh,
            material,
            positions: None,
            anchors: None,
            rest_anchors: None,
            forces: Vec::new(),
            pinned: Vec::new(),
            relax: None,
        }
    }

    /// One anchor per vertex (caller's order).
    pub fn with_anchors(mut self, anchors: Vec<VertexAnchor>) -> Self {
        self.anchors = Some(anchors);
        self.rest_anchors = None;
        self
    }

    /// Anchors every vertex to its rest position, along its area-weighted rest normal, with
    /// stiffness `k_normal` and `k_tangent` (N/m).
    pub fn with_rest_anchors(mut self, k_normal: f32, k_tangent: f32) -> Self {
        self.rest_anchors = Some((k_normal, k_tangent));
        self.anchors = None;
        self
    }

    /// Replaces the material's stiffness rule.
    pub fn with_stiffness_rule(mut self, rule: StiffnessRule) -> Self {
        self.material = self.material.with_stiffness_rule(rule);
        self
    }

    /// Pins these vertices (caller's indices) where they start.
    pub fn with_pinned(mut self, vertices: impl IntoIterator<Item = u32>) -> Self {
        self.pinned.extend(vertices);
        self
    }

    /// One external force per vertex, N.
    pub fn with_forces(mut self, forces_n: Vec<Vec3>) -> Self {
        self.forces = forces_n;
        self
    }

    /// Starting positions (the first frame's warm start) instead of the rest positions.
    pub fn with_positions(mut self, positions: Vec<Vec3>) -> Self {
        self.positions = Some(positions);
        self
    }

    /// Overrides [`DermisConfig::relax`] for this skin.
    pub fn with_relax_settings(mut self, settings: RelaxSettings) -> Self {
        self.relax = Some(settings);
        self
    }

    /// Validates everything and returns the bundle and the optional [`RelaxSettings`] override
    /// (insert both on one entity; [`spawn`](Self::spawn) does that).
    pub fn build(self) -> Result<(SkinBundle, Option<RelaxSettings>), SkinError> {
        let n = self.mesh.positions().len();
        let check_len = |what, given: usize| {
            if given == n {
                Ok(())
            } else {
                Err(SkinError::Length {
                    what,
                    given,
                    expected: n,
                })
            }
        };
        let check_finite = |what, v: &[Vec3]| match v.iter().position(|p| !p.is_finite()) {
            Some(vertex) => Err(SkinError::NonFinite { what, vertex }),
            None => Ok(()),
        };
        let positions = match self.positions {
            Some(p) => {
                check_len("positions", p.len())?;
                check_finite("position", &p)?;
                p
            }
            None => self.mesh.positions().to_vec(),
        };
        let anchors = match (self.anchors, self.rest_anchors) {
            (Some(a), _) => {
                check_len("anchors", a.len())?;
                if let Some(vertex) = a.iter().position(|a| !a.is_finite()) {
                    return Err(SkinError::NonFinite {
                        what: "anchor",
                        vertex,
                    });
                }
                a
            }
            (None, Some((k_normal, k_tangent))) => {
                let normals = vertex_normals(&self.mesh);
                SkinAnchors::uniform(self.mesh.positions(), &normals, k_normal, k_tangent).0
            }
            (None, None) => Vec::new(),
        };
        if !self.forces.is_empty() {
            check_len("forces", self.forces.len())?;
            check_finite("force", &self.forces)?;
        }
        let mut pinned = Vec::new();
        if !self.pinned.is_empty() {
            pinned = vec![false; n];
            for &v in &self.pinned {
                *pinned.get_mut(v as usize).ok_or(SkinError::PinOutOfRange {
                    vertex: v,
                    vertex_count: n,
                })? = true;
            }
        }
        let k = self
            .material
            .stiffness_rule
            .edge_stiffness(&self.mesh, &self.material.youngs_2d_n_per_m)?;
        let topology = SkinTopology(Arc::new(self.mesh.topology().clone()));
        let bundle = SkinBundle {
            topology,
            rest: RestGeometry::new(self.mesh),
            material: self.material,
            stiffness: EdgeStiffness { k_n_per_m: k },
            springs: SkinSprings::default(),
            last_valid: LastValidPositions(positions.clone()),
            positions: SkinPositions(positions),
            // The skin starts where its anchors put it: the first frame's warm start carries it
            // by their motion from here.
            solved_anchors: SolvedAnchors(anchors.clone(), Default::default()),
            anchors: SkinAnchors(anchors),
            loads: ExternalLoads {
                forces_n: self.forces,
                pinned,
            },
            diagnostics: RelaxDiagnostics::default(),
        };
        Ok((bundle, self.relax))
    }

    /// Validates and spawns the skin entity in `world`.
    pub fn spawn(self, world: &mut World) -> Result<Entity, SkinError> {
        let (bundle, relax) = self.build()?;
        let mut entity = world.spawn(bundle);
        if let Some(relax) = relax {
            entity.insert(relax);
        }
        Ok(entity.id())
    }

    /// Validates and spawns the skin entity through `commands` (from inside a system).
    pub fn spawn_with(self, commands: &mut Commands) -> Result<Entity, SkinError> {
        let (bundle, relax) = self.build()?;
        let mut entity = commands.spawn(bundle);
        if let Some(relax) = relax {
            entity.insert(relax);
        }
        Ok(entity.id())
    }
}

/// Area-weighted vertex normals of a mesh (unit length; `+z` where they cancel out).
pub fn vertex_normals(mesh: &TriMesh) -> Vec<Vec3> {
    let p = mesh.positions();
    let mut n = vec![Vec3::ZERO; p.len()];
    for &[a, b, c] in mesh.triangles() {
        let face = (p[b as usize] - p[a as usize]).cross(p[c as usize] - p[a as usize]);
        for v in [a, b, c] {
            n[v as usize] += face;
        }
    }
    n.into_iter().map(|n| n.normalize_or(Vec3::Z)).collect()
}

/// The current (after [`DermisSystems::Relax`](super::DermisSystems::Relax): relaxed)
/// positions of a skin, in the vertex order of the mesh it was built from.
pub fn skin_positions(world: &World, skin: Entity) -> Result<&[Vec3], SkinError> {
    world
        .get::<SkinPositions>(skin)
        .map(|p| &p[..])
        .ok_or(SkinError::NotASkin(skin))
}
