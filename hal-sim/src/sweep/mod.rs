//! Studies at scale: every run of a [`plan::Plan`] in parallel over the cores, one table of
//! results, slices (`--shard I/N`) that other machines run and [`merge`] joins.
//!
//! The table (`results.csv`) holds one row per run: its index, the axes' values and every
//! field of `run`'s JSON summary (`docs/formats.md` §3) except the two wall-clock ones, which
//! differ from machine to machine; so a plan's table is the same bytes however it was
//! sharded, and the merged slices equal the unsharded table byte for byte. Rows are in run
//! order whatever order the threads finished in.

pub mod journal;
pub mod plan;
pub mod report;

use std::collections::BTreeMap;
use std::io::Write;

use rayon::prelude::*;

use crate::run::{run_streamed, Summary};
use plan::{Base, Plan};

/// A slice of a plan: runs `index`, `index + count`, … (`--shard I/N`, `0 ≤ I < N`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Shard {
    /// Which slice, from 0.
    pub index: u64,
    /// How many slices.
    pub count: u64,
}

impl Shard {
    /// The whole plan.
    pub const ALL: Shard = Shard { index: 0, count: 1 };

    /// Parses `I/N` (as a Slurm array's `$SLURM_ARRAY_TASK_ID/N`).
    pub fn parse(text: &str) -> Result<Shard, String> {
        let bad = || {
            format!(
                "--shard {}: must be I/N with 0 ≤ I < N (the I-th of N slices, from 0)",
                crate::output::clip(text, 40)
            )
        };
        let (i, n) = text.split_once('/').ok_or_else(bad)?;
        let index: u64 = i.trim().parse().map_err(|_| bad())?;
        let count: u64 = n.trim().parse().map_err(|_| bad())?;
        if count == 0 || index >= count {
            return Err(bad());
        }
        Ok(Shard { index, count })
    }

    /// This slice's runs of a plan of `total` runs.
    pub fn runs(self, total: u64) -> impl Iterator<Item = u64> {
        (self.index..total).step_by(self.count.max(1) as usize)
    }
}

/// The summary fields of a row, after the axes (`docs/formats.md` §3 less the wall clock, and
/// `controller`, which a plan gives as an axis), and `error` (a run that could not be
/// simulated).
pub const FIELDS: [&str; 40] = [
    "sim_time_s",
    "cycles",
    "cycles_requested",
    "stopped_early",
    "faults_not_injected",
    "pressure_ratio_target",
    "discharge_open_pressure_error",
    "tracking_error_rms_m",
    "indicated_work_j_per_cycle",
    "dead_point_error_m",
    "min_head_clearance_m",
    "peak_speed_mps",
    "master_slave_force_diff_rms_n",
    "faults",
    "state",
    "dead_point_force_diff_n",
    "force_diff_rms_fraction",
    "overshoot_m",
    "travel_m",
    "volume_ratio_reached",
    "pv_pressure_ratio",
    "line_hz",
    "line_m",
    "line_floor_m",
    "rest_line_hz",
    "rest_line_m",
    "rest_line_floor_m",
    "electrical_energy_j_per_cycle",
    "copper_loss_j_per_cycle",
    "bridge_loss_j_per_cycle",
    "servo_energy_j_per_cycle",
    "regenerated_j_per_cycle",
    "fight_loss_j_per_cycle",
    "efficiency",
    "peak_motor_force_n",
    "wide_line_hz",
    "wide_line_m",
    "rest_wide_line_hz",
    "rest_wide_line_m",
    "error",
];

/// One row of the table: the run's index and its cells after it.
#[derive(Clone, Debug, PartialEq)]
pub struct Row {
    /// Run index in the plan.
    pub run: u64,
    /// Axes' values, then [`FIELDS`].
    pub cells: Vec<String>,
}

fn opt(v: Option<f64>) -> String {
    v.map_or_else(String::new, |x| x.to_string())
}

