//! Where `fpc-sim` writes, made safe: every output is checked before any work (exit 2 when it
//! cannot be written, already exists without `--force`, or is one of the command's own
//! inputs), written into a staging directory beside its final place, and moved into place
//! only once the whole set is complete. A failure part-way leaves the earlier files as they
//! were and no partial new ones (`docs/faults.md` row 23).
//!
//! `--force` replaces existing outputs of the same names; it never replaces an input, and it
//! leaves every other file in the directory alone.

use std::path::{Path, PathBuf};

use crate::failure::Failure;

/// A directory of output files, staged until [`OutDir::commit`]: the names known
/// beforehand are checked at once, any other file written is checked before it moves.
#[derive(Debug)]
pub struct OutDir {
    dir: PathBuf,
    staging: PathBuf,
    names: Vec<String>,
    force: bool,
    inputs: Vec<PathBuf>,
    committed: bool,
}

/// Longest path echoed in a message, in characters (longer ones are cut with `…`).
const ECHO_CHARS: usize = 120;

/// `text` cut to `max` characters, with `…` when cut (values and paths echoed in messages).
pub fn clip(text: &str, max: usize) -> String {
    if text.chars().count() <= max {
        text.to_string()
    } else {
        let mut cut: String = text.chars().take(max).collect();
        cut.push('…');
        cut
    }
}

/// `path` for a message, cut to a sensible length.
pub fn show(path: &Path) -> String {
    clip(&path.display().to_string(), ECHO_CHARS)
}

/// Whether `a` and `b` name the same existing file (after resolving links and `..`).
fn same_file(a: &Path, b: &Path) -> bool {
    match (a.canonicalize(), b.canonicalize()) {
        (Ok(a), Ok(b)) => a == b,
        _ => false,
    }
}

impl OutDir {
    /// Checks that `names` can be written into `dir` and prepares their staging directory.
    ///
    /// Refused (exit 2, before any work): `dir` is an existing file or the filesystem root,
    /// it cannot be created or written, one of `names` exists there and `force` is off, or
    /// one of them is one of `inputs` (even with `force`).
    pub fn prepare(
        dir: &Path,
        names: &[&str],
        force: bool,
        inputs: &[&Path],
    ) -> Result<OutDir, Failure> {
        if dir.as_os_str().is_empty() {
            return Err(Failure::bad_input("the output directory is an empty path"));
        }
        if dir.is_file() {
            return Err(Failure::bad_input(format!(
                "output directory {} is an existing file",
                show(dir)
            )));
        }
        let resolved = dir.canonicalize().unwrap_or_else(|_| dir.to_path_buf());
        if resolved.parent().is_none() {
            return Err(Failure::bad_input(format!(
                "output directory {}: refusing to write into the filesystem root",
                show(dir)
            )));
        }
        for name in names {
            let target = dir.join(name);
            if let Some(input) = inputs.iter().find(|i| same_file(i, &target)) {
                return Err(Failure::bad_input(format!(
                    "{} is an input of this command; refusing to overwrite it (choose another \
                     output directory)",
                    show(input)
                )));
            }
            if is_special(&target) {
                return Err(Failure::bad_input(format!(
                    "{} is a device, pipe or socket, not a file; refusing to replace it (even \
                     with --force)",
                    show(&target)
                )));
            }
            if !force && target.symlink_metadata().is_ok() {
                return Err(Failure::bad_input(format!(
                    "{} exists; refusing to overwrite it (add --force to replace the outputs)",
                    show(&target)
                )));
            }
            if target.is_dir() {
                return Err(Failure::bad_input(format!(
                    "{} is a directory; cannot write the output file there",
                    show(&target)
                )));
            }
        }
        // The staging directory goes into the directory itself or, when that does not
        // exist yet, into its nearest existing ancestor (the same filesystem, so the final
        // renames are atomic); the directory is created only at the commit, so a failed
        // command leaves no empty directory behind either.
        let absolute = if dir.is_absolute() {
            dir.to_path_buf()
        } else {
            std::env::current_dir()
                .map_err(|e| Failure::bad_input(format!("no current directory: {e}")))?
                .join(dir)
        };
        let ancestor = absolute
            .ancestors()
            .find(|a| a.symlink_metadata().is_ok())
            .unwrap_or(Path::new("/"));
        if !ancestor.is_dir() {
            return Err(Failure::bad_input(format!(
                "cannot create output directory {}: {} is an existing file",
                show(dir),
                show(ancestor)
            )));
        }
        // One staging directory per output set of this process (two sets may share a
        // directory: `run --out D --telemetry D/t.bin`).
        static SETS: std::sync::atomic::AtomicUsize = std::sync::atomic::AtomicUsize::new(0);
        let set = SETS.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        let staging = ancestor.join(format!(".fpc-sim-staging-{}-{set}", std::process::id()));
        // A stale staging directory of an earlier process with our id is ours to replace.
        let _ = std::fs::remove_dir_all(&staging);
        std::fs::create_dir(&staging).map_err(|e| {
            Failure::bad_input(format!("cannot write output directory {}: {e}", show(dir)))
        })?;
        Ok(OutDir {
            dir: dir.to_path_buf(),
            staging,
            names: names.iter().map(|s| s.to_string()).collect(),
            force,
            inputs: inputs.iter().map(|p| p.to_path_buf()).collect(),
            committed: false,
        })
    }

