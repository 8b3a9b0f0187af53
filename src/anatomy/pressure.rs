//! Pressure cells: closed triangulated surfaces filled with an isothermal ideal gas.

use glam::Vec3;

use super::{AnatomyError, non_negative, positive};

/// A closed, consistently oriented triangulated surface over particles, filled with an ideal gas
/// kept at constant temperature: `P = P0 * V0 / V`.
///
/// The force on each face is `(P - P_outside) * area` along the face's outward normal, spread in
/// equal thirds to its three vertices. `P_outside` is the pressure of the surroundings (for the
/// cells of a muscle, the rest pressure `P0`, so a muscle at rest is in equilibrium and neighbouring
/// cells push on their shared faces with the difference of their pressures).
///
/// ```
/// use dermis::anatomy::pressure::PressureCell;
/// use glam::Vec3;
/// // A tetrahedron, faces wound counter-clockwise seen from outside.
/// let x = vec![Vec3::ZERO, Vec3::X, Vec3::Y, Vec3::Z];
/// let cell = PressureCell::new(vec![[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]], &x, 1000.0, 0.0).unwrap();
/// assert!((cell.rest_volume_m3() - 1.0 / 6.0).abs() < 1e-6);
/// let squeezed: Vec<Vec3> = x.iter().map(|p| *p * Vec3::new(1.0, 1.0, 0.5)).collect();
/// assert!((cell.pressure_pa(&squeezed) - 2000.0).abs() < 1e-2);
/// ```
#[derive(Debug, Clone, PartialEq)]
pub struct PressureCell {
    faces: Vec<[u32; 3]>,
    p0_pa: f32,
    v0_m3: f32,
    outside_pa: f32,
}

impl PressureCell {
    /// A cell over `faces` (indices into `positions`), with the rest volume taken from
    /// `positions`, rest pressure `p0_pa > 0` and surrounding pressure `outside_pa >= 0`.
    ///
    /// Errors: [`AnatomyError::OpenSurface`] unless every directed edge has exactly one opposite
    /// (closed, manifold, consistently oriented), [`AnatomyError::InvertedCell`] if the enclosed
    /// volume is not positive, and index or parameter errors.
    pub fn new(
        faces: Vec<[u32; 3]>,
        positions: &[Vec3],
        p0_pa: f32,
        outside_pa: f32,
    ) -> Result<Self, AnatomyError> {
        positive("p0_pa", p0_pa)?;
        non_negative("outside_pa", outside_pa)?;
        check_closed(&faces, positions.len())?;
        let v0_m3 = volume(&faces, positions);
        if v0_m3.is_nan() || v0_m3 <= 0.0 {
            return Err(AnatomyError::InvertedCell {
                cell: 0,
                volume_m3: v0_m3,
            });
        }
        Ok(Self {
            faces,
            p0_pa,
            v0_m3,
            outside_pa,
        })
    }
    /// The faces, wound counter-clockwise seen from outside.
    pub fn faces(&self) -> &[[u32; 3]] {
        &self.faces
    }
    /// Pressure at rest, `P0`.
    pub fn rest_pressure_pa(&self) -> f32 {
        self.p0_pa
    }
    /// Volume at rest, `V0`.
    pub fn rest_volume_m3(&self) -> f32 {
        self.v0_m3
    }
    /// Pressure of the surroundings.
    pub fn outside_pressure_pa(&self) -> f32 {
        self.outside_pa
    }
    /// Enclosed volume for `positions`, from the signed tetrahedra of the faces.
    pub fn volume_m3(&self, positions: &[Vec3]) -> f32 {
        volume(&self.faces, positions)
    }
    /// Gas pressure `P0 V0 / V` for `positions` (infinite when the cell is flat or inverted).
    pub fn pressure_pa(&self, positions: &[Vec3]) -> f32 {
        gas_pressure(self.p0_pa, self.v0_m3, self.volume_m3(positions))
    }
    /// Adds the pressure force on every vertex to `forces` (same indexing as `positions`).
    pub fn add_forces(&self, positions: &[Vec3], forces: &mut [Vec3]) {
        let gauge = self.pressure_pa(positions) - self.outside_pa;
        for face in &self.faces {
            let f = face_force(gauge, face, positions) / 3.0;
            for &v in face {
                forces[v as usize] += f;
            }
        }
    }
    /// Potential energy of the gas and the surroundings, `-P0 V0 ln(V / V0) + P_outside (V - V0)`;
    /// [`Self::add_forces`] is its negative gradient.
    pub fn energy_j(&self, positions: &[Vec3]) -> f32 {
        let v = self.volume_m3(positions);
        -self.p0_pa * self.v0_m3 * (v / self.v0_m3).ln() + self.outside_pa * (v - self.v0_m3)
    }
}

/// `P0 V0 / V`, infinite for a non-positive volume.
pub(crate) fn gas_pressure(p0: f32, v0: f32, v: f32) -> f32 {
    if v > 0.0 { p0 * v0 / v } else { f32::INFINITY }
}

/// Force of gauge pressure `gauge` on the whole face: `gauge * area * outward normal`.
#[inline]
pub(crate) fn face_force(gauge: f32, face: &[u32; 3], x: &[Vec3]) -> Vec3 {
    let [a, b, c] = face.map(|i| x[i as usize]);
    (0.5 * gauge) * (b - a).cross(c - a)
}

