//! `fpc-sim sweep` (every run of a plan, in parallel, one table) and `fpc-sim sweep-merge`
//! (the slices of one plan, run anywhere, joined into that table).

use std::io::Read;
use std::path::{Path, PathBuf};
use std::time::Instant;

use clap::Args;

use crate::errln;
use crate::failure::{CmdResult, Failure};
use crate::output::{show, OutDir};
use crate::sweep::journal::{Identity, Journal, JOURNAL};
use crate::sweep::plan::Plan;
use crate::sweep::report::{plots, PLOTS};
use crate::sweep::{check, execute, header, merge, read_table, write_table, Shard, Table};

/// Every run of a plan (the axes' combinations), in parallel over the cores.
#[derive(Args, Debug)]
#[command(after_help = "A plan (TOML) names the axes as lists or ranges:

  cycles = 5
  [axes]
  pressure_ratio = [2.2, 3.1, 4.5]
  speed_mps = { from = 1.0, to = 4.0, steps = 4 }
  seed = { from = 1, to = 10 }
  fault = [\"none\", \"overrun@1.5:cycles=2\"]
  \"model.piston.mass_kg\" = [11.0, 12.0, 13.0]

Every combination is one `fpc-sim run`; results.csv has one row per run: its index, the \
axes, every field of run's JSON summary but the wall-clock ones. While the sweep runs, each \
finished row is written at once to results.partial.csv in --out; if the sweep is cut short, \
those rows are readable there and --resume runs only the rest. On a cluster, run slice I \
of N on each node (--shard I/N, I from 0, e.g. a Slurm array's task id) and join the \
slices' directories with `fpc-sim sweep-merge`: the merged table equals the unsharded one \
byte for byte.")]
pub struct SweepArgs {
    /// The plan (TOML).
    pub plan: PathBuf,
    /// Output directory: results.csv, plan.toml (a copy), work.svg, opening_error.svg,
    /// clearance.svg.
    #[arg(long, default_value = "out/sweep")]
    pub out: PathBuf,
    /// Run only slice I of N (`I/N`, 0 ≤ I < N): runs I, I+N, I+2N, …
    #[arg(long, default_value = "0/1")]
    pub shard: String,
    /// Runs at a time (default: one per core).
    #[arg(long, value_parser = clap::value_parser!(u16).range(1..=1024))]
    pub jobs: Option<u16>,
    /// Also write each run's log (`run-0000042.csv`, as `fpc-sim run` writes it).
    #[arg(long)]
    pub keep_logs: bool,
    /// Rows per simulated second of the kept logs (as `run --log-rate`).
    #[arg(long, default_value_t = crate::run::CONTROL_RATE_HZ, value_name = "HZ")]
    pub log_rate: u32,
    /// Replace the outputs of an earlier sweep in `--out` (and start over, dropping the rows
    /// of an interrupted one).
    #[arg(long, conflicts_with = "resume")]
    pub force: bool,
    /// Complete an interrupted sweep of the same plan and slice in `--out`: the rows in its
    /// results.partial.csv are kept, only the other runs run. On a finished sweep it does
    /// nothing.
    #[arg(long)]
    pub resume: bool,
    /// Print the sweep's figures as one JSON object on stdout.
    #[arg(long)]
    pub json: bool,
}

/// Join the slices (`--shard I/N`) of one plan into its whole table.
#[derive(Args, Debug)]
pub struct MergeArgs {
    /// The slices: their output directories or their results.csv files.
    #[arg(required = true)]
    pub slices: Vec<PathBuf>,
    /// Output directory: results.csv and the plots.
    #[arg(long, default_value = "out/sweep-merge")]
    pub out: PathBuf,
    /// Replace the outputs of an earlier merge in `--out`.
    #[arg(long)]
    pub force: bool,
    /// Print the merged table's figures as one JSON object on stdout.
    #[arg(long)]
    pub json: bool,
}

/// Largest plan or model file read, bytes.
const MAX_PLAN_BYTES: u64 = 1 << 20;

/// Largest results table read, bytes (10⁷ runs of ≈ 300 bytes).
const MAX_TABLE_BYTES: u64 = 4 << 30;

fn read_text(path: &Path, max: u64, what: &str) -> Result<String, Failure> {
    let fail = |m: String| Failure::bad_input(format!("{what} {}: {m}", show(path)));
    let file = std::fs::File::open(path).map_err(|e| fail(e.to_string()))?;
    let mut bytes = Vec::new();
    file.take(max + 1)
        .read_to_end(&mut bytes)
        .map_err(|e| fail(e.to_string()))?;
    if bytes.len() as u64 > max {
        return Err(fail(format!("larger than {max} bytes")));
    }
    String::from_utf8(bytes).map_err(|e| {
        fail(format!(
            "not UTF-8 text (byte {})",
            e.utf8_error().valid_up_to()
        ))
    })
}

