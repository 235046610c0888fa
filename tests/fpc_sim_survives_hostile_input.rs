//! `fpc-sim` under hostile input (`docs/faults.md` row 23): every subcommand driven in-process
//! with generated hostile logs, models, captures and flags. Each case must end with exit 2
//! and an error naming the cause, or exit 0 having done its work without one (a hostile
//! draw can be valid input); exit 1 only where a replayed recording, standing for the board,
//! answers nothing usable — never a panic, an abort or a hang — within a wall-time bound,
//! leave its inputs and any earlier outputs untouched (no `--force`), and leave nothing
//! behind when it fails.
//!
//! The default run is a few dozen cases per subcommand; the slow suite runs 10⁴ per
//! subcommand (`cargo test --profile slow-tests --test fpc_sim_survives_hostile_input --
//! --ignored`). Set `FPC_HOSTILE_CASES` to choose another count.

use std::collections::BTreeMap;
use std::ffi::OsString;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use rand::seq::IndexedRandom;
use rand::{Rng, RngCore, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// A valid 400-row run log with closed ports (written by hand, not by the simulator).
const BASE_LOG: &str = include_str!("data/hand_stroke.csv");
/// The reference machine's model file.
const BASE_MODEL: &str = include_str!("../hal-sim/src/plant/model/reference.toml");
/// A calibration file as `fpc-sim calibrate` writes it for the reference machine.
const BASE_CALIBRATION: &str = include_str!("data/calibration.toml");

/// Longest a case may take: a hang detector, not a speed target (debug build, loaded CI).
const CASE_LIMIT: Duration = Duration::from_secs(60);

const SUBCOMMANDS: [&str; 13] = [
    "run",
    "calibrate",
    "derive",
    "decode",
    "lag",
    "filters",
    "forces",
    "energy",
    "pv",
    "gap",
    "sweep",
    "sweep-merge",
    "link",
];

/// Values that break parsers and arithmetic.
const HOSTILE_NUMBERS: [&str; 22] = [
    "1e20",
    "-1e20",
    "1e300",
    "-1e300",
    "1e-300",
    "0",
    "-0",
    "-1",
    "nan",
    "NaN",
    "inf",
    "-inf",
    "1e308",
    "4.9e-324",
    "",
    " ",
    "abc",
    "0x10",
    "1,5",
    "99999999999999999999999",
    "1e-12",
    "1e6",
];

/// One case: the arguments and the files it reads and must not touch.
struct Case {
    args: Vec<OsString>,
    dir: PathBuf,
}

/// Every file under `dir` with its bytes (directories as a marker).
fn snapshot(dir: &Path) -> BTreeMap<PathBuf, Vec<u8>> {
    let mut files = BTreeMap::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        let Ok(entries) = std::fs::read_dir(&d) else {
            continue;
        };
        for e in entries.flatten() {
            let p = e.path();
            if p.is_dir() {
                files.insert(p.clone(), b"<directory>".to_vec());
                stack.push(p);
            } else if let Ok(bytes) = std::fs::read(&p) {
                files.insert(p, bytes);
            }
        }
    }
    files
}

/// A simulated run of one cycle at 2.5 kHz (the gap workflow wants ≥ 2 kHz), made once.
fn sim_log() -> &'static str {
    static LOG: std::sync::OnceLock<String> = std::sync::OnceLock::new();
    LOG.get_or_init(|| {
        let opts = hal_sim::run::RunOptions {
            cycles: 1,
            ..hal_sim::run::RunOptions::reference()
        };
        let Ok(o) = hal_sim::run::run(&opts) else {
            return String::new();
        };
        let mut log = o.log.clone();
        for c in &mut log.columns {
            *c = c.iter().step_by(8).copied().collect();
        }
        for (k, v) in &mut log.meta {
            if k == "sample_rate_hz" {
                *v = "2500".into();
            }
        }
        log.to_csv()
    })
}

