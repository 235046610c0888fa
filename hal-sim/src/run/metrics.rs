//! The figures a run collects while it goes on, and the summary made of them when it ends.

use fpc::safety::faults::Fault;
use fpc::status::{ModeKind, Status};
use fpc::units::CONTROL_PERIOD_S;

use super::figures::{
    discharge_opening, electrical_per_cycle, indicated_work, last_max, PaperFigures,
};
use super::summary::{realtime_factor, Summary};
use super::RunOptions;
use crate::board::world::World;
use crate::failure::num;
use crate::faults::apply::InjectionReport;

/// Collects the figures while the run goes on.
#[derive(Default)]
pub(super) struct Metrics {
    dead_point_errors: Vec<f64>,
    /// (completed cycles, |p_chamber − p_d|/p_d) at each discharge opening (plant truth).
    pub(super) opening_errors: Vec<(u32, f64)>,
    tracking_sq_m2: f64,
    tracking_n: u64,
    /// Port phase of the previous cycle, rad.
    last_phase_rad: Option<f64>,
    /// Work done on the gas of both chambers at each completed cycle, J (cumulative).
    pub(super) work_at_cycle_j: Vec<f64>,
    /// Work the two motor sections did on the piston, J (cumulative since compression began).
    motor_work_j: f64,
    /// `motor_work_j` at each completed cycle.
    pub(super) motor_work_at_cycle_j: Vec<f64>,
    /// The plant's electrical energies at each completed cycle.
    electrical_at_cycle: Vec<crate::plant::bridge::ElectricalTotals>,
    extreme_m: Option<f64>,
    min_clearance_m: Option<f64>,
    peak_speed_mps: f64,
    force_diff_sq: f64,
    force_diff_n: u64,
    paper: PaperFigures,
    faults: Vec<Fault>,
    /// The homing command went out.
    pub(super) home_sent: bool,
}

/// How a run ended, as its driver saw it.
pub(super) struct RunEnd {
    /// Simulated time, s.
    pub(super) sim_time_s: f64,
    /// Wall-clock time of the loop alone, s.
    pub(super) wall_time_s: f64,
    /// Completed compression cycles.
    pub(super) cycles_done: u32,
    /// Why the run stopped, when it was not a latched fault or the last cycle.
    pub(super) stop_reason: Option<String>,
    /// The firmware's last mode.
    pub(super) last_mode: ModeKind,
}

impl Metrics {
    /// Every control period: the faults latched, the peak speed, and while `stroking` the
    /// discharge openings (counted against `cycles_done`), the tracking error and the
    /// sections' work; while `homing`, the figures at rest. `fresh`: the status was seen this
    /// period (a stale one counts for the plant's figures only).
    pub(super) fn observe(
        &mut self,
        w: &World,
        status: &Status,
        fresh: bool,
        stroking: bool,
        homing: bool,
        cycles_done: u32,
    ) {
        // `iter` walks every kind of fault: only when one is latched.
        if !status.faults.is_empty() {
            for f in status.faults.iter() {
                if !self.faults.contains(&f) {
                    self.faults.push(f);
                }
            }
        }
        self.peak_speed_mps = self.peak_speed_mps.max(w.plant.v_mps.abs());
        if stroking {
            if let Some(e) = discharge_opening(&w.plant, self.last_phase_rad) {
                self.opening_errors.push((cycles_done, e));
            }
            if fresh {
                let e = w.plant.x_m - f64::from(status.reference_m);
                self.tracking_sq_m2 += e * e;
                self.tracking_n += 1;
            }
            self.motor_work_j += (w.plant.force_n.master + w.plant.force_n.slave)
                * w.plant.v_mps
                * f64::from(CONTROL_PERIOD_S);
        }
        self.last_phase_rad = Some(w.plant.port_phase_rad());
        if homing && fresh {
            self.paper
                .before_strokes(f64::from(status.position_m), status.reference_m);
        }
    }

    /// While stroking toward head B (`toward_b`) or A, at `t_s`: the head clearance, the
    /// force difference and the paper's figures (from a `fresh` status), the stroke's extreme.
    pub(super) fn stroking(
        &mut self,
        w: &World,
        status: &Status,
        fresh: bool,
        t_s: f64,
        toward_b: bool,
    ) {
        let x = w.plant.x_m;
        let c = w.plant.head_clearance_m();
        self.min_clearance_m = Some(self.min_clearance_m.map_or(c, |m: f64| m.min(c)));
        if fresh {
            let diff = f64::from(status.force_master_n - status.force_slave_n);
            self.force_diff_sq += diff * diff;
            self.force_diff_n += 1;
            self.paper.stroking(
                t_s,
                f64::from(status.position_m - status.reference_m),
                f64::from(status.force_master_n),
                f64::from(status.force_slave_n),
                &w.plant,
            );
        }
        self.extreme_m = Some(match self.extreme_m {
            None => x,
            Some(e) if toward_b => e.max(x),
            Some(e) => e.min(x),
        });
    }

    /// The reference turned at `t_s`: the stroke toward B (`toward_b`) or A ended at its
    /// extreme (`x_m`, the position now, if none was seen), `target_m` the dead point aimed at.
    pub(super) fn dead_point(&mut self, x_m: f64, target_m: f64, toward_b: bool, t_s: f64) {
        let reached = self.extreme_m.take().unwrap_or(x_m);
        self.dead_point_errors.push((reached - target_m).abs());
        let overshoot = if toward_b {
            reached - target_m
        } else {
            target_m - reached
        };
        self.paper.dead_point(t_s, overshoot);
    }

