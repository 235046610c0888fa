//! `fpc-sim sweep` runs every combination of a plan's axes; three slices of it (`--shard
//! I/3`, as three nodes of a cluster would run them) joined by `fpc-sim sweep-merge` give the
//! unsharded table byte for byte, and every row is what `fpc-sim run` reports for the same
//! flags. A plan with a value `run` refuses is refused whole, before anything runs.

use std::path::Path;

use hal_sim::cli::execute;
use hal_sim::run::{run, RunOptions};
use hal_sim::sweep::read_table;

/// A scratch directory of its own (tests run concurrently, from several checkouts), removed
/// when the test ends, pass or fail.
fn scratch(prefix: &str) -> tempfile::TempDir {
    tempfile::Builder::new()
        .prefix(&format!("fpc-{prefix}-"))
        .tempdir()
        .expect("scratch directory")
}

fn fpc_sim(args: &[&str]) -> u8 {
    execute(std::iter::once("fpc-sim").chain(args.iter().copied()))
}

fn path(p: &Path) -> &str {
    p.to_str().expect("UTF-8 path")
}

const PLAN: &str = r#"
cycles = 1
[axes]
pressure_ratio = [2.2, 4.5]
speed_mps = { from = 2.0, to = 4.0, steps = 2 }
seed = { from = 3, to = 4 }
fault = ["none", "pressure_open@0.95:chamber=b"]
"#;

#[test]
fn three_slices_merge_to_the_unsharded_table_byte_for_byte() {
    let dir = scratch("slices");
    let dir = dir.path();
    let plan = dir.join("plan.toml");
    std::fs::write(&plan, PLAN).expect("plan written");
    let whole = dir.join("whole");
    assert_eq!(
        fpc_sim(&["sweep", path(&plan), "--out", path(&whole), "--jobs", "2"]),
        0
    );
    let mut slices = Vec::new();
    for i in 0..3 {
        let out = dir.join(format!("slice{i}"));
        let shard = format!("{i}/3");
        assert_eq!(
            fpc_sim(&["sweep", path(&plan), "--out", path(&out), "--shard", &shard]),
            0
        );
        slices.push(out);
    }
    let merged = dir.join("merged");
    let mut args = vec!["sweep-merge"];
    args.extend(slices.iter().map(|s| path(s)));
    args.extend(["--out", path(&merged)]);
    assert_eq!(fpc_sim(&args), 0);
    let a = std::fs::read(whole.join("results.csv")).expect("whole table");
    let b = std::fs::read(merged.join("results.csv")).expect("merged table");
    assert_eq!(a, b, "the merged slices differ from the unsharded table");
    for plot in ["work.svg", "opening_error.svg", "clearance.svg"] {
        assert!(merged.join(plot).is_file(), "{plot}");
    }

    // 2 × 2 × 2 × 2 runs, in run order, each as `run` reports it.
    let text = String::from_utf8(a).expect("UTF-8");
    let t = read_table(&text, "whole").expect("the table reads back");
    assert_eq!(t.runs, 16);
    assert_eq!(t.rows.len(), 16);
    let col = |name: &str| {
        t.header
            .iter()
            .position(|h| h == name)
            .and_then(|i| i.checked_sub(1))
            .expect(name)
    };
    // Run 13 = digits (1, 1, 0, 1) of (fault, pressure_ratio, seed, speed_mps).
    let row = &t.rows[13];
    assert_eq!(row.run, 13);
    assert_eq!(row.cells[col("fault")], "pressure_open@0.95:chamber=b");
    assert_eq!(row.cells[col("pressure_ratio")], "4.5");
    assert_eq!(row.cells[col("seed")], "3");
    assert_eq!(row.cells[col("speed_mps")], "4");
    let alone = run(&RunOptions {
        cycles: 1,
        pressure_ratio: 4.5,
        speed_mps: Some(4.0),
        seed: 3,
        faults: vec![hal_sim::faults::inject::parse("pressure_open@0.95:chamber=b").expect("spec")],
        ..RunOptions::reference()
    })
    .expect("the same run alone")
    .summary;
    assert_eq!(
        row.cells[col("min_head_clearance_m")],
        alone
            .min_head_clearance_m
            .map(|c| c.to_string())
            .unwrap_or_default()
    );
    assert_eq!(row.cells[col("faults")], alone.faults.join(";"));
    assert_eq!(row.cells[col("state")], alone.state);
    assert!(!alone.faults.is_empty(), "the injected fault latched");

    // A slice missing: refused, naming the runs, nothing written.
    let partial = dir.join("partial");
    assert_eq!(
        fpc_sim(&[
            "sweep-merge",
            path(&slices[0]),
            path(&slices[2]),
            "--out",
            path(&partial)
        ]),
        2
    );
    assert!(!partial.exists());
}

