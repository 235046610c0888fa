//! Where `fpc-sim` writes, made safe: every output is checked before any work (exit 2 when it
//! cannot be written, is one of the command's own inputs, or exists and is not fpc-sim's to
//! replace), written into a staging directory beside its final place, and moved into place
//! only once the whole set is complete. A failure part-way leaves the earlier files as they
//! were and no partial new ones (`docs/faults.md` row 23); Ctrl-C removes the staging
//! directory ([`crate::interrupt`]).
//!
//! **Reruns.** Every directory fpc-sim writes into keeps a manifest ([`MANIFEST`]): each file
//! it wrote there, with the command, its size and its modification time. A file the
//! manifest lists, unchanged since, is fpc-sim's own: a rerun replaces it without asking,
//! says so in one line, and removes the files of the same output set that this run no longer
//! writes (a per-channel plot of an earlier `gap`). Any other existing file of an output's
//! name — one the user made, or fpc-sim's but edited since — is refused unless `--force`.
//! `--force` replaces existing outputs of the same names; it never replaces an input, and it
//! leaves every other file in the directory alone.
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::Mutex;
use std::time::UNIX_EPOCH;

use crate::failure::Failure;

/// The manifest of a directory fpc-sim writes into: which files it wrote there.
pub const MANIFEST: &str = ".fpc-sim-manifest.json";

/// The command writing now, for the manifest and the rerun line (set by the tool's
/// dispatch; `fpc-sim` when unset).
static COMMAND: Mutex<String> = Mutex::new(String::new());

/// Names the command that writes from now on (`run`, `gap`, `link capture`, …).
pub fn set_command(name: &str) {
    if let Ok(mut c) = COMMAND.lock() {
        *c = name.to_string();
    }
}

/// The command running now (`fpc-sim` when unset), for its lines on stderr.
pub fn command() -> String {
    match COMMAND.lock() {
        Ok(c) if !c.is_empty() => c.clone(),
        _ => "fpc-sim".to_string(),
    }
}

/// One file of a manifest.
#[derive(Clone, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
struct Written {
    /// The command that wrote it.
    command: String,
    /// The output set it belongs to: the names its command declared (a set's stale files
    /// are removed only by a rerun of the same set).
    set: String,
    /// Its size, bytes, when written.
    bytes: u64,
    /// Its modification time when written, ns since the Unix epoch.
    modified_ns: u64,
}

/// A directory's manifest: file name → what fpc-sim wrote there.
#[derive(Clone, Debug, Default, serde::Serialize, serde::Deserialize)]
struct Manifest {
    files: BTreeMap<String, Written>,
}

/// Size and modification time of a file (`None`: not a file, or unreadable).
fn stamp(path: &Path) -> Option<(u64, u64)> {
    let m = path.symlink_metadata().ok()?;
    if !m.file_type().is_file() {
        return None;
    }
    let ns = m
        .modified()
        .ok()?
        .duration_since(UNIX_EPOCH)
        .ok()?
        .as_nanos();
    Some((m.len(), u64::try_from(ns).ok()?))
}

impl Manifest {
    /// The manifest of `dir`; none, or one that does not parse, lists nothing (nothing there
    /// is then fpc-sim's to replace without `--force`).
    fn read(dir: &Path) -> Manifest {
        std::fs::read_to_string(dir.join(MANIFEST))
            .ok()
            .and_then(|t| serde_json::from_str(&t).ok())
            .unwrap_or_default()
    }

    /// Whether `name` in `dir` is a file fpc-sim wrote and nobody changed since.
    fn owns(&self, dir: &Path, name: &str) -> bool {
        self.files.get(name).is_some_and(|w| {
            stamp(&dir.join(name))
                .is_some_and(|(bytes, ns)| bytes == w.bytes && ns == w.modified_ns)
        })
    }

