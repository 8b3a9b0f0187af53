//! Muscle lattice builder: cross-sections along a contraction poly-line, filled with a triangle lattice.

use std::collections::HashMap;

use glam::{Vec2, Vec3};

use super::{AnatomyError, non_negative, positive};
use crate::mesh::{NO_TRIANGLE, TriMesh};

/// Upper bound on the triangles of one cross-section, against runaway memory use.
const MAX_SECTION_TRIANGLES: f32 = 1e7;

/// Parameters of a muscle lattice.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MuscleConfig {
    /// Number of equally spaced cross-sections along the poly-line (at least 2; the first and
    /// last sit at the poly-line's ends).
    pub sections: usize,
    /// Area of one equilateral triangle of the main cross-section's lattice, m².
    pub cell_area_m2: f32,
    /// Mass of every muscle particle, kg.
    pub particle_mass_kg: f32,
    /// Stiffness of the longitudinal springs (between corresponding particles of consecutive
    /// sections), N/m.
    pub k_longitudinal_n_per_m: f32,
    /// Stiffness of the springs inside a cross-section, N/m.
    pub k_section_n_per_m: f32,
    /// Rest pressure `P0` of every pressure cell, and the pressure around the muscle, Pa.
    pub pressure_pa: f32,
    /// Fraction by which activation 1 shortens the longitudinal rest lengths, in `[0, 1)`.
    pub max_contraction: f32,
}

impl Default for MuscleConfig {
    fn default() -> Self {
        Self {
            sections: 10,
            cell_area_m2: 4e-6,
            particle_mass_kg: 1e-4,
            k_longitudinal_n_per_m: 50.0,
            k_section_n_per_m: 5.0,
            pressure_pa: 1e5,
            max_contraction: 0.4,
        }
    }
}

impl MuscleConfig {
    fn validate(&self) -> Result<(), AnatomyError> {
        if self.sections < 2 {
            return Err(AnatomyError::InvalidParameter {
                name: "sections",
                value: self.sections as f32,
            });
        }
        positive("cell_area_m2", self.cell_area_m2)?;
        positive("particle_mass_kg", self.particle_mass_kg)?;
        non_negative("k_longitudinal_n_per_m", self.k_longitudinal_n_per_m)?;
        non_negative("k_section_n_per_m", self.k_section_n_per_m)?;
        positive("pressure_pa", self.pressure_pa)?;
        if non_negative("max_contraction", self.max_contraction)? >= 1.0 {
            return Err(AnatomyError::InvalidParameter {
                name: "max_contraction",
                value: self.max_contraction,
            });
        }
        Ok(())
    }
}

/// The outer surface of a muscle lattice: two end caps and the sides between the outline
/// particles of consecutive sections, wound outwards. Usable as a collider for the skin.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct MuscleSurface {
    /// Particle index of each surface vertex (lattice indices in a [`MuscleLattice`], system
    /// indices in a [`super::dynamics::Muscle`]).
    pub particles: Vec<u32>,
    /// Triangles, indices into `particles`.
    pub triangles: Vec<[u32; 3]>,
}

/// A muscle lattice built as Dima et al. (2009) describe.
///
/// Cross-sections are cut perpendicular to the contraction poly-line at equally spaced points;
/// the one of largest area is filled with equilateral triangles of the given area, and every
/// other section gets the same particles mapped by radial similarity about its centroid (the
/// ratio of a particle's distance from the centroid to the outline's distance in the same
/// direction is the same in every section). Particle `i` of section `j` has index
/// `j * per_section + i`.
///
/// ```
/// use dermis::anatomy::lattice::{MuscleConfig, MuscleLattice};
/// use dermis::anatomy::scenes::tube_mesh;
/// use glam::Vec3;
/// // A 10 cm long muscle of 1 cm radius along z; the poly-line ends just inside its caps.
/// let surface = tube_mesh(Vec3::ZERO, Vec3::new(0.0, 0.0, 0.1), 0.01, 24, 10).unwrap();
/// let line = [Vec3::new(0.0, 0.0, 0.001), Vec3::new(0.0, 0.0, 0.099)];
/// let config = MuscleConfig { sections: 8, cell_area_m2: 1e-5, ..Default::default() };
/// let lattice = MuscleLattice::build(&surface, &line, config).unwrap();
/// assert_eq!(lattice.positions().len(), 8 * lattice.per_section());
/// assert!(lattice.per_section() > 10);
/// ```
#[derive(Debug, Clone, PartialEq)]
pub struct MuscleLattice {
    config: MuscleConfig,
    positions: Vec<Vec3>,
    per_section: usize,
    triangles: Vec<[u32; 3]>,
    edges: Vec<[u32; 2]>,
    main_section: usize,
}