    /// A compression cycle completed: the energies so far.
    pub(super) fn cycle_done(&mut self, w: &World) {
        let c = &w.plant.chambers;
        self.work_at_cycle_j
            .push(c.a.totals.work_on_gas_j + c.b.totals.work_on_gas_j);
        self.motor_work_at_cycle_j.push(self.motor_work_j);
        self.electrical_at_cycle.push(w.plant.electrical);
        self.paper.cycle_done();
    }

    /// Why a run of `opts` that ended as `end` stopped before its cycles were done (`None`
    /// when it did not): the faults latched first, else the driver's reason.
    fn stopped_early(&self, opts: &RunOptions, end: &RunEnd) -> Option<String> {
        (end.cycles_done < opts.cycles).then(|| {
            let names: Vec<&str> = self.faults.iter().map(|f| f.name()).collect();
            match (names.is_empty(), end.stop_reason.clone()) {
                (false, _) => format!("faults latched: {}", names.join(", ")),
                (true, Some(why)) => why,
                (true, None) => "the run ended early".to_string(),
            }
        })
    }

    /// The summary of the run of `opts` that ended as `end` (the paper's figures are taken).
    pub(super) fn summary(
        &mut self,
        opts: &RunOptions,
        end: &RunEnd,
        injection: &InjectionReport,
    ) -> Summary {
        let RunEnd {
            sim_time_s,
            wall_time_s: wall,
            cycles_done,
            ..
        } = *end;
        let last5 = self.dead_point_errors.len().saturating_sub(10);
        let paper = std::mem::take(&mut self.paper).finish();
        let indicated = indicated_work(&self.work_at_cycle_j);
        let electrical = electrical_per_cycle(&self.electrical_at_cycle);
        Summary {
            sim_time_s,
            wall_time_s: wall,
            realtime_factor: realtime_factor(sim_time_s, wall),
            cycles: cycles_done,
            cycles_requested: opts.cycles,
            stopped_early: self.stopped_early(opts, end),
            faults_not_injected: opts
                .faults
                .iter()
                .filter(|f| f.at_s > sim_time_s)
                .map(|f| format!("{}@{}", f.kind.name(), num(f.at_s)))
                .collect(),
            pressure_ratio_target: opts.pressure_ratio,
            discharge_open_pressure_error: last_max(
                &self
                    .opening_errors
                    .iter()
                    .map(|(_, e)| *e)
                    .collect::<Vec<_>>(),
                10,
            ),
            tracking_error_rms_m: (self.tracking_n > 0)
                .then(|| (self.tracking_sq_m2 / self.tracking_n as f64).sqrt()),
            indicated_work_j_per_cycle: indicated,
            dead_point_error_m: self
                .dead_point_errors
                .get(last5..)
                .and_then(|e| e.iter().copied().reduce(f64::max)),
            min_head_clearance_m: self.min_clearance_m,
            peak_speed_mps: self.peak_speed_mps,
            master_slave_force_diff_rms_n: (self.force_diff_n > 0)
                .then(|| (self.force_diff_sq / self.force_diff_n as f64).sqrt()),
            faults: self.faults.iter().map(|f| f.name().to_string()).collect(),
            state: end.last_mode.name().to_string(),
            controller: opts.controller.name().to_string(),
            dead_point_force_diff_n: paper.dead_point_force_diff_n,
            force_diff_rms_fraction: paper.force_diff_rms_fraction,
            overshoot_m: paper.overshoot_m,
            travel_m: paper.travel_m,
            volume_ratio_reached: paper.volume_ratio_reached,
            pv_pressure_ratio: paper.pv_pressure_ratio,
            peak_motor_force_n: paper.peak_motor_force_n,
            line_hz: paper.line_hz,
            line_m: paper.line_m,
            line_floor_m: paper.line_floor_m,
            rest_line_hz: paper.rest_line_hz,
            rest_line_m: paper.rest_line_m,
            rest_line_floor_m: paper.rest_line_floor_m,
            wide_line_hz: paper.wide_line_hz,
            wide_line_m: paper.wide_line_m,
            rest_wide_line_hz: paper.rest_wide_line_hz,
            rest_wide_line_m: paper.rest_wide_line_m,
            closed_port_peak_pa: None,
            closed_port_end_pa: None,
            electrical_energy_j_per_cycle: electrical.map(|e| e.input_j()),
            copper_loss_j_per_cycle: electrical.map(|e| e.copper_total_j()),
            bridge_loss_j_per_cycle: electrical.map(|e| e.bridge_loss_total_j()),
            servo_energy_j_per_cycle: electrical.map(|e| e.servo_j),
            regenerated_j_per_cycle: electrical.map(|e| e.regenerated_j),
            fight_loss_j_per_cycle: electrical.map(|e| e.fight_j),
            efficiency: indicated
                .zip(electrical)
                .and_then(|(w, e)| (e.input_j() > 0.0).then(|| w / e.input_j())),
            link_energy_left_j: injection.link.map(|l| l.energy_left_j),
            link_peak_v: injection.link.map(|l| l.peak_v),
            link_lowest_v: injection.link.map(|l| l.lowest_v),
        }
    }
}
