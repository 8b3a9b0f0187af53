//! The particle system: springs, pressure cells, rigid bones and muscles, stepped by velocity Verlet with drag.

use std::ops::Range;

use glam::{Quat, Vec3};
use rayon::prelude::*;

use super::lattice::{MuscleLattice, MuscleSurface};
use super::pressure::{PressureCell, check_closed, face_force, gas_pressure, volume};
use super::rigid::{BoneDesc, BoneKind, Collider, RigidBody};
use super::{AnatomyError, non_negative, positive};

/// Elements per rayon task. Fixed, so the work split never depends on the thread count (and every
/// output element is computed by the same operations in the same order anyway).
const CHUNK: usize = 1024;

/// Marker in the particle owner table for a particle that belongs to no rigid body.
const FREE: u32 = u32::MAX;

/// Time stepping parameters, shared by every particle of an [`AnatomySystem`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DynamicsConfig {
    /// Length of one [`AnatomySystem::step`], in seconds.
    pub dt_s: f32,
    /// Substeps per step; each advances `dt_s / substeps`.
    pub substeps: u32,
    /// Fraction of every velocity removed at the end of each substep, in `[0, 1)`.
    pub drag: f32,
    /// Gravitational acceleration, m/s² (zero by default: anatomy scenes are usually driven by
    /// muscles alone).
    pub gravity: Vec3,
}

impl Default for DynamicsConfig {
    fn default() -> Self {
        Self {
            dt_s: 1e-3,
            substeps: 1,
            drag: 0.01,
            gravity: Vec3::ZERO,
        }
    }
}

/// An ideal spring between two particles: force `k (l - rest)` along the line joining them.
/// Several springs may join the same pair. 16 bytes.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Spring {
    /// First particle.
    pub a: u32,
    /// Second particle.
    pub b: u32,
    /// Stiffness, N/m.
    pub k: f32,
    /// Rest length, m.
    pub rest: f32,
}

/// Which end of a muscle: the first cross-section (at the poly-line's start) or the last.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum MuscleEnd {
    /// The cross-section at the start of the contraction poly-line.
    Start,
    /// The cross-section at the end of the contraction poly-line.
    End,
}

/// A muscle added to a system: a range of particles laid out section by section, its
/// longitudinal springs (whose rest lengths follow the activation) and its pressure cells.
#[derive(Debug, Clone)]
pub struct Muscle {
    first: u32,
    sections: u32,
    per_section: u32,
    longitudinal: Range<u32>,
    rest0: Vec<f32>,
    cells: Range<u32>,
    activation: f32,
    max_contraction: f32,
    section_triangles: Vec<[u32; 3]>,
    surface: MuscleSurface,
    /// (bone, particle) pairs joined by insertion springs.
    inserted: Vec<(u32, u32)>,
}

impl Muscle {
    /// Number of cross-sections.
    pub fn sections(&self) -> usize {
        self.sections as usize
    }
    /// Particles per cross-section.
    pub fn particles_per_section(&self) -> usize {
        self.per_section as usize
    }
    /// System index of particle `i` of cross-section `section`.
    pub fn particle(&self, section: usize, i: usize) -> usize {
        self.first as usize + section * self.per_section as usize + i
    }
    /// All particle indices of the muscle.
    pub fn particles(&self) -> Range<usize> {
        self.first as usize..self.first as usize + (self.sections * self.per_section) as usize
    }
    /// Current activation in `[0, 1]`.
    pub fn activation(&self) -> f32 {
        self.activation
    }
    /// Indices of the muscle's pressure cells in the system.
    pub fn cells(&self) -> Range<usize> {
        self.cells.start as usize..self.cells.end as usize
    }
    /// Indices of the longitudinal springs in the system.
    pub fn longitudinal_springs(&self) -> Range<usize> {
        self.longitudinal.start as usize..self.longitudinal.end as usize
    }
    /// Triangles of one cross-section's lattice, indices within a section (add
    /// `particle(section, 0)`).
    pub fn section_triangles(&self) -> &[[u32; 3]] {
        &self.section_triangles
    }
    /// The outer surface of the lattice, with system particle indices.
    pub fn surface(&self) -> &MuscleSurface {
        &self.surface
    }
}

/// A muscle particle held outside a bone.
#[derive(Debug, Clone)]
struct BoneContact {
    bone: u32,
    particles: Vec<u32>,
}

/// Per-particle lists of the springs and faces acting on it (CSR), built once per topology.
#[derive(Debug, Clone, Default)]
struct Gather {
    spring_offsets: Vec<u32>,
    /// `spring << 1 | 1` when the particle is the spring's `b` (force sign flipped).
    spring_refs: Vec<u32>,
    face_offsets: Vec<u32>,
    face_refs: Vec<u32>,
}

/// Copy of the state at the start of a step, restored when the step diverges.
#[derive(Debug, Clone, Default)]
struct Snapshot {
    x: Vec<Vec3>,
    v: Vec<Vec3>,
    f: Vec<Vec3>,
    bodies: Vec<(Vec3, Vec3, Quat, Vec3, Vec3, Vec3)>,
}