/// A section frame: origin on the poly-line, in-plane axes `u`, `w`, normal `t = u x w`.
#[derive(Debug, Clone, Copy)]
struct Frame {
    origin: Vec3,
    u: Vec3,
    w: Vec3,
    t: Vec3,
}

impl Frame {
    fn to_2d(self, p: Vec3) -> Vec2 {
        let d = p - self.origin;
        Vec2::new(d.dot(self.u), d.dot(self.w))
    }
    fn to_3d(self, q: Vec2) -> Vec3 {
        self.origin + q.x * self.u + q.y * self.w
    }
}

impl MuscleLattice {
    /// Builds the lattice from a closed muscle `surface` and a contraction `polyline`.
    pub fn build(
        surface: &TriMesh,
        polyline: &[Vec3],
        config: MuscleConfig,
    ) -> Result<Self, AnatomyError> {
        config.validate()?;
        if polyline.len() < 2 {
            return Err(AnatomyError::PolylineTooShort {
                points: polyline.len(),
            });
        }
        if let Some(i) = polyline.iter().position(|p| !p.is_finite()) {
            return Err(AnatomyError::NonFinite {
                what: "poly-line point",
                index: i,
            });
        }
        let topo = surface.topology();
        if let Some(e) = topo.boundary_edges().next() {
            let [a, b] = topo.edges()[e];
            return Err(AnatomyError::OpenSurface { a, b });
        }
        let frames = section_frames(polyline, config.sections)?;
        let outlines: Vec<Vec<Vec2>> = frames
            .iter()
            .enumerate()
            .map(|(j, f)| {
                cross_section(surface, f).ok_or(AnatomyError::NoCrossSection { section: j })
            })
            .collect::<Result<_, _>>()?;
        let props: Vec<(f32, Vec2)> = outlines.iter().map(|o| area_centroid(o)).collect();
        if let Some(j) = props.iter().position(|(a, c)| !(c.is_finite() && *a > 0.0)) {
            return Err(AnatomyError::NoCrossSection { section: j });
        }
        let main = (0..props.len()).fold(
            0,
            |best, j| if props[j].0 > props[best].0 { j } else { best },
        );
        let (main_area, main_c) = props[main];
        if main_area / config.cell_area_m2 > MAX_SECTION_TRIANGLES {
            return Err(AnatomyError::InvalidParameter {
                name: "cell_area_m2 (too small: over 10 million triangles per section)",
                value: config.cell_area_m2,
            });
        }
        let (points, triangles) = fill(&outlines[main], main_c, config.cell_area_m2);
        if triangles.is_empty() {
            return Err(AnatomyError::EmptyLattice {
                cell_area_m2: config.cell_area_m2,
                section_area_m2: main_area,
            });
        }
        // Radial similarity: (direction, ratio) in the main section, reused everywhere.
        let mut polar = Vec::with_capacity(points.len());
        for p in &points {
            let d = *p - main_c;
            let r = d.length();
            if r < 1e-12 {
                polar.push((Vec2::X, 0.0));
                continue;
            }
            let dir = d / r;
            let reach = ray_reach(&outlines[main], main_c, dir)
                .ok_or(AnatomyError::NotStarShaped { section: main })?;
            polar.push((dir, r / reach));
        }
        let mut positions = Vec::with_capacity(points.len() * frames.len());
        for (j, frame) in frames.iter().enumerate() {
            let c = props[j].1;
            for &(dir, ratio) in &polar {
                let q = if ratio == 0.0 {
                    c
                } else {
                    let reach = ray_reach(&outlines[j], c, dir)
                        .ok_or(AnatomyError::NotStarShaped { section: j })?;
                    c + dir * (ratio * reach)
                };
                positions.push(frame.to_3d(q));
            }
        }
        let mut edges: Vec<[u32; 2]> = triangles
            .iter()
            .flat_map(|&[a, b, c]| [[a, b], [b, c], [c, a]])
            .map(|[a, b]| [a.min(b), a.max(b)])
            .collect();
        edges.sort_unstable();
        edges.dedup();
        Ok(Self {
            config,
            per_section: points.len(),
            positions,
            triangles,
            edges,
            main_section: main,
        })
    }