/// A hostile mutation of a valid log's text (`base`).
fn hostile_log(rng: &mut ChaCha8Rng, base: &str) -> Vec<u8> {
    let lines: Vec<&str> = base.lines().collect();
    let header = lines.iter().position(|l| l.starts_with("t_s")).unwrap_or(0);
    let mut out: Vec<String> = lines.iter().map(|s| s.to_string()).collect();
    let mutations = rng.random_range(0..=2);
    for _ in 0..mutations {
        let data = header + 1..out.len();
        if data.is_empty() {
            break;
        }
        let row = rng.random_range(data.clone());
        match rng.random_range(0..14) {
            // One cell replaced by a hostile number.
            0..=3 => {
                let mut fields: Vec<String> = out[row].split(',').map(str::to_string).collect();
                let c = rng.random_range(0..fields.len());
                fields[c] = HOSTILE_NUMBERS.choose(rng).unwrap_or(&"1e20").to_string();
                out[row] = fields.join(",");
            }
            // The time axis rescaled: tiny or huge steps, or reversed.
            4 => {
                let k: f64 = *[1e-12, 1e-9, 1e3, 1e6, -1.0].choose(rng).unwrap_or(&1e6);
                for r in data.clone() {
                    let mut fields: Vec<String> = out[r].split(',').map(str::to_string).collect();
                    if let Ok(t) = fields[0].parse::<f64>() {
                        fields[0] = format!("{}", t * k);
                    }
                    out[r] = fields.join(",");
                }
            }
            5 => out.truncate(rng.random_range(header..out.len())),
            6 => {
                let dup = out[row].clone();
                out.insert(row, dup);
            }
            7 => out[header] = out[header].replacen("x_m", "p_a_pa", 1),
            8 => out.insert(
                0,
                format!(
                    "# ports = {}",
                    ["open", "closed", "ajar"][rng.random_range(0..3)]
                ),
            ),
            9 => out.insert(
                0,
                format!(
                    "# sample_rate_hz = {}",
                    HOSTILE_NUMBERS.choose(rng).unwrap_or(&"0")
                ),
            ),
            10 => out[row] = "\"0.1,".to_string(),
            11 => out[row].push_str(",1"),
            12 => out.retain(|l| !l.starts_with("# ports")),
            _ => out.insert(0, "# force_delay_s = 1e300".to_string()),
        }
    }
    let sep = ["\n", "\r\n", "\r"][rng.random_range(0..3)];
    let mut bytes = out.join(sep).into_bytes();
    match rng.random_range(0..16) {
        0 => bytes.splice(0..0, "\u{feff}".bytes()).for_each(drop),
        1 => {
            for _ in 0..rng.random_range(1..20) {
                let i = rng.random_range(0..bytes.len());
                bytes[i] = rng.random();
            }
        }
        2 => bytes.truncate(rng.random_range(0..bytes.len())),
        3 => {
            let mut junk = vec![0u8; rng.random_range(1..5000)];
            rng.fill_bytes(&mut junk);
            bytes = junk;
        }
        _ => {}
    }
    bytes
}

/// A hostile sweep plan: a small valid plan (at most 4 one-cycle runs) with hostile values,
/// keys, ranges and faults put in.
fn hostile_plan(rng: &mut ChaCha8Rng) -> String {
    // Some plans are valid (their runs are what the case then costs: at most two).
    if rng.random_bool(0.08) {
        let axis = [
            "pressure_ratio = [2.2, 4.5]",
            "seed = { from = 1, to = 2 }",
            "speed_mps = { from = 2.0, to = 4.0, steps = 2 }",
            "\"model.piston.mass_kg\" = [11.5]",
            "fault = [\"pressure_open@0.95:chamber=b\"]",
        ][rng.random_range(0..5)];
        return format!("cycles = 1\n[axes]\n{axis}\n");
    }
    let value = |rng: &mut ChaCha8Rng| -> String {
        if rng.random_bool(0.5) {
            HOSTILE_NUMBERS.choose(rng).unwrap_or(&"0").to_string()
        } else {
            ["2.2", "3.1", "1", "4", "12.0", "0.05"][rng.random_range(0..6)].to_string()
        }
    };
    let mut lines = vec![format!(
        "cycles = {}",
        ["1", "1", "0", "-1", "1.5", "\"x\"", "1e9"][rng.random_range(0..7)]
    )];
    if rng.random_bool(0.2) {
        lines.push(format!(
            "model = \"{}\"",
            ["model.toml", "nowhere.toml", "log.csv", "/dev/zero", ""][rng.random_range(0..5)]
        ));
    }
    if rng.random_bool(0.1) {
        lines.push("colour = 3".into());
    }
    if rng.random_bool(0.95) {
        lines.push("[axes]".into());
    }
    for _ in 0..rng.random_range(0..=2) {
        let axis = [
            "pressure_ratio",
            "speed_mps",
            "seed",
            "model_error",
            "cycles",
            "\"model.piston.mass_kg\"",
            "\"model.effects.leakage.gap_m\"",
            "\"model.nope.x\"",
            "\"model.\"",
            "speeds",
            "volume_ratio",
        ][rng.random_range(0..11)];
        let modes = [
            "\"adaptive\"",
            "\"fixed:3.1\"",
            "\"fixed:nan\"",
            "\"fixed:\"",
            "\"\"",
        ];
        let values = match rng.random_range(0..5) {
            _ if axis == "volume_ratio" && rng.random_bool(0.7) => format!(
                "[{}, {}]",
                modes[rng.random_range(0..modes.len())],
                modes[rng.random_range(0..modes.len())]
            ),
            0 | 4 => format!("[{}]", value(rng)),
            1 => format!("[{}, {}]", value(rng), value(rng)),
            2 => format!(
                "{{ from = {}, to = {}, steps = {} }}",
                value(rng),
                value(rng),
                ["2", "0", "-1", "1e9", "3.5", "1", "x"][rng.random_range(0..7)]
            ),
            _ => format!("{{ from = {}, to = {} }}", value(rng), value(rng)),
        };
        lines.push(format!("{axis} = {values}"));
    }
    if rng.random_bool(0.3) {
        let spec = [
            "none",
            "overrun@1:cycles=2.5",
            "nonsense@1",
            "overrun@nan",
            "pressure_open@0.95:chamber=b",
            "overrun@0.95;none",
        ][rng.random_range(0..6)];
        lines.push(format!("fault = [\"{spec}\"]"));
    }
    let mut text = lines.join("\n");
    if rng.random_bool(0.1) {
        let mut bytes = text.into_bytes();
        let i = rng.random_range(0..bytes.len().max(1));
        if let Some(b) = bytes.get_mut(i) {
            *b = rng.random();
        }
        text = String::from_utf8_lossy(&bytes).into_owned();
    }
    text
}

