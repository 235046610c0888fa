//! A sweep killed part-way (a job's wall-time limit, a lost node) leaves its finished rows
//! readable in `results.partial.csv`; `fpc-sim sweep --resume` runs only the other runs and
//! writes the table an uninterrupted sweep writes, byte for byte. The kill is a real
//! `SIGKILL` of the `fpc-sim` process, and a torn last line is added as a kill mid-write
//! would leave it.

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

const PLAN: &str = r#"
cycles = 4
[axes]
pressure_ratio = [2.2, 4.5]
volume_ratio = ["adaptive", "fixed:3.1"]
seed = { from = 1, to = 3 }
"#;

const RUNS: usize = 12;

fn scratch(name: &str) -> PathBuf {
    let dir = PathBuf::from(env!("CARGO_TARGET_TMPDIR"))
        .join("sweep_resumes_where_it_was_cut")
        .join(name);
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).expect("scratch directory");
    dir
}

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
    let dir = scratch("killed");
    let plan = dir.join("plan.toml");
    std::fs::write(&plan, PLAN).expect("plan written");
    let (whole, cut) = (dir.join("whole"), dir.join("cut"));

    let (code, err) = fpc_sim(&["sweep", path(&plan), "--out", path(&whole), "--jobs", "1"]);
    assert_eq!(code, 0, "{err}");

    // One run at a time, killed once some rows are in the journal.
    let journal = cut.join("results.partial.csv");
    let mut child = Command::new(env!("CARGO_BIN_EXE_fpc-sim"))
        .args(["sweep", path(&plan), "--out", path(&cut), "--jobs", "1"])
        .stderr(Stdio::null())
        .spawn()
        .expect("fpc-sim starts");
    let started = Instant::now();
    while journal_rows(&journal) < 3 {
        assert!(
            child.try_wait().expect("child state").is_none(),
            "the sweep finished before it could be killed: make the plan longer"
        );
        assert!(started.elapsed() < Duration::from_secs(120), "no rows came");
        std::thread::sleep(Duration::from_millis(5));
    }
    child.kill().expect("killed");
    child.wait().expect("reaped");
    assert!(
        !cut.join("results.csv").exists(),
        "a killed sweep wrote a table"
    );

    // What was finished is readable as it is (pandas: comment='#').
    let text = std::fs::read_to_string(&journal).expect("journal readable");
    let finished = journal_rows(&journal);
    assert!((3..RUNS).contains(&finished), "{finished} rows");
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
