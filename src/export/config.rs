//! The `dermis export` settings file (`--config dermis.toml`): every field optional, every
//! default documented; command-line flags override it.

use std::path::Path;

use serde::{Deserialize, Serialize};

use crate::io::IoError;
use crate::stiffness::StiffnessRule;

/// All settings of an export. A TOML file may set any subset:
///
/// ```toml
/// fps = 30.0
///
/// [material]
/// youngs_2d_n_per_m = 1000.0
/// rule = "area-len2"          # or "poisson" (with poisson_ratio), "constant", "inverse-length"
/// poisson_ratio = 0.3
///
/// [anchors]
/// k_normal_n_per_m = 200.0
/// k_tangent_n_per_m = 20.0
///
/// [solver]
/// max_iterations = 60
/// tolerance = 1e-3
///
/// [contact]
/// enabled = true
/// thickness_m = 0.002
/// friction = 0.0
///
/// [output]
/// format = "glb"              # glb | obj | ply | usda
/// with_colliders = false
/// strain_colors = true
/// checkpoint_every = 10
/// ```
///
/// ```
/// let c: dermis::export::ExportConfig = toml::from_str("fps = 24.0\n[contact]\nfriction = 0.5").unwrap();
/// assert_eq!(c.fps, 24.0);
/// assert_eq!(c.contact.friction, 0.5);
/// assert_eq!(c.contact.thickness_m, 0.002); // the default
/// ```
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ExportConfig {
    /// Frames per second of the export (the simulation's fixed timestep is `1 / fps`). Default 30.
    pub fps: f32,
    /// Skin material.
    pub material: MaterialConfig,
    /// How strongly the skin follows the skinned body.
    pub anchors: AnchorConfig,
    /// Relaxation budget per frame.
    pub solver: SolverConfig,
    /// Skin against muscles and bones.
    pub contact: ContactSettings,
    /// What is written.
    pub output: OutputConfig,
}

impl Default for ExportConfig {
    fn default() -> Self {
        Self {
            fps: 30.0,
            material: MaterialConfig::default(),
            anchors: AnchorConfig::default(),
            solver: SolverConfig::default(),
            contact: ContactSettings::default(),
            output: OutputConfig::default(),
        }
    }
}

impl ExportConfig {
    /// Reads a TOML settings file; unknown keys are errors (a typo must not pass silently).
    pub fn read(path: &Path) -> Result<Self, IoError> {
        let text = std::fs::read_to_string(path).map_err(|source| IoError::File {
            path: path.to_path_buf(),
            source,
        })?;
        toml::from_str(&text).map_err(|e| IoError::Loads {
            path: path.to_path_buf(),
            message: e.to_string(),
        })
    }
}

/// Skin material.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct MaterialConfig {
    /// 2D Young's modulus `E2`, N/m. Default 1000.
    pub youngs_2d_n_per_m: f32,
    /// Stiffness rule: `area-len2` (default), `poisson`, `constant`, `inverse-length`.
    pub rule: String,
    /// Poisson ratio for the `poisson` rule. Default 0.3.
    pub poisson_ratio: f32,
}

impl Default for MaterialConfig {
    fn default() -> Self {
        Self {
            youngs_2d_n_per_m: 1000.0,
            rule: "area-len2".into(),
            poisson_ratio: 0.3,
        }
    }
}

impl MaterialConfig {
    /// The stiffness rule named by [`rule`](Self::rule); baselines take `E2` as their constant.
    pub fn stiffness_rule(&self) -> Result<StiffnessRule, String> {
        Ok(match self.rule.as_str() {
            "area-len2" => StiffnessRule::AreaOverLengthSquared,
            "poisson" => StiffnessRule::poisson(self.poisson_ratio),
            "constant" => StiffnessRule::Constant {
                k_n_per_m: self.youngs_2d_n_per_m,
            },
            "inverse-length" => StiffnessRule::InverseLength {
                e1_n: self.youngs_2d_n_per_m,
            },
            other => {
                return Err(format!(
                    "unknown stiffness rule {other:?} (expected area-len2, poisson, constant or inverse-length)"
                ));
            }
        })
    }
}

/// Anchor springs pulling each skin vertex towards its skinned position.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct AnchorConfig {
    /// Stiffness along the body normal, N/m. Default 200.
    pub k_normal_n_per_m: f32,
    /// Stiffness along the body surface (skin slides more easily), N/m. Default 20.
    pub k_tangent_n_per_m: f32,
}

impl Default for AnchorConfig {
    fn default() -> Self {
        Self {
            k_normal_n_per_m: 200.0,
            k_tangent_n_per_m: 20.0,
        }
    }
}

/// Relaxation budget per frame.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SolverConfig {
    /// Iteration budget per frame (and per collision substep). Default 60.
    pub max_iterations: u32,
    /// Relative residual tolerance. Default 1e-3.
    pub tolerance: f32,
}

impl Default for SolverConfig {
    fn default() -> Self {
        Self {
            max_iterations: 60,
            tolerance: 1e-3,
        }
    }
}

/// Skin against muscles and bones.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ContactSettings {
    /// Collide the skin with the muscle and bone meshes. Default true.
    pub enabled: bool,
    /// Skin thickness: how far outside a collider's surface the skin settles, m. Default 0.002.
    pub thickness_m: f32,
    /// Fraction of tangential slip over a collider removed per contact pass, in `[0, 1]`.
    /// Default 0 (skin slides freely).
    pub friction: f32,
}

impl Default for ContactSettings {
    fn default() -> Self {
        Self {
            enabled: true,
            thickness_m: 0.002,
            friction: 0.0,
        }
    }
}

/// What is written.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct OutputConfig {
    /// `glb` (default), `obj`, `ply` or `usda`.
    pub format: String,
    /// Also write the muscle and bone meshes as they moved. Default false.
    pub with_colliders: bool,
    /// Per-vertex strain colours. Default true.
    pub strain_colors: bool,
    /// Write a resumable checkpoint every this many frames (0: never). Default 10.
    pub checkpoint_every: u32,
}

impl Default for OutputConfig {
    fn default() -> Self {
        Self {
            format: "glb".into(),
            with_colliders: false,
            strain_colors: true,
            checkpoint_every: 10,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_field_has_a_default_and_typos_are_errors() {
        let empty: ExportConfig = toml::from_str("").unwrap();
        assert_eq!(empty, ExportConfig::default());
        let round: ExportConfig = toml::from_str(&toml::to_string(&empty).unwrap()).unwrap();
        assert_eq!(round, empty);
        assert!(toml::from_str::<ExportConfig>("[contact]\nthicknes_m = 0.1").is_err());
        let c: ExportConfig = toml::from_str("[material]\nrule = \"poisson\"").unwrap();
        assert!(matches!(
            c.material.stiffness_rule(),
            Ok(StiffnessRule::Poisson { .. })
        ));
        let c: ExportConfig = toml::from_str("[material]\nrule = \"springy\"").unwrap();
        assert!(c.material.stiffness_rule().unwrap_err().contains("springy"));
    }
}
