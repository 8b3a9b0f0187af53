//! Rigid bodies (bones): particles that keep their distances, moved by net force and torque.

use std::ops::Range;

use glam::{Mat3, Quat, Vec3};

use crate::mesh::TriMesh;

/// How a bone moves.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum BoneKind {
    /// Moved by the forces of the springs attached to its particles.
    #[default]
    Dynamic,
    /// Driven by a pose given every step ([`super::dynamics::AnatomySystem::set_kinematic_pose`]);
    /// forces on it are ignored.
    Kinematic,
}

/// Description of a bone: one particle per mesh vertex, plus optional attachment particles
/// (hinge points, insertion points) that move rigidly with it.
///
/// ```
/// use dermis::anatomy::rigid::{BoneDesc, BoneKind};
/// use dermis::anatomy::scenes::box_mesh;
/// use glam::Vec3;
/// let bone = BoneDesc::new(box_mesh(Vec3::ZERO, Vec3::ONE, 1).unwrap(), 0.01)
///     .with_kind(BoneKind::Kinematic)
///     .with_attachments(vec![Vec3::new(0.5, 0.5, 2.0)]);
/// assert_eq!(bone.particle_count(), 8 + 1);
/// ```
#[derive(Debug, Clone, PartialEq)]
pub struct BoneDesc {
    /// Surface of the bone at rest (world frame). Closed and outward-oriented if the bone is used
    /// as a collider for muscles.
    pub mesh: TriMesh,
    /// Mass of each particle, in kg.
    pub particle_mass_kg: f32,
    /// Extra particles (world frame, at rest) that belong to the body, after the mesh vertices.
    pub attachments: Vec<Vec3>,
    /// Dynamic or kinematic.
    pub kind: BoneKind,
}

impl BoneDesc {
    /// A dynamic bone with a particle of `particle_mass_kg` at each vertex of `mesh`.
    pub fn new(mesh: TriMesh, particle_mass_kg: f32) -> Self {
        Self {
            mesh,
            particle_mass_kg,
            attachments: Vec::new(),
            kind: BoneKind::Dynamic,
        }
    }
    /// Sets the kind.
    pub fn with_kind(mut self, kind: BoneKind) -> Self {
        self.kind = kind;
        self
    }
    /// Sets the attachment particles.
    pub fn with_attachments(mut self, attachments: Vec<Vec3>) -> Self {
        self.attachments = attachments;
        self
    }
    /// Number of particles the bone will have: mesh vertices then attachments.
    pub fn particle_count(&self) -> usize {
        self.mesh.positions().len() + self.attachments.len()
    }
}

/// State of a rigid body in an [`super::dynamics::AnatomySystem`].
///
/// Its particles are a contiguous range of the system's particles (mesh vertices first, then
/// attachments); their world positions are always `com + rotation * local`.
#[derive(Debug, Clone)]
pub struct RigidBody {
    pub(crate) particles: Range<u32>,
    pub(crate) local: Vec<Vec3>,
    pub(crate) triangles: Vec<[u32; 3]>,
    pub(crate) mass: f32,
    pub(crate) inertia_body: Mat3,
    pub(crate) inv_inertia_body: Mat3,
    pub(crate) rest_com: Vec3,
    pub(crate) com: Vec3,
    pub(crate) velocity: Vec3,
    pub(crate) rotation: Quat,
    pub(crate) angular_momentum: Vec3,
    pub(crate) force: Vec3,
    pub(crate) torque: Vec3,
    pub(crate) kind: BoneKind,
    /// Kinematic target pose (rotation, translation) for the end of the next step.
    pub(crate) target: Option<(Quat, Vec3)>,
    pub(crate) collider: Option<Collider>,
}

/// A bone's surface as a parry3d shape in the body's local frame (centred on the centre of mass).
#[derive(Clone)]
pub(crate) struct Collider {
    pub(crate) shape: parry3d::shape::TriMesh,
    pub(crate) min: Vec3,
    pub(crate) max: Vec3,
}

impl std::fmt::Debug for Collider {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Collider")
            .field("triangles", &self.shape.indices().len())
            .finish()
    }
}