fn summary_cells(s: &Summary) -> Vec<String> {
    vec![
        s.sim_time_s.to_string(),
        s.cycles.to_string(),
        s.cycles_requested.to_string(),
        s.stopped_early.clone().unwrap_or_default(),
        s.faults_not_injected.join(";"),
        s.pressure_ratio_target.to_string(),
        opt(s.discharge_open_pressure_error),
        opt(s.tracking_error_rms_m),
        opt(s.indicated_work_j_per_cycle),
        opt(s.dead_point_error_m),
        opt(s.min_head_clearance_m),
        s.peak_speed_mps.to_string(),
        opt(s.master_slave_force_diff_rms_n),
        s.faults.join(";"),
        s.state.clone(),
        opt(s.dead_point_force_diff_n),
        opt(s.force_diff_rms_fraction),
        opt(s.overshoot_m),
        opt(s.travel_m),
        opt(s.volume_ratio_reached),
        opt(s.pv_pressure_ratio),
        opt(s.line_hz),
        opt(s.line_m),
        opt(s.line_floor_m),
        opt(s.rest_line_hz),
        opt(s.rest_line_m),
        opt(s.rest_line_floor_m),
        opt(s.electrical_energy_j_per_cycle),
        opt(s.copper_loss_j_per_cycle),
        opt(s.bridge_loss_j_per_cycle),
        opt(s.servo_energy_j_per_cycle),
        opt(s.regenerated_j_per_cycle),
        opt(s.fight_loss_j_per_cycle),
        opt(s.efficiency),
        opt(s.peak_motor_force_n),
        opt(s.wide_line_hz),
        opt(s.wide_line_m),
        opt(s.rest_wide_line_hz),
        opt(s.rest_wide_line_m),
        String::new(),
    ]
}

/// The table's column names for `plan`.
pub fn header(plan: &Plan) -> Vec<String> {
    std::iter::once("run".to_string())
        .chain(plan.axes.iter().map(|a| a.name.clone()))
        .chain(FIELDS.iter().map(|f| f.to_string()))
        .collect()
}

/// Checks every run of `shard` as `run` would, in parallel; the first refused (lowest index)
/// is returned.
pub fn check(plan: &Plan, base: &Base, shard: Shard) -> Result<(), String> {
    let runs: Vec<u64> = shard.runs(plan.len()).collect();
    let first_bad = runs
        .par_iter()
        .filter_map(|&k| plan.options(k, base).err().map(|e| (k, e)))
        .min_by_key(|(k, _)| *k);
    match first_bad {
        Some((_, e)) => Err(e),
        None => Ok(()),
    }
}

/// Where a run's log goes, if anywhere (`--keep-logs`).
pub type LogSink<'a> = &'a (dyn Fn(u64) -> Result<Box<dyn Write>, String> + Sync);

/// Runs `f` on every item over rayon's current pool, calling `done` with each result as it
/// comes; the results in the items' order, whatever order the threads finished in. The one
/// runner of every study: [`execute`]'s plans, the safety suite's fault sweep.
pub fn run_each<T: Sync, R: Send>(
    items: &[T],
    f: impl Fn(&T) -> R + Sync,
    done: &(dyn Fn(&R) + Sync),
) -> Vec<R> {
    items
        .par_iter()
        .map(|item| {
            let r = f(item);
            done(&r);
            r
        })
        .collect()
}

/// Runs `runs` of `plan` over rayon's pool (checked first with [`check`]), logging at
/// `log_rate_hz`, calling `done` with each finished row; rows in run order. A run's log is written where `logs` says, or
/// nowhere (the run keeps a bounded copy for nothing else).
pub fn execute(
    plan: &Plan,
    base: &Base,
    runs: &[u64],
    log_rate_hz: u32,
    logs: Option<LogSink<'_>>,
    done: &(dyn Fn(&Row) + Sync),
) -> Vec<Row> {
    let mut rows: Vec<Row> = run_each(
        runs,
        |&k| {
            let mut cells: Vec<String> = plan.point(k).iter().map(|v| v.to_string()).collect();
            let outcome = plan.options(k, base).and_then(|mut opts| {
                opts.log_rate_hz = log_rate_hz;
                opts.validate()?;
                match logs {
                    Some(open) => {
                        let mut out = open(k)?;
                        run_streamed(&opts, &mut out)
                    }
                    None => {
                        // Nothing reads the log: one row per simulated second instead of
                        // formatting 20,000 to throw away (the summary does not come from it).
                        opts.log_rate_hz = 1;
                        run_streamed(&opts, &mut std::io::sink())
                    }
                }
            });
            match outcome {
                Ok(o) => cells.extend(summary_cells(&o.summary)),
                Err(e) => {
                    cells.extend(std::iter::repeat_n(String::new(), FIELDS.len() - 1));
                    cells.push(e);
                }
            }
            Row { run: k, cells }
        },
        done,
    );
    rows.sort_by_key(|r| r.run);
    rows
}

