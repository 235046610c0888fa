use fpc::control::command::Command;
use fpc::motion::synchroniser::Rotation;
use hal_sim::faults::inject::parse;
use hal_sim::plant::model::MachineModel;
use hal_sim::run::{run, HostAction, RunOptions};

#[test]
fn trace() {
    let spec = std::env::var("SPEC").unwrap();
    let pr: f64 = std::env::var("PR").unwrap().parse().unwrap();
    let mass: f64 = std::env::var("MASS").unwrap().parse().unwrap();
    let seed: u64 = std::env::var("SEED").unwrap().parse().unwrap();
    let step: usize = std::env::var("STEP")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(20);
    let mut o = RunOptions::reference();
    o.pressure_ratio = pr;
    o.cycles = 20;
    o.seed = seed;
    o.start_position_m = 0.002;
    o.faults = vec![parse(&spec).unwrap()];
    if std::env::var("EXP").is_ok() {
        o.schedule = vec![(
            0,
            HostAction::Command(Command::SetRotation {
                rotation: Rotation::Expander,
            }),
        )];
    }
    o.model = MachineModel::reference();
    o.model.piston.mass_kg *= mass;
    o.configure = Some(|config| config.moving_mass_kg = 12.0);
    let out = run(&o).unwrap();
    let r = &out.injection;
    println!(
        "min clearance {:?} fault {:?} onset {:?} off {:?}",
        r.min_clearance_m,
        r.first_fault_after_onset(),
        r.first_onset_us(),
        r.outputs_off_us
    );
    let l = &out.log;
    let c = |n: &str| l.column(n).unwrap();
    let (t, x, v, th, thr, fm, fs, pa, pb, f, pd) = (
        c("t_s"),
        c("vol_a_m3"),
        c("v_mps"),
        c("theta_rad"),
        c("theta_ref_rad"),
        c("f_master_n"),
        c("f_slave_n"),
        c("p_a_true_pa"),
        c("p_b_true_pa"),
        c("fault"),
        c("p_discharge_pa"),
    );
    let t0 = r.first_onset_us().unwrap() as f64 * 1e-6 - 0.005;
    for i in (0..t.len()).step_by(step) {
        if t[i] < t0 {
            continue;
        }
        println!("{:.4} x {:7.2}mm v {:+6.3} th {:6.1} ref {:6.1} F {:+7.0} pa {:5.2} pb {:5.2} pd {:4.2} f {}", t[i], x[i]/6.0476e-3*1e3-0.5, v[i], th[i].to_degrees().rem_euclid(360.0), thr[i].to_degrees().rem_euclid(360.0), fm[i]+fs[i], pa[i]*1e-5, pb[i]*1e-5, pd[i]*1e-5, f[i]);
    }
}