/// A mass-spring particle system with pressure cells, rigid bodies and muscles.
///
/// Particles are structure-of-arrays (positions, velocities, masses). Each [`Self::step`] runs
/// `substeps` velocity-Verlet substeps (kick, drift, forces, kick), then removes the fraction
/// `drag` of every velocity. Forces are gathered per particle in a fixed order, so results are
/// bit-identical for any number of rayon threads.
///
/// See the [module docs](super) for an example.
#[derive(Debug, Clone)]
pub struct AnatomySystem {
    config: DynamicsConfig,
    x: Vec<Vec3>,
    v: Vec<Vec3>,
    m: Vec<f32>,
    f: Vec<Vec3>,
    owner: Vec<u32>,
    springs: Vec<Spring>,
    spring_force: Vec<Vec3>,
    cell_offsets: Vec<u32>,
    cell_faces: Vec<[u32; 3]>,
    face_cell: Vec<u32>,
    cell_p0: Vec<f32>,
    cell_v0: Vec<f32>,
    cell_outside: Vec<f32>,
    cell_gauge: Vec<f32>,
    face_force: Vec<Vec3>,
    bodies: Vec<RigidBody>,
    muscles: Vec<Muscle>,
    contacts: Vec<BoneContact>,
    gather: Option<Gather>,
    forces_valid: bool,
    snapshot: Snapshot,
    time_s: f64,
}

impl AnatomySystem {
    /// An empty system. Errors if `dt_s` is not positive, `substeps` is zero or `drag` is outside
    /// `[0, 1)`.
    pub fn new(config: DynamicsConfig) -> Result<Self, AnatomyError> {
        positive("dt_s", config.dt_s)?;
        if config.substeps == 0 {
            return Err(AnatomyError::InvalidParameter {
                name: "substeps",
                value: 0.0,
            });
        }
        if non_negative("drag", config.drag)? >= 1.0 {
            return Err(AnatomyError::InvalidParameter {
                name: "drag",
                value: config.drag,
            });
        }
        if !config.gravity.is_finite() {
            return Err(AnatomyError::NonFinite {
                what: "gravity",
                index: 0,
            });
        }
        Ok(Self {
            config,
            x: Vec::new(),
            v: Vec::new(),
            m: Vec::new(),
            f: Vec::new(),
            owner: Vec::new(),
            springs: Vec::new(),
            spring_force: Vec::new(),
            cell_offsets: vec![0],
            cell_faces: Vec::new(),
            face_cell: Vec::new(),
            cell_p0: Vec::new(),
            cell_v0: Vec::new(),
            cell_outside: Vec::new(),
            cell_gauge: Vec::new(),
            face_force: Vec::new(),
            bodies: Vec::new(),
            muscles: Vec::new(),
            contacts: Vec::new(),
            gather: None,
            forces_valid: false,
            snapshot: Snapshot::default(),
            time_s: 0.0,
        })
    }

    /// The time stepping parameters.
    pub fn config(&self) -> &DynamicsConfig {
        &self.config
    }
    /// Simulated time, in seconds.
    pub fn time_s(&self) -> f64 {
        self.time_s
    }
    /// Particle positions.
    pub fn positions(&self) -> &[Vec3] {
        &self.x
    }
    /// Particle velocities.
    pub fn velocities(&self) -> &[Vec3] {
        &self.v
    }
    /// Particle masses, kg.
    pub fn masses(&self) -> &[f32] {
        &self.m
    }
    /// Net force on each particle at the current positions (valid after a step).
    pub fn forces(&self) -> &[Vec3] {
        &self.f
    }
    /// All springs.
    pub fn springs(&self) -> &[Spring] {
        &self.springs
    }
    /// Rigid body `i`.
    pub fn body(&self, i: usize) -> Option<&RigidBody> {
        self.bodies.get(i)
    }
    /// Muscle `i`.
    pub fn muscle(&self, i: usize) -> Option<&Muscle> {
        self.muscles.get(i)
    }
    /// Number of pressure cells.
    pub fn cell_count(&self) -> usize {
        self.cell_p0.len()
    }

    /// Adds a free particle; returns its index.
    pub fn add_particle(&mut self, position: Vec3, mass_kg: f32) -> Result<usize, AnatomyError> {
        if !position.is_finite() {
            return Err(AnatomyError::NonFinite {
                what: "particle position",
                index: self.x.len(),
            });
        }
        positive("mass_kg", mass_kg)?;
        self.push_particle(position, mass_kg, FREE);
        Ok(self.x.len() - 1)
    }

    fn push_particle(&mut self, position: Vec3, mass_kg: f32, owner: u32) {
        self.x.push(position);
        self.v.push(Vec3::ZERO);
        self.m.push(mass_kg);
        self.f.push(Vec3::ZERO);
        self.owner.push(owner);
        self.invalidate();
    }

    fn invalidate(&mut self) {
        self.gather = None;
        self.forces_valid = false;
    }

    fn check_particle(&self, p: usize) -> Result<(), AnatomyError> {
        if p < self.x.len() {
            Ok(())
        } else {
            Err(AnatomyError::IndexOutOfRange {
                what: "particle",
                index: p,
                count: self.x.len(),
            })
        }
    }

