//! Ready-made anatomy scenes and the simple meshes they are built from (tubes, boxes).

use glam::{Quat, Vec3};

use super::AnatomyError;
use super::dynamics::{AnatomySystem, DynamicsConfig, MuscleEnd};
use super::lattice::{MuscleConfig, MuscleLattice};
use super::rigid::{BoneDesc, BoneKind};
use crate::mesh::TriMesh;

/// A closed cylinder from `a` to `b` of radius `radius_m`: `rings + 1` rings of `segments`
/// vertices and a centre vertex on each flat cap, wound outwards.
pub fn tube_mesh(
    a: Vec3,
    b: Vec3,
    radius_m: f32,
    segments: u32,
    rings: u32,
) -> Result<TriMesh, AnatomyError> {
    super::positive("radius_m", radius_m)?;
    if segments < 3 || rings < 1 {
        return Err(AnatomyError::InvalidParameter {
            name: "segments (>= 3) or rings (>= 1)",
            value: segments.min(rings) as f32,
        });
    }
    let t = (b - a).normalize_or_zero();
    if t == Vec3::ZERO {
        return Err(AnatomyError::DegenerateSegment { segment: 0 });
    }
    let u = t.any_orthonormal_vector();
    let w = t.cross(u);
    let mut x = Vec::new();
    for k in 0..=rings {
        let c = a.lerp(b, k as f32 / rings as f32);
        for i in 0..segments {
            let th = std::f32::consts::TAU * i as f32 / segments as f32;
            x.push(c + radius_m * (th.cos() * u + th.sin() * w));
        }
    }
    let (c0, c1) = (x.len() as u32, x.len() as u32 + 1);
    x.push(a);
    x.push(b);
    let p = |k: u32, i: u32| k * segments + i % segments;
    let mut tris = Vec::new();
    for k in 0..rings {
        for i in 0..segments {
            tris.push([p(k, i), p(k, i + 1), p(k + 1, i + 1)]);
            tris.push([p(k, i), p(k + 1, i + 1), p(k + 1, i)]);
        }
    }
    for i in 0..segments {
        tris.push([c0, p(0, i + 1), p(0, i)]);
        tris.push([c1, p(rings, i), p(rings, i + 1)]);
    }
    Ok(TriMesh::new(x, tris)?)
}

/// An open cylinder (a sleeve) from `a` to `b` of radius `radius_m`: `rings + 1` rings of
/// `segments` vertices, no caps, normals pointing outwards. Used as a skin over a muscle.
pub fn sleeve_mesh(
    a: Vec3,
    b: Vec3,
    radius_m: f32,
    segments: u32,
    rings: u32,
) -> Result<TriMesh, AnatomyError> {
    let closed = tube_mesh(a, b, radius_m, segments, rings)?;
    let ring_vertices = ((rings + 1) * segments) as usize;
    let x = closed.positions()[..ring_vertices].to_vec();
    let tris = closed.triangles()[..(2 * rings * segments) as usize].to_vec();
    Ok(TriMesh::new(x, tris)?)
}

