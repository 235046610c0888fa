//! The sweep's journal (`results.partial.csv` in the output directory): every finished row,
//! written and flushed as its run ends, so that a sweep cut short (a killed job, a node
//! lost, a wall-time limit) leaves its finished rows readable, and `--resume` runs only the
//! rest.
//!
//! It is a results table ([`super::write_table`]'s format) with one more line, `# shard =
//! I/N`, and its rows in the order they finished. A last line cut short by the kill is
//! dropped on reading (its run is simply run again); the finished sweep removes the journal
//! once `results.csv` is in place.

use std::collections::BTreeSet;
use std::fs::{File, OpenOptions};
use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::Mutex;

use super::{read_table, Row, Shard};

/// The journal's file name in the output directory.
pub const JOURNAL: &str = "results.partial.csv";

/// Fault injection for the test of a killed sweep (`hal-sim/tests/sweep_resumes_where_it_was_cut.rs`):
/// set to N, the process aborts right after its Nth row is written — no unwinding, no flush,
/// nothing more written, as a `SIGKILL` at that instant leaves it — so the kill comes at a
/// known row instead of wherever a timer catches it. Unset in any real use.
pub const ABORT_AFTER_ROWS_VAR: &str = "FPC_SWEEP_ABORT_AFTER_ROWS";

/// The row count of [`ABORT_AFTER_ROWS_VAR`], read once.
fn abort_after_rows() -> Option<u64> {
    static N: std::sync::OnceLock<Option<u64>> = std::sync::OnceLock::new();
    *N.get_or_init(|| {
        std::env::var(ABORT_AFTER_ROWS_VAR)
            .ok()?
            .trim()
            .parse()
            .ok()
    })
}

/// An open journal: rows are appended by any worker thread.
pub struct Journal {
    path: PathBuf,
    out: Mutex<File>,
    /// The first write error (later rows are not written; the sweep still finishes).
    error: Mutex<Option<String>>,
    /// Rows this process has appended.
    appended: std::sync::atomic::AtomicU64,
}

/// What the journal needs to know about the sweep it belongs to.
#[derive(Clone, Copy, Debug)]
pub struct Identity<'a> {
    /// The plan's fingerprint.
    pub fingerprint: u64,
    /// Runs of the whole plan.
    pub runs: u64,
    /// The slice this sweep runs.
    pub shard: Shard,
    /// The table's columns.
    pub header: &'a [String],
}

fn head(id: &Identity<'_>) -> Result<Vec<u8>, String> {
    let mut bytes = Vec::new();
    super::write_table(&mut bytes, id.fingerprint, id.runs, id.header, &[])?;
    // `# shard` goes with the other `#` lines, before the column names.
    let text = String::from_utf8(bytes).map_err(|e| e.to_string())?;
    let cut = text
        .char_indices()
        .filter(|&(i, c)| c == '\n' && !text[i + 1..].starts_with('#'))
        .map(|(i, _)| i + 1)
        .next()
        .unwrap_or(0);
    let (meta, columns) = text.split_at(cut);
    Ok(format!(
        "{meta}# shard = {}/{}\n{columns}",
        id.shard.index, id.shard.count
    )
    .into_bytes())
}

impl Journal {
    /// Starts a new journal at `path` (replacing any).
    pub fn create(path: &Path, id: &Identity<'_>) -> Result<Journal, String> {
        let fail = |e: std::io::Error| format!("cannot write {}: {e}", path.display());
        let mut f = File::create(path).map_err(fail)?;
        f.write_all(&head(id)?).map_err(fail)?;
        f.sync_data().map_err(fail)?;
        Ok(Journal {
            path: path.to_path_buf(),
            out: Mutex::new(f),
            error: Mutex::new(None),
            appended: 0.into(),
        })
    }