/// A results table as `sweep` writes it (4 runs), hostilely mutated.
fn hostile_table(rng: &mut ChaCha8Rng) -> Vec<u8> {
    let mut lines = vec![
        "# source = fpc-sim sweep".to_string(),
        "# plan = 00000000000000ab".into(),
        "# runs = 4".into(),
        "run,seed,min_head_clearance_m,error".into(),
    ];
    let mut runs: Vec<u64> = (0..4).collect();
    runs.retain(|_| rng.random_bool(0.8));
    for k in runs {
        lines.push(format!("{k},{k},0.00098,"));
    }
    match rng.random_range(0..8) {
        0 => lines[1] = format!("# plan = {}", HOSTILE_NUMBERS.choose(rng).unwrap_or(&"x")),
        1 => lines[2] = format!("# runs = {}", HOSTILE_NUMBERS.choose(rng).unwrap_or(&"x")),
        2 => lines.push(format!(
            "{},1,1,",
            HOSTILE_NUMBERS.choose(rng).unwrap_or(&"x")
        )),
        3 => lines.push("1,1".into()),
        4 => {
            lines.remove(3);
        }
        _ => {}
    }
    let mut bytes = lines.join("\n").into_bytes();
    if rng.random_bool(0.15) && !bytes.is_empty() {
        let i = rng.random_range(0..bytes.len());
        bytes[i] = rng.random();
    }
    bytes
}

/// A telemetry capture of a short simulated run (made once).
fn base_capture() -> &'static [u8] {
    static CAPTURE: std::sync::OnceLock<Vec<u8>> = std::sync::OnceLock::new();
    CAPTURE.get_or_init(|| {
        let opts = hal_sim::run::RunOptions {
            cycles: 1,
            telemetry_decimation: 4,
            ..hal_sim::run::RunOptions::reference()
        };
        hal_sim::run::run(&opts)
            .map(|o| o.telemetry)
            .unwrap_or_default()
    })
}

/// A hostile mutation of that capture: flipped bytes, repeated or cut pieces, noise.
fn hostile_capture(rng: &mut ChaCha8Rng) -> Vec<u8> {
    let mut bytes = base_capture().to_vec();
    if bytes.is_empty() {
        return bytes;
    }
    for _ in 0..rng.random_range(1..=3) {
        let i = rng.random_range(0..bytes.len());
        match rng.random_range(0..5) {
            0 => {
                for _ in 0..rng.random_range(1..2000) {
                    let j = rng.random_range(0..bytes.len());
                    bytes[j] ^= 1 << rng.random_range(0..8);
                }
            }
            1 => {
                let piece = bytes[i..(i + 200).min(bytes.len())].to_vec();
                bytes.splice(i..i, piece).for_each(drop);
            }
            2 => bytes.truncate(i),
            3 => {
                let mut junk = vec![0u8; rng.random_range(0..20_000)];
                rng.fill_bytes(&mut junk);
                bytes = junk;
            }
            _ => {}
        }
    }
    bytes
}

