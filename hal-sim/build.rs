//! Build script: the commit `fpc-sim --version` names (`FPC_SIM_COMMIT`: git's short hash of
//! HEAD, or `unknown` outside a git checkout, e.g. a source archive). It runs again when
//! HEAD moves (a commit, a checkout), not on every edit.

use std::process::Command;

/// `git ARGS` in this package's directory, its trimmed output if it succeeded.
fn git(args: &[&str]) -> Option<String> {
    let out = Command::new("git").args(args).output().ok()?;
    out.status
        .success()
        .then(|| String::from_utf8_lossy(&out.stdout).trim().to_string())
        .filter(|s| !s.is_empty())
}

fn main() {
    println!("cargo:rerun-if-changed=build.rs");
    let commit = git(&["rev-parse", "--short=7", "HEAD"]).unwrap_or_else(|| "unknown".into());
    println!("cargo:rustc-env=FPC_SIM_COMMIT={commit}");
    // HEAD itself (a checkout of another branch) and the ref it names (a new commit on it),
    // wherever this checkout keeps them (a worktree keeps refs in the common directory).
    for path in [
        git(&["rev-parse", "--git-path", "HEAD"]),
        git(&["symbolic-ref", "-q", "HEAD"]).and_then(|r| git(&["rev-parse", "--git-path", &r])),
        git(&["rev-parse", "--git-path", "packed-refs"]),
    ]
    .into_iter()
    .flatten()
    {
        let path = std::path::Path::new(&path);
        if path.exists() {
            println!("cargo:rerun-if-changed={}", path.display());
        }
    }
}