    /// The parameters it was built with.
    pub fn config(&self) -> &MuscleConfig {
        &self.config
    }
    /// Particle rest positions, section by section.
    pub fn positions(&self) -> &[Vec3] {
        &self.positions
    }
    /// Number of cross-sections.
    pub fn sections(&self) -> usize {
        self.config.sections
    }
    /// Particles per cross-section.
    pub fn per_section(&self) -> usize {
        self.per_section
    }
    /// Index of the largest cross-section (the one filled with equilateral triangles).
    pub fn main_section(&self) -> usize {
        self.main_section
    }
    /// Triangles of one section's lattice (indices within a section), counter-clockwise about
    /// the poly-line direction.
    pub fn section_triangles(&self) -> &[[u32; 3]] {
        &self.triangles
    }
    /// Unique edges of one section's lattice (indices within a section), `a < b`.
    pub fn section_edges(&self) -> &[[u32; 2]] {
        &self.edges
    }
    /// The 8 outward faces of the prism between triangle `t` of section `j` and of section
    /// `j + 1`, with lattice particle indices.
    pub fn prism_faces(&self, j: usize, t: usize) -> [[u32; 3]; 8] {
        let n = self.per_section as u32;
        let [a, b, c] = self.triangles[t];
        let lo = |i: u32| j as u32 * n + i;
        let hi = |i: u32| (j as u32 + 1) * n + i;
        let mut faces = [
            [lo(a), lo(c), lo(b)],
            [hi(a), hi(b), hi(c)],
            [0; 3],
            [0; 3],
            [0; 3],
            [0; 3],
            [0; 3],
            [0; 3],
        ];
        for (k, (p, q)) in [(a, b), (b, c), (c, a)].into_iter().enumerate() {
            faces[2 + 2 * k] = [lo(p), lo(q), hi(q)];
            faces[3 + 2 * k] = [lo(p), hi(q), hi(p)];
        }
        faces
    }
    /// The lattice's closed outer surface (end caps plus sides along the section outlines).
    pub fn surface(&self) -> MuscleSurface {
        let n = self.per_section as u32;
        let last = self.config.sections as u32 - 1;
        let mut directed: Vec<[u32; 2]> = self
            .triangles
            .iter()
            .flat_map(|&[a, b, c]| [[a, b], [b, c], [c, a]])
            .collect();
        directed.sort_unstable();
        let outline: Vec<[u32; 2]> = directed
            .iter()
            .filter(|&&[a, b]| directed.binary_search(&[b, a]).is_err())
            .copied()
            .collect();
        let mut triangles = Vec::new();
        for &[a, b, c] in &self.triangles {
            triangles.push([a, c, b]);
            triangles.push([last * n + a, last * n + b, last * n + c]);
        }
        for j in 0..last {
            let (lo, hi) = (j * n, (j + 1) * n);
            for &[p, q] in &outline {
                triangles.push([lo + p, lo + q, hi + q]);
                triangles.push([lo + p, hi + q, hi + p]);
            }
        }
        // Compact to the particles actually on the surface.
        let mut map = vec![u32::MAX; self.positions.len()];
        let mut particles = Vec::new();
        for t in &mut triangles {
            for v in t.iter_mut() {
                if map[*v as usize] == u32::MAX {
                    map[*v as usize] = particles.len() as u32;
                    particles.push(*v);
                }
                *v = map[*v as usize];
            }
        }
        MuscleSurface {
            particles,
            triangles,
        }
    }
}