    /// Sets the velocity of a free particle (or of any particle before it joins a body).
    pub fn set_velocity(&mut self, particle: usize, velocity: Vec3) -> Result<(), AnatomyError> {
        self.check_particle(particle)?;
        if !velocity.is_finite() {
            return Err(AnatomyError::NonFinite {
                what: "particle velocity",
                index: particle,
            });
        }
        self.v[particle] = velocity;
        Ok(())
    }

    /// Adds a spring of stiffness `k_n_per_m >= 0` and rest length `rest_m >= 0` between two
    /// distinct particles; returns its index.
    pub fn add_spring(
        &mut self,
        a: usize,
        b: usize,
        k_n_per_m: f32,
        rest_m: f32,
    ) -> Result<usize, AnatomyError> {
        self.check_particle(a)?;
        self.check_particle(b)?;
        if a == b {
            return Err(AnatomyError::InvalidParameter {
                name: "spring with both ends on one particle",
                value: a as f32,
            });
        }
        non_negative("k_n_per_m", k_n_per_m)?;
        non_negative("rest_m", rest_m)?;
        self.springs.push(Spring {
            a: a as u32,
            b: b as u32,
            k: k_n_per_m,
            rest: rest_m,
        });
        self.invalidate();
        Ok(self.springs.len() - 1)
    }

    /// Adds a pressure cell over existing particles; returns its index.
    pub fn add_pressure_cell(&mut self, cell: &PressureCell) -> Result<usize, AnatomyError> {
        check_closed(cell.faces(), self.x.len())?;
        self.push_cell(
            cell.faces(),
            cell.rest_pressure_pa(),
            cell.rest_volume_m3(),
            cell.outside_pressure_pa(),
        );
        Ok(self.cell_p0.len() - 1)
    }

    fn push_cell(&mut self, faces: &[[u32; 3]], p0: f32, v0: f32, outside: f32) {
        let c = self.cell_p0.len() as u32;
        self.cell_faces.extend_from_slice(faces);
        self.face_cell.extend(std::iter::repeat_n(c, faces.len()));
        self.cell_offsets.push(self.cell_faces.len() as u32);
        self.cell_p0.push(p0);
        self.cell_v0.push(v0);
        self.cell_outside.push(outside);
        self.invalidate();
    }

    /// Current volume of cell `cell`, m³.
    pub fn cell_volume_m3(&self, cell: usize) -> f32 {
        volume(self.faces_of(cell), &self.x)
    }
    /// Current gas pressure of cell `cell`, `P0 V0 / V`, Pa.
    pub fn cell_pressure_pa(&self, cell: usize) -> f32 {
        gas_pressure(
            self.cell_p0[cell],
            self.cell_v0[cell],
            self.cell_volume_m3(cell),
        )
    }
    fn faces_of(&self, cell: usize) -> &[[u32; 3]] {
        &self.cell_faces[self.cell_offsets[cell] as usize..self.cell_offsets[cell + 1] as usize]
    }

    /// Adds a bone: a particle per mesh vertex then per attachment, all moving as one rigid
    /// body; returns the body index.
    pub fn add_bone(&mut self, desc: &BoneDesc) -> Result<usize, AnatomyError> {
        positive("particle_mass_kg", desc.particle_mass_kg)?;
        if let Some(i) = desc.attachments.iter().position(|p| !p.is_finite()) {
            return Err(AnatomyError::NonFinite {
                what: "bone attachment",
                index: i,
            });
        }
        let body = self.bodies.len();
        let first = self.x.len() as u32;
        let points: Vec<Vec3> = desc
            .mesh
            .positions()
            .iter()
            .chain(&desc.attachments)
            .copied()
            .collect();
        let masses = vec![desc.particle_mass_kg; points.len()];
        let rb = RigidBody::new(
            first..first + points.len() as u32,
            &points,
            &masses,
            desc.mesh.triangles().to_vec(),
            desc.kind,
        )
        .ok_or(AnatomyError::DegenerateBody { body })?;
        for p in &points {
            self.push_particle(*p, desc.particle_mass_kg, body as u32);
        }
        self.bodies.push(rb);
        Ok(body)
    }

    /// Drives kinematic body `body` to the pose (rotation, translation relative to rest) by the
    /// end of the next step, interpolating over its substeps.
    pub fn set_kinematic_pose(
        &mut self,
        body: usize,
        rotation: Quat,
        translation: Vec3,
    ) -> Result<(), AnatomyError> {
        let count = self.bodies.len();
        let b = self
            .bodies
            .get_mut(body)
            .ok_or(AnatomyError::IndexOutOfRange {
                what: "body",
                index: body,
                count,
            })?;
        if b.kind != BoneKind::Kinematic {
            return Err(AnatomyError::NotKinematic { body });
        }
        if !rotation.is_finite() || !translation.is_finite() || rotation.length() < 1e-6 {
            return Err(AnatomyError::NonFinite {
                what: "kinematic pose of body",
                index: body,
            });
        }
        b.target = Some((rotation.normalize(), translation));
        Ok(())
    }