/// Runs `fpc-sim sweep`.
pub fn main(args: SweepArgs) -> CmdResult {
    let (text, plan, model_path) = read_plan(&args.plan)?;
    let shard = Shard::parse(&args.shard).map_err(Failure::bad_input)?;
    let rate = crate::run::RunOptions {
        log_rate_hz: args.log_rate,
        ..crate::run::RunOptions::reference()
    };
    rate.validate().map_err(Failure::bad_input)?;
    let base = plan
        .base()
        .map_err(|e| Failure::bad_input(format!("{}: {e}", show(&args.plan))))?;
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(args.jobs.map_or(0, usize::from))
        .build()
        .map_err(|e| Failure::runtime(format!("cannot start the worker threads: {e}")))?;
    // Every run is checked as `run` checks its flags before any runs.
    pool.install(|| check(&plan, &base, shard))
        .map_err(|e| Failure::bad_input(format!("{}: {e}", show(&args.plan))))?;
    let mut names = vec!["results.csv", "plan.toml"];
    names.extend(PLOTS);
    let inputs: Vec<&Path> = std::iter::once(args.plan.as_path())
        .chain(model_path.as_deref())
        .collect();
    let journal_path = args.out.join(JOURNAL);
    let header = header(&plan);
    let id = Identity {
        fingerprint: plan.fingerprint,
        runs: plan.len(),
        shard,
        header: &header,
    };
    let has_journal = journal_path.symlink_metadata().is_ok();
    if has_journal && !args.resume && !args.force {
        return Err(Failure::bad_input(format!(
            "{} holds the rows of an interrupted sweep: add --resume to complete it, or \
             --force to start over",
            show(&journal_path)
        )));
    }
    if args.resume && !has_journal {
        return finished_already(&args.out, &id);
    }
    // A resumed sweep replaces the outputs of its own plan.
    let out = OutDir::prepare(&args.out, &names, args.force || args.resume, &inputs)?;
    if inputs.iter().any(|i| same_path(i, &journal_path)) {
        return Err(Failure::bad_input(format!(
            "{} is an input of this command; choose another output directory",
            show(&journal_path)
        )));
    }
    let (mut rows, journal) = start_journal(&args, &journal_path, &id)?;
    let finished: std::collections::BTreeSet<u64> = rows.iter().map(|r| r.run).collect();
    let todo: Vec<u64> = shard
        .runs(plan.len())
        .filter(|k| !finished.contains(k))
        .collect();
    if args.resume {
        errln!(
            "fpc-sim sweep: resuming: {} runs finished before, {} to go",
            finished.len(),
            todo.len()
        )?;
    }

    let runs = todo.len() as u64;
    let bar = super::analysis::progress(runs, "runs");
    let started = Instant::now();
    let staging = out.staging_dir().to_path_buf();
    let open_log = |k: u64| -> Result<Box<dyn std::io::Write>, String> {
        let path = staging.join(format!("run-{k:07}.csv"));
        let file = std::fs::File::create(&path)
            .map_err(|e| format!("cannot write {}: {e}", show(&path)))?;
        Ok(Box::new(std::io::BufWriter::with_capacity(1 << 20, file)))
    };
    let logs: Option<crate::sweep::LogSink<'_>> = if args.keep_logs {
        Some(&open_log)
    } else {
        None
    };
    let done = |row: &crate::sweep::Row| {
        journal.append(row);
        bar.inc(1);
    };
    let log_rate = args.log_rate;
    rows.extend(pool.install(|| execute(&plan, &base, &todo, log_rate, logs, &done)));
    rows.sort_by_key(|r| r.run);
    bar.finish_and_clear();
    let wall_s = started.elapsed().as_secs_f64();
    if let Some(e) = journal.error() {
        errln!("fpc-sim sweep: warning: {e}: an interruption now would lose those rows")?;
    }

    let table = Table {
        fingerprint: plan.fingerprint,
        runs: plan.len(),
        header,
        rows,
    };
    write_files(&out, &table)?;
    std::fs::write(out.path("plan.toml"), &text)
        .map_err(|e| Failure::runtime(format!("cannot write plan.toml: {e}")))?;
    out.commit()?;
    journal.remove().map_err(Failure::runtime)?;
    let mut figures = report(&table, &args.out)?;
    let threads = pool.current_num_threads();
    print_speed(shard, plan.len(), runs, wall_s, threads)?;
    figures.slice = format!("{}/{}", shard.index, shard.count);
    figures.wall_s = Some(wall_s);
    figures.threads = Some(threads);
    if args.json {
        print_json(&figures)?;
    }
    failed(&table)
}

