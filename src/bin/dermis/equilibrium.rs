//! `dermis equilibrium`: relax a mesh under the loads of a JSON file.

use std::path::PathBuf;
use std::time::Instant;

use clap::ValueEnum;
use dermis::fem::{solve_linear_springs, solve_membrane};
use dermis::io::{MeshFile, obj_text, read_loads, read_mesh, tet_boundary, write_atomic};
use dermis::solver::{Loads, RelaxConfig, SpringSystem};
use dermis::stiffness::{Modulus, StiffnessRule, tetrahedral_stiffness};
use glam::Vec3;
use serde_json::json;

use crate::CliResult;

/// Stiffness rule names on the command line.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum Rule {
    /// Van Gelder Eq. 29 (the default).
    #[value(name = "area-len2")]
    AreaLen2,
    /// Van Gelder Eq. 27 with `--nu`.
    Poisson,
    /// Van Gelder Eq. 30 (needs a tetrahedral JSON mesh; `--e2` is then E in N/m²).
    Tetrahedral,
    /// Baseline: every spring `--e2` N/m.
    Constant,
    /// Baseline: every spring `--e2 / length`.
    InverseLength,
    /// The linear constant-strain membrane FEM (planar meshes, small displacements).
    Fem,
    /// The linearised spring mesh (area-len2 springs, `K d = f`; planar meshes).
    LinearSprings,
}

#[derive(clap::Args)]
pub struct Args {
    /// The mesh: `.obj`, or `.json` with triangles or tetrahedra.
    #[arg(long)]
    mesh: PathBuf,
    /// Forces and pinned vertices (see the README for the format).
    #[arg(long)]
    loads: PathBuf,
    /// How spring stiffness is derived from the rest geometry.
    #[arg(long, value_enum, default_value = "area-len2")]
    stiffness: Rule,
    /// Young's modulus: 2D (N/m) for surfaces, 3D (N/m²) for the tetrahedral rule.
    #[arg(long, default_value_t = 1000.0)]
    e2: f32,
    /// Poisson ratio for `poisson` and `fem`.
    #[arg(long, default_value_t = 0.25)]
    nu: f32,
    /// Relative residual tolerance.
    #[arg(long, default_value_t = 1e-4)]
    tolerance: f32,
    /// Iteration budget.
    #[arg(long, default_value_t = 10_000)]
    max_iterations: u32,
    /// Where to write the equilibrium mesh (`.obj`).
    #[arg(long)]
    out: PathBuf,
    /// Print the summary as JSON.
    #[arg(long)]
    json: bool,
}

pub fn run(args: Args) -> CliResult {
    let start = Instant::now();
    let mesh = read_mesh(&args.mesh)?;
    let (rest, triangles, edges, vertex_count) = match &mesh {
        MeshFile::Surface(m) => (
            m.positions().to_vec(),
            m.triangles().to_vec(),
            m.topology().edges().to_vec(),
            m.positions().len(),
        ),
        MeshFile::Volume(m) => (
            m.positions().to_vec(),
            tet_boundary(m),
            m.edges().to_vec(),
            m.positions().len(),
        ),
    };
    let loads = read_loads(&args.loads, vertex_count)?;
    let modulus = Modulus::Uniform(args.e2);
    let surface = |rule: Rule| match &mesh {
        MeshFile::Surface(m) => Ok(m),
        MeshFile::Volume(_) => Err(format!(
            "--stiffness {rule:?} needs a triangle mesh; {} holds tetrahedra",
            args.mesh.display()
        )),
    };
    let mut summary = json!({});
    let positions: Vec<Vec3> = match args.stiffness {
        Rule::Fem | Rule::LinearSprings => {
            let m = surface(args.stiffness)?;
            let sol = if args.stiffness == Rule::Fem {
                solve_membrane(m, &modulus, args.nu as f64, &loads.forces, &loads.pinned)?
            } else {
                let k = StiffnessRule::AreaOverLengthSquared.edge_stiffness(m, &modulus)?;
                solve_linear_springs(m, &k, &loads.forces, &loads.pinned)?
            };
            summary["iterations"] = json!(sol.iterations);
            summary["residual"] = json!(sol.residual);
            rest.iter()
                .zip(&sol.displacement)
                .map(|(p, d)| (p.as_dvec3() + *d).as_vec3())
                .collect()
        }
        rule => {
            let k = match rule {
                Rule::Tetrahedral => match &mesh {
                    MeshFile::Volume(t) => tetrahedral_stiffness(t, &modulus)?,
                    MeshFile::Surface(_) => {
                        return Err(
                            "--stiffness tetrahedral needs a JSON mesh with \"tetrahedra\"".into(),
                        );
                    }
                },
                other => {
                    let r = match other {
                        Rule::AreaLen2 => StiffnessRule::AreaOverLengthSquared,
                        Rule::Poisson => StiffnessRule::poisson(args.nu),
                        Rule::Constant => StiffnessRule::Constant { k_n_per_m: args.e2 },
                        _ => StiffnessRule::InverseLength { e1_n: args.e2 },
                    };
                    r.edge_stiffness(surface(other)?, &modulus)?
                }
            };
            let lengths: Vec<f32> = edges
                .iter()
                .map(|&[a, b]| rest[a as usize].distance(rest[b as usize]))
                .collect();
            let system = SpringSystem::new(&rest, &edges, &k, &lengths)?;
            let mut x = rest.clone();
            let l = Loads {
                forces: Some(&loads.forces),
                pinned: Some(&loads.pinned),
                anchors: None,
            };
            let config = RelaxConfig {
                max_iterations: args.max_iterations,
                tolerance: args.tolerance,
                ..RelaxConfig::DEFAULT
            };
            let report = system.relax(&mut x, &l, &config)?;
            summary["iterations"] = json!(report.iterations);
            summary["residual"] = json!(report.residual);
            summary["energy"] = json!(report.energy);
            summary["stop"] = json!(report.stop);
            x
        }
    };
    write_atomic(&args.out, obj_text(&positions, &triangles).as_bytes())?;
    summary["rule"] = json!(
        args.stiffness
            .to_possible_value()
            .map(|v| v.get_name().to_string())
    );
    summary["vertices"] = json!(vertex_count);
    summary["edges"] = json!(edges.len());
    summary["seconds"] = json!(start.elapsed().as_secs_f64());
    summary["out"] = json!(args.out);
    if args.json {
        println!("{}", serde_json::to_string_pretty(&summary)?);
    } else {
        println!(
            "{} vertices, {} edges, rule {}: {} iterations, residual {}, written to {}",
            vertex_count,
            edges.len(),
            summary["rule"],
            summary["iterations"],
            summary["residual"],
            args.out.display()
        );
    }
    Ok(())
}