    fn write(&self, dir: &Path) -> std::io::Result<()> {
        let text = serde_json::to_string_pretty(self).map_err(std::io::Error::other)?;
        let tmp = dir.join(format!("{MANIFEST}.{}", std::process::id()));
        std::fs::write(&tmp, text + "\n")?;
        std::fs::rename(&tmp, dir.join(MANIFEST))
    }
}

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
    /// What fpc-sim wrote in `dir` before this set.
    manifest: Manifest,
    /// Whether this set is recorded in `dir`'s manifest (a single file written into a
    /// folder fpc-sim does not keep is not: no manifest is left among the user's files).
    record: bool,
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
        let manifest = Manifest::read(dir);
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
            if !force && target.symlink_metadata().is_ok() && !manifest.owns(dir, name) {
                return Err(Failure::bad_input(not_ours(&target)));
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
        crate::interrupt::register(&staging);
        Ok(OutDir {
            dir: dir.to_path_buf(),
            staging,
            names: names.iter().map(|s| s.to_string()).collect(),
            force,
            inputs: inputs.iter().map(|p| p.to_path_buf()).collect(),
            committed: false,
            manifest,
            record: true,
        })
    }

    /// Keeps only `names` of the declared outputs (an interrupted `run --keep-partial`
    /// keeps its log and nothing it could not finish); files written under other names are
    /// removed from the set.
    pub fn keep_only(&mut self, names: &[&str]) {
        self.names.retain(|n| names.contains(&n.as_str()));
        if let Ok(entries) = std::fs::read_dir(&self.staging) {
            for e in entries.flatten() {
                let name = e.file_name();
                if !names.iter().any(|n| std::ffi::OsStr::new(n) == name) {
                    let _ = std::fs::remove_file(e.path());
                }
            }
        }
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
            let name = name.to_string_lossy();
            if !self.force
                && target.symlink_metadata().is_ok()
                && !self.manifest.owns(&self.dir, &name)
            {
                return Err(Failure::runtime(format!(
                    "{}; nothing replaced",
                    not_ours(&target)
                )));
            }
        }
        std::fs::create_dir_all(&self.dir).map_err(|e| {
            Failure::runtime(format!(
                "cannot create output directory {}: {e}",
                show(&self.dir)
            ))
        })?;
        let replaced = written
            .iter()
            .filter(|n| self.dir.join(n).symlink_metadata().is_ok())
            .count();
        for name in &written {
            let (from, to) = (self.staging.join(name), self.dir.join(name));
            std::fs::rename(&from, &to)
                .map_err(|e| Failure::runtime(format!("cannot write {}: {e}", show(&to))))?;
        }
        self.committed = true;
        let _ = std::fs::remove_dir_all(&self.staging);
        crate::interrupt::unregister(&self.staging);
        let written: Vec<String> = written
            .iter()
            .map(|n| n.to_string_lossy().into_owned())
            .collect();
        let stale = if self.record {
            self.record_written(&written)?
        } else {
            0
        };
        if replaced + stale > 0 {
            crate::errln!(
                "fpc-sim {}: replaced the earlier outputs in {} ({replaced} file{} rewritten{})",
                command(),
                show(&self.dir),
                if replaced == 1 { "" } else { "s" },
                match stale {
                    0 => String::new(),
                    n => format!(", {n} no longer written removed"),
                }
            )?;
        }
        Ok(())
    }

    /// The set's key in the manifest: its declared names.
    fn set_key(&self) -> String {
        let mut names = self.names.clone();
        names.sort();
        names.join(",")
    }

    /// Records the files just moved into place in the directory's manifest, and removes
    /// the files an earlier run of the same set wrote that this one did not (when nobody
    /// changed them since). Returns how many it removed.
    fn record_written(&self, written: &[String]) -> Result<usize, Failure> {
        // Read again: another set of this command (`run --telemetry` into the same folder)
        // may have committed since this one was prepared.
        let mut manifest = Manifest::read(&self.dir);
        let (command, set) = (command(), self.set_key());
        let mut removed = 0;
        let stale: Vec<String> = manifest
            .files
            .iter()
            .filter(|(n, w)| w.command == command && w.set == set && !written.contains(n))
            .map(|(n, _)| n.clone())
            .collect();
        for name in stale {
            if self.manifest.owns(&self.dir, &name)
                && std::fs::remove_file(self.dir.join(&name)).is_ok()
            {
                removed += 1;
            }
            manifest.files.remove(&name);
        }
        for name in written {
            if let Some((bytes, modified_ns)) = stamp(&self.dir.join(name)) {
                manifest.files.insert(
                    name.clone(),
                    Written {
                        command: command.clone(),
                        set: set.clone(),
                        bytes,
                        modified_ns,
                    },
                );
            }
        }
        manifest.write(&self.dir).map_err(|e| {
            Failure::runtime(format!(
                "cannot write {}: {e}",
                show(&self.dir.join(MANIFEST))
            ))
        })?;
        Ok(removed)
    }
}

/// Checks, before any work, that `path` may be written: it does not exist, it is a file
/// fpc-sim wrote there and nobody changed since, or `force` is given. For an output a
/// command writes only sometimes (the run log of a capture), outside its declared set.
pub fn check_replaceable(path: &Path, force: bool) -> Result<(), Failure> {
    let (dir, name) = match (path.parent(), path.file_name()) {
        (Some(d), Some(n)) => (d, n.to_string_lossy()),
        _ => return Ok(()),
    };
    if force || path.symlink_metadata().is_err() || Manifest::read(dir).owns(dir, &name) {
        Ok(())
    } else {
        Err(Failure::bad_input(not_ours(path)))
    }
}

