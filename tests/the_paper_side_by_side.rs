//! The paper's claims that the simulator's published rig (`--controller published`) makes as
//! results, not inputs, each with the margin it holds by (`docs/paper.md`,
//! `docs/paper-numbers.md`). Each assertion fails if the baseline loses the problem it
//! shows: the lag removed, the loop tuned soft, the encoders' noise made the cause.
//!
//! - the force fight is the slave's lag (none without it) and costs next to no energy at the
//!   commissioned gain;
//! - tuned harder, the loop self-excites while stroking, only with the lag: at the motor's own
//!   current limit at 180 Hz (its harmonic in the paper's 340–460 Hz band), its summed force
//!   swinging to the ±10 kN of §4.1; clamped at 20 A, at twice that, near the paper's 400 Hz;
//! - Fig. 3's loops: ours reach the figure's pressure ratios, the published drives do not;
//! - the encoders' noise is a quarter of the fight at PR 3.1, not most of it;
//! - the electrical accounting closes: what the bridges deliver less the copper loss is the
//!   motors' work on the piston.

use hal_sim::plant::model::MachineModel;
use hal_sim::run::{run, Controller, RunOptions, RunOutcome, Summary};

/// A line "above the noise floor" (as `the_published_rigs_problems_appear_and_ours_remove_them`).
const LINE_PROMINENCE: f64 = 5.0;

fn run_at(model: &MachineModel, controller: Controller, pr: f64, cycles: u32) -> RunOutcome {
    let opts = RunOptions {
        model: model.clone(),
        controller,
        pressure_ratio: pr,
        cycles,
        ..RunOptions::reference()
    };
    let out = run(&opts).unwrap_or_else(|e| panic!("{controller:?} at PR {pr}: {e}"));
    assert_eq!(
        out.summary.cycles, cycles,
        "{:?}",
        out.summary.stopped_early
    );
    out
}

fn f(v: Option<f64>) -> f64 {
    v.unwrap_or(f64::NAN)
}

#[test]
fn the_force_fight_is_the_slaves_lag_and_costs_little_energy_at_the_commissioned_gain() {
    let model = MachineModel::reference();
    let published = run_at(&model, Controller::Published, 5.1, 8).summary;
    let ours = run_at(&model, Controller::Ours, 5.1, 8).summary;
    let mut no_lag = model.clone();
    no_lag.published.slave_lag_s = 0.0;
    let without = run_at(&no_lag, Controller::Published, 5.1, 8).summary;
    let (fight, none) = (
        f(published.dead_point_force_diff_n),
        f(without.dead_point_force_diff_n),
    );
    println!(
        "PR 5.1: fight {fight:.0} N with the lag, {none:.1} N without; its I²-loss {:.3} J of \
         {:.1} J a cycle (ours {:.4} J of {:.1} J)",
        f(published.fight_loss_j_per_cycle),
        f(published.electrical_energy_j_per_cycle),
        f(ours.fight_loss_j_per_cycle),
        f(ours.electrical_energy_j_per_cycle)
    );
    // Measured 615 N and 0 N: the lag is the whole fight.
    assert!((500.0..=1000.0).contains(&fight), "{fight} N");
    assert!(none < 0.05 * fight, "{none} N");
    // The fight's cost: tens of times ours, yet under 1 % of the input (measured ≈ 0.03 %).
    let cost = f(published.fight_loss_j_per_cycle);
    assert!(
        cost > 10.0 * f(ours.fight_loss_j_per_cycle).max(1e-4),
        "{cost} J"
    );
    assert!(
        cost < 0.01 * f(published.electrical_energy_j_per_cycle),
        "{cost} J"
    );
}

/// The published drives tuned hard (80 kN·s/m: above the gain where the lagged loop rings,
/// ≈ 45–60 kN·s/m here, below where the loop without the lag would), at `current_limit_a`
/// (0: the motor's own 62.5 A).
fn tuned_hard(slave_lag_s: f64, current_limit_a: f64) -> Summary {
    let mut m = MachineModel::reference();
    m.published.velocity_gain_ns_per_m = 80_000.0;
    m.published.slave_lag_s = slave_lag_s;
    m.published.current_limit_a = current_limit_a;
    run_at(&m, Controller::Published, 3.1, 4).summary
}

