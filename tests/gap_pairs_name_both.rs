//! Two effects hidden at once, in the same channel or in different ones: the forward
//! selection names both, and fits each near its truth.

mod support;

use hal_sim::gap::synth;
use hal_sim::plant::model::MachineModel;
use support::gap::*;

fn sorted(mut v: Vec<String>) -> Vec<String> {
    v.sort();
    v
}

#[test]
fn gap_names_cogging_and_a_slave_lag_together() {
    let truth = format!(
        "{}\n[effects.slave_lag]\ndelay_s = 0.00075\n",
        with_key(&cogging_truth(), "motor", "slave_follows_master", "true")
    );
    let model = without_section(&reference(), "effects.cogging");
    let j = gap(&model, &closed_loop(&truth, 2.3, 3, 31));
    show("cogging + slave_lag", &j);
    assert_eq!(sorted(names(&j)), ["cogging", "slave_lag"]);
    assert!((param(&j, "cogging", "period_m") - 0.024).abs() < 0.02 * 0.024);
    assert!((param(&j, "slave_lag", "delay_s") - 0.75e-3).abs() < 0.1e-3);
}

#[test]
#[ignore = "slow: three more pairs"]
fn gap_names_both_of_three_more_pairs() {
    // Same channel: a wrong mass and cogging.
    let truth = with_key(&cogging_truth(), "piston", "mass_kg", "15.0");
    let model = without_section(&reference(), "effects.cogging");
    let j = gap(&model, &closed_loop(&truth, 2.3, 3, 32));
    show("mass + cogging", &j);
    assert_eq!(sorted(names(&j)), ["cogging", "mass_error"]);
    assert!((param(&j, "mass_error", "mass_kg") - 15.0).abs() < 0.03 * 15.0);

    // Same channel, both lags of the force: an actuator lag and more viscous friction.
    let truth = format!(
        "{}\n[effects.actuator_lag]\ndelay_s = 0.0005\n",
        with_key(&reference(), "friction", "viscous_ns_per_m", "100.0")
    );
    let j = gap(&reference(), &closed_loop(&truth, 4.0, 3, 33));
    show("actuator_lag + viscous", &j);
    assert_eq!(sorted(names(&j)), ["actuator_lag", "viscous_friction"]);
    assert!((param(&j, "actuator_lag", "delay_s") - 0.5e-3).abs() < 0.1e-3);

    // The pressure channel: leakage and heat transfer both missing.
    let m = MachineModel::reference();
    let (start, moves) = synth::closed_port_moves(&m, 2);
    let log = synth::closed_port_run(&m, start, &moves, 34);
    let model = without_section(
        &without_section(&reference(), "effects.leakage"),
        "effects.heat_transfer",
    );
    let j = gap(&model, &log);
    show("leakage + heat_transfer", &j);
    assert_eq!(sorted(names(&j)), ["heat_transfer", "leakage"]);
    assert!((param(&j, "leakage", "gap_m") - 25e-6).abs() < 0.1 * 25e-6);
    assert!((param(&j, "heat_transfer", "ua_w_per_k") - 5.0).abs() < 0.1 * 5.0);
}

#[test]
#[ignore = "slow: two compression runs with the ports timed by the rotation"]
fn gap_names_a_port_restriction_and_a_leak_on_timed_ports() {
    // Both act on the pressure channel while the ports are timed: the restriction while a
    // port is open, the leak while both are shut. Fast at a low ratio, slow at a high one.
    let truth = format!(
        "{}\n[effects.port_restriction]\narea_scale = 0.4\n",
        reference()
    );
    let model = without_section(&reference(), "effects.leakage");
    for (pressure_ratio, speed, seed) in [(3.1, 2.3, 40), (4.5, 0.6, 41)] {
        let j = gap(&model, &compressing(&truth, pressure_ratio, speed, 3, seed));
        show(
            &format!("port_restriction + leakage, PR {pressure_ratio}, {speed} m/s"),
            &j,
        );
        assert_eq!(sorted(names(&j)), ["leakage", "port_restriction"]);
        assert!((param(&j, "port_restriction", "area_scale") - 0.4).abs() < 0.05 * 0.4);
        assert!((param(&j, "leakage", "gap_m") - 25e-6).abs() < 0.1 * 25e-6);
        assert!(shrink(&j, "pressure") >= 0.9);
    }
}
