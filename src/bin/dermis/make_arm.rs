//! `dermis make-arm`: regenerate the bundled arm model byte-for-byte.

use std::error::Error;
use std::path::PathBuf;

use clap::Args;

use crate::pose::write_atomic;

/// Arguments of `dermis make-arm`.
#[derive(Args)]
pub struct MakeArmArgs {
    /// Where to write the .glb.
    #[arg(long, default_value = "assets/arm.glb")]
    out: PathBuf,
}

/// Runs `dermis make-arm`.
pub fn run(args: MakeArmArgs) -> Result<(), Box<dyn Error>> {
    let bytes = dermis::gltf::arm::build_arm_glb();
    write_atomic(&args.out, &bytes)
        .map_err(|e| format!("cannot write {}: {e}", args.out.display()))?;
    crate::pose::emit(&format!(
        "wrote {} ({} bytes)\n",
        args.out.display(),
        bytes.len()
    ))
}