    /// Reopens the journal at `path` of the same sweep `id`: its finished rows (each run
    /// once; a torn last line dropped), and the journal to append the rest to. Refused,
    /// naming the file: another plan, slice or columns, a row of a run outside the slice.
    pub fn resume(path: &Path, id: &Identity<'_>) -> Result<(Vec<Row>, Journal), String> {
        let name = path.display().to_string();
        let fail = |e: std::io::Error| format!("cannot read {name}: {e}");
        let text = std::fs::read_to_string(path).map_err(fail)?;
        // The rows before the last line break are complete (each was written whole).
        let complete = text.rfind('\n').map_or(0, |i| i + 1);
        let text = text.get(..complete).unwrap_or("");
        let table = read_table(text, &name)?;
        if (table.fingerprint, table.runs) != (id.fingerprint, id.runs) {
            return Err(format!(
                "{name} is of plan {:016x} ({} runs), this plan is {:016x} ({} runs): \
                 --resume completes the same plan only (--force starts over)",
                table.fingerprint, table.runs, id.fingerprint, id.runs
            ));
        }
        let shard = text
            .lines()
            .take_while(|l| l.starts_with('#'))
            .find_map(|l| {
                let (k, v) = l.trim_start_matches('#').split_once('=')?;
                (k.trim() == "shard").then(|| Shard::parse(v.trim()).ok())?
            });
        if shard != Some(id.shard) {
            return Err(format!(
                "{name} is not of slice {}/{} (its `# shard` line says {}): --resume \
                 completes the same slice only",
                id.shard.index,
                id.shard.count,
                shard.map_or("nothing".into(), |s| format!("{}/{}", s.index, s.count))
            ));
        }
        if table.header != id.header {
            return Err(format!("{name}: its columns are not this plan's"));
        }
        let mine: BTreeSet<u64> = id.shard.runs(id.runs).collect();
        let mut seen = BTreeSet::new();
        let mut rows = Vec::new();
        for row in table.rows {
            if !mine.contains(&row.run) {
                return Err(format!(
                    "{name}: run {} is not of slice {}/{}",
                    row.run, id.shard.index, id.shard.count
                ));
            }
            if row.cells.len() + 1 != id.header.len() {
                return Err(format!(
                    "{name}: run {} has a row of the wrong width",
                    row.run
                ));
            }
            if seen.insert(row.run) {
                rows.push(row);
            }
        }
        let mut f = OpenOptions::new()
            .write(true)
            .open(path)
            .map_err(|e| format!("cannot write {name}: {e}"))?;
        // Drop the torn line, if any, before appending.
        f.set_len(complete as u64)
            .map_err(|e| format!("cannot write {name}: {e}"))?;
        std::io::Seek::seek(&mut f, std::io::SeekFrom::End(0))
            .map_err(|e| format!("cannot write {name}: {e}"))?;
        Ok((
            rows,
            Journal {
                path: path.to_path_buf(),
                out: Mutex::new(f),
                error: Mutex::new(None),
                appended: 0.into(),
            },
        ))
    }

    /// Appends a finished row (one write of the whole line, so a kill tears at most the
    /// last line).
    pub fn append(&self, row: &Row) {
        let mut w = csv::WriterBuilder::new().from_writer(Vec::new());
        let written = w
            .write_record(std::iter::once(row.run.to_string()).chain(row.cells.iter().cloned()))
            .map_err(|e| e.to_string())
            .and_then(|()| w.into_inner().map_err(|e| e.to_string()));
        let result = written.and_then(|line| {
            let mut f = self
                .out
                .lock()
                .map_err(|_| "a writer panicked".to_string())?;
            f.write_all(&line).map_err(|e| e.to_string())?;
            let n = 1 + self
                .appended
                .fetch_add(1, std::sync::atomic::Ordering::SeqCst);
            if abort_after_rows() == Some(n) {
                std::process::abort();
            }
            Ok(())
        });
        if let Err(e) = result {
            if let Ok(mut first) = self.error.lock() {
                first.get_or_insert(format!("cannot write {}: {e}", self.path.display()));
            }
        }
    }

    /// The first write error, if any.
    pub fn error(&self) -> Option<String> {
        self.error.lock().ok().and_then(|e| e.clone())
    }

    /// Removes the journal (the sweep's table is in place).
    pub fn remove(self) -> Result<(), String> {
        drop(self.out);
        std::fs::remove_file(&self.path)
            .map_err(|e| format!("cannot remove {}: {e}", self.path.display()))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn header() -> Vec<String> {
        ["run", "pressure_ratio", "error"]
            .iter()
            .map(|s| s.to_string())
            .collect()
    }

    #[test]
    fn a_torn_journal_gives_back_its_whole_rows_and_refuses_another_plan() {
        let scratch = tempfile::tempdir().unwrap();
        let dir = scratch.path();
        let path = dir.join(JOURNAL);
        let header = header();
        let shard = Shard { index: 1, count: 2 };
        let id = Identity {
            fingerprint: 0xfeed,
            runs: 6,
            shard,
            header: &header,
        };
        let j = Journal::create(&path, &id).unwrap();
        for run in [3, 1] {
            j.append(&Row {
                run,
                cells: vec![format!("{run}.5"), "a \"quoted\", text".into()],
            });
        }
        drop(j);
        // A kill in the middle of the third row.
        let mut f = OpenOptions::new().append(true).open(&path).unwrap();
        f.write_all(b"5,5.5,a \"quo").unwrap();
        drop(f);
        let (rows, j) = Journal::resume(&path, &id).unwrap();
        assert_eq!(rows.iter().map(|r| r.run).collect::<Vec<_>>(), [3, 1]);
        assert_eq!(rows[0].cells[1], "a \"quoted\", text");
        j.append(&Row {
            run: 5,
            cells: vec!["5.5".into(), String::new()],
        });
        drop(j);
        let (rows, _) = Journal::resume(&path, &id).unwrap();
        assert_eq!(rows.iter().map(|r| r.run).collect::<Vec<_>>(), [3, 1, 5]);

        let other = Identity {
            fingerprint: 0xbeef,
            ..id
        };
        let e = Journal::resume(&path, &other).err().unwrap();
        assert!(e.contains("the same plan only"), "{e}");
        let e = Journal::resume(
            &path,
            &Identity {
                shard: Shard { index: 0, count: 2 },
                ..id
            },
        )
        .err()
        .unwrap();
        assert!(e.contains("says 1/2"), "{e}");
    }
}