/// The plan file's text, the plan, and the model file it names (read beside the plan).
fn read_plan(plan_path: &Path) -> Result<(String, Plan, Option<PathBuf>), Failure> {
    let text = read_text(plan_path, MAX_PLAN_BYTES, "plan")?;
    let dir = plan_path.parent().unwrap_or(Path::new("."));
    let mut model_path: Option<PathBuf> = None;
    let plan = Plan::parse(&text, |p| {
        let path = dir.join(p);
        let text = read_text(&path, MAX_PLAN_BYTES, "model").map_err(|f| f.message)?;
        model_path = Some(path.clone());
        Ok((text, path.display().to_string()))
    })
    .map_err(|e| Failure::bad_input(format!("{}: {e}", show(plan_path))))?;
    Ok((text, plan, model_path))
}

/// The journal of the sweep `id` at `path`: resumed with the rows it holds (`--resume`),
/// or started empty in a fresh output directory.
fn start_journal(
    args: &SweepArgs,
    path: &Path,
    id: &Identity<'_>,
) -> Result<(Vec<crate::sweep::Row>, Journal), Failure> {
    Ok(if args.resume {
        Journal::resume(path, id).map_err(Failure::bad_input)?
    } else {
        std::fs::create_dir_all(&args.out)
            .map_err(|e| Failure::bad_input(format!("cannot create {}: {e}", show(&args.out))))?;
        (
            Vec::new(),
            Journal::create(path, id).map_err(Failure::bad_input)?,
        )
    })
}

/// The sweep's speed: `runs` of a plan of `plan_runs` in `wall_s` s on `threads` threads
/// (naming the slice when `shard` is one).
fn print_speed(shard: Shard, plan_runs: u64, runs: u64, wall_s: f64, threads: usize) -> CmdResult {
    let speed = format!(
        "{runs} runs in {wall_s:.1} s on {threads} threads ({:.2} runs/s)",
        runs as f64 / wall_s.max(1e-9)
    );
    if shard.count > 1 {
        errln!(
            "fpc-sim sweep: slice {}/{} of {plan_runs} runs: {speed}",
            shard.index,
            shard.count,
        )?;
    } else {
        errln!("fpc-sim sweep: {speed}")?;
    }
    Ok(())
}

/// What `sweep --json` and `sweep-merge --json` print.
#[derive(Debug, Default, serde::Serialize)]
pub struct SweepFigures {
    /// Rows in the table.
    pub runs: usize,
    /// Runs that stopped before their cycles.
    pub stopped_early: usize,
    /// Runs that could not be simulated.
    pub could_not_run: usize,
    /// The smallest head clearance of any run, m.
    pub smallest_head_clearance_m: Option<f64>,
    /// The run that had it.
    pub smallest_head_clearance_run: Option<u64>,
    /// The table written.
    pub results: String,
    /// The slice run, `I/N` (`0/1`: the whole plan; empty for a merge).
    pub slice: String,
    /// Wall time of the runs, s.
    pub wall_s: Option<f64>,
    /// Worker threads.
    pub threads: Option<usize>,
}

fn print_json(figures: &SweepFigures) -> CmdResult {
    let text =
        serde_json::to_string_pretty(figures).map_err(|e| Failure::runtime(e.to_string()))?;
    crate::outln!("{text}")
}

/// Whether `a` and `b` name the same existing file.
fn same_path(a: &Path, b: &Path) -> bool {
    matches!((a.canonicalize(), b.canonicalize()), (Ok(a), Ok(b)) if a == b)
}

/// `--resume` with no journal: the sweep of this plan and slice finished already (its
/// results.csv is there: nothing to do), or there is nothing to resume.
fn finished_already(dir: &Path, id: &Identity<'_>) -> CmdResult {
    let path = dir.join("results.csv");
    let nothing = || {
        Failure::bad_input(format!(
            "--resume: {} has no {JOURNAL} and no finished results.csv of this plan and \
             slice: nothing to resume (run without --resume)",
            show(dir)
        ))
    };
    let Ok(text) = read_text(&path, MAX_TABLE_BYTES, "table") else {
        return Err(nothing());
    };
    let t = read_table(&text, &show(&path)).map_err(|_| nothing())?;
    let mine: Vec<u64> = id.shard.runs(id.runs).collect();
    let same = t.fingerprint == id.fingerprint
        && t.header == id.header
        && t.rows.iter().map(|r| r.run).eq(mine.iter().copied());
    if !same {
        return Err(nothing());
    }
    errln!(
        "fpc-sim sweep: {} is finished ({} runs of slice {}/{}): nothing to resume",
        show(&path),
        mine.len(),
        id.shard.index,
        id.shard.count
    )
}

