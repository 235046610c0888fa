//! `fpc-sim`: one module per subcommand, and the plumbing the log tools share
//! ([`analysis`]: reading the log and the model, columns, output directory, progress).
//! Failures and their exit codes are [`crate::failure`]'s; plots are [`crate::plot`]'s.
//!
//! [`execute`] is the whole tool as a function (arguments in, exit code out), so the binary
//! is one line and tests can drive every subcommand in-process.

pub mod analysis;
pub mod calibrate;
pub mod decode;
pub mod derive;
pub mod energy;
pub mod filters;
pub mod forces;
pub mod gap;
pub mod lag;
pub mod link;
pub mod model;
pub mod paper;
pub mod pv;
pub mod run;
pub mod sweep;
pub mod view;

use clap::{Args, CommandFactory, Parser, Subcommand};

use crate::failure::{CmdResult, Failure};

/// `fpc-sim --version`: the package version, the commit it was built from, and the telemetry
/// frame layout it decodes (what a board's firmware must send).
pub const VERSION: &str = concat!(
    env!("CARGO_PKG_VERSION"),
    " (commit ",
    env!("FPC_SIM_COMMIT"),
    ", telemetry layout 2)"
);

/// The command line of `fpc-sim`.
#[derive(Parser)]
#[command(
    name = "fpc-sim",
    version = VERSION,
    about = "Simulator and analysis tools of the free-piston compressor"
)]
pub struct Cli {
    #[command(subcommand)]
    command: Cmd,
}

#[derive(Subcommand)]
enum Cmd {
    /// Closed-loop simulation with the firmware's tasks in the loop.
    Run(run::RunArgs),
    /// Commission the simulated machine (the firmware's Calibrate routines) and write the
    /// calibration file `run --calibration` loads.
    Calibrate(calibrate::CalibrateArgs),
    /// The firmware's Savitzky–Golay differentiator over a run log's position.
    Derive(derive::DeriveArgs),
    /// Decode a captured telemetry stream into a run log (CSV).
    Decode(decode::DecodeArgs),
    /// Time lag between two logged signals by FFT cross-correlation (Fig. 4).
    Lag(lag::LagArgs),
    /// Velocity without filter, filtfilt, firmware Savitzky-Golay, drive reading (Fig. 7).
    Filters(filters::FiltersArgs),
    /// Inertia force from position against the forces acting (Fig. 8).
    Forces(forces::ForcesArgs),
    /// Motor, inertia, gas and friction work along one stroke (Fig. 9).
    Energy(energy::EnergyArgs),
    /// p-V diagram of both chambers (Fig. 3).
    Pv(pv::PvArgs),
    /// The paper's Figs. 3-9 from the simulator, its controller and ours side by side.
    Paper(paper::PaperArgs),
    /// Find, name and add the effect missing from a model (model-gap workflow).
    Gap(gap::GapArgs),
    /// Every run of a plan (the axes' combinations) in parallel, one table of results.
    Sweep(sweep::SweepArgs),
    /// Join the slices (`sweep --shard I/N`) of one plan into its whole table.
    SweepMerge(sweep::MergeArgs),
    /// Talk to the running board over RTT: capture telemetry, send commands, read defmt.
    Link(link::LinkArgs),
    /// Print the built-in reference machine model with its comments (start your own from it).
    Model(model::ModelArgs),
    /// The bench console: live plots and controls in the browser, for the simulated board,
    /// a recorded session or the board.
    View(view::ViewArgs),
    /// Print the shell completions of fpc-sim (e.g. `fpc-sim completions bash >
    /// ~/.local/share/bash-completion/completions/fpc-sim`).
    Completions(CompletionsArgs),
}

/// `fpc-sim completions`.
#[derive(Args, Debug)]
pub struct CompletionsArgs {
    /// The shell.
    #[arg(value_enum)]
    shell: clap_complete::Shell,
}

/// The subcommand's name, as typed.
fn name(cmd: &Cmd) -> &'static str {
    match cmd {
        Cmd::Run(_) => "run",
        Cmd::Calibrate(_) => "calibrate",
        Cmd::Derive(_) => "derive",
        Cmd::Decode(_) => "decode",
        Cmd::Lag(_) => "lag",
        Cmd::Filters(_) => "filters",
        Cmd::Forces(_) => "forces",
        Cmd::Energy(_) => "energy",
        Cmd::Pv(_) => "pv",
        Cmd::Gap(_) => "gap",
        Cmd::Sweep(_) => "sweep",
        Cmd::SweepMerge(_) => "sweep-merge",
        Cmd::Link(_) => "link",
        Cmd::Model(_) => "model",
        Cmd::Paper(_) => "paper",
        Cmd::View(_) => "view",
        Cmd::Completions(_) => "completions",
    }
}