impl RigidBody {
    /// Mass properties of particles at `positions` with `masses`; `None` if the inertia tensor is
    /// singular.
    pub(crate) fn new(
        particles: Range<u32>,
        positions: &[Vec3],
        masses: &[f32],
        triangles: Vec<[u32; 3]>,
        kind: BoneKind,
    ) -> Option<Self> {
        let mass: f32 = masses.iter().sum();
        let com = positions
            .iter()
            .zip(masses)
            .map(|(p, m)| *p * *m)
            .sum::<Vec3>()
            / mass;
        let local: Vec<Vec3> = positions.iter().map(|p| *p - com).collect();
        let inertia_body = inertia(&local, masses);
        let scale = inertia_body.x_axis.x + inertia_body.y_axis.y + inertia_body.z_axis.z;
        let det = inertia_body.determinant();
        if det.is_nan() || det <= 1e-9 * scale * scale * scale {
            return None;
        }
        Some(Self {
            particles,
            local,
            triangles,
            mass,
            inertia_body,
            inv_inertia_body: inertia_body.inverse(),
            rest_com: com,
            com,
            velocity: Vec3::ZERO,
            rotation: Quat::IDENTITY,
            angular_momentum: Vec3::ZERO,
            force: Vec3::ZERO,
            torque: Vec3::ZERO,
            kind,
            target: None,
            collider: None,
        })
    }
    /// Indices of the body's particles in the system.
    pub fn particles(&self) -> Range<usize> {
        self.particles.start as usize..self.particles.end as usize
    }
    /// Dynamic or kinematic.
    pub fn kind(&self) -> BoneKind {
        self.kind
    }
    /// Total mass, in kg.
    pub fn mass_kg(&self) -> f32 {
        self.mass
    }
    /// Inertia tensor about the centre of mass in the rest orientation, in kg m².
    pub fn inertia_body(&self) -> Mat3 {
        self.inertia_body
    }
    /// Centre of mass, world frame.
    pub fn center_of_mass(&self) -> Vec3 {
        self.com
    }
    /// Velocity of the centre of mass.
    pub fn velocity(&self) -> Vec3 {
        self.velocity
    }
    /// Orientation relative to rest.
    pub fn rotation(&self) -> Quat {
        self.rotation
    }
    /// Angular momentum about the centre of mass, world frame.
    pub fn angular_momentum(&self) -> Vec3 {
        self.angular_momentum
    }
    /// Angular velocity `w = I^-1 L` with the world-frame inertia `R I_body R^T`.
    pub fn angular_velocity(&self) -> Vec3 {
        world_inv_inertia(self.rotation, self.inv_inertia_body) * self.angular_momentum
    }
    /// Pose relative to rest: world position of a rest point `p` is `rotation * p + translation`.
    pub fn pose(&self) -> (Quat, Vec3) {
        (self.rotation, self.com - self.rotation * self.rest_com)
    }
    /// Translational plus rotational kinetic energy, in J.
    pub fn kinetic_energy_j(&self) -> f32 {
        0.5 * self.mass * self.velocity.length_squared()
            + 0.5 * self.angular_velocity().dot(self.angular_momentum)
    }
    /// World position of the body's particle `i` (0-based within the body), `com + R local_i`.
    pub fn particle_position(&self, i: usize) -> Vec3 {
        self.com + self.rotation * self.local[i]
    }
    /// Number of particles that are vertices of the bone's mesh (the attachments follow them).
    pub fn mesh_vertex_count(&self) -> usize {
        self.triangles
            .iter()
            .flatten()
            .max()
            .map_or(0, |&v| v as usize + 1)
    }
    /// Triangles of the bone's mesh, indices within the body's particles.
    pub fn triangles(&self) -> &[[u32; 3]] {
        &self.triangles
    }
    /// Rest world positions of the bone's mesh vertices: apply [`Self::pose`] to place them.
    pub fn rest_mesh_vertices(&self) -> Vec<Vec3> {
        self.local[..self.mesh_vertex_count()]
            .iter()
            .map(|l| self.rest_com + *l)
            .collect()
    }
    /// Sets the pose from a rest-relative (rotation, translation).
    pub(crate) fn set_pose(&mut self, rotation: Quat, translation: Vec3) {
        self.rotation = rotation.normalize();
        self.com = self.rotation * self.rest_com + translation;
    }
}

/// `R I_body^-1 R^T`.
pub(crate) fn world_inv_inertia(rotation: Quat, inv_body: Mat3) -> Mat3 {
    let r = Mat3::from_quat(rotation);
    r * inv_body * r.transpose()
}

/// Inertia tensor `sum m (|r|² I - r r^T)` of point masses at offsets `r` from the centre.
pub(crate) fn inertia(local: &[Vec3], masses: &[f32]) -> Mat3 {
    let mut i = Mat3::ZERO;
    for (r, &m) in local.iter().zip(masses) {
        let rr = r.length_squared();
        i +=
            m * (Mat3::from_diagonal(Vec3::splat(rr)) - Mat3::from_cols(r * r.x, r * r.y, r * r.z));
    }
    i
}
