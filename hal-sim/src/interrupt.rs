//! Ctrl-C (SIGINT): what an interrupted `fpc-sim` leaves behind.
//!
//! Every command stages its outputs in a hidden directory (the `output` module's) that registers
//! itself here while it exists. At Ctrl-C the process removes every registered staging
//! directory and ends with exit code 130 (128 + SIGINT), so nothing half-written is left
//! in the user's folder — unless the command said it finishes an interrupted run itself
//! ([`catch`]: `run --keep-partial` keeps the log up to the interrupt, a live
//! `link capture` writes what it recorded, `view` ends its session). Then the first Ctrl-C
//! only sets [`interrupted`], which that command polls; a second one ends the process as
//! above.
//!
//! The handler is installed by the binary ([`install`]); a test harness that drives the tool
//! in-process keeps its own Ctrl-C.

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::Mutex;

/// Exit code of a process ended by Ctrl-C.
pub const EXIT_CODE: i32 = 130;

/// Ctrl-C presses so far.
static PRESSES: AtomicUsize = AtomicUsize::new(0);
/// The running command finishes an interrupted run itself (the first press).
static CAUGHT: AtomicBool = AtomicBool::new(false);
/// Staging directories that exist now.
static STAGING: Mutex<Vec<PathBuf>> = Mutex::new(Vec::new());

/// Installs the Ctrl-C handler (once per process; later calls do nothing).
pub fn install() {
    static ONCE: std::sync::Once = std::sync::Once::new();
    ONCE.call_once(|| {
        // A handler that cannot be installed (another one is) leaves the default: the
        // process ends at once, as before.
        let _ = ctrlc::set_handler(on_interrupt);
    });
}

/// What Ctrl-C does: the first press is the command's when it [`catch`]es it; otherwise
/// every staging directory goes and the process ends.
fn on_interrupt() {
    let presses = PRESSES.fetch_add(1, Ordering::SeqCst);
    if presses == 0 && CAUGHT.load(Ordering::SeqCst) {
        return;
    }
    remove_staging();
    std::process::exit(EXIT_CODE);
}

/// The running command handles the first Ctrl-C itself: it polls [`interrupted`] and ends
/// its work, writing what it keeps.
pub fn catch() {
    CAUGHT.store(true, Ordering::SeqCst);
}

/// Whether Ctrl-C has been pressed.
pub fn interrupted() -> bool {
    PRESSES.load(Ordering::SeqCst) > 0
}

/// Registers a staging directory: Ctrl-C removes it.
pub fn register(staging: &Path) {
    if let Ok(mut dirs) = STAGING.lock() {
        dirs.push(staging.to_path_buf());
    }
}

/// Unregisters a staging directory (committed or dropped).
pub fn unregister(staging: &Path) {
    if let Ok(mut dirs) = STAGING.lock() {
        dirs.retain(|d| d != staging);
    }
}

/// The staging directories registered now.
fn staging_now() -> Vec<PathBuf> {
    // A poisoned lock still holds the list: a panic elsewhere must not leave the folders.
    match STAGING.lock() {
        Ok(dirs) => dirs.clone(),
        Err(poisoned) => poisoned.into_inner().clone(),
    }
}

/// Removes every registered staging directory.
fn remove_staging() {
    for dir in staging_now() {
        let _ = std::fs::remove_dir_all(dir);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// (Other tests stage outputs at the same time: this one only reads the list.)
    #[test]
    fn a_staging_directory_is_listed_from_its_registration_to_its_end() {
        let root = tempfile::tempdir().unwrap();
        let (a, b) = (root.path().join("a"), root.path().join("b"));
        register(&a);
        register(&b);
        unregister(&b);
        let now = staging_now();
        unregister(&a);
        assert!(now.contains(&a) && !now.contains(&b), "{now:?}");
        assert!(!staging_now().contains(&a));
    }
}