/// `fpc-sim completions SHELL`: the script on stdout.
fn completions(args: CompletionsArgs) -> CmdResult {
    let mut text = Vec::new();
    clap_complete::generate(args.shell, &mut Cli::command(), "fpc-sim", &mut text);
    let mut out = crate::console::stdout();
    std::io::Write::write_all(&mut out, &text).map_err(|e| Failure::stdout_error(&e))
}

fn dispatch(cmd: Cmd) -> CmdResult {
    crate::output::set_command(name(&cmd));
    match cmd {
        Cmd::Run(args) => run::main(args),
        Cmd::Calibrate(args) => calibrate::main(args),
        Cmd::Derive(args) => derive::main(args),
        Cmd::Decode(args) => decode::main(args),
        Cmd::Lag(args) => lag::main(args),
        Cmd::Filters(args) => filters::main(args),
        Cmd::Forces(args) => forces::main(args),
        Cmd::Energy(args) => energy::main(args),
        Cmd::Pv(args) => pv::main(args),
        Cmd::Paper(args) => paper::main(args),
        Cmd::Gap(args) => gap::main(args),
        Cmd::Sweep(args) => sweep::main(args),
        Cmd::SweepMerge(args) => sweep::merge_main(args),
        Cmd::Link(args) => link::main(args),
        Cmd::Model(args) => model::main(args),
        Cmd::View(args) => view::main(args),
        Cmd::Completions(args) => completions(args),
    }
}

/// Runs `fpc-sim` with these arguments (the first is the program name) and returns the exit
/// code: 0 success (and `--help`/`--version`), 1 runtime failure, 2 bad usage or input. The
/// failure's one line goes to stderr; if even that cannot be written the code stands.
pub fn execute<I, T>(args: I) -> u8
where
    I: IntoIterator<Item = T>,
    T: Into<std::ffi::OsString> + Clone,
{
    let cli = match Cli::try_parse_from(args) {
        Ok(c) => c,
        Err(e) => {
            // Help and version go to stdout with exit 0; usage errors exit 2.
            let text = e.render().to_string();
            let text = text.trim_end();
            return if e.use_stderr() {
                let _ = crate::errln!("{text}");
                2
            } else {
                match crate::outln!("{text}") {
                    Ok(()) => 0,
                    Err(f) => f.code,
                }
            };
        }
    };
    match dispatch(cli.command) {
        Ok(()) => 0,
        Err(f) if f.is_closed_pipe() => f.code,
        Err(f) => {
            // clap's style for its own usage errors, so every refusal reads alike.
            let _ = crate::errln!("error: {}", f.message);
            f.code
        }
    }
}

#[cfg(test)]
mod tests {
    use super::Cli;
    use clap::{CommandFactory, Parser};

    /// clap's own checks of the whole command tree: no two arguments of a command (global
    /// ones included) share a name or a flag, every default parses.
    #[test]
    fn the_command_line_is_well_formed() {
        Cli::command().debug_assert();
    }

    /// `--version` names the telemetry layout this build decodes: the firmware's.
    #[test]
    fn the_version_names_the_commit_and_the_telemetry_layout() {
        let layout = format!("telemetry layout {})", fpc::link::telemetry::LAYOUT);
        assert!(super::VERSION.ends_with(&layout), "{}", super::VERSION);
        assert!(super::VERSION.contains("(commit "), "{}", super::VERSION);
    }

    /// Every shell's script names every subcommand.
    #[test]
    fn completions_cover_every_subcommand() {
        for shell in [clap_complete::Shell::Bash, clap_complete::Shell::Zsh] {
            let mut text = Vec::new();
            clap_complete::generate(shell, &mut Cli::command(), "fpc-sim", &mut text);
            let text = String::from_utf8(text).unwrap();
            for sub in Cli::command().get_subcommands() {
                assert!(text.contains(sub.get_name()), "{shell}: {}", sub.get_name());
            }
        }
    }

    /// The link's target options may follow the subcommand, and `send start` keeps its own
    /// `--speed`.
    #[test]
    fn link_options_follow_a_subcommand() {
        let cli = Cli::try_parse_from([
            "fpc-sim", "link", "send", "start", "--speed", "2.3", "--replay", "rec",
        ]);
        assert!(cli.is_ok(), "{:?}", cli.err());
        let cli = Cli::try_parse_from([
            "fpc-sim",
            "link",
            "scope",
            "arm",
            "--trigger",
            "strokes:4",
            "--replay",
            "rec",
        ]);
        assert!(cli.is_ok(), "{:?}", cli.err());
    }
}