/// A hostile mutation of the reference model file.
fn hostile_model(rng: &mut ChaCha8Rng) -> String {
    hostile_toml(rng, BASE_MODEL)
}

/// `base` (TOML) with one or two values made hostile, a line doubled or a key added.
fn hostile_toml(rng: &mut ChaCha8Rng, base: &str) -> String {
    let mut lines: Vec<String> = base.lines().map(str::to_string).collect();
    let numeric: Vec<usize> = lines
        .iter()
        .enumerate()
        .filter(|(_, l)| {
            l.split_once('=').is_some_and(|(_, v)| {
                v.trim()
                    .starts_with(|c: char| c.is_ascii_digit() || c == '-')
            })
        })
        .map(|(i, _)| i)
        .collect();
    for _ in 0..rng.random_range(1..=2) {
        match (numeric.choose(rng).copied(), rng.random_range(0..8)) {
            (Some(i), 0..=4) => {
                if let Some((k, _)) = lines[i].clone().split_once('=') {
                    let v = [
                        "1e300",
                        "-1e300",
                        "1e-300",
                        "0",
                        "-1",
                        "nan",
                        "inf",
                        "1e6",
                        "1e4",
                        "1e50",
                        "0.2",
                        "\"x\"",
                        "[1, 2, 3]",
                        "[]",
                        "true",
                    ]
                    .choose(rng)
                    .unwrap_or(&"0");
                    lines[i] = format!("{k}= {v}");
                }
            }
            (Some(i), 5) => {
                let dup = lines[i].clone();
                lines.insert(i, dup);
            }
            (_, 6) => lines.push("[effects.slave_lag]\ndelay_s = 1e6".into()),
            (_, _) => lines.push("bogus_key = 1".into()),
        }
    }
    lines.join("\n")
}

