//! Running the built `sylva` binary from integration tests.

use std::process::Command;

/// Runs `sylva ARGS`; returns (success, stdout, stderr).
pub fn sylva(args: &[&str]) -> (bool, String, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_sylva"))
        .args(args)
        .output()
        .expect("run sylva");
    (
        out.status.success(),
        String::from_utf8_lossy(&out.stdout).into_owned(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}