    /// Where to write `name` now (inside the staging directory).
    pub fn path(&self, name: &str) -> PathBuf {
        self.staging.join(name)
    }

    /// The staging directory, for writers that name their own files inside it.
    pub fn staging_dir(&self) -> &Path {
        &self.staging
    }

    /// Where `name` will be once committed.
    pub fn final_path(&self, name: &str) -> PathBuf {
        self.dir.join(name)
    }

    /// Moves every written file into place (each by an atomic rename) and removes the
    /// staging directory. Refused before anything moves (runtime failure naming the file):
    /// a declared name that was not written, or a file whose name could not be known
    /// beforehand (a per-channel plot) that exists without `--force` or is an input.
    pub fn commit(mut self) -> Result<(), Failure> {
        for name in &self.names {
            if !self.staging.join(name).is_file() {
                return Err(Failure::runtime(format!(
                    "{} was not written; nothing replaced",
                    show(&self.final_path(name))
                )));
            }
        }
        let mut written: Vec<std::ffi::OsString> = std::fs::read_dir(&self.staging)
            .map_err(|e| Failure::runtime(format!("cannot list {}: {e}", show(&self.staging))))?
            .filter_map(|e| e.ok().map(|e| e.file_name()))
            .collect();
        written.sort();
        for name in &written {
            let target = self.dir.join(name);
            if self.names.iter().any(|n| std::ffi::OsStr::new(n) == name) {
                continue;
            }
            if let Some(input) = self.inputs.iter().find(|i| same_file(i, &target)) {
                return Err(Failure::runtime(format!(
                    "{} is an input of this command; nothing replaced",
                    show(input)
                )));
            }
            if is_special(&target) {
                return Err(Failure::runtime(format!(
                    "{} is a device, pipe or socket, not a file; nothing replaced",
                    show(&target)
                )));
            }
            if !self.force && target.symlink_metadata().is_ok() {
                return Err(Failure::runtime(format!(
                    "{} exists; nothing replaced (add --force to replace the outputs)",
                    show(&target)
                )));
            }
        }
        std::fs::create_dir_all(&self.dir).map_err(|e| {
            Failure::runtime(format!(
                "cannot create output directory {}: {e}",
                show(&self.dir)
            ))
        })?;
        for name in &written {
            let (from, to) = (self.staging.join(name), self.dir.join(name));
            std::fs::rename(&from, &to)
                .map_err(|e| Failure::runtime(format!("cannot write {}: {e}", show(&to))))?;
        }
        self.committed = true;
        let _ = std::fs::remove_dir_all(&self.staging);
        Ok(())
    }
}

impl Drop for OutDir {
    fn drop(&mut self) {
        // Not committed: the command failed; the partial set goes.
        let _ = std::fs::remove_dir_all(&self.staging);
    }
}

/// One output file, staged beside its final place until [`OutFile::commit`].
#[derive(Debug)]
pub struct OutFile {
    inner: OutDir,
    name: String,
}

impl OutFile {
    /// Checks that `path` can be written (see [`OutDir::prepare`]; its directory is created).
    pub fn prepare(path: &Path, force: bool, inputs: &[&Path]) -> Result<OutFile, Failure> {
        let name = path
            .file_name()
            .and_then(|n| n.to_str())
            .ok_or_else(|| {
                Failure::bad_input(format!("output file {}: not a file name", show(path)))
            })?
            .to_string();
        let dir = match path.parent() {
            Some(p) if !p.as_os_str().is_empty() => p,
            _ => Path::new("."),
        };
        let inner = OutDir::prepare(dir, &[&name], force, inputs)?;
        Ok(OutFile { inner, name })
    }

    /// Where to write now.
    pub fn path(&self) -> PathBuf {
        self.inner.path(&self.name)
    }

    /// Where the file will be once committed.
    pub fn final_path(&self) -> PathBuf {
        self.inner.final_path(&self.name)
    }