/// Signed volume enclosed by `faces`: sum of the tetrahedra from the first vertex to each face
/// (a reference point on the surface keeps the rounding small far from the origin).
pub(crate) fn volume(faces: &[[u32; 3]], x: &[Vec3]) -> f32 {
    let Some(first) = faces.first() else {
        return 0.0;
    };
    let o = x[first[0] as usize];
    let mut six_v = 0.0;
    for face in faces {
        let [a, b, c] = face.map(|i| x[i as usize] - o);
        six_v += a.dot(b.cross(c));
    }
    six_v / 6.0
}

/// Every directed edge must appear exactly once, and its reverse exactly once.
pub(crate) fn check_closed(faces: &[[u32; 3]], vertex_count: usize) -> Result<(), AnatomyError> {
    if faces.is_empty() {
        return Err(AnatomyError::InvalidParameter {
            name: "faces.len()",
            value: 0.0,
        });
    }
    let mut directed = Vec::with_capacity(faces.len() * 3);
    for (f, face) in faces.iter().enumerate() {
        for (k, &v) in face.iter().enumerate() {
            if v as usize >= vertex_count {
                return Err(AnatomyError::IndexOutOfRange {
                    what: "vertex",
                    index: v as usize,
                    count: vertex_count,
                });
            }
            if face[..k].contains(&v) {
                return Err(AnatomyError::Topology(
                    crate::mesh::TopologyError::RepeatedVertex {
                        element: f,
                        index: v,
                    },
                ));
            }
        }
        for k in 0..3 {
            directed.push((face[k], face[(k + 1) % 3]));
        }
    }
    directed.sort_unstable();
    for (i, &(a, b)) in directed.iter().enumerate() {
        let repeated = i + 1 < directed.len() && directed[i + 1] == (a, b);
        let opposite = directed.binary_search(&(b, a)).is_ok();
        if repeated || !opposite {
            return Err(AnatomyError::OpenSurface { a, b });
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Unit cube, 12 triangles wound outwards.
    pub(crate) fn cube() -> (Vec<Vec3>, Vec<[u32; 3]>) {
        let x = (0..8)
            .map(|i| Vec3::new((i & 1) as f32, ((i >> 1) & 1) as f32, ((i >> 2) & 1) as f32))
            .collect();
        let f = vec![
            [0, 2, 1],
            [1, 2, 3],
            [4, 5, 6],
            [5, 7, 6],
            [0, 1, 4],
            [1, 5, 4],
            [2, 6, 3],
            [3, 6, 7],
            [0, 4, 2],
            [2, 4, 6],
            [1, 3, 5],
            [3, 7, 5],
        ];
        (x, f)
    }

    #[test]
    fn cube_volume_and_halving_doubles_pressure() {
        let (x, f) = cube();
        let cell = PressureCell::new(f, &x, 1.0e5, 0.0).unwrap();
        assert!((cell.rest_volume_m3() - 1.0).abs() < 1e-6);
        let half: Vec<Vec3> = x.iter().map(|p| *p * Vec3::new(1.0, 0.5, 1.0)).collect();
        assert!((cell.volume_m3(&half) - 0.5).abs() < 1e-6);
        assert!((cell.pressure_pa(&half) / 2.0e5 - 1.0).abs() < 1e-5);
    }

    #[test]
    fn force_is_minus_energy_gradient_and_sums_to_zero() {
        let (x, f) = cube();
        let x: Vec<Vec3> = x
            .iter()
            .enumerate()
            .map(|(i, p)| *p + 0.05 * Vec3::new((i as f32).sin(), (i as f32).cos(), 0.3))
            .collect();
        let cell = PressureCell::new(f, &x, 1000.0, 400.0).unwrap();
        let squeezed: Vec<Vec3> = x.iter().map(|p| *p * 0.9).collect();
        let mut forces = vec![Vec3::ZERO; 8];
        cell.add_forces(&squeezed, &mut forces);
        let net: Vec3 = forces.iter().sum();
        assert!(net.length() < 1e-3, "net force {net}");
        // Finite differences of the energy (f64-free: central differences with h = 1e-3).
        let h = 1e-3;
        for v in 0..8 {
            for axis in 0..3 {
                let mut plus = squeezed.clone();
                let mut minus = squeezed.clone();
                plus[v][axis] += h;
                minus[v][axis] -= h;
                let grad = (cell.energy_j(&plus) - cell.energy_j(&minus)) / (2.0 * h);
                assert!(
                    (forces[v][axis] + grad).abs() < 2e-2 * forces[v].length().max(1.0),
                    "vertex {v} axis {axis}: force {} vs -dE/dx {}",
                    forces[v][axis],
                    -grad
                );
            }
        }
    }

    #[test]
    fn open_or_inverted_surfaces_are_rejected() {
        let (x, mut f) = cube();
        let mut open = f.clone();
        open.pop();
        assert!(matches!(
            PressureCell::new(open, &x, 1.0, 0.0),
            Err(AnatomyError::OpenSurface { .. })
        ));
        let mut flipped = f.clone();
        flipped[0] = [0, 1, 2];
        assert!(matches!(
            PressureCell::new(flipped, &x, 1.0, 0.0),
            Err(AnatomyError::OpenSurface { .. })
        ));
        for face in &mut f {
            face.swap(1, 2);
        }
        assert!(matches!(
            PressureCell::new(f, &x, 1.0, 0.0),
            Err(AnatomyError::InvertedCell { .. })
        ));
    }
}