#[test]
fn tuned_harder_the_loop_rings_at_a_frequency_its_current_clamp_sets_only_with_the_slaves_lag() {
    // 0 A: the motor's own 62.5 A.
    let with = tuned_hard(0.75e-3, 0.0);
    let clamped = tuned_hard(0.75e-3, 20.0);
    let without = tuned_hard(0.0, 0.0);
    for (name, s) in [
        ("with the lag", &with),
        ("with the lag, 20 A", &clamped),
        ("without", &without),
    ] {
        println!(
            "80 kN·s/m, PR 3.1, {name}: line {:.0} Hz, {:.2} µm ({:.1}× floor); strongest line \
             100–2000 Hz {:.0} Hz, {:.2} µm; summed force up to {:.2} kN; copper loss {:.0} J a cycle",
            f(s.line_hz),
            1e6 * f(s.line_m),
            f(s.line_m) / f(s.line_floor_m),
            f(s.wide_line_hz),
            1e6 * f(s.wide_line_m),
            1e-3 * f(s.peak_motor_force_n),
            f(s.copper_loss_j_per_cycle)
        );
    }
    // With the lag at the motor's 62.5 A (measured: strongest line 180 Hz, the drives' summed
    // force at their ±10 kN limit; in the paper's 340–460 Hz band only its second harmonic,
    // 357 Hz, 10.8 µm, 72× its floor). docs/paper.md, "The line's frequency": 136–187 Hz at
    // 62.5 A over the drives' cycle, bandwidth and filter.
    assert!((130.0..=200.0).contains(&f(with.wide_line_hz)));
    assert!((f(with.line_hz) - 2.0 * f(with.wide_line_hz)).abs() < 10.0);
    assert!(f(with.line_m) / f(with.line_floor_m) > 4.0 * LINE_PROMINENCE);
    assert!(f(with.peak_motor_force_n) > 9000.0);
    // The clamp sets the frequency: at 20 A the strongest line moves up toward the paper's
    // ≈ 400 Hz (docs/paper.md: 189–355 Hz at 20 A; at least 1.5× the 62.5 A line here).
    assert!(f(clamped.wide_line_hz) > 1.5 * f(with.wide_line_hz));
    // Without the lag (measured 2.7× floor, 0.19 µm): nothing stands out.
    assert!(f(without.line_m) / f(without.line_floor_m) < LINE_PROMINENCE);
    assert!(f(without.line_m) < 1e-6);
    // The ringing is what costs energy (measured 1168 J against 26 J of copper loss).
    assert!(f(with.copper_loss_j_per_cycle) > 10.0 * f(without.copper_loss_j_per_cycle));
}

#[test]
fn fig_3s_pressure_ratios_are_ours_and_the_published_drives_overshoot_them() {
    let model = MachineModel::reference();
    for pr in [3.1, 3.7, 4.3, 5.1] {
        let o = run_at(&model, Controller::Ours, pr, 8).summary;
        let p = run_at(&model, Controller::Published, pr, 8).summary;
        let (lo, lp) = (f(o.pv_pressure_ratio), f(p.pv_pressure_ratio));
        println!("PR {pr}: loop ratio ours {lo:.2}, published {lp:.2}");
        // Ours: the line's ratio plus the discharge's flow overpressure (measured +2–4 %).
        assert!(lo >= pr && lo <= 1.06 * pr, "{lo}");
        // Published: the rotation programmed on the reference while the stroke overshoots
        // (measured +35–41 %): not the paper's figure, and flagged so in docs/paper.md.
        assert!(lp > 1.25 * pr, "{lp}");
    }
}

#[test]
fn the_encoders_noise_is_a_quarter_of_the_fight_at_the_slowest_point() {
    let model = MachineModel::reference();
    let mut quiet = model.clone();
    quiet.sensors.encoder_master.noise_codes = 0.0;
    quiet.sensors.encoder_slave.noise_codes = 0.0;
    let noisy = f(run_at(&model, Controller::Published, 3.1, 8)
        .summary
        .dead_point_force_diff_n);
    let clean = f(run_at(&quiet, Controller::Published, 3.1, 8)
        .summary
        .dead_point_force_diff_n);
    println!("PR 3.1: fight {noisy:.0} N with the encoders' noise, {clean:.0} N without");
    // Measured 181 N and 135 N: the lag's part stays; the noise adds a quarter.
    assert!(
        clean > 0.6 * noisy && clean < 0.9 * noisy,
        "{clean} of {noisy} N"
    );
}

#[test]
fn what_the_bridges_deliver_less_the_copper_loss_is_the_motors_work_on_the_piston() {
    let model = MachineModel::reference();
    for controller in [Controller::Ours, Controller::Published] {
        let out = run_at(&model, controller, 4.3, 6);
        let s = &out.summary;
        let k = out.cycle_motor_work_j.len();
        let mech: f64 = out.cycle_motor_work_j[k - 5..].iter().sum::<f64>() / 5.0;
        let delivered = f(s.electrical_energy_j_per_cycle)
            - f(s.bridge_loss_j_per_cycle)
            - f(s.servo_energy_j_per_cycle);
        let into_motion = delivered - f(s.copper_loss_j_per_cycle);
        println!(
            "{controller:?}: delivered {delivered:.2} J, copper {:.2} J, motors' work \
             {mech:.2} J a cycle; efficiency {:.3}",
            f(s.copper_loss_j_per_cycle),
            f(s.efficiency)
        );
        assert!(
            (into_motion - mech).abs() < 0.01 * mech,
            "{into_motion} vs {mech} J"
        );
        assert!(f(s.efficiency) > 0.5 && f(s.efficiency) < 1.0);
    }
}