/// The arguments of a hostile case for `sub`, its input files written into `dir`.
fn hostile_case(sub: &str, rng: &mut ChaCha8Rng, dir: &Path) -> Case {
    let log = dir.join("log.csv");
    let model = dir.join("model.toml");
    let out = dir.join("out");
    let base = if sub == "gap" { sim_log() } else { BASE_LOG };
    std::fs::write(&log, hostile_log(rng, base)).unwrap();
    let model_text = if rng.random_bool(0.35) {
        hostile_model(rng)
    } else {
        BASE_MODEL.to_string()
    };
    std::fs::write(&model, model_text).unwrap();
    // An earlier output in the output directory, that must survive without --force.
    std::fs::create_dir_all(&out).unwrap();
    for name in [
        "run.csv",
        "filters.svg",
        "forces.svg",
        "pv.svg",
        "energy.svg",
        "report.md",
        "results.csv",
        "cal.toml",
    ] {
        if rng.random_bool(0.1) {
            std::fs::write(out.join(name), b"earlier output").unwrap();
        }
    }
    let num = |rng: &mut ChaCha8Rng| -> String {
        if rng.random_bool(0.4) {
            HOSTILE_NUMBERS.choose(rng).unwrap_or(&"0").to_string()
        } else {
            let plausible = [
                "0.05", "0.5", "1", "1.01", "2", "3", "3.1", "5", "6", "10", "50", "300",
            ];
            plausible.choose(rng).unwrap_or(&"1").to_string()
        }
    };
    let mut args: Vec<OsString> = vec!["fpc-sim".into(), sub.into()];
    let out_arg: PathBuf = match rng.random_range(0..16) {
        0 => log.clone(), // over its own input
        1 => dir.join("log.csv").join("sub"),
        2 => PathBuf::from("/"),
        3 => PathBuf::from("/proc/forbidden"),
        _ => out.clone(),
    };
    match sub {
        "run" => {
            if rng.random_bool(0.7) {
                push(&mut args, "--model", &model);
            }
            // Hostile runs must stay short: a valid one simulates one cycle.
            push(
                &mut args,
                "--cycles",
                &["0", "1", "-1", "1e9", "x"][rng.random_range(0..5)],
            );
            if rng.random_bool(0.5) {
                push(&mut args, "--pressure-ratio", &num(rng));
            }
            if rng.random_bool(0.3) {
                push(&mut args, "--speed", &num(rng));
            }
            if rng.random_bool(0.3) {
                let spec = [
                    "overrun@1:cycles=2.5",
                    "overrun@1:cycles=1,cycles=2",
                    "encoder_noise@1e9",
                    "nonsense@1",
                    "slave_lag@-1",
                    "overrun@nan",
                ][rng.random_range(0..6)];
                push(&mut args, "--fault", &spec);
            }
            if rng.random_bool(0.25) {
                let cal = dir.join("calibration.toml");
                let text = if rng.random_bool(0.6) {
                    hostile_toml(rng, BASE_CALIBRATION)
                } else {
                    BASE_CALIBRATION.to_string()
                };
                std::fs::write(&cal, text).unwrap();
                push(
                    &mut args,
                    "--calibration",
                    &[cal.clone(), cal, log.clone(), dir.join("none.toml")][rng.random_range(0..4)],
                );
            }
            if rng.random_bool(0.2) {
                push(
                    &mut args,
                    "--telemetry",
                    &[log.clone(), dir.join("t.bin")][rng.random_range(0..2)],
                );
            }
            push(&mut args, "--out", &out_arg);
        }
        "calibrate" => {
            if rng.random_bool(0.7) {
                push(&mut args, "--model", &model);
            }
            if rng.random_bool(0.3) {
                push(&mut args, "--seed", &num(rng));
            }
            push(
                &mut args,
                "--out",
                &[
                    out.join("cal.toml"),
                    out.join("cal.toml"),
                    out_arg.join("cal.toml"),
                    model.clone(),
                    log.clone(),
                ][rng.random_range(0..5)],
            );
        }
        "decode" => {
            let capture = dir.join("capture.bin");
            std::fs::write(&capture, hostile_capture(rng)).unwrap();
            push(
                &mut args,
                "--capture",
                &[
                    capture.clone(),
                    capture.clone(),
                    log.clone(),
                    dir.to_path_buf(),
                ][rng.random_range(0..4)],
            );
            push(
                &mut args,
                "--out",
                &[
                    out.join("d.csv"),
                    out.join("d.csv"),
                    out_arg.join("d.csv"),
                    log.clone(),
                    capture,
                ][rng.random_range(0..5)],
            );
        }
        "link" => {
            // Recorded channels only (a board is never attached here): a hostile capture on
            // up 1, noise on up 0 and up 2.
            let rec = dir.join("rec");
            std::fs::create_dir_all(&rec).unwrap();
            std::fs::write(rec.join("up1.bin"), hostile_capture(rng)).unwrap();
            for name in ["up0.bin", "up2.bin"] {
                if rng.random_bool(0.7) {
                    let noise: Vec<u8> = (0..rng.random_range(0..300))
                        .map(|_| rng.random::<u8>() & [0xFF, 0x0F][rng.random_range(0..2)])
                        .collect();
                    std::fs::write(rec.join(name), noise).unwrap();
                }
            }
            let replay = [
                rec.clone(),
                rec.clone(),
                rec.clone(),
                log.clone(),
                dir.join("none"),
            ][rng.random_range(0..5)]
            .clone();
            if rng.random_bool(0.2) {
                // The calibration transfer: a read into a file, or a (hostile) file written.
                args.push("calibration".into());
                if rng.random_bool(0.5) {
                    args.push("read".into());
                    push(&mut args, "--replay", &replay);
                    let to = [out.clone(), out_arg.clone(), rec][rng.random_range(0..3)].clone();
                    push(&mut args, "--out", &to);
                } else {
                    args.push("write".into());
                    push(&mut args, "--replay", &replay);
                    let cal = dir.join("calibration.toml");
                    std::fs::write(&cal, hostile_toml(rng, BASE_CALIBRATION)).unwrap();
                    args.push(
                        [cal.clone(), cal, log.clone(), dir.join("none.toml")]
                            [rng.random_range(0..4)]
                        .clone()
                        .into(),
                    );
                }
                if rng.random_bool(0.3) {
                    push(&mut args, "--timeout-ms", &num(rng));
                }
            } else if rng.random_bool(0.25) {
                // The link requests: hostile rates, channel sets, triggers and ports.
                match rng.random_range(0..4) {
                    0 => {
                        args.push("telemetry".into());
                        push(&mut args, "--rate", &num(rng));
                        if rng.random_bool(0.5) {
                            let sets = ["gap", "all", "x_m,p_a_pa", "x_m,,", "", "nope"];
                            push(&mut args, "--channels", sets.choose(rng).unwrap());
                        }
                    }
                    1 => {
                        args.extend(["scope".into(), "arm".into()]);
                        let triggers =
                            ["command", "fault", "strokes:", "strokes:0", "strokes:99999"];
                        push(&mut args, "--trigger", triggers.choose(rng).unwrap());
                        if rng.random_bool(0.5) {
                            push(&mut args, "--pre", &num(rng));
                        }
                    }
                    2 => args.extend([
                        "scope".into(),
                        ["fire", "disarm", "arm"][rng.random_range(0..3)].into(),
                    ]),
                    _ => {
                        args.push("ports".into());
                        args.push(["timed", "sealed", "open", ""][rng.random_range(0..4)].into());
                    }
                }
                push(&mut args, "--replay", &replay);
            } else if rng.random_bool(0.5) {
                args.push("capture".into());
                push(&mut args, "--replay", &replay);
                if rng.random_bool(0.3) {
                    push(&mut args, "--seconds", &num(rng));
                }
                let to = [out.clone(), out.clone(), out_arg.clone(), rec][rng.random_range(0..4)]
                    .clone();
                push(&mut args, "--out", &to);
            } else {
                args.push("send".into());
                push(&mut args, "--replay", &replay);
                if rng.random_bool(0.3) {
                    push(&mut args, "--timeout-ms", &num(rng));
                }
                match rng.random_range(0..7) {
                    0 => args.push("home".into()),
                    1 => {
                        args.push("start".into());
                        push(&mut args, "--speed", &num(rng));
                    }
                    2 => {
                        args.push("move-to".into());
                        push(&mut args, "--position", &num(rng));
                        push(&mut args, "--speed", &num(rng));
                    }
                    3 => {
                        args.push("set-parameter".into());
                        args.push("position-kp".into());
                        args.push(num(rng).into());
                    }
                    4 => {
                        args.push("set-volume-ratio".into());
                        if rng.random_bool(0.5) {
                            push(&mut args, "--ratio", &num(rng));
                        }
                    }
                    5 => {
                        args.push("calibrate".into());
                        args.push(["cogging", "x", ""][rng.random_range(0..3)].into());
                    }
                    _ => args.push("no-such-command".into()),
                }
            }
        }
        "derive" => {
            push(&mut args, "--measured", &log);
            for flag in ["--window", "--order", "--lag"] {
                if rng.random_bool(0.4) {
                    push(&mut args, flag, &num(rng));
                }
            }
        }
        "lag" => {
            push(&mut args, "--measured", &log);
            let cols = ["t_s", "x_m", "f_master_n", "f_slave_n", "nope", ""];
            push(&mut args, "--a", cols.choose(rng).unwrap_or(&"t_s"));
            push(&mut args, "--b", cols.choose(rng).unwrap_or(&"t_s"));
            if rng.random_bool(0.4) {
                push(&mut args, "--max-lag-s", &num(rng));
            }
        }
        "sweep" => {
            let plan = dir.join("plan.toml");
            std::fs::write(&plan, hostile_plan(rng)).unwrap();
            args.push(
                [
                    plan.clone(),
                    plan.clone(),
                    plan,
                    log.clone(),
                    dir.join("none.toml"),
                ][rng.random_range(0..5)]
                .clone()
                .into(),
            );
            if rng.random_bool(0.3) {
                let shard = ["0/1", "1/2", "2/2", "0/0", "x", "1e20/2", "-1/3"];
                push(
                    &mut args,
                    "--shard",
                    &shard[rng.random_range(0..shard.len())],
                );
            }
            if rng.random_bool(0.2) {
                push(&mut args, "--jobs", &num(rng));
            }
            if rng.random_bool(0.1) {
                args.push("--keep-logs".into());
            }
            if rng.random_bool(0.15) {
                push(&mut args, "--log-rate", &num(rng));
            }
            if rng.random_bool(0.1) {
                args.push("--resume".into());
            }
            push(&mut args, "--out", &out_arg);
        }
        "sweep-merge" => {
            for i in 0..rng.random_range(0..=3) {
                let table = dir.join(format!("slice{i}.csv"));
                std::fs::write(&table, hostile_table(rng)).unwrap();
                args.push(
                    [table.clone(), table, log.clone(), dir.join("none.csv")]
                        [rng.random_range(0..4)]
                    .clone()
                    .into(),
                );
            }
            push(&mut args, "--out", &out_arg);
        }
        "gap" => {
            push(&mut args, "--measured", &log);
            push(&mut args, "--model", &model);
            if rng.random_bool(0.4) {
                push(&mut args, "--band-hz", &num(rng));
            }
            push(&mut args, "--out", &out_arg);
        }
        tool => {
            push(&mut args, "--measured", &log);
            if rng.random_bool(0.5) {
                push(&mut args, "--model", &model);
            }
            push(&mut args, "--out", &out_arg);
            let flags: &[&str] = match tool {
                "filters" => &[
                    "--cutoff-hz",
                    "--filter-order",
                    "--sg-window",
                    "--sg-order",
                    "--sg-lag",
                    "--drive-delay-ms",
                    "--from-s",
                    "--to-s",
                ],
                "forces" => &["--cutoff-hz", "--filter-order", "--from-s", "--to-s"],
                "energy" => &["--cutoff-hz", "--filter-order", "--stroke"],
                _ => &[],
            };
            for flag in flags {
                if rng.random_bool(0.25) {
                    push(&mut args, flag, &num(rng));
                }
            }
        }
    }
    Case {
        args,
        dir: dir.to_path_buf(),
    }
}

