//! The reference tables of `docs/formats.md` are the code's, not a copy that drifts: every
//! key of the machine model with its unit, range, reference value and origin (from
//! `validate::RANGES` and the embedded `reference.toml`), every `--fault` kind with its
//! parameters (from `FaultKind`), and every field of `fpc-sim run --json` (from `Summary`).
//!
//! The first two are rendered here and must equal the text between the document's
//! `<!-- generated: NAME -->` and `<!-- end generated -->` markers; `FPC_BLESS_DOCS=1`
//! rewrites them after a deliberate change. The summary's fields must each have a row.

use std::collections::BTreeMap;
use std::path::PathBuf;

use hal_sim::faults::inject::{FaultKind, WORDS};
use hal_sim::plant::model::validate::RANGES;
use hal_sim::run::Summary;

const REFERENCE_TOML: &str = include_str!("../src/plant/model/reference.toml");

fn formats_md() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../docs/formats.md")
}

/// A number as a reader writes it: plain in 0.001–99,999, else in exponent form.
fn num(v: f64) -> String {
    if v == 0.0 || (1e-3..1e5).contains(&v.abs()) {
        let s = format!("{v}");
        let s = if s.len() > 9 { format!("{v:.4}") } else { s };
        s.strip_suffix(".0").map_or(s.clone(), str::to_string)
    } else {
        format!("{v:e}")
    }
}

/// The comment each key of `reference.toml` carries (or its section's, when the key has
/// none): where the value comes from.
fn origins() -> BTreeMap<String, String> {
    let mut section = String::new();
    let mut section_note = String::new();
    let mut out = BTreeMap::new();
    for line in REFERENCE_TOML.lines() {
        let line = line.trim();
        let (code, note) = match line.split_once('#') {
            Some((c, n)) => (c.trim(), n.trim()),
            None => (line, ""),
        };
        if let Some(name) = code.strip_prefix('[').and_then(|c| c.strip_suffix(']')) {
            section = name.to_string();
            section_note = note.to_string();
        } else if let Some((key, _)) = code.split_once('=') {
            let note = if note.is_empty() { &section_note } else { note };
            out.insert(format!("{section}.{}", key.trim()), note.to_string());
        }
    }
    out
}

/// The reference value at a dotted path, as TOML writes it.
fn reference_value(table: &toml::Table, path: &str) -> String {
    let mut parts = path.split('.').peekable();
    let mut t = table;
    while let Some(part) = parts.next() {
        match t.get(part) {
            Some(toml::Value::Table(inner)) if parts.peek().is_some() => t = inner,
            Some(toml::Value::Float(f)) => return num(*f),
            Some(toml::Value::Integer(i)) => return i.to_string(),
            Some(v) => return v.to_string(),
            None => return "—".into(),
        }
    }
    "—".into()
}

fn model_keys() -> String {
    let table: toml::Table = REFERENCE_TOML
        .parse()
        .expect("the embedded reference parses");
    let origins = origins();
    let mut s =
        String::from("| key | unit | range | reference | origin |\n|---|---|---|---|---|\n");
    for (key, lo, hi, unit) in RANGES.iter() {
        let origin = origins.get(key).map_or("", String::as_str);
        s.push_str(&format!(
            "| `{key}` | {unit} | {} … {} | {} | {} |\n",
            num(*lo),
            num(*hi),
            reference_value(&table, key),
            origin.replace('|', "\\|")
        ));
    }
    s
}

fn fault_specs() -> String {
    let mut s = String::from("| name | parameters (default; range) | what |\n|---|---|---|\n");
    for (kind, name) in FaultKind::ALL {
        let params: Vec<String> = kind
            .parameters()
            .iter()
            .map(|(p, default, lo, hi)| {
                let words: Vec<&str> = WORDS
                    .iter()
                    .filter(|(w, ..)| w == p)
                    .map(|(_, word, _)| *word)
                    .collect();
                if words.is_empty() {
                    format!("`{p}` = {} ({} … {})", num(*default), num(*lo), num(*hi))
                } else {
                    let d = WORDS
                        .iter()
                        .find(|(w, _, code)| w == p && code == default)
                        .map_or("?", |(_, word, _)| *word);
                    format!("`{p}` = {d} ({})", words.join("\\|"))
                }
            })
            .collect();
        let params = if params.is_empty() {
            "—".to_string()
        } else {
            params.join("; ")
        };
        s.push_str(&format!(
            "| `{name}` | {params} | {} |\n",
            kind.description().replace('|', "\\|")
        ));
    }
    s
}