    /// Sets the linear velocity and angular momentum of a dynamic body.
    pub fn set_body_motion(
        &mut self,
        body: usize,
        velocity: Vec3,
        angular_momentum: Vec3,
    ) -> Result<(), AnatomyError> {
        let count = self.bodies.len();
        let b = self
            .bodies
            .get_mut(body)
            .ok_or(AnatomyError::IndexOutOfRange {
                what: "body",
                index: body,
                count,
            })?;
        if !velocity.is_finite() || !angular_momentum.is_finite() {
            return Err(AnatomyError::NonFinite {
                what: "motion of body",
                index: body,
            });
        }
        b.velocity = velocity;
        b.angular_momentum = angular_momentum;
        let w = b.angular_velocity();
        for (i, p) in b.particles().enumerate() {
            self.v[p] = velocity + w.cross(b.rotation * b.local[i]);
        }
        Ok(())
    }

    /// Adds a muscle lattice: its particles, in-section and longitudinal springs, and a pressure
    /// cell per prism; returns the muscle index.
    pub fn add_muscle(&mut self, lattice: &MuscleLattice) -> Result<usize, AnatomyError> {
        let cfg = lattice.config();
        let first = self.x.len() as u32;
        let n = lattice.per_section() as u32;
        for p in lattice.positions() {
            self.push_particle(*p, cfg.particle_mass_kg, FREE);
        }
        let off = |i: u32| i + first;
        for j in 0..lattice.sections() as u32 {
            for &[a, b] in lattice.section_edges() {
                let (a, b) = (off(j * n + a), off(j * n + b));
                let rest = (self.x[a as usize] - self.x[b as usize]).length();
                self.springs.push(Spring {
                    a,
                    b,
                    k: cfg.k_section_n_per_m,
                    rest,
                });
            }
        }
        let l0 = self.springs.len() as u32;
        let mut rest0 = Vec::new();
        for j in 0..lattice.sections() as u32 - 1 {
            for i in 0..n {
                let (a, b) = (off(j * n + i), off((j + 1) * n + i));
                let rest = (self.x[a as usize] - self.x[b as usize]).length();
                rest0.push(rest);
                self.springs.push(Spring {
                    a,
                    b,
                    k: cfg.k_longitudinal_n_per_m,
                    rest,
                });
            }
        }
        let l1 = self.springs.len() as u32;
        let c0 = self.cell_p0.len() as u32;
        for j in 0..lattice.sections() - 1 {
            for t in 0..lattice.section_triangles().len() {
                let faces = lattice.prism_faces(j, t).map(|f| f.map(off));
                let v0 = volume(&faces, &self.x);
                if v0.is_nan() || v0 <= 0.0 {
                    return Err(AnatomyError::InvertedCell {
                        cell: self.cell_p0.len(),
                        volume_m3: v0,
                    });
                }
                self.push_cell(&faces, cfg.pressure_pa, v0, cfg.pressure_pa);
            }
        }
        let c1 = self.cell_p0.len() as u32;
        let mut surface = lattice.surface();
        for p in &mut surface.particles {
            *p = off(*p);
        }
        self.muscles.push(Muscle {
            first,
            sections: lattice.sections() as u32,
            per_section: n,
            longitudinal: l0..l1,
            rest0,
            cells: c0..c1,
            activation: 0.0,
            max_contraction: cfg.max_contraction,
            section_triangles: lattice.section_triangles().to_vec(),
            surface,
            inserted: Vec::new(),
        });
        self.invalidate();
        Ok(self.muscles.len() - 1)
    }

    fn check_muscle(&self, muscle: usize) -> Result<&Muscle, AnatomyError> {
        self.muscles
            .get(muscle)
            .ok_or(AnatomyError::IndexOutOfRange {
                what: "muscle",
                index: muscle,
                count: self.muscles.len(),
            })
    }
    fn check_body(&self, body: usize) -> Result<&RigidBody, AnatomyError> {
        self.bodies.get(body).ok_or(AnatomyError::IndexOutOfRange {
            what: "body",
            index: body,
            count: self.bodies.len(),
        })
    }

    /// Sets a muscle's activation in `[0, 1]`: every longitudinal rest length becomes
    /// `rest0 * (1 - max_contraction * activation)`.
    pub fn set_activation(&mut self, muscle: usize, activation: f32) -> Result<(), AnatomyError> {
        self.check_muscle(muscle)?;
        if !(0.0..=1.0).contains(&activation) {
            return Err(AnatomyError::ActivationOutOfRange { muscle, activation });
        }
        let m = &mut self.muscles[muscle];
        m.activation = activation;
        let scale = 1.0 - m.max_contraction * activation;
        for (s, r0) in self.springs[m.longitudinal.start as usize..m.longitudinal.end as usize]
            .iter_mut()
            .zip(&m.rest0)
        {
            s.rest = r0 * scale;
        }
        self.forces_valid = false;
        Ok(())
    }

