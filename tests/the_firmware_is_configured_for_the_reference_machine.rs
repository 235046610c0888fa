//! The flashed firmware has no machine model: it runs `ControlConfig::reference()`, with the
//! calibration record from its flash on top. The simulator's runs derive their controller
//! configuration from the machine model (`hal_sim::run::control_config`). Both must describe
//! the same reference machine, or the simulator proves a controller that is not the one a
//! user flashes: with the servo drive's full scale at 5 N·m in the firmware and 20 N·m in the
//! model, the flashed binary commanded 4× the torque it meant (found by `fpc-pil run`, whose
//! ELF then drifted 61 µm RMS from the host build; now bit for bit the same trajectory).

use fpc::control::config::ControlConfig;
use hal_sim::plant::model::MachineModel;

#[test]
fn the_built_in_configuration_is_the_reference_models_but_for_the_calibration() {
    let flashed = ControlConfig::reference();
    let mut modelled = hal_sim::run::control_config(&MachineModel::reference());
    // What the calibration record brings at boot (`CalibrationRecord::apply`): the cogging
    // map the routine measures. The model's true map stands in for it in the simulator.
    modelled.allocation.cogging = flashed.allocation.cogging;
    let (a, b) = (format!("{flashed:#?}"), format!("{modelled:#?}"));
    let differences: Vec<String> = a
        .lines()
        .zip(b.lines())
        .enumerate()
        .filter(|(_, (x, y))| x != y)
        .map(|(i, (x, y))| format!("line {i}: firmware `{}`, model `{}`", x.trim(), y.trim()))
        .collect();
    assert!(differences.is_empty(), "{differences:#?}");
    assert_eq!(flashed, modelled);
}