/// Writes the table: the plan's fingerprint and size as `#` lines (pandas reads them with
/// `comment='#'`), the header, the rows.
pub fn write_table(
    out: &mut dyn Write,
    fingerprint: u64,
    runs: u64,
    header: &[String],
    rows: &[Row],
) -> Result<(), String> {
    let fail = |e: &dyn std::fmt::Display| format!("cannot write the results: {e}");
    writeln!(out, "# source = fpc-sim sweep").map_err(|e| fail(&e))?;
    writeln!(out, "# plan = {fingerprint:016x}").map_err(|e| fail(&e))?;
    writeln!(out, "# runs = {runs}").map_err(|e| fail(&e))?;
    let mut w = csv::Writer::from_writer(out);
    w.write_record(header).map_err(|e| fail(&e))?;
    for r in rows {
        w.write_record(std::iter::once(r.run.to_string()).chain(r.cells.iter().cloned()))
            .map_err(|e| fail(&e))?;
    }
    w.flush().map_err(|e| fail(&e))
}

/// A table read back: what [`write_table`] wrote.
#[derive(Clone, Debug, PartialEq)]
pub struct Table {
    /// The plan's fingerprint.
    pub fingerprint: u64,
    /// Runs of the whole plan.
    pub runs: u64,
    /// Column names.
    pub header: Vec<String>,
    /// Rows, in the file's order.
    pub rows: Vec<Row>,
}

impl Table {
    /// Where column `name` is in a row's cells (the cells follow `run`), if the table has it.
    pub fn cell_index(&self, name: &str) -> Option<usize> {
        self.header.iter().position(|h| h == name)?.checked_sub(1)
    }
}

/// Reads a table written by [`write_table`]; `name` is for messages.
pub fn read_table(text: &str, name: &str) -> Result<Table, String> {
    let mut fingerprint = None;
    let mut runs = None;
    let mut body = 0;
    for line in text.split_inclusive('\n') {
        let Some(meta) = line.strip_prefix('#') else {
            break;
        };
        body += line.len();
        if let Some((k, v)) = meta.split_once('=') {
            match k.trim() {
                "plan" => fingerprint = u64::from_str_radix(v.trim(), 16).ok(),
                "runs" => runs = v.trim().parse::<u64>().ok(),
                _ => {}
            }
        }
    }
    let (Some(fingerprint), Some(runs)) = (fingerprint, runs) else {
        return Err(format!(
            "{name}: no `# plan` and `# runs` lines: not a table `fpc-sim sweep` wrote"
        ));
    };
    let mut r = csv::Reader::from_reader(text.get(body..).unwrap_or("").as_bytes());
    let header: Vec<String> = r
        .headers()
        .map_err(|e| format!("{name}: {e}"))?
        .iter()
        .map(str::to_string)
        .collect();
    if header.first().map(String::as_str) != Some("run") {
        return Err(format!("{name}: the first column is not `run`"));
    }
    let mut rows = Vec::new();
    for (i, rec) in r.records().enumerate() {
        let rec = rec.map_err(|e| format!("{name}: {e}"))?;
        let mut cells = rec.iter();
        let run = cells
            .next()
            .and_then(|c| c.parse::<u64>().ok())
            .filter(|k| *k < runs)
            .ok_or_else(|| format!("{name}: data row {}: `run` is not a run of the plan", i + 1))?;
        rows.push(Row {
            run,
            cells: cells.map(str::to_string).collect(),
        });
    }
    Ok(Table {
        fingerprint,
        runs,
        header,
        rows,
    })
}

