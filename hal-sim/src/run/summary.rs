//! The JSON summary of a run: its figures, each in SI units, `null` where the run cannot
//! produce it.

use serde::Serialize;

/// Simulated seconds per wall second of `sim_time_s` simulated in `wall_s` (infinite for a
/// wall time the clock could not resolve).
pub fn realtime_factor(sim_time_s: f64, wall_s: f64) -> f64 {
    if wall_s > 0.0 {
        sim_time_s / wall_s
    } else {
        f64::INFINITY
    }
}

/// The JSON summary of a run (`docs/formats.md` §3). `None` is printed as `null`: a figure that
/// this simulation cannot yet produce is never invented.
#[derive(Clone, Debug, Default, Serialize, PartialEq)]
pub struct Summary {
    /// Simulated time, s.
    pub sim_time_s: f64,
    /// Wall-clock time of the simulation, s.
    pub wall_time_s: f64,
    /// Simulated seconds per wall second.
    pub realtime_factor: f64,
    /// Completed compression cycles.
    pub cycles: u32,
    /// Cycles asked for (`--cycles`).
    pub cycles_requested: u32,
    /// Why the run ended before `cycles_requested`, if it did (a latched fault, a stage that
    /// made no progress, the injected faults' outcome known); `null` when it completed.
    pub stopped_early: Option<String>,
    /// The `--fault` specifications the run ended before (`NAME@T`): never injected.
    pub faults_not_injected: Vec<String>,
    /// Requested pressure ratio.
    pub pressure_ratio_target: f64,
    /// Max over the last 5 cycles of |p_chamber − p_discharge|/p_discharge at discharge
    /// opening (needs the chamber model).
    pub discharge_open_pressure_error: Option<f64>,
    /// RMS of (piston position − reference) while compressing, m.
    pub tracking_error_rms_m: Option<f64>,
    /// Indicated work per cycle, ∮p·dV over both chambers, mean of the last 5 cycles, J.
    pub indicated_work_j_per_cycle: Option<f64>,
    /// Max over the last 5 cycles of |reached − target| dead point, m.
    pub dead_point_error_m: Option<f64>,
    /// Smallest distance to a head after homing, m.
    pub min_head_clearance_m: Option<f64>,
    /// Largest |velocity|, m/s.
    pub peak_speed_mps: f64,
    /// RMS of the master − slave force difference while stroking, N.
    pub master_slave_force_diff_rms_n: Option<f64>,
    /// Faults in the order latched.
    pub faults: Vec<String>,
    /// Final mode.
    pub state: String,
    /// Which controller drove the plant (`ours`, `published`).
    pub controller: String,
    /// Largest |F_master − F_slave| (the sections' reported forces) within ±5 ms of a dead
    /// point, over the last 5 cycles, N (the paper's force fight, §4.1).
    pub dead_point_force_diff_n: Option<f64>,
    /// RMS of F_master − F_slave over the RMS of F_master + F_slave while stroking.
    pub force_diff_rms_fraction: Option<f64>,
    /// Largest overshoot past a dead point toward its head over the last 5 cycles, m
    /// (negative: every dead point short of its target).
    pub overshoot_m: Option<f64>,
    /// Largest minus smallest position over the last 5 cycles, m.
    pub travel_m: Option<f64>,
    /// V_max/V_min of each chamber over the last 5 cycles, mean of A and B.
    pub volume_ratio_reached: Option<f64>,
    /// p_max/p_min of each chamber over the last 5 cycles, mean of A and B (the PR of the
    /// paper's Fig. 3 read from its p–V loops; the target is the line ratio).
    pub pv_pressure_ratio: Option<f64>,
    /// Largest |F_master + F_slave| (the sections' reported forces) over the last 5 cycles,
    /// N (the paper's "sum of both forces", §4.1, and the motor force of Fig. 9).
    pub peak_motor_force_n: Option<f64>,
    /// Frequency of the line in 340–460 Hz of the measured position error (the master
    /// encoder's position − the reference: what the rig sees of a vibration) while
    /// stroking, Hz.
    pub line_hz: Option<f64>,
    /// Its amplitude, m.
    pub line_m: Option<f64>,
    /// Its noise floor: the median amplitude 15–100 Hz either side of it, m (the line is the bin of
    /// the band that stands highest above its floor).
    pub line_floor_m: Option<f64>,
    /// As `line_hz`, with the piston held at rest before the strokes (at least 0.1 s).
    pub rest_line_hz: Option<f64>,
    /// Its amplitude, m.
    pub rest_line_m: Option<f64>,
    /// Its noise floor, m.
    pub rest_line_floor_m: Option<f64>,
    /// The position error's most prominent line in 100–2000 Hz while stroking, Hz (a limit
    /// cycle wherever it settles).
    pub wide_line_hz: Option<f64>,
    /// Its amplitude, m.
    pub wide_line_m: Option<f64>,
    /// The same at rest, Hz.
    pub rest_wide_line_hz: Option<f64>,
    /// Its amplitude, m.
    pub rest_wide_line_m: Option<f64>,
    /// Closed-port run (`--closed-port`): the highest pressure of chamber B, Pa.
    pub closed_port_peak_pa: Option<f64>,
    /// Closed-port run: chamber B's pressure at the end of the hold, Pa.
    pub closed_port_end_pa: Option<f64>,
    /// Electrical input per cycle, mean of the last 5 cycles, J: both sections' bridges'
    /// output and losses and the servo drive's draw, regeneration stored in the DC link and
    /// used again (`plant::bridge`).
    pub electrical_energy_j_per_cycle: Option<f64>,
    /// Both sections' copper loss per cycle, mean of the last 5 cycles, J.
    pub copper_loss_j_per_cycle: Option<f64>,
    /// Both bridges' loss per cycle (conduction and switching, the stated model), J.
    pub bridge_loss_j_per_cycle: Option<f64>,
    /// The servo drive's draw per cycle, J.
    pub servo_energy_j_per_cycle: Option<f64>,
    /// What the sections returned to the DC link per cycle while braking, J.
    pub regenerated_j_per_cycle: Option<f64>,
    /// The I²-losses per cycle the sections' unequal currents added (the fight's cost), J.
    pub fight_loss_j_per_cycle: Option<f64>,
    /// Indicated work over electrical input, the same cycles.
    pub efficiency: Option<f64>,
    /// A `power_cut` run: the energy the DC link held at the end of the mains outage (or of
    /// the run), J; `null` without one.
    pub link_energy_left_j: Option<f64>,
    /// A `power_cut` run: the DC link's highest voltage over the outage (regeneration, at
    /// most the chopper's threshold), V.
    pub link_peak_v: Option<f64>,
    /// A `power_cut` run: the DC link's lowest voltage over the outage, V.
    pub link_lowest_v: Option<f64>,
}