/// Runs `fpc-sim sweep-merge`.
pub fn merge_main(args: MergeArgs) -> CmdResult {
    let mut tables = Vec::new();
    let mut inputs = Vec::new();
    for s in &args.slices {
        let path = if s.is_dir() {
            s.join("results.csv")
        } else {
            s.clone()
        };
        let text = read_text(&path, MAX_TABLE_BYTES, "table")?;
        let t = read_table(&text, &show(&path)).map_err(Failure::bad_input)?;
        tables.push((show(&path), t));
        inputs.push(path);
    }
    let table = merge(&tables).map_err(Failure::bad_input)?;
    let mut names = vec!["results.csv"];
    names.extend(PLOTS);
    let input_refs: Vec<&Path> = inputs.iter().map(PathBuf::as_path).collect();
    let out = OutDir::prepare(&args.out, &names, args.force, &input_refs)?;
    write_files(&out, &table)?;
    out.commit()?;
    let figures = report(&table, &args.out)?;
    if args.json {
        print_json(&figures)?;
    }
    failed(&table)
}

/// Writes results.csv and the plots into the staging of `out`.
fn write_files(out: &OutDir, t: &Table) -> CmdResult {
    let path = out.path("results.csv");
    let file = std::fs::File::create(&path)
        .map_err(|e| Failure::runtime(format!("cannot write {}: {e}", show(&path))))?;
    let mut w = std::io::BufWriter::new(file);
    write_table(&mut w, t.fingerprint, t.runs, &t.header, &t.rows).map_err(Failure::runtime)?;
    std::io::Write::flush(&mut w)
        .map_err(|e| Failure::runtime(format!("cannot write {}: {e}", show(&path))))?;
    plots(out.staging_dir(), t).map_err(Failure::runtime)
}

/// One line on what the runs did: how many stopped early or failed, the smallest clearance;
/// the same as figures.
fn report(t: &Table, dir: &Path) -> Result<SweepFigures, Failure> {
    let col = |name: &str| t.cell_index(name);
    fn cell(r: &crate::sweep::Row, i: Option<usize>) -> &str {
        i.and_then(|i| r.cells.get(i)).map_or("", String::as_str)
    }
    let (early, err, clear) = (
        col("stopped_early"),
        col("error"),
        col("min_head_clearance_m"),
    );
    let stopped = t.rows.iter().filter(|r| !cell(r, early).is_empty()).count();
    let failed = t.rows.iter().filter(|r| !cell(r, err).is_empty()).count();
    let worst = t
        .rows
        .iter()
        .filter_map(|r| cell(r, clear).parse::<f64>().ok().map(|c| (c, r.run)))
        .min_by(|a, b| a.0.total_cmp(&b.0));
    let worst_text = worst.map_or_else(
        || "no clearance measured".to_string(),
        |(c, k)| format!("smallest head clearance {:.3} mm (run {k})", c * 1e3),
    );
    let results = dir.join("results.csv");
    errln!(
        "fpc-sim sweep: {} runs: {stopped} stopped early, {failed} could not run; {worst_text}; wrote {}",
        t.rows.len(),
        show(&results)
    )?;
    Ok(SweepFigures {
        runs: t.rows.len(),
        stopped_early: stopped,
        could_not_run: failed,
        smallest_head_clearance_m: worst.map(|w| w.0),
        smallest_head_clearance_run: worst.map(|w| w.1),
        results: results.display().to_string(),
        ..SweepFigures::default()
    })
}

/// Exit 1 when a run could not be simulated (its row says why in `error`).
fn failed(t: &Table) -> CmdResult {
    let i = t.cell_index("error");
    match t.rows.iter().find(|r| {
        i.and_then(|i| r.cells.get(i))
            .is_some_and(|c| !c.is_empty())
    }) {
        Some(r) => Err(Failure::runtime(format!(
            "run {} could not be simulated (see its `error` in results.csv); the files are written",
            r.run
        ))),
        None => Ok(()),
    }
}