/// Appends `--flag value`.
fn push(args: &mut Vec<OsString>, flag: &str, value: &dyn AsRef<std::ffi::OsStr>) {
    args.push(flag.into());
    args.push(value.as_ref().to_os_string());
}

/// Runs `count` hostile cases of every subcommand and checks each.
fn hostile_cases(count: usize, seed: u64) {
    let scratch = tempfile::Builder::new()
        .prefix(&format!("fpc-hostile-{seed}-"))
        .tempdir()
        .expect("scratch directory");
    let root = scratch.path().to_path_buf();
    // The subcommands are independent (each case has its own directory and the console
    // capture is per thread), so they share the cores: the costliest first.
    let mut order: Vec<&str> = SUBCOMMANDS.to_vec();
    order.sort_by_key(|sub| !matches!(*sub, "calibrate" | "gap" | "run" | "sweep"));
    let next = std::sync::atomic::AtomicUsize::new(0);
    let workers = std::thread::available_parallelism().map_or(1, |n| n.get());
    let mut summaries: Vec<(usize, String)> = std::thread::scope(|scope| {
        let handles: Vec<_> = (0..workers)
            .map(|_| {
                scope.spawn(|| {
                    let mut done = Vec::new();
                    loop {
                        let k = next.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
                        let Some(sub) = order.get(k) else { break };
                        done.push((k, subcommand_cases(sub, count, seed, &root)));
                    }
                    done
                })
            })
            .collect();
        handles
            .into_iter()
            .flat_map(|h| h.join().unwrap_or_else(|p| std::panic::resume_unwind(p)))
            .collect()
    });
    summaries.sort();
    for (_, line) in summaries {
        println!("{line}");
    }
    drop(scratch);
    if let Some(rss) = peak_rss_kib() {
        println!("peak RSS of the whole test: {:.0} MiB", rss as f64 / 1024.0);
        assert!(rss < 4 << 20, "peak RSS {rss} KiB");
    }
}