#[test]
fn a_plan_with_a_run_that_run_refuses_is_refused_before_anything_runs() {
    let dir = scratch("refused");
    let dir = dir.path();
    for (name, plan) in [
        ("ratio", "[axes]\npressure_ratio = [3.1, 9.0]\n"),
        ("mass", "[axes]\n\"model.piston.mass_kg\" = [12.0, -3.0]\n"),
        ("fault", "[axes]\nfault = [\"overheat@1\"]\n"),
        ("axis", "[axes]\nspeeds = [1.0]\n"),
        ("empty", "[axes]\npressure_ratio = []\n"),
        (
            "mode",
            "[axes]\nvolume_ratio = [\"adaptive\", \"fixed:0.5\"]\n",
        ),
        ("rate", "cycles = 1\n[axes]\nseed = [1]\n"),
        ("toml", "[axes\n"),
    ] {
        let file = dir.join(format!("{name}.toml"));
        std::fs::write(&file, plan).expect("plan written");
        let out = dir.join(name);
        // The last plan is good: its `--log-rate` is not.
        let rate = if name == "rate" { "3000" } else { "20000" };
        assert_eq!(
            fpc_sim(&[
                "sweep",
                path(&file),
                "--out",
                path(&out),
                "--log-rate",
                rate
            ]),
            2,
            "{name}"
        );
        assert!(!out.exists(), "{name}: nothing written");
    }
    let file = dir.join("ok.toml");
    std::fs::write(&file, "cycles = 1\n[axes]\nseed = [1]\n").expect("plan written");
    for bad in ["3/3", "1", "x/2"] {
        let out = dir.join("shard");
        assert_eq!(
            fpc_sim(&["sweep", path(&file), "--out", path(&out), "--shard", bad]),
            2,
            "{bad}"
        );
        assert!(!out.exists());
    }
}

#[test]
fn keep_logs_writes_each_runs_log_as_run_writes_it() {
    let dir = scratch("logs");
    let dir = dir.path();
    let plan = dir.join("plan.toml");
    std::fs::write(&plan, "cycles = 1\n[axes]\nseed = { from = 5, to = 6 }\n").expect("plan");
    let out = dir.join("out");
    assert_eq!(
        fpc_sim(&["sweep", path(&plan), "--out", path(&out), "--keep-logs"]),
        0
    );
    for (k, seed) in [(0, 5), (1, 6)] {
        let text = std::fs::read_to_string(out.join(format!("run-{k:07}.csv"))).expect("run log");
        let log = hal_sim::runlog::RunLog::parse(&text).expect("the log reads back");
        assert_eq!(log.meta("seed"), Some(seed.to_string().as_str()));
        assert_eq!(log.meta("ports"), Some("open"));
        let mut alone = Vec::new();
        hal_sim::run::run_streamed(
            &RunOptions {
                cycles: 1,
                seed,
                ..RunOptions::reference()
            },
            &mut alone,
        )
        .expect("the same run alone");
        assert_eq!(text.as_bytes(), alone.as_slice(), "run {k}");
    }
}