    /// Joins each particle of a muscle's end cross-section to its `per_particle` nearest
    /// particles of `bone` (ties broken by index) with springs of stiffness `k_n_per_m` at their
    /// current length; returns the range of new spring indices.
    pub fn insert_muscle(
        &mut self,
        muscle: usize,
        end: MuscleEnd,
        bone: usize,
        k_n_per_m: f32,
        per_particle: usize,
    ) -> Result<Range<usize>, AnatomyError> {
        let m = self.check_muscle(muscle)?;
        let b = self.check_body(bone)?;
        positive("k_n_per_m", k_n_per_m)?;
        if per_particle == 0 {
            return Err(AnatomyError::InvalidParameter {
                name: "per_particle",
                value: 0.0,
            });
        }
        let section = match end {
            MuscleEnd::Start => 0,
            MuscleEnd::End => m.sections() - 1,
        };
        let ends: Vec<usize> = (0..m.particles_per_section())
            .map(|i| m.particle(section, i))
            .collect();
        let bone_particles = b.particles();
        let start = self.springs.len();
        let mut new = Vec::new();
        for &p in &ends {
            let mut near: Vec<(f32, usize)> = bone_particles
                .clone()
                .map(|q| ((self.x[q] - self.x[p]).length(), q))
                .collect();
            near.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
            for &(d, q) in near.iter().take(per_particle) {
                self.springs.push(Spring {
                    a: q as u32,
                    b: p as u32,
                    k: k_n_per_m,
                    rest: d,
                });
            }
            new.push((bone as u32, p as u32));
        }
        self.muscles[muscle].inserted.extend(new);
        self.invalidate();
        Ok(start..self.springs.len())
    }

    /// Keeps the particles of `muscle` outside `bone` by projecting them onto the bone's surface
    /// after every substep (particles inserted into that bone are exempt). The bone mesh must be
    /// closed and outward-oriented.
    pub fn add_bone_contact(&mut self, muscle: usize, bone: usize) -> Result<(), AnatomyError> {
        let m = self.check_muscle(muscle)?;
        self.check_body(bone)?;
        let exempt: Vec<u32> = m
            .inserted
            .iter()
            .filter(|(b, _)| *b as usize == bone)
            .map(|(_, p)| *p)
            .collect();
        let particles: Vec<u32> = m
            .particles()
            .map(|p| p as u32)
            .filter(|p| !exempt.contains(p))
            .collect();
        let b = &mut self.bodies[bone];
        if b.collider.is_none() {
            let vertex_count = b.triangles.iter().flatten().max().map_or(0, |&v| v + 1);
            let local: Vec<Vec3> = b.local[..vertex_count as usize].to_vec();
            let min = local.iter().fold(Vec3::INFINITY, |a, p| a.min(*p));
            let max = local.iter().fold(Vec3::NEG_INFINITY, |a, p| a.max(*p));
            let shape = parry3d::shape::TriMesh::with_flags(
                local,
                b.triangles.clone(),
                parry3d::shape::TriMeshFlags::ORIENTED,
            )
            .map_err(|e| AnatomyError::Collider {
                body: bone,
                message: e.to_string(),
            })?;
            b.collider = Some(Collider { shape, min, max });
        }
        self.contacts.push(BoneContact {
            bone: bone as u32,
            particles,
        });
        Ok(())
    }

    fn build_gather(&self) -> Gather {
        let n = self.x.len();
        let mut g = Gather::default();
        let mut count = vec![0u32; n + 1];
        for s in &self.springs {
            count[s.a as usize + 1] += 1;
            count[s.b as usize + 1] += 1;
        }
        for i in 0..n {
            count[i + 1] += count[i];
        }
        let mut fill = count.clone();
        g.spring_refs = vec![0; *count.last().unwrap_or(&0) as usize];
        for (i, s) in self.springs.iter().enumerate() {
            for (p, sign) in [(s.a, 0), (s.b, 1)] {
                let slot = &mut fill[p as usize];
                g.spring_refs[*slot as usize] = (i as u32) << 1 | sign;
                *slot += 1;
            }
        }
        g.spring_offsets = count;
        let mut count = vec![0u32; n + 1];
        for face in &self.cell_faces {
            for &v in face {
                count[v as usize + 1] += 1;
            }
        }
        for i in 0..n {
            count[i + 1] += count[i];
        }
        let mut fill = count.clone();
        g.face_refs = vec![0; *count.last().unwrap_or(&0) as usize];
        for (i, face) in self.cell_faces.iter().enumerate() {
            for &v in face {
                let slot = &mut fill[v as usize];
                g.face_refs[*slot as usize] = i as u32;
                *slot += 1;
            }
        }
        g.face_offsets = count;
        g
    }