    /// Moves the file into place.
    pub fn commit(self) -> Result<(), Failure> {
        self.inner.commit()
    }
}

/// Whether `path` is there and is neither a file, a directory nor a symbolic link: a device,
/// a pipe or a socket. An output never replaces one — a rename over `/dev/null` by a root
/// user with `--force` would leave a regular file in its place for every other program.
fn is_special(path: &Path) -> bool {
    path.symlink_metadata().is_ok_and(|m| {
        let t = m.file_type();
        !(t.is_file() || t.is_dir() || t.is_symlink())
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A scratch directory, removed with everything in it when the guard drops.
    fn temp(name: &str) -> tempfile::TempDir {
        tempfile::Builder::new()
            .prefix(&format!("fpc-output-{name}-"))
            .tempdir()
            .unwrap()
    }

    #[test]
    fn existing_outputs_need_force_and_inputs_are_never_replaced() {
        let dir = temp("force");
        let d = dir.path();
        std::fs::write(d.join("a.txt"), "old").unwrap();
        let e = OutDir::prepare(d, &["a.txt"], false, &[]).unwrap_err();
        assert_eq!(e.code, 2);
        assert!(e.message.contains("--force"), "{}", e.message);
        let input = d.join("a.txt");
        let e = OutDir::prepare(d, &["a.txt"], true, &[&input]).unwrap_err();
        assert!(e.message.contains("input"), "{}", e.message);
        let o = OutDir::prepare(d, &["a.txt"], true, &[]).unwrap();
        std::fs::write(o.path("a.txt"), "new").unwrap();
        o.commit().unwrap();
        assert_eq!(std::fs::read_to_string(d.join("a.txt")).unwrap(), "new");
        assert_eq!(std::fs::read_dir(d).unwrap().count(), 1, "no staging left");
    }

    #[test]
    fn a_failed_set_leaves_the_old_files() {
        let dir = temp("partial");
        let d = dir.path();
        std::fs::write(d.join("a.txt"), "old a").unwrap();
        let o = OutDir::prepare(d, &["a.txt", "b.txt"], true, &[]).unwrap();
        std::fs::write(o.path("a.txt"), "new a").unwrap();
        // b.txt never written: the commit refuses and nothing is replaced.
        assert_eq!(o.commit().unwrap_err().code, 1);
        assert_eq!(std::fs::read_to_string(d.join("a.txt")).unwrap(), "old a");
        assert!(!d.join("b.txt").exists());
        let o = OutDir::prepare(d, &["a.txt"], true, &[]).unwrap();
        std::fs::write(o.path("a.txt"), "dropped").unwrap();
        drop(o);
        assert_eq!(std::fs::read_to_string(d.join("a.txt")).unwrap(), "old a");
        assert_eq!(std::fs::read_dir(d).unwrap().count(), 1);
    }

    #[test]
    fn a_device_or_pipe_is_never_replaced_even_with_force() {
        let dir = temp("special");
        let d = dir.path();
        let fifo = d.join("pipe");
        let made = std::process::Command::new("mkfifo").arg(&fifo).status();
        if !made.is_ok_and(|s| s.success()) {
            eprintln!("mkfifo is not available here; the pipe case is not checked");
            return;
        }
        for force in [false, true] {
            let e = OutFile::prepare(&fifo, force, &[]).unwrap_err();
            assert_eq!(e.code, 2, "{}", e.message);
            assert!(
                e.message.contains("device, pipe or socket"),
                "{}",
                e.message
            );
        }
        let e = OutDir::prepare(d, &["pipe"], true, &[]).unwrap_err();
        assert_eq!(e.code, 2, "{}", e.message);
        let t = fifo.symlink_metadata().unwrap().file_type();
        assert!(!t.is_file(), "the pipe was replaced by a file");
    }

    #[test]
    fn unwritable_places_are_refused_before_work() {
        let dir = temp("unwritable");
        let d = dir.path();
        std::fs::write(d.join("file"), "x").unwrap();
        assert_eq!(
            OutDir::prepare(&d.join("file"), &["a"], false, &[])
                .unwrap_err()
                .code,
            2
        );
        assert_eq!(
            OutDir::prepare(&d.join("file").join("sub"), &["a"], false, &[])
                .unwrap_err()
                .code,
            2
        );
        let e = OutDir::prepare(Path::new("/"), &["a"], true, &[]).unwrap_err();
        assert!(e.message.contains("root"), "{}", e.message);
        let e = OutFile::prepare(d, false, &[]).unwrap_err();
        assert_eq!(e.code, 2, "{}", e.message);
    }
}