/// The surface of the box `[min, max]`, each face split into `subdivisions²` squares (two
/// triangles each), wound outwards.
pub fn box_mesh(min: Vec3, max: Vec3, subdivisions: u32) -> Result<TriMesh, AnatomyError> {
    let s = subdivisions.max(1);
    if !(min.is_finite() && max.is_finite() && min.cmplt(max).all()) {
        return Err(AnatomyError::InvalidParameter {
            name: "box extent (max - min must be positive)",
            value: (max - min).min_element(),
        });
    }
    let n = s + 1;
    let mut index = vec![u32::MAX; (n * n * n) as usize];
    let mut x = Vec::new();
    let mut vertex = |g: [u32; 3]| {
        let slot = &mut index[((g[2] * n + g[1]) * n + g[0]) as usize];
        if *slot == u32::MAX {
            *slot = x.len() as u32;
            let f = Vec3::new(g[0] as f32, g[1] as f32, g[2] as f32) / s as f32;
            x.push(min + (max - min) * f);
        }
        *slot
    };
    let mut tris = Vec::new();
    for axis in 0..3 {
        let (b, c) = ((axis + 1) % 3, (axis + 2) % 3);
        for side in [0, s] {
            for i in 0..s {
                for j in 0..s {
                    let mut corner = |di: u32, dj: u32| {
                        let mut g = [0; 3];
                        g[axis] = side;
                        g[b] = i + di;
                        g[c] = j + dj;
                        vertex(g)
                    };
                    let (p00, p10, p11, p01) =
                        (corner(0, 0), corner(1, 0), corner(1, 1), corner(0, 1));
                    if side == s {
                        tris.push([p00, p10, p11]);
                        tris.push([p00, p11, p01]);
                    } else {
                        tris.push([p00, p11, p10]);
                        tris.push([p00, p01, p11]);
                    }
                }
            }
        }
    }
    Ok(TriMesh::new(x, tris)?)
}

/// Parameters of the [`jaw`] scene.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct JawConfig {
    /// Time stepping.
    pub dynamics: DynamicsConfig,
    /// The platysma-like muscle.
    pub muscle: MuscleConfig,
    /// Mass of each bone particle, kg.
    pub bone_particle_mass_kg: f32,
    /// Stiffness of each of the two zero-length hinge springs, N/m.
    pub hinge_k_n_per_m: f32,
    /// Stiffness of each insertion spring, N/m.
    pub insertion_k_n_per_m: f32,
    /// Stiffness of the elastic tissue that holds the jaw closed, N/m.
    pub closing_k_n_per_m: f32,
}

impl Default for JawConfig {
    fn default() -> Self {
        Self {
            dynamics: DynamicsConfig {
                dt_s: 1e-3,
                substeps: 10,
                drag: 0.01,
                gravity: Vec3::ZERO,
            },
            muscle: MuscleConfig {
                sections: 10,
                cell_area_m2: 6e-6,
                ..MuscleConfig::default()
            },
            bone_particle_mass_kg: 0.01,
            hinge_k_n_per_m: 2e4,
            insertion_k_n_per_m: 200.0,
            closing_k_n_per_m: 400.0,
        }
    }
}

/// The paper's Fig. 1: a skull, a hinged jaw and a platysma-like muscle from under the chin to
/// the top of the spine. Axes: `x` lateral, `y` up, `z` forward; the hinge is the `x` axis.
#[derive(Debug, Clone)]
pub struct JawScene {
    /// The simulation.
    pub system: AnatomySystem,
    /// Kinematic skull.
    pub skull: usize,
    /// Dynamic jaw, hinged to the skull.
    pub jaw: usize,
    /// Kinematic spine (the muscle's fixed anchor).
    pub spine: usize,
    /// The platysma.
    pub muscle: usize,
}

impl JawScene {
    /// Where the muscle's axis starts (under the chin) and ends (at the spine), m.
    pub const MUSCLE_AXIS: [Vec3; 2] = [Vec3::new(0.0, -0.032, 0.07), Vec3::new(0.0, -0.11, -0.04)];
    /// Rest radius of the muscle surface, m.
    pub const MUSCLE_RADIUS_M: f32 = 0.01;

    /// Hinge axis: positive rotation about it moves the chin down (opens the mouth).
    pub const HINGE_AXIS: Vec3 = Vec3::X;

    /// Jaw opening angle about [`Self::HINGE_AXIS`], radians (0 when closed).
    pub fn jaw_angle_rad(&self) -> f32 {
        let q = self
            .system
            .body(self.jaw)
            .map_or(Quat::IDENTITY, |b| b.rotation());
        let q = if q.w < 0.0 { -q } else { q };
        2.0 * Vec3::new(q.x, q.y, q.z).dot(Self::HINGE_AXIS).atan2(q.w)
    }

