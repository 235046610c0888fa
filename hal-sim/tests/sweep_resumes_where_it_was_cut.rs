//! A sweep killed part-way (a job's wall-time limit, a lost node) leaves its finished rows
//! readable in `results.partial.csv`; `fpc-sim sweep --resume` runs only the other runs and
//! writes the table an uninterrupted sweep writes, byte for byte. The kill comes at a known
//! row, not when a timer catches it: the `fpc-sim` process aborts right after writing its
//! third row (`FPC_SWEEP_ABORT_AFTER_ROWS`: no unwinding, no flush, as a `SIGKILL` at that
//! instant leaves it), and a torn last line is added as a kill mid-write would leave it.

use std::os::unix::process::ExitStatusExt;
use std::path::Path;
use std::process::{Command, Stdio};

const PLAN: &str = r#"
cycles = 4
[axes]
pressure_ratio = [2.2, 4.5]
volume_ratio = ["adaptive", "fixed:3.1"]
seed = { from = 1, to = 3 }
"#;

const RUNS: usize = 12;

/// Rows written before the kill.
const KILLED_AFTER: usize = 3;

fn fpc_sim(args: &[&str]) -> (i32, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_fpc-sim"))
        .args(args)
        .output()
        .expect("fpc-sim starts");
    (
        out.status.code().unwrap_or(-1),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

fn path(p: &Path) -> &str {
    p.to_str().expect("UTF-8 path")
}

/// Data rows in a journal (lines after the column names).
fn journal_rows(journal: &Path) -> usize {
    std::fs::read_to_string(journal).map_or(0, |t| {
        t.lines().filter(|l| !l.starts_with('#')).skip(1).count()
    })
}

#[test]
fn a_killed_sweep_resumes_without_rerunning_its_finished_runs() {
    let scratch = tempfile::tempdir().expect("scratch directory");
    let dir = scratch.path();
    let plan = dir.join("plan.toml");
    std::fs::write(&plan, PLAN).expect("plan written");
    let (whole, cut) = (dir.join("whole"), dir.join("cut"));

    let (code, err) = fpc_sim(&["sweep", path(&plan), "--out", path(&whole), "--jobs", "1"]);
    assert_eq!(code, 0, "{err}");

    // One run at a time, killed right after its third row is in the journal.
    let journal = cut.join("results.partial.csv");
    let status = Command::new(env!("CARGO_BIN_EXE_fpc-sim"))
        .args(["sweep", path(&plan), "--out", path(&cut), "--jobs", "1"])
        .env("FPC_SWEEP_ABORT_AFTER_ROWS", KILLED_AFTER.to_string())
        .stderr(Stdio::null())
        .status()
        .expect("fpc-sim starts");
    assert!(
        status.signal().is_some(),
        "the sweep was not killed: {status}"
    );
    assert!(
        !cut.join("results.csv").exists(),
        "a killed sweep wrote a table"
    );

    // What was finished is readable as it is (pandas: comment='#').
    let text = std::fs::read_to_string(&journal).expect("journal readable");
    let finished = journal_rows(&journal);
    assert_eq!(finished, KILLED_AFTER, "rows in the journal after the kill");
    assert!(text.contains("# shard = 0/1"), "{text}");
    // A kill in the middle of a write tears the last line.
    std::fs::write(&journal, format!("{text}11,4.5,3,fixed:3.1,0.9")).expect("torn line");

    // Without --resume or --force the rows are not thrown away.
    let (code, err) = fpc_sim(&["sweep", path(&plan), "--out", path(&cut)]);
    assert_eq!(code, 2, "{err}");
    assert!(err.contains("--resume"), "{err}");

    let (code, err) = fpc_sim(&["sweep", path(&plan), "--out", path(&cut), "--resume"]);
    assert_eq!(code, 0, "{err}");
    let said = format!(
        "resuming: {finished} runs finished before, {} to go",
        RUNS - finished
    );
    assert!(err.contains(&said), "expected `{said}` in: {err}");
    assert_eq!(
        std::fs::read(cut.join("results.csv")).expect("resumed table"),
        std::fs::read(whole.join("results.csv")).expect("whole table"),
        "the resumed table differs from the uninterrupted one"
    );
    assert!(!journal.exists(), "the journal outlived the finished sweep");

    // Resuming a finished sweep does nothing; resuming another plan is refused.
    let (code, err) = fpc_sim(&["sweep", path(&plan), "--out", path(&cut), "--resume"]);
    assert_eq!(code, 0, "{err}");
    assert!(err.contains("nothing to resume"), "{err}");
    let other = dir.join("other.toml");
    std::fs::write(&other, PLAN.replace("cycles = 4", "cycles = 5")).expect("plan written");
    let (code, err) = fpc_sim(&["sweep", path(&other), "--out", path(&cut), "--resume"]);
    assert_eq!(code, 2, "{err}");
    assert!(err.contains("nothing to resume"), "{err}");
}
