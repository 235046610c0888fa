//! Every parser of outside input refuses garbage cleanly and never panics (`docs/faults.md` #17–19,
//! the no-panic policy): a bounded, seeded random fuzzer that runs in CI. Each input is a
//! valid document mangled by byte flips, insertions of the format's own tokens and of
//! special numbers, deletions, duplications, truncation and line swaps — or plain random
//! text. Parsers covered here: run logs (`RunLog::parse`), machine-model files
//! (`MachineModel::parse`) and `--fault` specifications (`inject::parse`). The command and
//! telemetry frame decoders have their own 10⁶-input fuzzers next to them
//! (`src/link.rs`, `src/telemetry.rs`).
//!
//! What a parser accepts is checked too, not only counted: every value of an accepted run
//! log finite and within its column's physical range, time increasing uniformly, and the log
//! written and read again the same; every key of an accepted model file within its rule and
//! range, and the file's values re-written by `toml` loading to the same model; every
//! parameter of an accepted `--fault` within its range (whole where it counts), and the
//! specification written out and parsed again the same.
//!
//! 20,000 inputs per parser run by default. 10⁶ per parser are `#[ignore]`
//! (`cargo test --profile slow-tests --test parsers_survive_fuzzing -- --ignored`);
//! CI runs a slice of them (`FPC_FUZZ_INPUTS`, see `.ci/run`).