    /// Computes every particle's net force at the current positions, and each dynamic body's
    /// net force and torque.
    fn compute_forces(&mut self) {
        if self.gather.is_none() {
            self.gather = Some(self.build_gather());
        }
        let x = &self.x;
        self.spring_force.resize(self.springs.len(), Vec3::ZERO);
        self.spring_force
            .par_chunks_mut(CHUNK)
            .zip(self.springs.par_chunks(CHUNK))
            .for_each(|(out, springs)| {
                for (o, s) in out.iter_mut().zip(springs) {
                    let d = x[s.b as usize] - x[s.a as usize];
                    let l = d.length();
                    *o = if l > 0.0 {
                        (s.k * (l - s.rest) / l) * d
                    } else {
                        Vec3::ZERO
                    };
                }
            });
        let cells = self.cell_p0.len();
        self.cell_gauge.resize(cells, 0.0);
        let (offsets, faces) = (&self.cell_offsets, &self.cell_faces);
        let (p0, v0, outside) = (&self.cell_p0, &self.cell_v0, &self.cell_outside);
        self.cell_gauge
            .par_chunks_mut(CHUNK)
            .enumerate()
            .for_each(|(chunk, out)| {
                for (k, o) in out.iter_mut().enumerate() {
                    let c = chunk * CHUNK + k;
                    let f = &faces[offsets[c] as usize..offsets[c + 1] as usize];
                    *o = gas_pressure(p0[c], v0[c], volume(f, x)) - outside[c];
                }
            });
        self.face_force.resize(self.cell_faces.len(), Vec3::ZERO);
        let (gauge, face_cell) = (&self.cell_gauge, &self.face_cell);
        self.face_force
            .par_chunks_mut(CHUNK)
            .enumerate()
            .for_each(|(chunk, out)| {
                for (k, o) in out.iter_mut().enumerate() {
                    let i = chunk * CHUNK + k;
                    *o = face_force(gauge[face_cell[i] as usize], &faces[i], x) / 3.0;
                }
            });
        let g = self.gather.as_ref().expect("built above");
        let (sf, ff, m, gravity) = (
            &self.spring_force,
            &self.face_force,
            &self.m,
            self.config.gravity,
        );
        self.f
            .par_chunks_mut(CHUNK)
            .enumerate()
            .for_each(|(chunk, out)| {
                for (k, o) in out.iter_mut().enumerate() {
                    let p = chunk * CHUNK + k;
                    let mut f = gravity * m[p];
                    for &r in &g.spring_refs
                        [g.spring_offsets[p] as usize..g.spring_offsets[p + 1] as usize]
                    {
                        let s = sf[(r >> 1) as usize];
                        if r & 1 == 0 {
                            f += s;
                        } else {
                            f -= s;
                        }
                    }
                    for &i in
                        &g.face_refs[g.face_offsets[p] as usize..g.face_offsets[p + 1] as usize]
                    {
                        f += ff[i as usize];
                    }
                    *o = f;
                }
            });
        for b in &mut self.bodies {
            let (mut force, mut torque) = (Vec3::ZERO, Vec3::ZERO);
            for p in b.particles() {
                force += self.f[p];
                torque += (self.x[p] - b.com).cross(self.f[p]);
            }
            b.force = force;
            b.torque = torque;
        }
        self.forces_valid = true;
    }

    /// Writes body particle positions and velocities from the body state.
    fn sync_bodies(&mut self) {
        for b in &self.bodies {
            let w = b.angular_velocity();
            for (i, p) in b.particles().enumerate() {
                let r = b.rotation * b.local[i];
                self.x[p] = b.com + r;
                self.v[p] = b.velocity + w.cross(r);
            }
        }
    }

    /// Projects contact particles out of their bones and removes their velocity into the bone;
    /// a dynamic bone receives the momentum removed (equal and opposite impulse at the contact
    /// point), so muscle-bone contact conserves linear and angular momentum.
    fn project_contacts(&mut self) {
        for c in &self.contacts {
            let b = &self.bodies[c.bone as usize];
            let Some(col) = &b.collider else { continue };
            let inv = b.rotation.inverse();
            let w = b.angular_velocity();
            let x = &self.x;
            let v = &self.v;
            let moved: Vec<Option<(Vec3, Vec3)>> = c
                .particles
                .par_iter()
                .with_min_len(CHUNK)
                .map(|&p| {
                    let p = p as usize;
                    let local = inv * (x[p] - b.com);
                    if local.cmpge(col.min).all() && local.cmple(col.max).all() {
                        use parry3d::query::PointQuery;
                        let proj = col.shape.project_local_point(local, false);
                        if proj.is_inside {
                            let r = b.rotation * proj.point;
                            let n = (r - b.rotation * local).normalize_or_zero();
                            let rel = v[p] - (b.velocity + w.cross(r));
                            let vn = rel.dot(n);
                            let vel = if vn < 0.0 { v[p] - vn * n } else { v[p] };
                            return Some((b.com + r, vel));
                        }
                    }
                    None
                })
                .collect();
            // Reaction: the momentum a particle loses into the bone goes to a dynamic bone, as
            // an impulse at the contact point (summed in particle order: deterministic).
            let (mut impulse, mut angular) = (Vec3::ZERO, Vec3::ZERO);
            for (&p, m) in c.particles.iter().zip(moved) {
                if let Some((xp, vp)) = m {
                    let p = p as usize;
                    let j = self.m[p] * (self.v[p] - vp);
                    impulse += j;
                    angular += (xp - b.com).cross(j);
                    self.x[p] = xp;
                    self.v[p] = vp;
                }
            }
            let b = &mut self.bodies[c.bone as usize];
            if b.kind == BoneKind::Dynamic {
                b.velocity += impulse / b.mass;
                b.angular_momentum += angular;
            }
        }
    }

    /// Advances the system by `dt_s` in `substeps` velocity-Verlet substeps.
    ///
    /// On a non-finite position the whole step is rolled back and
    /// [`AnatomyError::Diverged`] is returned.
    pub fn step(&mut self) -> Result<(), AnatomyError> {
        if !self.forces_valid {
            self.sync_bodies();
            self.compute_forces();
        }
        self.save_snapshot();
        let starts: Vec<(Quat, Vec3)> = self.bodies.iter().map(|b| b.pose()).collect();
        let n = self.config.substeps;
        let h = self.config.dt_s / n as f32;
        for s in 0..n {
            self.substep(h, (s + 1) as f32 / n as f32, &starts);
        }
        if let Some(particle) = self.x.iter().position(|p| !p.is_finite()) {
            self.restore_snapshot();
            return Err(AnatomyError::Diverged { particle });
        }
        self.time_s += f64::from(self.config.dt_s);
        Ok(())
    }