/// `count` hostile cases of one subcommand; its summary line.
fn subcommand_cases(sub: &str, count: usize, seed: u64, root: &Path) -> String {
    let mut rng =
        ChaCha8Rng::seed_from_u64(seed ^ sub.len() as u64 ^ u64::from(sub.as_bytes()[0]) << 8);
    let mut codes = [0usize; 3];
    let mut slowest = (Duration::ZERO, String::new());
    // What each case adds: the distinct outcomes (exit code and the message's first line
    // without its values), and the case that brought the last new one.
    let mut outcomes = std::collections::BTreeSet::new();
    let mut last_new = 0;
    for i in 0..count {
        let dir = root.join(format!("{sub}-{i}"));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        let case = hostile_case(sub, &mut rng, &dir);
        let before = snapshot(&case.dir);
        let shown = case
            .args
            .iter()
            .map(|a| a.to_string_lossy().into_owned())
            .collect::<Vec<_>>()
            .join(" ");
        let started = Instant::now();
        let (result, text) = hal_sim::console::captured(|| {
            std::panic::catch_unwind(|| hal_sim::cli::execute(case.args.clone()))
        });
        let took = started.elapsed();
        let code = match result {
            Ok(code) => code,
            Err(_) => panic!("case {sub} #{i} panicked: {shown}\n{text}"),
        };
        // The exit codes' contract (`docs/faults.md` #23, `docs/formats.md` §3): bad input
        // is refused with exit 2 and an error naming it; exit 0 is a command that did its
        // work and says no error; exit 1, a failure while running, only where the
        // "board" is a hostile recording that answers nothing usable (`link` replays:
        // no telemetry in it, or no reply to a request).
        match code {
            0 => assert!(
                !text.contains("error:"),
                "case {sub} #{i}: exit 0 with an error: {shown}\n{text}"
            ),
            2 => assert!(
                text.contains("error:"),
                "case {sub} #{i}: exit 2 naming no error: {shown}\n{text}"
            ),
            1 => assert!(
                sub == "link"
                    && (text.contains("error: telemetry:")
                        || text.contains("error: the recording of up-channel")),
                "case {sub} #{i}: exit 1 (a runtime failure) on bad input: {shown}\n{text}"
            ),
            _ => panic!("case {sub} #{i}: exit {code}: {shown}\n{text}"),
        }
        codes[usize::from(code)] += 1;
        assert!(took < CASE_LIMIT, "case {sub} #{i} took {took:?}: {shown}");
        if took > slowest.0 {
            slowest = (took, shown.clone());
        }
        let after = snapshot(&case.dir);
        for (path, bytes) in &before {
            assert_eq!(
                after.get(path),
                Some(bytes),
                "case {sub} #{i} (exit {code}) changed {}: {shown}\n{text}",
                path.display()
            );
        }
        let staging: Vec<_> = after
            .keys()
            .filter(|p| p.to_string_lossy().contains(".fpc-sim-staging"))
            .collect();
        assert!(
            staging.is_empty(),
            "case {sub} #{i} left {staging:?}: {shown}"
        );
        // A run that stopped early writes its complete set for diagnosis and says so.
        if code != 0 && !text.contains("the files are written") {
            let new: Vec<_> = after.keys().filter(|p| !before.contains_key(*p)).collect();
            assert!(
                new.is_empty(),
                "case {sub} #{i} failed (exit {code}) but left {new:?}: {shown}\n{text}"
            );
            let lines = text.lines().filter(|l| !l.trim().is_empty()).count();
            assert!(
                lines >= 1,
                "case {sub} #{i}: exit {code} said nothing: {shown}"
            );
            assert!(
                !text.contains(" { "),
                "case {sub} #{i}: a debug dump: {text}"
            );
        }
        if outcomes.insert((code, outcome_class(&text))) {
            last_new = i;
        }
        if std::env::var_os("FPC_HOSTILE_SHOW").is_some() {
            println!(
                "{sub} #{i} exit {code}: {}",
                text.lines().last().unwrap_or("")
            );
        }
        let _ = std::fs::remove_dir_all(&dir);
    }
    format!(
        "{sub:>8}: {count} cases: exit 0 {}, 1 {}, 2 {}; {} distinct outcomes, the last new one \
         at case {last_new}; slowest {:.2} s ({})",
        codes[0],
        codes[1],
        codes[2],
        outcomes.len(),
        slowest.0.as_secs_f64(),
        slowest.1
    )
}

