//! `fpc-sim paper`: the paper's Figs. 3–9 redrawn from the simulator, the published rig's
//! controller and ours side by side, with the electrical cost of both at the Fig. 3 points
//! ([`crate::paper`]; what each figure shows: `docs/paper.md`).

use clap::Args;

use crate::console::Num;
use crate::failure::{CmdResult, Failure};
use crate::outln;
use crate::output::OutDir;
use crate::paper::{paper_runs, write_figures, PaperFigures, FIGURES};

/// The paper's figures from the simulator (Figs. 3–9) and both controllers' electrical cost.
#[derive(Args, Debug)]
pub struct PaperArgs {
    /// Output directory for the figures and paper.json (default: out/paper).
    #[arg(long)]
    pub out: Option<std::path::PathBuf>,
    /// Compression cycles of each run (the figures use the last five).
    #[arg(long, default_value_t = 10)]
    pub cycles: u32,
    /// Seed of the runs' noise.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Replace the figures of an earlier `paper` in the output directory.
    #[arg(long)]
    pub force: bool,
    /// Print the figures as one JSON object on stdout (also written as paper.json).
    #[arg(long)]
    pub json: bool,
}

/// Runs `fpc-sim paper`.
pub fn main(args: PaperArgs) -> CmdResult {
    if !(6..=100).contains(&args.cycles) {
        return Err(Failure::bad_input(format!(
            "--cycles {}: must be 6..=100 (the figures use the last five complete cycles)",
            args.cycles
        )));
    }
    let dir = args
        .out
        .clone()
        .unwrap_or_else(|| crate::cli::analysis::default_out("paper"));
    let mut names: Vec<&str> = FIGURES.to_vec();
    names.push("paper.json");
    let out = OutDir::prepare(&dir, &names, args.force, &[])?;
    let runs = paper_runs(args.cycles, args.seed).map_err(Failure::runtime)?;
    let figures = write_figures(&runs, out.staging_dir()).map_err(Failure::runtime)?;
    let text =
        serde_json::to_string_pretty(&figures).map_err(|e| Failure::runtime(e.to_string()))?;
    let json_path = out.path("paper.json");
    std::fs::write(&json_path, format!("{text}\n"))
        .map_err(|e| Failure::runtime(format!("cannot write {}: {e}", json_path.display())))?;
    let shown = out.final_path("").display().to_string();
    out.commit()?;
    if args.json {
        return outln!("{text}");
    }
    print(&figures)?;
    outln!(
        "wrote {} figures and paper.json to {}",
        FIGURES.len(),
        shown.trim_end_matches('/')
    )
}

/// The figures, a line each.
fn print(f: &PaperFigures) -> CmdResult {
    let loops = |k: usize| {
        f.points
            .iter()
            .map(|p| format!("{:.2}", Num(p.loop_ratio[k])))
            .collect::<Vec<_>>()
            .join(" ")
    };
    let p_top = |k: usize| f.points.last().map_or(f64::NAN, |p| p.p_max_mpa[k]);
    outln!(
        "Fig. 3: loop pressure ratio ours {}, published {} (paper 3.1 3.7 4.3 5.1); p_max at PR 5.1 {:.2} / {:.2} MPa (axis 0.5)",
        loops(0),
        loops(1),
        Num(p_top(0)),
        Num(p_top(1))
    )?;
    outln!(
        "Fig. 4: published sections at most {:.2} / {:.2} kN (paper 0.8-1.6), slave {:.2} ms late (the model's input, read back)",
        Num(f.fig4_section_peak_kn[0]),
        Num(f.fig4_section_peak_kn[1]),
        Num(f.fig4_lag_ms)
    )?;
    let [pc, pn, o] = f.fig5_peak_difference_kn;
    outln!(
        "Fig. 5: master - slave at most {:.2} kN compressing, {:.2} kN not (paper ±0.7); ours {:.3} kN",
        Num(pc),
        Num(pn),
        Num(o)
    )?;
    let [c, n, m] = f.fig6_rms_um;
    outln!(
        "Fig. 6: slave - master {:.1} µm RMS compressing, {:.1} µm not; steps {:.0} µm a pitch, {:.0} µm more toward B; with the firmware's map {:.2} µm",
        Num(c),
        Num(n),
        Num(f.fig6_step_um),
        Num(f.fig6_direction_um),
        Num(m)
    )?;
    let [lu, ls, ld] = f.fig7_lag_ms;
    let [eu, _, _] = f.fig7_rms_mps;
    outln!(
        "Fig. 7: late behind filtfilt: unfiltered {:.3} ms ({:.0} mm/s RMS noise), Savitzky-Golay {:.3} ms, drive reading {:.2} ms (the model's input, read back)",
        Num(lu),
        Num(eu * 1e3),
        Num(ls),
        Num(ld)
    )?;
    let [peak, raw, filt] = f.fig8_kn;
    let t = &f.filter_tuning;
    outln!(
        "Fig. 8: expected inertia force at most {:.2} kN (axis ±10); unfiltered off by {:.2} kN RMS, filtered {:.3}; §4.3 best Savitzky-Golay window {} (firmware {})",
        Num(peak),
        Num(raw),
        Num(filt),
        t.best_window,
        t.firmware_window
    )?;
    outln!(
        "Fig. 9: motor force at most {:.2} kN ours, {:.2} kN published (paper ≈ 6); published motor work {:.0} J accelerating, {:.0} J decelerating",
        Num(f.fig9_motor_peak_kn[0]),
        Num(f.fig9_motor_peak_kn[1]),
        Num(f.fig9_motor_work_j[0]),
        Num(f.fig9_motor_work_j[1])
    )?;
    let c = &f.closed_port;
    outln!(
        "§4 closed ports, to {} m: closed loop ends at {:.4} m, {:.2} bar; the same force open loop ends at {:.4} m, {:.2} bar, clearance {:.2} mm",
        c.stop_m,
        Num(c.end_m[0]),
        Num(c.peak_bar[0]),
        Num(c.end_m[1]),
        Num(c.peak_bar[1]),
        Num(c.min_clearance_mm[1])
    )?;
    for p in &f.points {
        outln!(
            "PR {} at {} m/s, per cycle: indicated {:.1} / {:.1} J, electrical {:.1} / {:.1} J, efficiency {:.1} / {:.1} %, fight {:.2} J (ours / published)",
            p.pressure_ratio,
            p.speed_mps,
            Num(p.indicated_j[0]),
            Num(p.indicated_j[1]),
            Num(p.electrical_j[0]),
            Num(p.electrical_j[1]),
            Num(100.0 * p.efficiency[0]),
            Num(100.0 * p.efficiency[1]),
            Num(p.fight_j[1])
        )?;
    }
    Ok(())
}