    fn substep(&mut self, h: f32, alpha: f32, starts: &[(Quat, Vec3)]) {
        let owner = &self.owner;
        let (m, f) = (&self.m, &self.f);
        self.x
            .par_chunks_mut(CHUNK)
            .zip(self.v.par_chunks_mut(CHUNK))
            .enumerate()
            .for_each(|(chunk, (xs, vs))| {
                for (k, (x, v)) in xs.iter_mut().zip(vs).enumerate() {
                    let p = chunk * CHUNK + k;
                    if owner[p] == FREE {
                        *v += (0.5 * h / m[p]) * f[p];
                        *x += h * *v;
                    }
                }
            });
        for (b, start) in self.bodies.iter_mut().zip(starts) {
            match b.kind {
                BoneKind::Dynamic => {
                    b.velocity += (0.5 * h / b.mass) * b.force;
                    b.angular_momentum += 0.5 * h * b.torque;
                    b.com += h * b.velocity;
                    let w = b.angular_velocity();
                    b.rotation = (Quat::from_scaled_axis(w * h) * b.rotation).normalize();
                }
                BoneKind::Kinematic => {
                    let Some(target) = b.target else { continue };
                    let (old_q, old_com) = (b.rotation, b.com);
                    let q = start.0.slerp(target.0, alpha);
                    b.set_pose(q, start.1.lerp(target.1, alpha));
                    b.velocity = (b.com - old_com) / h;
                    let w = (b.rotation * old_q.inverse()).to_scaled_axis() / h;
                    let r = glam::Mat3::from_quat(b.rotation);
                    b.angular_momentum = r * b.inertia_body * r.transpose() * w;
                }
            }
        }
        self.sync_bodies();
        self.project_contacts();
        self.compute_forces();
        let keep = 1.0 - self.config.drag;
        let (m, f, owner) = (&self.m, &self.f, &self.owner);
        self.v
            .par_chunks_mut(CHUNK)
            .enumerate()
            .for_each(|(chunk, vs)| {
                for (k, v) in vs.iter_mut().enumerate() {
                    let p = chunk * CHUNK + k;
                    if owner[p] == FREE {
                        *v = (*v + (0.5 * h / m[p]) * f[p]) * keep;
                    }
                }
            });
        for b in &mut self.bodies {
            if b.kind == BoneKind::Dynamic {
                b.velocity = (b.velocity + (0.5 * h / b.mass) * b.force) * keep;
                b.angular_momentum = (b.angular_momentum + 0.5 * h * b.torque) * keep;
            }
        }
        for b in &self.bodies {
            let w = b.angular_velocity();
            for (i, p) in b.particles().enumerate() {
                self.v[p] = b.velocity + w.cross(b.rotation * b.local[i]);
            }
        }
    }

    fn save_snapshot(&mut self) {
        let s = &mut self.snapshot;
        s.x.clone_from(&self.x);
        s.v.clone_from(&self.v);
        s.f.clone_from(&self.f);
        s.bodies.clear();
        s.bodies.extend(self.bodies.iter().map(|b| {
            (
                b.com,
                b.velocity,
                b.rotation,
                b.angular_momentum,
                b.force,
                b.torque,
            )
        }));
    }

    fn restore_snapshot(&mut self) {
        let s = &self.snapshot;
        self.x.clone_from(&s.x);
        self.v.clone_from(&s.v);
        self.f.clone_from(&s.f);
        for (b, &(com, v, q, l, f, t)) in self.bodies.iter_mut().zip(&s.bodies) {
            (
                b.com,
                b.velocity,
                b.rotation,
                b.angular_momentum,
                b.force,
                b.torque,
            ) = (com, v, q, l, f, t);
        }
    }

    /// Kinetic energy of free particles and rigid bodies, J.
    pub fn kinetic_energy_j(&self) -> f32 {
        let free: f32 = (0..self.x.len())
            .filter(|&p| self.owner[p] == FREE)
            .map(|p| 0.5 * self.m[p] * self.v[p].length_squared())
            .sum();
        free + self
            .bodies
            .iter()
            .map(RigidBody::kinetic_energy_j)
            .sum::<f32>()
    }

    /// Potential energy of springs, pressure cells and gravity, J.
    pub fn potential_energy_j(&self) -> f32 {
        let springs: f32 = self
            .springs
            .iter()
            .map(|s| {
                let l = (self.x[s.b as usize] - self.x[s.a as usize]).length();
                0.5 * s.k * (l - s.rest) * (l - s.rest)
            })
            .sum();
        let cells: f32 = (0..self.cell_count())
            .map(|c| {
                let v = self.cell_volume_m3(c);
                let (p0, v0) = (self.cell_p0[c], self.cell_v0[c]);
                -p0 * v0 * (v / v0).ln() + self.cell_outside[c] * (v - v0)
            })
            .sum();
        let gravity: f32 = self
            .x
            .iter()
            .zip(&self.m)
            .map(|(x, m)| -m * self.config.gravity.dot(*x))
            .sum();
        springs + cells + gravity
    }