/// Joins the slices of one plan into its whole table. Refused, naming the files: slices of
/// different plans or columns, a run in two slices, runs in none.
pub fn merge(tables: &[(String, Table)]) -> Result<Table, String> {
    let Some((first_name, first)) = tables.first() else {
        return Err("no tables to merge".into());
    };
    let mut by_run: BTreeMap<u64, (&str, &Row)> = BTreeMap::new();
    for (name, t) in tables {
        if (t.fingerprint, t.runs) != (first.fingerprint, first.runs) {
            return Err(format!(
                "{name} is of plan {:016x} ({} runs), {first_name} of plan {:016x} ({} runs): \
                 slices of one plan only",
                t.fingerprint, t.runs, first.fingerprint, first.runs
            ));
        }
        if t.header != first.header {
            return Err(format!("{name} and {first_name} have different columns"));
        }
        for row in &t.rows {
            if let Some((other, _)) = by_run.insert(row.run, (name, row)) {
                return Err(format!(
                    "run {} is in both {other} and {name}: overlapping slices",
                    row.run
                ));
            }
        }
    }
    let missing: Vec<u64> = (0..first.runs)
        .filter(|k| !by_run.contains_key(k))
        .take(6)
        .collect();
    if !missing.is_empty() {
        let shown: Vec<String> = missing.iter().take(5).map(u64::to_string).collect();
        return Err(format!(
            "{} of {} runs are in no slice (runs {}{}): a slice is missing or unfinished",
            first.runs - by_run.len() as u64,
            first.runs,
            shown.join(", "),
            if missing.len() > 5 { ", …" } else { "" }
        ));
    }
    Ok(Table {
        fingerprint: first.fingerprint,
        runs: first.runs,
        header: first.header.clone(),
        rows: by_run.into_values().map(|(_, r)| r.clone()).collect(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shards_split_the_runs_without_overlap() {
        assert_eq!(Shard::parse("1/3"), Ok(Shard { index: 1, count: 3 }));
        for bad in ["3/3", "1", "a/b", "0/0", "-1/2"] {
            assert!(Shard::parse(bad).is_err(), "{bad}");
        }
        let mut all: Vec<u64> = (0..3)
            .flat_map(|i| Shard { index: i, count: 3 }.runs(10))
            .collect();
        all.sort_unstable();
        assert_eq!(all, (0..10).collect::<Vec<_>>());
    }

    #[test]
    fn merge_refuses_overlaps_gaps_and_other_plans() {
        let table = |fp, rows: &[u64]| Table {
            fingerprint: fp,
            runs: 4,
            header: vec!["run".into(), "x".into()],
            rows: rows
                .iter()
                .map(|&run| Row {
                    run,
                    cells: vec![run.to_string()],
                })
                .collect(),
        };
        let ok = merge(&[
            ("a".into(), table(1, &[0, 2])),
            ("b".into(), table(1, &[3, 1])),
        ])
        .unwrap();
        assert_eq!(
            ok.rows.iter().map(|r| r.run).collect::<Vec<_>>(),
            [0, 1, 2, 3]
        );
        let e = merge(&[
            ("a".into(), table(1, &[0, 2])),
            ("b".into(), table(1, &[2, 1, 3])),
        ])
        .unwrap_err();
        assert!(e.contains("run 2 is in both a and b"), "{e}");
        let e = merge(&[("a".into(), table(1, &[0, 2]))]).unwrap_err();
        assert!(e.contains("2 of 4 runs are in no slice (runs 1, 3)"), "{e}");
        let e = merge(&[
            ("a".into(), table(1, &[0, 2])),
            ("b".into(), table(2, &[1, 3])),
        ])
        .unwrap_err();
        assert!(e.contains("slices of one plan only"), "{e}");
    }

    #[test]
    fn a_table_reads_back_as_written() {
        let rows = vec![Row {
            run: 1,
            cells: vec!["3.1".into(), "a, quoted \"text\"".into(), String::new()],
        }];
        let header: Vec<String> = ["run", "pressure_ratio", "stopped_early", "error"]
            .iter()
            .map(|s| s.to_string())
            .collect();
        let mut bytes = Vec::new();
        write_table(&mut bytes, 0xabc, 2, &header, &rows).unwrap();
        let text = String::from_utf8(bytes).unwrap();
        let t = read_table(&text, "t").unwrap();
        assert_eq!((t.fingerprint, t.runs), (0xabc, 2));
        assert_eq!(t.header, header);
        assert_eq!(t.rows, rows);
        let mut again = Vec::new();
        write_table(&mut again, t.fingerprint, t.runs, &t.header, &t.rows).unwrap();
        assert_eq!(again, text.as_bytes());
        assert!(read_table("run,x\n0,1\n", "t")
            .unwrap_err()
            .contains("no `# plan`"));
    }
}
