//! The source papers' experiments, reproducible from the command line.
//!
//! [`fig4`] reruns Van Gelder's Fig. 4: an irregular, graded hexagonal membrane under uniform
//! outward traction on its six sides. The exact membrane answer is a uniform expansion, so the
//! distance of each model's answer from the best-fitting uniform expansion measures its error.

use std::collections::BTreeMap;
use std::path::Path;

use glam::{DMat4, DVec2, DVec3, DVec4, Vec2, Vec3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::Serialize;
use spade::{DelaunayTriangulation, Point2, Triangulation};
use thiserror::Error;

use crate::fem::{FemError, solve_membrane};
use crate::io::{IoError, write_atomic};
use crate::mesh::{TopologyError, TriMesh};
use crate::solver::{Loads, RelaxConfig, SolverError, SpringSystem};
use crate::stiffness::{Modulus, StiffnessError, StiffnessRule};

/// Why a paper experiment failed.
#[derive(Debug, Error)]
pub enum PaperError {
    /// The generated mesh was rejected (a bug in the generator for this seed).
    #[error("generated mesh: {0}")]
    Mesh(#[from] TopologyError),
    /// Stiffness could not be computed.
    #[error(transparent)]
    Stiffness(#[from] StiffnessError),
    /// The spring relaxation failed.
    #[error(transparent)]
    Solver(#[from] SolverError),
    /// The FEM reference failed.
    #[error(transparent)]
    Fem(#[from] FemError),
    /// Writing the figure failed.
    #[error(transparent)]
    Io(#[from] IoError),
}

/// Settings of the Fig. 4 experiment.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Fig4Config {
    /// 2D Young's modulus, N/m.
    pub e2_n_per_m: f32,
    /// Poisson ratio for the `poisson` rule and the FEM.
    pub nu: f32,
    /// Outward traction on the six sides, N/m (the strain is about `traction / e2`).
    pub traction_n_per_m: f32,
    /// Smallest target edge length (left side), for a hexagon of circumradius 1.
    pub min_spacing: f32,
    /// Ratio of the largest to the smallest target edge length across the hexagon.
    pub grading: f32,
}

impl Default for Fig4Config {
    fn default() -> Self {
        Self {
            e2_n_per_m: 1000.0,
            nu: 0.25,
            traction_n_per_m: 1.0,
            min_spacing: 0.075,
            grading: 4.0,
        }
    }
}

/// The rules compared, in figure order.
pub const FIG4_RULES: [&str; 5] = ["constant", "inverse-length", "area-len2", "poisson", "fem"];

/// One seed's result.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Fig4Run {
    /// The mesh generator's seed.
    pub seed: u64,
    /// Vertices in the membrane.
    pub vertices: usize,
    /// Triangles in the membrane.
    pub triangles: usize,
    /// Ratio of the largest to the smallest triangle area.
    pub area_ratio: f32,
    /// `|d − s X| / |s X|` after removing rigid motion, per rule.
    pub deviation: BTreeMap<&'static str, f64>,
    /// Relaxation iterations per spring rule.
    pub iterations: BTreeMap<&'static str, u32>,
    /// Fitted uniform stretch `s` per rule.
    pub stretch: BTreeMap<&'static str, f64>,
}

/// A run plus the deformed positions, for drawing.
#[derive(Debug, Clone)]
pub struct Fig4Result {
    /// The figures.
    pub run: Fig4Run,
    /// The membrane at rest.
    pub mesh: TriMesh,
    /// Displacement per rule, in [`FIG4_RULES`] order.
    pub displacements: Vec<Vec<DVec3>>,
}

/// Builds the irregular graded hexagon of circumradius 1 in the `z = 0` plane: boundary sides
/// subdivided, interior points by seeded dart throwing with a spacing that grows `grading`-fold
/// from left to right, Delaunay-triangulated (spade).
pub fn graded_hexagon(seed: u64, config: &Fig4Config) -> Result<TriMesh, TopologyError> {
    let spacing = |p: DVec2| {
        config.min_spacing as f64
            * (config.grading as f64).powf(((p.x + 1.0) / 2.0).clamp(0.0, 1.0))
    };
    let corners: Vec<DVec2> = (0..6)
        .map(|k| DVec2::from_angle(k as f64 * std::f64::consts::FRAC_PI_3))
        .collect();
    let mut points: Vec<DVec2> = Vec::new();
    for k in 0..6 {
        let (a, b) = (corners[k], corners[(k + 1) % 6]);
        // Place points so that consecutive ones are about spacing() apart along the side.
        const STEPS: usize = 400;
        let mut cumulative = vec![0.0f64];
        for i in 0..STEPS {
            let p = a.lerp(b, (i as f64 + 0.5) / STEPS as f64);
            cumulative.push(cumulative[i] + (b - a).length() / STEPS as f64 / spacing(p));
        }
        let total = cumulative[STEPS];
        let segments = total.round().max(1.0) as usize;
        points.push(a);
        for s in 1..segments {
            let target = total * s as f64 / segments as f64;
            let i = cumulative.partition_point(|&c| c < target).clamp(1, STEPS);
            let frac = (target - cumulative[i - 1]) / (cumulative[i] - cumulative[i - 1]);
            points.push(a.lerp(b, (i as f64 - 1.0 + frac) / STEPS as f64));
        }
    }
    let boundary = points.len();
    let inside = |p: DVec2, margin: f64| {
        (0..6).all(|k| {
            let n = DVec2::from_angle((k as f64 + 0.5) * std::f64::consts::FRAC_PI_3);
            p.dot(n) < (3.0f64).sqrt() / 2.0 - margin
        })
    };
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    for _ in 0..40_000 {
        let p = DVec2::new(rng.random_range(-1.0..1.0), rng.random_range(-1.0..1.0));
        let h = spacing(p);
        if !inside(p, 0.6 * h) {
            continue;
        }
        let clear = points.iter().enumerate().all(|(i, q)| {
            let hq = if i < boundary { 0.85 } else { 0.8 } * 0.5 * (h + spacing(*q));
            p.distance_squared(*q) > hq * hq
        });
        if clear {
            points.push(p);
        }
    }
    let mut dt: DelaunayTriangulation<Point2<f64>> = DelaunayTriangulation::new();
    let mut index = Vec::with_capacity(points.len());
    for p in &points {
        let handle = dt
            .insert(Point2::new(p.x, p.y))
            .map_err(|_| TopologyError::Degenerate {
                element: index.len(),
            })?;
        index.push(handle.index());
    }
    // Map spade's vertex indices back to ours (they are insertion order unless a duplicate was
    // merged, which the spacing rules out).
    let mut ours = vec![u32::MAX; dt.num_vertices()];
    for (i, &h) in index.iter().enumerate() {
        ours[h] = i as u32;
    }
    let mut triangles: Vec<[u32; 3]> = dt
        .inner_faces()
        .map(|f| f.vertices().map(|v| ours[v.fix().index()]))
        // Side points are collinear only up to rounding: drop the hull slivers between them.
        .filter(|t| {
            let [a, b, c] = t.map(|i| points[i as usize]);
            let longest = (b - a).length().max((c - b).length()).max((a - c).length());
            (b - a).perp_dot(c - a).abs() > 1e-6 * longest * longest
        })
        .collect();
    // Deterministic triangle order, independent of spade's internals.
    triangles.sort_unstable();
    let positions = points
        .iter()
        .map(|p| Vec3::new(p.x as f32, p.y as f32, 0.0))
        .collect();
    TriMesh::new(positions, triangles)
}

/// Nodal forces of a uniform outward traction `t` (N/m) on the boundary edges of a planar,
/// convex membrane centred on the origin: each edge's `t · length` along its outward normal,
/// split equally between its two vertices (the consistent load for linear elements).
pub fn uniform_traction(mesh: &TriMesh, traction: f32) -> Vec<Vec3> {
    let p = mesh.positions();
    let mut f = vec![Vec3::ZERO; p.len()];
    let topo = mesh.topology();
    for e in topo.boundary_edges() {
        let [a, b] = topo.edges()[e];
        let (pa, pb) = (p[a as usize], p[b as usize]);
        let edge = (pb - pa).truncate();
        let mut n = edge.perp().normalize();
        if n.dot((pa + pb).truncate()) < 0.0 {
            n = -n;
        }
        let force = (n * traction * edge.length() * 0.5).extend(0.0);
        f[a as usize] += force;
        f[b as usize] += force;
    }
    f
}

/// The uniform expansion `s X` plus rigid motion that best fits `displacement` (least squares
/// over in-plane coordinates about the centroid), and the relative deviation from it:
/// `(|d − rigid − s X| / |s X|, s)`.
pub fn deviation_from_uniform_expansion(rest: &[Vec3], displacement: &[DVec3]) -> (f64, f64) {
    let c = rest.iter().map(|p| p.as_dvec3()).sum::<DVec3>() / rest.len() as f64;
    // Unknowns (tx, ty, ω, s): d ≈ (tx − ω y + s x, ty + ω x + s y).
    let mut ata = DMat4::ZERO;
    let mut atb = DVec4::ZERO;
    for (p, d) in rest.iter().zip(displacement) {
        let q = p.as_dvec3() - c;
        let rows = [
            (DVec4::new(1.0, 0.0, -q.y, q.x), d.x),
            (DVec4::new(0.0, 1.0, q.x, q.y), d.y),
        ];
        for (row, rhs) in rows {
            ata += DMat4::from_cols(row * row.x, row * row.y, row * row.z, row * row.w);
            atb += row * rhs;
        }
    }
    let sol = ata.inverse() * atb;
    let (mut num, mut den) = (0.0, 0.0);
    for (p, d) in rest.iter().zip(displacement) {
        let q = p.as_dvec3() - c;
        let fit = DVec2::new(
            sol.x - sol.z * q.y + sol.w * q.x,
            sol.y + sol.z * q.x + sol.w * q.y,
        );
        num += (d.truncate() - fit).length_squared();
        den += (q.truncate() * sol.w).length_squared();
    }
    ((num / den).sqrt(), sol.w)
}

/// Runs Fig. 4 for one seed: each spring rule relaxed (nonlinear) and the FEM solved, all under
/// the same loads.
pub fn fig4(seed: u64, config: &Fig4Config) -> Result<Fig4Result, PaperError> {
    let mesh = graded_hexagon(seed, config)?;
    let forces = uniform_traction(&mesh, config.traction_n_per_m);
    let e2 = Modulus::Uniform(config.e2_n_per_m);
    let lengths = mesh.edge_lengths();
    let reference = StiffnessRule::AreaOverLengthSquared.edge_stiffness(&mesh, &e2)?;
    // Baselines scaled to the same mean stiffness, so all meshes stretch by similar amounts.
    let mean_k = reference.iter().sum::<f32>() / reference.len() as f32;
    let mean_e1 = reference
        .iter()
        .zip(&lengths)
        .map(|(k, l)| k * l)
        .sum::<f32>()
        / lengths.len() as f32;
    let rules = [
        StiffnessRule::Constant { k_n_per_m: mean_k },
        StiffnessRule::InverseLength { e1_n: mean_e1 },
        StiffnessRule::AreaOverLengthSquared,
        StiffnessRule::poisson(config.nu),
    ];
    let mut run = Fig4Run {
        seed,
        vertices: mesh.positions().len(),
        triangles: mesh.triangles().len(),
        area_ratio: mesh.quality().area_ratio,
        deviation: BTreeMap::new(),
        iterations: BTreeMap::new(),
        stretch: BTreeMap::new(),
    };
    let mut displacements = Vec::new();
    let loads = Loads {
        forces: Some(&forces),
        ..Default::default()
    };
    let relax = RelaxConfig {
        max_iterations: 20_000,
        tolerance: 1e-6,
        ..RelaxConfig::DEFAULT
    };
    for rule in rules {
        let k = rule.edge_stiffness(&mesh, &e2)?;
        let system = SpringSystem::from_mesh(&mesh, &k)?;
        let mut x = mesh.positions().to_vec();
        let report = system.relax(&mut x, &loads, &relax)?;
        let d: Vec<DVec3> = x
            .iter()
            .zip(mesh.positions())
            .map(|(x, p)| x.as_dvec3() - p.as_dvec3())
            .collect();
        let (dev, s) = deviation_from_uniform_expansion(mesh.positions(), &d);
        run.deviation.insert(rule.name(), dev);
        run.stretch.insert(rule.name(), s);
        run.iterations.insert(rule.name(), report.iterations);
        displacements.push(d);
    }
    let pinned = vec![false; forces.len()];
    let fem = solve_membrane(&mesh, &e2, config.nu as f64, &forces, &pinned)?;
    let (dev, s) = deviation_from_uniform_expansion(mesh.positions(), &fem.displacement);
    run.deviation.insert("fem", dev);
    run.stretch.insert("fem", s);
    displacements.push(fem.displacement);
    Ok(Fig4Result {
        run,
        mesh,
        displacements,
    })
}

/// Draws the rest mesh and the four spring-mesh results side by side (like the paper's
/// figure), each with its non-uniform part exaggerated so that the uniform expansion shows as
/// 30 %; the grey outline is the exact (uniform) answer. Written atomically as PNG.
pub fn render_fig4(result: &Fig4Result, path: &Path) -> Result<(), PaperError> {
    const PANEL: u32 = 360;
    let panels = 5;
    let mut pixmap = tiny_skia::Pixmap::new(PANEL * panels, PANEL).expect("non-zero size");
    pixmap.fill(tiny_skia::Color::WHITE);
    let rest = result.mesh.positions();
    let scale = PANEL as f32 / 2.0 / 1.45;
    for panel in 0..panels {
        let center = Vec2::new((panel * PANEL + PANEL / 2) as f32, PANEL as f32 / 2.0);
        let to_px = |p: Vec2| center + Vec2::new(p.x, -p.y) * scale;
        let drawn: Vec<Vec2> = if panel == 0 {
            rest.iter().map(|p| p.truncate()).collect()
        } else {
            let d = &result.displacements[panel as usize - 1];
            let (_, s) = deviation_from_uniform_expansion(rest, d);
            let m = 0.3 / s;
            rest.iter()
                .zip(d)
                .map(|(p, d)| p.truncate() + (d.truncate() * m).as_vec2())
                .collect()
        };
        if panel > 0 {
            let mut outline = tiny_skia::PathBuilder::new();
            for k in 0..=6 {
                let c = to_px(Vec2::from_angle(k as f32 * std::f32::consts::FRAC_PI_3) * 1.3);
                if k == 0 {
                    outline.move_to(c.x, c.y)
                } else {
                    outline.line_to(c.x, c.y)
                }
            }
            if let Some(path) = outline.finish() {
                stroke(&mut pixmap, &path, [170, 170, 170], 3.0);
            }
        }
        let mut edges = tiny_skia::PathBuilder::new();
        for &[a, b] in result.mesh.topology().edges() {
            let (pa, pb) = (to_px(drawn[a as usize]), to_px(drawn[b as usize]));
            edges.move_to(pa.x, pa.y);
            edges.line_to(pb.x, pb.y);
        }
        if let Some(path) = edges.finish() {
            stroke(&mut pixmap, &path, [20, 40, 120], 1.0);
        }
    }
    let png = pixmap
        .encode_png()
        .map_err(|e| IoError::Encode(e.to_string()))?;
    write_atomic(path, &png)?;
    Ok(())
}

fn stroke(pixmap: &mut tiny_skia::Pixmap, path: &tiny_skia::Path, rgb: [u8; 3], width: f32) {
    let mut paint = tiny_skia::Paint::default();
    paint.set_color_rgba8(rgb[0], rgb[1], rgb[2], 255);
    paint.anti_alias = true;
    let stroke = tiny_skia::Stroke {
        width,
        ..Default::default()
    };
    pixmap.stroke_path(
        path,
        &paint,
        &stroke,
        tiny_skia::Transform::identity(),
        None,
    );
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn hexagon_is_graded_and_well_shaped() {
        let mesh = graded_hexagon(0, &Fig4Config::default()).unwrap();
        let q = mesh.quality();
        assert!((120..400).contains(&q.vertices), "{q:?}");
        assert!(q.area_ratio > 5.0, "sizes should vary several-fold: {q:?}");
        assert!(q.min_angle_deg > 15.0, "{q:?}");
        // Total area of the regular hexagon of circumradius 1.
        let area: f32 = (0..mesh.triangles().len())
            .map(|t| mesh.triangle_area(t))
            .sum();
        assert!((area - 1.5 * 3f32.sqrt()).abs() < 1e-4);
        // The boundary is exactly the six sides.
        let on = mesh.topology().boundary_vertices();
        for (p, b) in mesh.positions().iter().zip(on) {
            let r = (0..6)
                .map(|k| {
                    p.truncate().dot(Vec2::from_angle(
                        (k as f32 + 0.5) * std::f32::consts::FRAC_PI_3,
                    ))
                })
                .fold(f32::MIN, f32::max);
            assert_eq!(b, (r - 3f32.sqrt() / 2.0).abs() < 1e-5);
        }
    }

    #[test]
    fn traction_is_balanced_and_sums_to_perimeter() {
        let mesh = graded_hexagon(3, &Fig4Config::default()).unwrap();
        let f = uniform_traction(&mesh, 2.0);
        let net: Vec3 = f.iter().sum();
        assert!(net.length() < 1e-4);
        let torque: f32 = f
            .iter()
            .zip(mesh.positions())
            .map(|(f, p)| p.truncate().perp_dot(f.truncate()))
            .sum();
        assert!(torque.abs() < 1e-4);
        // Σ f·X = t · ∮ X·n ds = t · 2 · area for a uniform traction.
        let work: f32 = f.iter().zip(mesh.positions()).map(|(f, p)| f.dot(*p)).sum();
        assert!((work - 2.0 * 2.0 * 1.5 * 3f32.sqrt()).abs() < 1e-3);
    }

    #[test]
    fn deviation_ignores_rigid_motion_and_sees_distortion() {
        let rest: Vec<Vec3> = (0..20)
            .map(|i| Vec3::new((i as f32 * 0.7).sin(), (i as f32 * 1.3).cos(), 0.0))
            .collect();
        let d: Vec<DVec3> = rest
            .iter()
            .map(|p| {
                let q = p.as_dvec3();
                DVec3::new(
                    0.3 + 0.01 * q.x - 0.2 * q.y,
                    -0.1 + 0.01 * q.y + 0.2 * q.x,
                    0.0,
                )
            })
            .collect();
        let (dev, s) = deviation_from_uniform_expansion(&rest, &d);
        assert!(dev < 1e-9);
        assert!((s - 0.01).abs() < 1e-9);
        let bent: Vec<DVec3> = d
            .iter()
            .zip(&rest)
            .map(|(d, p)| *d + DVec3::new(0.001 * p.x as f64, 0.0, 0.0))
            .collect();
        assert!(deviation_from_uniform_expansion(&rest, &bent).0 > 0.01);
    }
}

#[cfg(test)]
mod regular_mesh_tests {
    use super::*;

    /// An independent check of the whole chain (stiffness, loads, relaxation, deviation): on a
    /// mesh of equilateral triangles every area-len2 spring has the same stiffness and every
    /// interior vertex sees six symmetric neighbours, so uniform traction must give a uniform
    /// expansion, up to solver precision.
    #[test]
    fn equilateral_hexagon_expands_uniformly_with_area_len2() {
        let n = 6i32;
        let h = 1.0 / n as f32;
        let mut index = std::collections::BTreeMap::new();
        let mut p = Vec::new();
        for j in -n..=n {
            for i in -n..=n {
                // Axial coordinates of a hexagon of radius n.
                if (i + j).abs() > n {
                    continue;
                }
                index.insert((i, j), p.len() as u32);
                p.push(Vec3::new(
                    h * (i as f32 + 0.5 * j as f32),
                    h * 0.75f32.sqrt() * j as f32,
                    0.0,
                ));
            }
        }
        let mut t = Vec::new();
        for (&(i, j), &a) in &index {
            if let (Some(&b), Some(&c)) = (index.get(&(i + 1, j)), index.get(&(i, j + 1))) {
                t.push([a, b, c]);
            }
            if let (Some(&b), Some(&c)) = (index.get(&(i + 1, j)), index.get(&(i + 1, j - 1))) {
                t.push([a, c, b]);
            }
        }
        let mesh = TriMesh::new(p, t).unwrap();
        let f = uniform_traction(&mesh, 1.0);
        let k = StiffnessRule::AreaOverLengthSquared
            .edge_stiffness(&mesh, &Modulus::Uniform(1000.0))
            .unwrap();
        let system = SpringSystem::from_mesh(&mesh, &k).unwrap();
        let mut x = mesh.positions().to_vec();
        let loads = Loads {
            forces: Some(&f),
            ..Default::default()
        };
        system
            .relax(
                &mut x,
                &loads,
                &RelaxConfig {
                    tolerance: 1e-6,
                    max_iterations: 5000,
                    ..Default::default()
                },
            )
            .unwrap();
        let d: Vec<DVec3> = x
            .iter()
            .zip(mesh.positions())
            .map(|(x, p)| x.as_dvec3() - p.as_dvec3())
            .collect();
        let (dev, s) = deviation_from_uniform_expansion(mesh.positions(), &d);
        assert!(dev < 1e-3, "deviation {dev}");
        // An equilateral spring lattice is a membrane with ν = 1/3: strain t (1 − ν) / E2 with
        // E2 the Eq. 29 modulus, i.e. 2/3 of t / E2.
        assert!((s / (2.0 / 3.0 * 1e-3) - 1.0).abs() < 0.01, "stretch {s}");
    }
}