/// Frames at `sections` equally spaced arc-length points, the in-plane axes parallel-transported
/// along the poly-line so the lattice does not twist.
fn section_frames(polyline: &[Vec3], sections: usize) -> Result<Vec<Frame>, AnatomyError> {
    let mut cumulative = vec![0.0f32];
    for (s, w) in polyline.windows(2).enumerate() {
        let l = (w[1] - w[0]).length();
        if l.is_nan() || l <= 0.0 {
            return Err(AnatomyError::DegenerateSegment { segment: s });
        }
        cumulative.push(cumulative[s] + l);
    }
    let total = *cumulative.last().expect("two points at least");
    let mut frames: Vec<Frame> = Vec::with_capacity(sections);
    let mut seg = 0;
    for j in 0..sections {
        let s = total * j as f32 / (sections - 1) as f32;
        while seg + 2 < polyline.len() && cumulative[seg + 1] < s {
            seg += 1;
        }
        let (a, b) = (polyline[seg], polyline[seg + 1]);
        let along =
            ((s - cumulative[seg]) / (cumulative[seg + 1] - cumulative[seg])).clamp(0.0, 1.0);
        let t = (b - a).normalize();
        let u = match frames.last() {
            Some(prev) => (prev.u - prev.u.dot(t) * t).normalize_or(t.any_orthonormal_vector()),
            None => t.any_orthonormal_vector(),
        };
        let w = t.cross(u);
        frames.push(Frame {
            origin: a.lerp(b, along),
            u,
            w,
            t,
        });
    }
    Ok(frames)
}

/// The outline of the plane section of a closed surface that contains the frame's origin, as a
/// 2D polygon in the frame. `None` if no outline loop surrounds the origin.
fn cross_section(surface: &TriMesh, frame: &Frame) -> Option<Vec<Vec2>> {
    let x = surface.positions();
    let topo = surface.topology();
    // Vertices exactly on the plane count as above it, so every edge is cut at most once.
    let above: Vec<bool> = x
        .iter()
        .map(|p| (*p - frame.origin).dot(frame.t) >= 0.0)
        .collect();
    let cut = |e: usize| {
        let [a, b] = topo.edges()[e];
        above[a as usize] != above[b as usize]
    };
    let point = |e: usize| {
        let [a, b] = topo.edges()[e].map(|i| x[i as usize]);
        let (da, db) = (
            (a - frame.origin).dot(frame.t),
            (b - frame.origin).dot(frame.t),
        );
        frame.to_2d(a + (b - a) * (da / (da - db)))
    };
    let mut visited = vec![false; topo.edges().len()];
    for start in 0..topo.edges().len() {
        if visited[start] || !cut(start) {
            continue;
        }
        // Walk the loop: edge -> triangle -> its other cut edge -> next triangle.
        let mut poly = Vec::new();
        let mut e = start;
        let mut from_tri = NO_TRIANGLE;
        loop {
            visited[e] = true;
            poly.push(point(e));
            let [t0, t1] = topo.edge_triangles()[e];
            let t = if t0 != from_tri { t0 } else { t1 };
            if t == NO_TRIANGLE {
                break;
            }
            let next = topo.triangle_edges()[t as usize]
                .iter()
                .map(|&n| n as usize)
                .find(|&n| n != e && cut(n));
            match next {
                Some(n) if n != start => {
                    from_tri = t;
                    e = n;
                }
                _ => break,
            }
        }
        if poly.len() >= 3 && contains(&poly, Vec2::ZERO) {
            return Some(poly);
        }
    }
    None
}

/// Even-odd point-in-polygon test.
fn contains(poly: &[Vec2], p: Vec2) -> bool {
    let mut inside = false;
    let mut j = poly.len() - 1;
    for i in 0..poly.len() {
        let (a, b) = (poly[i], poly[j]);
        if (a.y > p.y) != (b.y > p.y) && p.x < (b.x - a.x) * (p.y - a.y) / (b.y - a.y) + a.x {
            inside = !inside;
        }
        j = i;
    }
    inside
}

/// Unsigned area and centroid of a simple polygon.
fn area_centroid(poly: &[Vec2]) -> (f32, Vec2) {
    let o = poly[0];
    let (mut a2, mut c) = (0.0, Vec2::ZERO);
    for i in 1..poly.len() - 1 {
        let (p, q) = (poly[i] - o, poly[i + 1] - o);
        let cross = p.perp_dot(q);
        a2 += cross;
        c += cross * (p + q) / 3.0;
    }
    (0.5 * a2.abs(), o + c / a2)
}

/// Distance from `c` along unit `dir` to the nearest crossing of the polygon outline.
fn ray_reach(poly: &[Vec2], c: Vec2, dir: Vec2) -> Option<f32> {
    let mut best: Option<f32> = None;
    let mut j = poly.len() - 1;
    for i in 0..poly.len() {
        let (a, b) = (poly[j], poly[i]);
        j = i;
        let e = b - a;
        let denom = dir.perp_dot(e);
        if denom.abs() < 1e-20 {
            continue;
        }
        // c + t dir = a + s e
        let ac = a - c;
        let t = ac.perp_dot(e) / denom;
        let s = ac.perp_dot(dir) / denom;
        if t > 0.0 && (0.0..=1.0).contains(&s) {
            best = Some(best.map_or(t, |bt| bt.min(t)));
        }
    }
    best
}