/// A case's outcome class: the first non-empty line it printed (clap's last line is the same
/// `--help` hint for every refusal), with quoted parts blanked and the words that carry a
/// value (numbers, `inf`, `NaN`, paths) dropped, so that two cases refused for the same
/// reason count once.
fn outcome_class(text: &str) -> String {
    let first = text.lines().find(|l| !l.trim().is_empty()).unwrap_or("");
    let mut unquoted = String::with_capacity(first.len());
    let mut quoted = false;
    let mut prev = ' ';
    for c in first.chars() {
        // An apostrophe inside a word ("doesn't") is not a quote.
        let apostrophe = c == '\'' && !quoted && prev.is_alphabetic();
        prev = c;
        match c {
            '\'' | '"' | '`' if !apostrophe => {
                quoted = !quoted;
                unquoted.push('"');
            }
            _ if quoted => {}
            _ => unquoted.push(c),
        }
    }
    unquoted
        .split_whitespace()
        .filter(|w| {
            let bare = w
                .trim_matches(|c: char| !c.is_alphanumeric())
                .to_ascii_lowercase();
            !(w.contains('/')
                || w.chars().any(|c| c.is_ascii_digit())
                || bare == "inf"
                || bare == "nan")
        })
        .collect::<Vec<_>>()
        .join(" ")
}

/// The process's peak resident set, KiB (Linux).
fn peak_rss_kib() -> Option<u64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = status.lines().find(|l| l.starts_with("VmHWM:"))?;
    line.split_whitespace().nth(1)?.parse().ok()
}

fn cases_from_env(default: usize) -> usize {
    std::env::var("FPC_HOSTILE_CASES")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(default)
}

#[test]
fn every_subcommand_survives_hostile_input() {
    hostile_cases(cases_from_env(60), 0x5EED_0018);
}

#[test]
#[ignore = "slow: 10^4 hostile cases per subcommand"]
fn every_subcommand_survives_ten_thousand_hostile_inputs() {
    hostile_cases(cases_from_env(10_000), 0x5EED_1018);
}