    /// Sets the activation and runs `steps` steps; returns the jaw angle at the end.
    pub fn settle(&mut self, activation: f32, steps: usize) -> Result<f32, AnatomyError> {
        self.system.set_activation(self.muscle, activation)?;
        for _ in 0..steps {
            self.system.step()?;
        }
        Ok(self.jaw_angle_rad())
    }
}

/// Builds the jaw scene (see [`JawScene`]).
///
/// ```no_run
/// use dermis::anatomy::scenes::{JawConfig, jaw};
/// let mut scene = jaw(&JawConfig::default()).unwrap();
/// let closed = scene.settle(0.0, 100).unwrap();
/// let open = scene.settle(1.0, 300).unwrap();
/// assert!(open > closed);
/// ```
pub fn jaw(config: &JawConfig) -> Result<JawScene, AnatomyError> {
    let mut system = AnatomySystem::new(config.dynamics)?;
    let hinge = [Vec3::new(-0.045, 0.0, 0.0), Vec3::new(0.045, 0.0, 0.0)];
    let (skull_tissue, jaw_tissue) = (Vec3::new(0.0, 0.02, 0.05), Vec3::new(0.0, -0.005, 0.05));
    let mass = config.bone_particle_mass_kg;
    let skull = system.add_bone(
        &BoneDesc::new(
            box_mesh(
                Vec3::new(-0.06, 0.01, -0.06),
                Vec3::new(0.06, 0.12, 0.10),
                2,
            )?,
            mass,
        )
        .with_kind(BoneKind::Kinematic)
        .with_attachments(vec![hinge[0], hinge[1], skull_tissue]),
    )?;
    let jaw = system.add_bone(
        &BoneDesc::new(
            box_mesh(
                Vec3::new(-0.045, -0.02, 0.0),
                Vec3::new(0.045, -0.004, 0.09),
                4,
            )?,
            mass,
        )
        .with_attachments(vec![hinge[0], hinge[1], jaw_tissue]),
    )?;
    let spine = system.add_bone(
        &BoneDesc::new(
            box_mesh(
                Vec3::new(-0.02, -0.16, -0.07),
                Vec3::new(0.02, -0.12, -0.01),
                2,
            )?,
            mass,
        )
        .with_kind(BoneKind::Kinematic),
    )?;
    let [chin, neck] = JawScene::MUSCLE_AXIS;
    let dir = (neck - chin).normalize();
    let surface = tube_mesh(chin, neck, JawScene::MUSCLE_RADIUS_M, 24, 12)?;
    let line = [chin + 0.001 * dir, neck - 0.001 * dir];
    let lattice = MuscleLattice::build(&surface, &line, config.muscle)?;
    let muscle = system.add_muscle(&lattice)?;
    let attachment = |body: usize, k: usize| {
        system
            .body(body)
            .map(|b| b.particles().end - 3 + k)
            .expect("body just added")
    };
    let (s_h0, s_h1, s_t) = (
        attachment(skull, 0),
        attachment(skull, 1),
        attachment(skull, 2),
    );
    let (j_h0, j_h1, j_t) = (attachment(jaw, 0), attachment(jaw, 1), attachment(jaw, 2));
    system.add_spring(s_h0, j_h0, config.hinge_k_n_per_m, 0.0)?;
    system.add_spring(s_h1, j_h1, config.hinge_k_n_per_m, 0.0)?;
    system.add_spring(
        s_t,
        j_t,
        config.closing_k_n_per_m,
        (skull_tissue - jaw_tissue).length(),
    )?;
    system.insert_muscle(muscle, MuscleEnd::Start, jaw, config.insertion_k_n_per_m, 3)?;
    system.insert_muscle(muscle, MuscleEnd::End, spine, config.insertion_k_n_per_m, 3)?;
    system.add_bone_contact(muscle, jaw)?;
    Ok(JawScene {
        system,
        skull,
        jaw,
        spine,
        muscle,
    })
}