/// Equilateral triangles of area `cell_area` with a vertex at `centre`, kept where all three
/// vertices are inside the polygon. Returns the used points and counter-clockwise triangles.
fn fill(poly: &[Vec2], centre: Vec2, cell_area: f32) -> (Vec<Vec2>, Vec<[u32; 3]>) {
    let side = (4.0 * cell_area / 3f32.sqrt()).sqrt();
    let e1 = Vec2::new(side, 0.0);
    let e2 = Vec2::new(0.5 * side, 0.5 * 3f32.sqrt() * side);
    let (min, max) = poly
        .iter()
        .fold((Vec2::INFINITY, Vec2::NEG_INFINITY), |(lo, hi), p| {
            (lo.min(*p), hi.max(*p))
        });
    let j_lo = ((min.y - centre.y) / e2.y).floor() as i32 - 1;
    let j_hi = ((max.y - centre.y) / e2.y).ceil() as i32 + 1;
    let point = |i: i32, j: i32| centre + i as f32 * e1 + j as f32 * e2;
    // Candidate points inside the polygon, keyed by lattice coordinates (lookup only).
    let mut inside: HashMap<(i32, i32), usize> = HashMap::new();
    let mut candidates = Vec::new();
    for j in j_lo..=j_hi {
        let shift = j as f32 * e2.x;
        let i_lo = ((min.x - centre.x - shift) / side).floor() as i32 - 1;
        let i_hi = ((max.x - centre.x - shift) / side).ceil() as i32 + 1;
        for i in i_lo..=i_hi {
            let p = point(i, j);
            if contains(poly, p) {
                inside.insert((i, j), candidates.len());
                candidates.push((i, j));
            }
        }
    }
    let mut tris = Vec::new();
    for &(i, j) in &candidates {
        for corners in [
            [(i, j), (i + 1, j), (i, j + 1)],
            [(i + 1, j), (i + 1, j + 1), (i, j + 1)],
        ] {
            let idx: Option<Vec<usize>> = corners.iter().map(|c| inside.get(c).copied()).collect();
            if let Some(idx) = idx {
                tris.push([idx[0], idx[1], idx[2]]);
            }
        }
    }
    // Keep only points used by a triangle, in candidate order.
    let mut used = vec![u32::MAX; candidates.len()];
    for t in &tris {
        for &v in t {
            used[v] = 0;
        }
    }
    let mut points = Vec::new();
    for (k, u) in used.iter_mut().enumerate() {
        if *u == 0 {
            *u = points.len() as u32;
            let (i, j) = candidates[k];
            points.push(point(i, j));
        }
    }
    let triangles = tris.iter().map(|t| t.map(|v| used[v])).collect();
    (points, triangles)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::anatomy::scenes::tube_mesh;

    fn tube() -> TriMesh {
        tube_mesh(Vec3::ZERO, Vec3::new(0.0, 0.0, 0.1), 0.01, 32, 10).unwrap()
    }

    #[test]
    fn main_section_is_equilateral_with_the_requested_area() {
        let line = [Vec3::new(0.0, 0.0, 0.001), Vec3::new(0.0, 0.0, 0.099)];
        let cfg = MuscleConfig {
            sections: 5,
            cell_area_m2: 4e-6,
            ..Default::default()
        };
        let lat = MuscleLattice::build(&tube(), &line, cfg).unwrap();
        let base = lat.main_section() * lat.per_section();
        for t in lat.section_triangles() {
            let [a, b, c] = t.map(|i| lat.positions()[base + i as usize]);
            let area = 0.5 * (b - a).cross(c - a).length();
            assert!((area / 4e-6 - 1.0).abs() < 1e-3, "area {area}");
            let (l0, l1) = ((b - a).length(), (c - b).length());
            assert!((l0 / l1 - 1.0).abs() < 1e-3);
            // Counter-clockwise about the poly-line direction (+z).
            assert!((b - a).cross(c - a).z > 0.0);
        }
        // The lattice fills most of the disk: area within one boundary strip of pi r^2.
        let total = lat.section_triangles().len() as f32 * 4e-6;
        let disk = std::f32::consts::PI * 1e-4;
        assert!(total < disk && total > 0.6 * disk, "{total} vs {disk}");
    }

    #[test]
    fn sections_follow_the_surface_by_radial_similarity() {
        // A cone-like tube: radius 1 cm at z = 0, 0.5 cm at z = 0.1 (by scaling a tube).
        let t = tube();
        let x: Vec<Vec3> = t
            .positions()
            .iter()
            .map(|p| {
                let s = 1.0 - 5.0 * p.z;
                Vec3::new(p.x * s, p.y * s, p.z)
            })
            .collect();
        let cone = TriMesh::new(x, t.triangles().to_vec()).unwrap();
        let line = [Vec3::new(0.0, 0.0, 0.001), Vec3::new(0.0, 0.0, 0.099)];
        let cfg = MuscleConfig {
            sections: 6,
            cell_area_m2: 4e-6,
            ..Default::default()
        };
        let lat = MuscleLattice::build(&cone, &line, cfg).unwrap();
        assert_eq!(lat.main_section(), 0);
        let n = lat.per_section();
        for j in 1..6 {
            let z = lat.positions()[j * n].z;
            let s = (1.0 - 5.0 * z) / (1.0 - 5.0 * lat.positions()[0].z);
            for i in 0..n {
                let p0 = lat.positions()[i].truncate();
                let pj = lat.positions()[j * n + i].truncate();
                // The outline is a 32-gon, so similarity holds up to its facets.
                assert!((pj - p0 * s).length() < 2e-4, "section {j} particle {i}");
            }
        }
    }

    #[test]
    fn surface_is_closed_and_encloses_the_cells() {
        let line = [Vec3::new(0.0, 0.0, 0.001), Vec3::new(0.0, 0.0, 0.099)];
        let lat = MuscleLattice::build(&tube(), &line, MuscleConfig::default()).unwrap();
        let s = lat.surface();
        let x: Vec<Vec3> = s
            .particles
            .iter()
            .map(|&p| lat.positions()[p as usize])
            .collect();
        crate::anatomy::pressure::check_closed(&s.triangles, x.len()).unwrap();
        let outer = crate::anatomy::pressure::volume(&s.triangles, &x);
        let cells: f32 = (0..lat.sections() - 1)
            .flat_map(|j| (0..lat.section_triangles().len()).map(move |t| (j, t)))
            .map(|(j, t)| crate::anatomy::pressure::volume(&lat.prism_faces(j, t), lat.positions()))
            .sum();
        assert!((outer / cells - 1.0).abs() < 1e-4, "{outer} vs {cells}");
    }

    #[test]
    fn bad_input_is_a_typed_error() {
        let t = tube();
        let cfg = MuscleConfig::default();
        assert_eq!(
            MuscleLattice::build(&t, &[Vec3::ZERO], cfg),
            Err(AnatomyError::PolylineTooShort { points: 1 })
        );
        let dup = [Vec3::ZERO, Vec3::ZERO, Vec3::Z];
        assert_eq!(
            MuscleLattice::build(&t, &dup, cfg),
            Err(AnatomyError::DegenerateSegment { segment: 0 })
        );
        let outside = [Vec3::new(1.0, 0.0, 0.0), Vec3::new(1.0, 0.0, 0.1)];
        assert_eq!(
            MuscleLattice::build(&t, &outside, cfg),
            Err(AnatomyError::NoCrossSection { section: 0 })
        );
        let nan = [Vec3::ZERO, Vec3::new(f32::NAN, 0.0, 0.0)];
        assert!(matches!(
            MuscleLattice::build(&t, &nan, cfg),
            Err(AnatomyError::NonFinite { .. })
        ));
        let line = [Vec3::new(0.0, 0.0, 0.001), Vec3::new(0.0, 0.0, 0.099)];
        let huge = MuscleConfig {
            cell_area_m2: 1.0,
            ..cfg
        };
        assert!(matches!(
            MuscleLattice::build(&t, &line, huge),
            Err(AnatomyError::EmptyLattice { .. })
        ));
        let open = TriMesh::new(t.positions().to_vec(), t.triangles()[1..].to_vec()).unwrap();
        assert!(matches!(
            MuscleLattice::build(&open, &line, cfg),
            Err(AnatomyError::OpenSurface { .. })
        ));
    }
}