    /// Kinetic plus potential energy, J.
    pub fn total_energy(&self) -> f32 {
        self.kinetic_energy_j() + self.potential_energy_j()
    }

    /// Sum of the volumes of a muscle's pressure cells, m³.
    pub fn muscle_volume_m3(&self, muscle: usize) -> Result<f32, AnatomyError> {
        let m = self.check_muscle(muscle)?;
        Ok(m.cells().map(|c| self.cell_volume_m3(c)).sum())
    }

    /// Centroid of the particles of one cross-section of a muscle.
    pub fn muscle_section_centroid(
        &self,
        muscle: usize,
        section: usize,
    ) -> Result<Vec3, AnatomyError> {
        let m = self.check_muscle(muscle)?;
        let n = m.particles_per_section();
        if section >= m.sections() {
            return Err(AnatomyError::IndexOutOfRange {
                what: "section",
                index: section,
                count: m.sections(),
            });
        }
        Ok((0..n).map(|i| self.x[m.particle(section, i)]).sum::<Vec3>() / n as f32)
    }

    /// Area of one cross-section's lattice (sum of its triangles), m².
    pub fn muscle_section_area_m2(
        &self,
        muscle: usize,
        section: usize,
    ) -> Result<f32, AnatomyError> {
        let m = self.check_muscle(muscle)?;
        if section >= m.sections() {
            return Err(AnatomyError::IndexOutOfRange {
                what: "section",
                index: section,
                count: m.sections(),
            });
        }
        let base = m.particle(section, 0);
        Ok(m.section_triangles
            .iter()
            .map(|t| {
                let [a, b, c] = t.map(|i| self.x[base + i as usize]);
                0.5 * (b - a).cross(c - a).length()
            })
            .sum())
    }

    /// Current positions of a muscle's outer surface vertices (same order as
    /// [`MuscleSurface::particles`]).
    pub fn muscle_surface_positions(&self, muscle: usize) -> Result<Vec<Vec3>, AnatomyError> {
        let m = self.check_muscle(muscle)?;
        Ok(m.surface
            .particles
            .iter()
            .map(|&p| self.x[p as usize])
            .collect())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A tetrahedral pressure cell with springs on its edges plus a second spring on one edge,
    /// deformed away from rest.
    fn small_system() -> AnatomySystem {
        let mut sys = AnatomySystem::new(DynamicsConfig {
            gravity: Vec3::new(0.0, -9.81, 0.0),
            ..Default::default()
        })
        .unwrap();
        let rest = [Vec3::ZERO, Vec3::X, Vec3::Y, Vec3::Z];
        for p in rest {
            sys.add_particle(p, 0.5).unwrap();
        }
        let cell = PressureCell::new(
            vec![[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]],
            &rest,
            300.0,
            100.0,
        )
        .unwrap();
        sys.add_pressure_cell(&cell).unwrap();
        for (a, b) in [(0, 1), (0, 2), (0, 3), (1, 2), (1, 3), (2, 3), (1, 2)] {
            sys.add_spring(a, b, 40.0 + a as f32, 0.9).unwrap();
        }
        sys.x[3] = Vec3::new(0.1, 0.2, 1.3);
        sys.x[1] = Vec3::new(0.8, -0.1, 0.05);
        sys
    }

    #[test]
    fn forces_are_minus_the_energy_gradient() {
        let mut sys = small_system();
        sys.compute_forces();
        let f = sys.f.clone();
        let h = 1e-3;
        for (p, fp) in f.iter().enumerate() {
            for axis in 0..3 {
                let x0 = sys.x[p];
                sys.x[p][axis] = x0[axis] + h;
                let plus = sys.potential_energy_j();
                sys.x[p][axis] = x0[axis] - h;
                let minus = sys.potential_energy_j();
                sys.x[p] = x0;
                let grad = (plus - minus) / (2.0 * h);
                assert!(
                    (fp[axis] + grad).abs() < 2e-2 * (1.0 + fp.length()),
                    "particle {p} axis {axis}: force {} vs -dE/dx {}",
                    fp[axis],
                    -grad
                );
            }
        }
    }

    #[test]
    fn muscle_at_rest_is_in_equilibrium() {
        use crate::anatomy::scenes::tube_mesh;
        let surface = tube_mesh(Vec3::ZERO, Vec3::new(0.0, 0.0, 0.1), 0.01, 16, 5).unwrap();
        let line = [Vec3::new(0.0, 0.0, 0.001), Vec3::new(0.0, 0.0, 0.099)];
        let lattice = MuscleLattice::build(&surface, &line, Default::default()).unwrap();
        let mut sys = AnatomySystem::new(DynamicsConfig::default()).unwrap();
        sys.add_muscle(&lattice).unwrap();
        sys.compute_forces();
        // Rest lengths and volumes are the built ones, and the outside pressure equals P0.
        let worst = sys.f.iter().map(|f| f.length()).fold(0.0, f32::max);
        assert!(worst < 1e-4, "largest force at rest {worst} N");
    }
}
