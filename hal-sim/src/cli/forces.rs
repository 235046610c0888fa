//! `fpc-sim forces` (the paper's Fig. 8): the inertia force `m·a` estimated from the logged
//! position — unfiltered (second difference), zero-phase filtered (`filtfilt` of the second
//! difference: filtering the position instead would bend its curvature at the log's ends),
//! and by the firmware's own
//! Savitzky–Golay differentiator — against the inertia force the other forces imply:
//!
//! `m·a = F_master + F_slave + (p_a − p_b)·A_eff − F_fr(v)`
//!
//! (`fpc::physics::friction`'s law with the model's parameters, `v` the filtered central difference). The
//! delay of each estimate behind the expected force is what the paper tuned its filters on.

use clap::Args;
use fpc::control::config::ControlConfig;

use crate::cli::analysis::{
    column, default_window, interior, read_log, read_model, sample_time_s, time_window,
    LogToolArgs, Steps, WindowArgs, ZeroPhaseArgs,
};
use crate::console::Num;
use crate::failure::{CmdResult, Failure};
use crate::outln;
use crate::plant::model::MachineModel;
use crate::plot;
use crate::runlog::RunLog;
use crate::signal::{
    central_difference, filtfilt, firmware_derivatives, rms_difference, second_difference, strokes,
    xcorr_lag, Biquad, SgSettings,
};

/// Inertia force from position vs expected (Fig. 8).
#[derive(Args, Debug)]
pub struct ForcesArgs {
    #[command(flatten)]
    #[allow(missing_docs)]
    pub io: LogToolArgs,
    #[command(flatten)]
    #[allow(missing_docs)]
    pub filter: ZeroPhaseArgs,
    #[command(flatten)]
    #[allow(missing_docs)]
    pub window: WindowArgs,
}

/// The forces on the piston along a log, N, one per sample.
#[derive(Clone, Debug, PartialEq)]
pub struct ForceBalance {
    /// Position as logged, m.
    pub x_m: Vec<f64>,
    /// Velocity, zero-phase filtered central difference, m/s.
    pub v_mps: Vec<f64>,
    /// Both motor sections, `F_master + F_slave`.
    pub motor_n: Vec<f64>,
    /// Gas force `(p_a − p_b)·A_eff`, toward +x.
    pub gas_n: Vec<f64>,
    /// Friction `F_fr(v)` (it opposes motion: subtracted).
    pub friction_n: Vec<f64>,
    /// What the forces imply for `m·a`.
    pub expected_inertia_n: Vec<f64>,
    /// `m·a` from the unfiltered position (second difference).
    pub inertia_raw_n: Vec<f64>,
    /// `m·a` from the zero-phase filtered position.
    pub inertia_filtered_n: Vec<f64>,
    /// `m·a` from the firmware's Savitzky–Golay differentiator.
    pub inertia_firmware_n: Vec<f64>,
}

/// Computes the force balance of `log` with `model`'s parameters.
pub fn force_balance(
    log: &RunLog,
    model: &MachineModel,
    sections: &[Biquad],
) -> Result<ForceBalance, Failure> {
    let dt = sample_time_s(log)?;
    let x = column(log, "x_m", "x_m")?;
    let fm = column(log, "f_master_n", "f_master_n")?;
    let fs = column(log, "f_slave_n", "f_slave_n")?;
    let pa = column(log, "p_a_pa", "p_a_pa")?;
    let pb = column(log, "p_b_pa", "p_b_pa")?;
    let m = model.piston.mass_kg;
    let area = model.piston_area_m2();
    let friction = model.friction();
    let v = filtfilt(sections, &central_difference(x, dt));
    let motor: Vec<f64> = fm.iter().zip(fs).map(|(a, b)| a + b).collect();
    let gas: Vec<f64> = pa.iter().zip(pb).map(|(a, b)| (a - b) * area).collect();
    let fr: Vec<f64> = v.iter().map(|&v| friction.force_n(v)).collect();
    let expected = motor
        .iter()
        .zip(&gas)
        .zip(&fr)
        .map(|((f, g), r)| f + g - r)
        .collect();
    let inertia = |a: Vec<f64>| a.into_iter().map(|a| m * a).collect::<Vec<f64>>();
    let c = ControlConfig::reference();
    let sg = SgSettings {
        window: c.sg_window,
        order: c.sg_order,
        lag: c.sg_lag,
    };
    // The settings are the firmware's: only the log's sample time can make them unusable.
    let (_, a_fw) = firmware_derivatives(x, dt, model.encoder.period_m, sg).map_err(|e| {
        Failure::bad_input(format!(
            "the log's sample time {dt:e} s: the firmware's differentiator cannot run at it ({e})"
        ))
    })?;
    Ok(ForceBalance {
        inertia_raw_n: inertia(second_difference(x, dt)),
        inertia_filtered_n: inertia(filtfilt(sections, &second_difference(x, dt))),
        inertia_firmware_n: inertia(a_fw),
        x_m: x.to_vec(),
        v_mps: v,
        motor_n: motor,
        gas_n: gas,
        friction_n: fr,
        expected_inertia_n: expected,
    })
}