/// The refusal of an existing file that is not fpc-sim's to replace.
fn not_ours(target: &Path) -> String {
    format!(
        "{} exists and is not an output fpc-sim wrote there (or it changed since); refusing \
         to overwrite it (add --force to replace it)",
        show(target)
    )
}

impl Drop for OutDir {
    fn drop(&mut self) {
        // Not committed: the command failed; the partial set goes.
        let _ = std::fs::remove_dir_all(&self.staging);
        crate::interrupt::unregister(&self.staging);
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
        // A folder fpc-sim keeps (it has a manifest, or this write creates it) records the
        // file; in any other folder the file is the user's from the moment it is written.
        let record = !dir.exists() || dir.join(MANIFEST).is_file();
        let mut inner = OutDir::prepare(dir, &[&name], force, inputs)?;
        inner.record = record;
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
        let left: Vec<_> = std::fs::read_dir(d)
            .unwrap()
            .flatten()
            .map(|e| e.file_name())
            .collect();
        assert_eq!(left.len(), 2, "no staging left: {left:?}");
        assert!(left.contains(&MANIFEST.into()), "{left:?}");
    }

    /// Writes `files` (name, text) as one committed set of `names` into `d`.
    fn write_set(d: &Path, names: &[&str], files: &[(&str, &str)]) -> Result<(), Failure> {
        let o = OutDir::prepare(d, names, false, &[])?;
        for (name, text) in files {
            std::fs::write(o.path(name), text).unwrap();
        }
        o.commit()
    }

    #[test]
    fn a_rerun_replaces_fpc_sims_own_files_and_drops_what_it_no_longer_writes() {
        let dir = temp("rerun");
        let d = dir.path();
        write_set(d, &["a.txt"], &[("a.txt", "1"), ("map_x.svg", "x")]).unwrap();
        // Another set in the same folder (run's telemetry file beside its outputs).
        write_set(d, &["t.bin"], &[("t.bin", "t")]).unwrap();
        write_set(d, &["a.txt"], &[("a.txt", "2"), ("map_y.svg", "y")]).unwrap();
        assert_eq!(std::fs::read_to_string(d.join("a.txt")).unwrap(), "2");
        assert!(
            !d.join("map_x.svg").exists(),
            "the earlier run's own plot stays"
        );
        assert!(d.join("map_y.svg").exists() && d.join("t.bin").exists());
        // A file the user made, of an output's name: refused, before and at the commit.
        std::fs::write(d.join("notes.svg"), "mine").unwrap();
        let e = write_set(d, &["a.txt"], &[("a.txt", "3"), ("notes.svg", "n")]).unwrap_err();
        assert!(
            e.message.contains("not an output fpc-sim wrote"),
            "{}",
            e.message
        );
        assert_eq!(
            std::fs::read_to_string(d.join("notes.svg")).unwrap(),
            "mine"
        );
        // fpc-sim's file edited since is the user's now.
        std::fs::write(d.join("a.txt"), "edited by hand").unwrap();
        let e = OutDir::prepare(d, &["a.txt"], false, &[]).unwrap_err();
        assert_eq!(e.code, 2);
        assert!(e.message.contains("--force"), "{}", e.message);
        assert_eq!(
            std::fs::read_to_string(d.join("a.txt")).unwrap(),
            "edited by hand"
        );
    }

    #[test]
    fn a_single_file_in_a_folder_fpc_sim_does_not_keep_leaves_no_manifest() {
        let dir = temp("single");
        let d = dir.path();
        std::fs::write(d.join("mine.txt"), "x").unwrap();
        let f = OutFile::prepare(&d.join("dec.csv"), false, &[]).unwrap();
        std::fs::write(f.path(), "1").unwrap();
        f.commit().unwrap();
        assert!(!d.join(MANIFEST).exists());
        // So writing it again needs --force.
        assert_eq!(
            OutFile::prepare(&d.join("dec.csv"), false, &[])
                .unwrap_err()
                .code,
            2
        );
        // In a folder it creates, it keeps one.
        let f = OutFile::prepare(&d.join("new/dec.csv"), false, &[]).unwrap();
        std::fs::write(f.path(), "1").unwrap();
        f.commit().unwrap();
        assert!(d.join("new").join(MANIFEST).is_file());
        assert!(OutFile::prepare(&d.join("new/dec.csv"), false, &[]).is_ok());
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
