//! Helpers shared by the integration-test areas.

use std::process::{Command, Output};

/// The `dermis` binary of this build.
pub fn dermis() -> Command {
    Command::new(env!("CARGO_BIN_EXE_dermis"))
}

/// Runs `cmd` and asserts it succeeded, showing its stderr otherwise.
pub fn run_ok(cmd: &mut Command) -> Output {
    let out = cmd.output().expect("the command starts");
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    out
}