/// The first steps of the force plots (`forces`, `energy`): the log and the model read, the
/// log's sample time, and the force balance under the zero-phase filter.
pub fn read_force_balance(
    io: &LogToolArgs,
    filter: &ZeroPhaseArgs,
    steps: &Steps,
) -> Result<(RunLog, MachineModel, f64, ForceBalance), Failure> {
    let log = read_log(&io.measured)?;
    let model = read_model(io.model.as_deref())?;
    let dt = sample_time_s(&log)?;
    steps.next("filtering");
    let fb = force_balance(&log, &model, &filter.sections(dt)?)?;
    Ok((log, model, dt, fb))
}

/// The samples of `v` in `range`, N → kN (empty where the range is out of the data).
pub fn kilonewtons(v: &[f64], range: std::ops::Range<usize>) -> Vec<f64> {
    v.get(range)
        .unwrap_or_default()
        .iter()
        .map(|f| f * 1e-3)
        .collect()
}

/// Runs `fpc-sim forces`.
pub fn main(args: ForcesArgs) -> CmdResult {
    let out = args.io.output(&["forces.svg"])?;
    let steps = Steps::new(3, "reading");
    let (log, model, dt, fb) = read_force_balance(&args.io, &args.filter, &steps)?;
    steps.next("plotting");
    let t = column(&log, "t_s", "t_s")?;
    let window = time_window(
        t,
        args.window.from_s,
        args.window.to_s,
        default_window(t, &strokes(&fb.x_m, &fb.v_mps), dt),
    )?;
    let kn = |v: &[f64]| kilonewtons(v, window.clone());
    let tw = t.get(window.clone()).unwrap_or_default();
    let curves = [
        ("unfiltered from position", kn(&fb.inertia_raw_n)),
        (
            "filtered from position (filtfilt)",
            kn(&fb.inertia_filtered_n),
        ),
        ("firmware Savitzky-Golay", kn(&fb.inertia_firmware_n)),
        ("expected inertia force", kn(&fb.expected_inertia_n)),
    ];
    let path = out.path("forces.svg");
    plot::curves(
        &path,
        "Inertia force from position (Fig. 8)",
        "t, s",
        "m·a, kN",
        tw,
        &curves,
    )
    .map_err(Failure::runtime)?;
    steps.finish();

    let max_lag = Some(((0.05 / dt).round() as usize).max(2));
    let inner = interior(log.len(), dt);
    let expected = fb.expected_inertia_n.get(inner.clone()).unwrap_or_default();
    outln!(
        "mass {} kg, A_eff {:.4e} m², {}; peak expected |m·a| {:.3} kN",
        model.piston.mass_kg,
        model.piston_area_m2(),
        args.filter.describe(),
        expected.iter().fold(0.0f64, |m, f| m.max(f.abs())) * 1e-3
    )?;
    outln!(
        "{:<36} {:>16} {:>18}",
        "m·a estimate",
        "rms vs expected N",
        "delay ms"
    )?;
    for (label, est) in [
        ("unfiltered from position", &fb.inertia_raw_n),
        ("filtered from position (filtfilt)", &fb.inertia_filtered_n),
        ("firmware Savitzky-Golay", &fb.inertia_firmware_n),
    ] {
        let est = est.get(inner.clone()).unwrap_or_default();
        let delay = xcorr_lag(expected, est, dt, max_lag).map_or(f64::NAN, |l| l.seconds);
        outln!(
            "{label:<36} {:>16.1} {:>18.4}",
            Num(rms_difference(est, expected)),
            Num(delay * 1e3)
        )?;
    }
    let shown = out.final_path("forces.svg");
    out.commit()?;
    outln!("wrote {}", shown.display())?;
    Ok(())
}