use hal_sim::faults::inject;
use hal_sim::plant::model::validate::{Rule, Value};
use hal_sim::plant::model::{MachineModel, REFERENCE_TOML};
use hal_sim::runlog::{physical_range, RunLog, MIN_ROWS, REQUIRED};
use rand::{Rng as _, RngCore, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// Seeded ChaCha8 (`rand_chacha`): the same inputs on every machine.
struct Rng(ChaCha8Rng);

impl Rng {
    fn new(seed: u64) -> Self {
        Rng(ChaCha8Rng::seed_from_u64(seed))
    }

    fn next(&mut self) -> u64 {
        self.0.next_u64()
    }

    fn below(&mut self, n: usize) -> usize {
        self.0.random_range(0..n.max(1))
    }
}

/// Tokens every format shares, and numbers that break naive readers.
const TOKENS: [&str; 28] = [
    ",",
    "\n",
    "\r\n",
    "=",
    "[",
    "]",
    "#",
    "\"",
    "@",
    ":",
    ".",
    "-",
    "e",
    "_",
    " ",
    "nan",
    "NaN",
    "inf",
    "-inf",
    "1e309",
    "-0",
    "0",
    "1e-320",
    "18446744073709551616",
    "0x10",
    "é",
    "[effects.cogging]",
    "# x = 1",
];

/// One mangled version of `seed`.
fn mutate(rng: &mut Rng, seed: &str) -> String {
    if rng.below(16) == 0 {
        // Random text.
        let n = rng.below(200);
        let bytes: Vec<u8> = (0..n).map(|_| rng.next() as u8).collect();
        return String::from_utf8_lossy(&bytes).into_owned();
    }
    let mut bytes = seed.as_bytes().to_vec();
    for _ in 0..1 + rng.below(4) {
        let len = bytes.len();
        let at = rng.below(len + 1);
        match rng.below(7) {
            0 if len > 0 => {
                let i = rng.below(len);
                bytes[i] ^= 1 << rng.below(8);
            }
            1 => {
                let t = TOKENS[rng.below(TOKENS.len())];
                bytes.splice(at..at, t.bytes());
            }
            2 if len > 0 => {
                let end = (at + 1 + rng.below(40)).min(len);
                bytes.drain(at.min(end)..end);
            }
            3 if len > 0 => {
                let end = (at + 1 + rng.below(60)).min(len);
                let piece = bytes[at.min(end)..end].to_vec();
                let to = rng.below(len + 1);
                bytes.splice(to..to, piece);
            }
            4 => bytes.truncate(at),
            5 => {
                // Swap two lines.
                let text = String::from_utf8_lossy(&bytes).into_owned();
                let mut lines: Vec<&str> = text.split('\n').collect();
                if lines.len() > 1 {
                    let (a, b) = (rng.below(lines.len()), rng.below(lines.len()));
                    lines.swap(a, b);
                }
                bytes = lines.join("\n").into_bytes();
            }
            _ => {
                // A number replaced by a special one.
                let t = ["nan", "inf", "-1", "0", "1e400", "-0.0", "abc"][rng.below(7)];
                if let Some(p) = bytes.iter().skip(at).position(|b| b.is_ascii_digit()) {
                    let i = at + p;
                    let end = i + bytes[i..]
                        .iter()
                        .position(|b| !(b.is_ascii_digit() || *b == b'.'))
                        .unwrap_or(bytes.len() - i);
                    bytes.splice(i..end, t.bytes());
                }
            }
        }
    }
    String::from_utf8_lossy(&bytes).into_owned()
}

/// What a parser made of one input.
enum Verdict {
    /// Refused.
    Refused,
    /// Accepted, and what it accepted holds up.
    Accepted,
    /// Accepted, but what it accepted does not hold up: why.
    Wrong(String),
}

/// Feeds `n` inputs mangled from `seeds` to `parse`; returns (accepted, refused). Panics on
/// the first accepted input that does not hold up, showing it.
fn fuzz(n: u32, seed: u64, seeds: &[String], parse: impl Fn(&str) -> Verdict) -> (u32, u32) {
    let mut rng = Rng::new(seed);
    let (mut ok, mut refused) = (0, 0);
    for i in 0..n {
        let base = &seeds[rng.below(seeds.len())];
        let input = mutate(&mut rng, base);
        match parse(&input) {
            Verdict::Accepted => ok += 1,
            Verdict::Refused => refused += 1,
            Verdict::Wrong(why) => {
                panic!("input #{i} (seed {seed:#x}) was accepted but {why}:\n{input}")
            }
        }
    }
    (ok, refused)
}

/// An accepted run log: every required column, at least [`MIN_ROWS`] rows, every value finite
/// and within its column's physical range, time increasing by one step (1 %), and the text
/// it writes reads back as the same log.
fn check_run_log(log: &RunLog) -> Result<(), String> {
    for name in REQUIRED {
        if log.column(name).is_none() {
            return Err(format!("it has no `{name}` column"));
        }
    }
    if log.len() < MIN_ROWS {
        return Err(format!("it has {} rows", log.len()));
    }
    for (name, column) in log.names.iter().zip(&log.columns) {
        let (lo, hi) = physical_range(name);
        if let Some(v) = column
            .iter()
            .find(|v| !(v.is_finite() && (lo..=hi).contains(*v)))
        {
            return Err(format!("`{name}` holds {v:e}, outside {lo:e} ..= {hi:e}"));
        }
    }
    let t = log.column("t_s").unwrap_or_default();
    let step = t[1] - t[0];
    if let Some(w) = t
        .windows(2)
        .find(|w| !(w[1] > w[0] && ((w[1] - w[0]) / step - 1.0).abs() <= 0.01))
    {
        return Err(format!(
            "its time goes {} → {} (first step {step:e} s)",
            w[0], w[1]
        ));
    }
    // The data read back the same; how the first reading put the rows on the grid
    // (`resampled`) is a report of that reading, not part of what was written.
    match RunLog::parse(&log.to_csv()) {
        Ok(again)
            if again.meta == log.meta
                && again.names == log.names
                && again.columns == log.columns =>
        {
            Ok(())
        }
        Ok(_) => Err("it reads back as another log".into()),
        Err(e) => Err(format!("what it writes is refused: {e}")),
    }
}

/// An accepted model file: every numeric key within its rule and its range (the sections'
/// own tables, checked here value by value), and the document's values, re-written by
/// `toml` in its own layout, load to the same model.
fn check_model(text: &str, model: &MachineModel) -> Result<(), String> {
    for section in model.sections() {
        let Some(values) = section.values else {
            continue;
        };
        for (spec, value) in section.fields.iter().zip(values) {
            let numbers: Vec<f64> = match value {
                Value::One(x) | Value::Maybe(Some(x)) => vec![x],
                Value::Maybe(None) => vec![],
                Value::Many(xs) => xs.to_vec(),
                Value::Count(n) => vec![f64::from(n)],
            };
            for x in numbers {
                let by_rule = match spec.rule {
                    Rule::Positive => x > 0.0,
                    Rule::NonNegative | Rule::Count => x >= 0.0,
                    Rule::Finite => true,
                    Rule::InUnit(max) => x > 0.0 && x <= max,
                    Rule::Degrees => (0.0..=360.0).contains(&x),
                };
                if !(x.is_finite() && by_rule && (spec.lo..=spec.hi).contains(&x)) {
                    return Err(format!(
                        "`{}.{}` = {x:e} is outside its rule {:?} or its range {:e} ..= {:e}",
                        section.path, spec.name, spec.rule, spec.lo, spec.hi
                    ));
                }
            }
        }
    }
    let table: toml::Table = text
        .parse()
        .map_err(|e| format!("`toml` cannot read what the model parser took: {e}"))?;
    let rewritten = toml::to_string(&table).map_err(|e| format!("`toml` cannot write it: {e}"))?;
    match MachineModel::parse(&rewritten) {
        Ok(again) if again == *model => Ok(()),
        Ok(_) => Err(format!(
            "re-written it loads as another model:\n{rewritten}"
        )),
        Err(e) => Err(format!("re-written it is refused ({e}):\n{rewritten}")),
    }
}

/// An accepted `--fault`: a finite, non-negative time, every parameter of its kind within
/// its range and whole where it counts, and the specification written out (every parameter
/// given: pickers as their words, the others as numbers) parsed again the same.
fn check_fault_spec(spec: &inject::FaultSpec) -> Result<(), String> {
    if !(spec.at_s.is_finite() && spec.at_s >= 0.0) {
        return Err(format!("its time is {}", spec.at_s));
    }
    let allowed = spec.kind.parameters();
    if spec.params.len() != allowed.len() {
        return Err(format!("it has {} parameters", spec.params.len()));
    }
    for ((name, value), (want, _, lo, hi)) in spec.params.iter().zip(allowed) {
        let counts = ["encoder", "channel", "chamber", "section", "cycles", "task"];
        if name != want
            || !(value.is_finite() && (*lo..=*hi).contains(value))
            || (counts.contains(name) && value.fract() != 0.0)
        {
            return Err(format!("`{name}` = {value} (its range {lo} ..= {hi})"));
        }
    }
    let name = inject::FaultKind::ALL
        .iter()
        .find(|(k, _)| *k == spec.kind)
        .map(|(_, n)| *n)
        .unwrap_or_default();
    // Pickers are written as their words, every other parameter as a number.
    let params: Vec<String> = spec
        .params
        .iter()
        .map(|(k, v)| {
            match inject::WORDS
                .iter()
                .find(|(p, _, code)| p == k && code == v)
            {
                Some((_, word, _)) => format!("{k}={word}"),
                None => format!("{k}={v:?}"),
            }
        })
        .collect();
    let text = format!("{name}@{:?}:{}", spec.at_s, params.join(","));
    match inject::parse(&text) {
        Ok(again) if again == *spec => Ok(()),
        Ok(again) => Err(format!("`{text}` parses as {again:?}")),
        Err(e) => Err(format!("`{text}` is refused: {e}")),
    }
}

fn verdict<T>(
    parsed: Result<T, impl std::fmt::Debug>,
    check: impl Fn(&T) -> Result<(), String>,
) -> Verdict {
    match parsed {
        Err(_) => Verdict::Refused,
        Ok(v) => match check(&v) {
            Ok(()) => Verdict::Accepted,
            Err(why) => Verdict::Wrong(why),
        },
    }
}

/// A valid run log: the required columns and the fault column, 100 rows.
fn run_log() -> String {
    let mut s = String::from("# source = fuzz\n# sample_rate_hz = 20000\n");
    s.push_str("t_s,x_m,x_slave_m,theta_rad,f_master_n,f_slave_n,p_a_pa,p_b_pa,fault\n");
    for k in 0..100 {
        s.push_str(&format!("{},0.1,0.1,0,1,-1,1e5,2e5,0\n", k as f64 * 5e-5));
    }
    s
}

/// The minimal model file of `docs/formats.md` §2.
const MINIMAL_MODEL: &str = "[piston]\nmass_kg = 12.0\nbore_m = 0.090\nrod_m = 0.020\n\
travel_m = 0.205\ndead_length_a_m = 0.0005\ndead_length_b_m = 0.0005\n\n[friction]\n\
coulomb_n = 40.0\nviscous_ns_per_m = 25.0\n\n[gas]\ngamma = 1.4\n\
gas_constant_j_per_kg_k = 287.0\ntemperature_k = 293.15\nambient_pa = 101325.0\n\n\
[motor]\npole_pitch_m = 0.012\nslave_follows_master = true\n\n[encoder]\nperiod_m = 0.024\n\
\n[effects.cogging]\namplitude_n = 30.0\nperiod_m = 0.012\n";

fn fault_specs() -> Vec<String> {
    let mut v: Vec<String> = inject::FaultKind::ALL
        .iter()
        .map(|(kind, name)| {
            let params: Vec<String> = kind
                .parameters()
                .iter()
                .map(|(p, default, _, _)| {
                    // Text-valued parameters take their words.
                    let word = match *p {
                        "channel" => Some("cos"),
                        "section" => Some("master"),
                        "chamber" => Some("b"),
                        "task" => Some("supervision"),
                        "encoder" => Some("both"),
                        _ => None,
                    };
                    word.map_or_else(|| format!("{p}={default}"), |w| format!("{p}={w}"))
                })
                .collect();
            format!("{name}@1.25:{}", params.join(","))
        })
        .collect();
    v.push("section_loss@0.5:section=master".into());
    v.push("encoder_amplitude@2:gain=1.5,encoder=both".into());
    v
}

fn run_logs(n: u32) -> (u32, u32) {
    let seeds = [run_log()];
    fuzz(n, 0x5EED_0001, &seeds, |t| {
        verdict(RunLog::parse(t), check_run_log)
    })
}

fn model_files(n: u32) -> (u32, u32) {
    // The minimal file mostly (fast), the full reference file one time in eight.
    let mut seeds = vec![MINIMAL_MODEL.to_string(); 7];
    seeds.push(REFERENCE_TOML.to_string());
    fuzz(n, 0x5EED_0002, &seeds, |t| {
        verdict(MachineModel::parse(t), |m| check_model(t, m))
    })
}

fn fault_spec_texts(n: u32) -> (u32, u32) {
    let seeds = fault_specs();
    fuzz(n, 0x5EED_0003, &seeds, |t| {
        verdict(inject::parse(t), check_fault_spec)
    })
}

#[test]
fn the_seeds_are_valid_and_hold_up() {
    check_run_log(&RunLog::parse(&run_log()).unwrap()).unwrap();
    for text in [MINIMAL_MODEL, REFERENCE_TOML] {
        check_model(text, &MachineModel::parse(text).unwrap()).unwrap();
    }
    for s in fault_specs() {
        check_fault_spec(&inject::parse(&s).unwrap()).unwrap_or_else(|e| panic!("{s}: {e}"));
    }
}

#[test]
fn parsers_refuse_fuzzed_input_without_panic() {
    for (name, f) in [
        ("run log", run_logs as fn(u32) -> (u32, u32)),
        ("model file", model_files),
        ("--fault spec", fault_spec_texts),
    ] {
        let (ok, refused) = f(20_000);
        println!(
            "{name}: 20000 fuzzed inputs, {ok} accepted and each holding up, {refused} refused, \
             no panic"
        );
        assert!(
            refused > 1000 && ok > 0,
            "{name}: the mutations reach both outcomes"
        );
    }
}

/// Inputs per parser of the slow runs: `FPC_FUZZ_INPUTS`, or 10⁶ (CI runs a slice).
fn slow_inputs() -> u32 {
    std::env::var("FPC_FUZZ_INPUTS")
        .ok()
        .and_then(|v| v.trim().parse().ok())
        .unwrap_or(1_000_000)
}

#[test]
#[ignore = "slow: 10⁶ fuzzed run logs (≈ 30 s in release)"]
fn a_million_fuzzed_run_logs_never_panic() {
    let n = slow_inputs();
    let (ok, refused) = run_logs(n);
    println!(
        "run log: {n} fuzzed inputs, {ok} accepted and each holding up, {refused} refused, \
         no panic"
    );
    assert!(
        refused > n / 20 && ok > 0,
        "the mutations reach both outcomes"
    );
}

#[test]
#[ignore = "slow: 10⁶ fuzzed model files (≈ 30 s in release)"]
fn a_million_fuzzed_model_files_never_panic() {
    let n = slow_inputs();
    let (ok, refused) = model_files(n);
    println!(
        "model file: {n} fuzzed inputs, {ok} accepted and each holding up, {refused} refused, \
         no panic"
    );
    assert!(
        refused > n / 20 && ok > 0,
        "the mutations reach both outcomes"
    );
}

#[test]
#[ignore = "slow: 10⁶ fuzzed --fault specifications (≈ 2 s in release)"]
fn a_million_fuzzed_fault_specs_never_panic() {
    let n = slow_inputs();
    let (ok, refused) = fault_spec_texts(n);
    println!(
        "--fault spec: {n} fuzzed inputs, {ok} accepted and each holding up, {refused} refused, \
         no panic"
    );
    assert!(
        refused > n / 20 && ok > 0,
        "the mutations reach both outcomes"
    );
}