/// The text between the markers of `name`, and where it starts and ends.
fn region(doc: &str, name: &str) -> (usize, usize) {
    let open = format!("<!-- generated: {name} -->\n");
    let start = doc
        .find(&open)
        .unwrap_or_else(|| panic!("docs/formats.md has no `{}` marker", open.trim()))
        + open.len();
    let end = start
        + doc[start..]
            .find("<!-- end generated -->")
            .unwrap_or_else(|| panic!("the `{name}` region of docs/formats.md is not closed"));
    (start, end)
}

#[test]
fn the_generated_tables_are_the_codes() {
    let path = formats_md();
    let mut doc = std::fs::read_to_string(&path).expect("docs/formats.md is readable");
    let bless = std::env::var_os("FPC_BLESS_DOCS").is_some();
    let mut stale = Vec::new();
    for (name, text) in [("model-keys", model_keys()), ("fault-specs", fault_specs())] {
        let (start, end) = region(&doc, name);
        if doc[start..end] != text {
            if bless {
                doc.replace_range(start..end, &text);
            } else {
                stale.push(name);
            }
        }
    }
    if bless {
        std::fs::write(&path, doc).expect("docs/formats.md is writable");
    }
    assert!(
        stale.is_empty(),
        "docs/formats.md's generated tables {stale:?} differ from the code: \
         FPC_BLESS_DOCS=1 cargo test -p hal-sim --test the_reference_docs_match_the_code"
    );
}

#[test]
fn every_field_of_the_run_summary_is_documented() {
    let doc = std::fs::read_to_string(formats_md()).expect("docs/formats.md is readable");
    let value = serde_json::to_value(Summary::default()).expect("the summary serialises");
    let fields = value.as_object().expect("the summary is an object");
    let missing: Vec<&String> = fields
        .keys()
        .filter(|k| !doc.contains(&format!("`{k}`")))
        .collect();
    assert!(missing.is_empty(), "docs/formats.md §4 lacks {missing:?}");
}

#[test]
fn the_module_map_names_every_module() {
    // `docs/architecture.md` is the one module map; the `lib.rs` headers point to it.
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("..");
    let map = std::fs::read_to_string(root.join("docs/architecture.md"))
        .expect("docs/architecture.md is readable");
    let mut missing = Vec::new();
    for lib in ["src/lib.rs", "hal-sim/src/lib.rs"] {
        let text = std::fs::read_to_string(root.join(lib)).expect("lib.rs is readable");
        for name in text
            .lines()
            .filter_map(|l| l.trim().strip_prefix("pub mod "))
            .filter_map(|l| l.strip_suffix(';'))
        {
            if !map.contains(&format!("`{name}`")) && !map.contains(&format!("`{name}/`")) {
                missing.push(format!("{lib}: {name}"));
            }
        }
    }
    assert!(
        missing.is_empty(),
        "docs/architecture.md's module map lacks {missing:?}"
    );
}

/// Every subcommand's `--help`, as `docs/cli.md` holds it.
fn cli_reference() -> String {
    use clap::CommandFactory;
    fn walk(cmd: &mut clap::Command, path: &str, out: &mut String) {
        let name = format!("{path} {}", cmd.get_name());
        let name = name.trim().to_string();
        let help = cmd.render_long_help().to_string();
        out.push_str(&format!(
            "## `{name}`\n\n```text\n{}\n```\n\n",
            help.trim_end()
        ));
        let mut subs: Vec<clap::Command> = cmd.get_subcommands().cloned().collect();
        for sub in &mut subs {
            if sub.get_name() != "help" {
                walk(sub, &name, out);
            }
        }
    }
    let mut out = String::from(
        "# `fpc-sim` command reference\n\n\
         Every command's `--help`, generated from the code (`cargo test -p hal-sim --test \
         the_reference_docs_match_the_code`; `FPC_BLESS_DOCS=1` rewrites this file). What each \
         command is for, its conventions and its outputs: [fpc-sim.md](fpc-sim.md).\n\n",
    );
    let mut top = hal_sim::cli::Cli::command();
    top.build();
    let mut subs: Vec<clap::Command> = top.get_subcommands().cloned().collect();
    for sub in &mut subs {
        if sub.get_name() != "help" {
            walk(sub, "fpc-sim", &mut out);
        }
    }
    out.trim_end().to_string() + "\n"
}

#[test]
fn the_command_reference_is_every_commands_help() {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../docs/cli.md");
    let text = cli_reference();
    if std::env::var_os("FPC_BLESS_DOCS").is_some() {
        std::fs::write(&path, &text).expect("docs/cli.md is writable");
    }
    let doc = std::fs::read_to_string(&path).unwrap_or_default();
    assert!(
        doc == text,
        "docs/cli.md differs from the commands' --help: \
         FPC_BLESS_DOCS=1 cargo test -p hal-sim --test the_reference_docs_match_the_code"
    );
}
