//! Running a command again in the same folder replaces what fpc-sim wrote there, saying so;
//! a file it did not write — or one changed since — is never touched without `--force`.
//! Ctrl-C leaves nothing staged behind, and `run --keep-partial` keeps the log up to the
//! interrupt. The binary is run as a user runs it, in a folder of its own.

use std::path::Path;
use std::process::{Command, Output, Stdio};
use std::time::{Duration, Instant};

const FPC_SIM: &str = env!("CARGO_BIN_EXE_fpc-sim");

fn fpc_sim(dir: &Path, args: &[&str]) -> Output {
    Command::new(FPC_SIM)
        .args(args)
        .current_dir(dir)
        .output()
        .expect("fpc-sim runs")
}

fn text(o: &Output) -> String {
    format!(
        "{}{}",
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    )
}

/// The hidden staging folders left in `dir`.
fn staging_left(dir: &Path) -> Vec<String> {
    std::fs::read_dir(dir)
        .unwrap()
        .flatten()
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .filter(|n| n.starts_with(".fpc-sim-staging"))
        .collect()
}

#[test]
fn run_twice_in_one_folder_replaces_its_own_outputs_and_says_so() {
    let dir = tempfile::tempdir().unwrap();
    let first = fpc_sim(dir.path(), &["run", "--cycles", "1"]);
    assert_eq!(first.status.code(), Some(0), "{}", text(&first));
    let again = fpc_sim(
        dir.path(),
        &["run", "--cycles", "1", "--pressure-ratio", "5.1"],
    );
    assert_eq!(again.status.code(), Some(0), "{}", text(&again));
    assert!(
        text(&again).contains("fpc-sim run: replaced the earlier outputs in out/run (5 files"),
        "{}",
        text(&again)
    );
    assert!(
        std::fs::read_to_string(dir.path().join("out/run/summary.json"))
            .unwrap()
            .contains("\"pressure_ratio_target\": 5.1"),
        "the second run's files are in place"
    );
    assert!(staging_left(dir.path()).is_empty());
}

#[test]
fn a_file_fpc_sim_did_not_write_is_refused_and_left_as_it_was() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out/run");
    std::fs::create_dir_all(&out).unwrap();
    std::fs::write(out.join("run.csv"), "my own notes\n").unwrap();
    let o = fpc_sim(dir.path(), &["run", "--cycles", "1"]);
    assert_eq!(o.status.code(), Some(2), "{}", text(&o));
    assert!(
        text(&o).contains("out/run/run.csv exists and is not an output fpc-sim wrote there"),
        "{}",
        text(&o)
    );
    assert_eq!(
        std::fs::read_to_string(out.join("run.csv")).unwrap(),
        "my own notes\n"
    );
    // fpc-sim's own file, edited by the user since: the user's now.
    let dir = tempfile::tempdir().unwrap();
    assert_eq!(
        fpc_sim(dir.path(), &["run", "--cycles", "1"]).status.code(),
        Some(0)
    );
    let summary = dir.path().join("out/run/summary.json");
    std::fs::write(&summary, "{\"edited\": true}\n").unwrap();
    let o = fpc_sim(dir.path(), &["run", "--cycles", "1"]);
    assert_eq!(o.status.code(), Some(2), "{}", text(&o));
    assert!(text(&o).contains("summary.json exists and is not an output"));
    assert_eq!(
        std::fs::read_to_string(&summary).unwrap(),
        "{\"edited\": true}\n"
    );
    // --force replaces it.
    let o = fpc_sim(dir.path(), &["run", "--cycles", "1", "--force"]);
    assert_eq!(o.status.code(), Some(0), "{}", text(&o));
    assert!(std::fs::read_to_string(&summary)
        .unwrap()
        .contains("sim_time_s"));
}

/// Starts a long run in `dir`, sends it Ctrl-C once it has simulated a while, and returns
/// how it ended.
fn interrupted_run(dir: &Path, extra: &[&str]) -> Output {
    let mut args = vec!["run", "--cycles", "10000"];
    args.extend(extra);
    let child = Command::new(FPC_SIM)
        .args(&args)
        .current_dir(dir)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    // Its staging folder exists from the start (the outputs are checked before any work).
    let started = Instant::now();
    while staging_left(dir).is_empty() && started.elapsed() < Duration::from_secs(30) {
        std::thread::sleep(Duration::from_millis(20));
    }
    std::thread::sleep(Duration::from_millis(1500));
    let kill = Command::new("kill")
        .args(["-INT", &child.id().to_string()])
        .status()
        .unwrap();
    assert!(kill.success());
    child.wait_with_output().unwrap()
}

#[test]
fn ctrl_c_leaves_no_staging_behind() {
    let dir = tempfile::tempdir().unwrap();
    let o = interrupted_run(dir.path(), &[]);
    assert_eq!(o.status.code(), Some(130), "{}", text(&o));
    assert!(
        staging_left(dir.path()).is_empty(),
        "{:?}",
        staging_left(dir.path())
    );
    assert!(
        !dir.path().join("out").exists(),
        "an interrupted run wrote nothing"
    );
}

#[test]
fn run_keep_partial_keeps_the_log_up_to_the_interrupt() {
    let dir = tempfile::tempdir().unwrap();
    let o = interrupted_run(dir.path(), &["--keep-partial"]);
    assert_eq!(o.status.code(), Some(130), "{}", text(&o));
    assert!(text(&o).contains("interrupted (Ctrl-C)"), "{}", text(&o));
    assert!(staging_left(dir.path()).is_empty());
    let log = hal_sim::runlog::RunLog::read(&dir.path().join("out/run/run.csv"))
        .expect("the log up to the interrupt reads");
    assert!(log.len() > 1000, "{} rows", log.len());
    let summary = std::fs::read_to_string(dir.path().join("out/run/summary.json")).unwrap();
    assert!(
        summary.contains("interrupted (Ctrl-C) at"),
        "the summary says why it stopped: {summary}"
    );
}
