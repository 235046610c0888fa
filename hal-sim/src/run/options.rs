//! What a run is asked to do: the accepted ranges, [`RunOptions`] and their checks, and the
//! controller configuration and simulated board a model gives.

use fpc::control::command::Command;
use fpc::control::config::ControlConfig;
use fpc::motion::volume_ratio::RatioTarget;

use crate::board::exec::WATCHDOG_TIMEOUT_US;
use crate::board::world::World;
use crate::failure::num;
use crate::faults::inject::FaultSpec;
use crate::plant::chambers::PortMode;
use crate::plant::model::validate::PRESSURE_FULL_SCALE_PA;
use crate::plant::model::MachineModel;

/// Pressure ratio → peak speed of the paper's Fig. 3 (PR, m/s).
pub const FIG3_SPEEDS: [(f64, f64); 4] = [(3.1, 2.3), (3.7, 2.8), (4.3, 3.5), (5.1, 4.1)];

/// Accepted pressure ratios. Near 1 the volume ratio is so near 1 that the discharge port
/// opens almost as the intake closes, and at speed the rotation cannot time the ports: the
/// run stops on `rotation_sync` (measured on the reference machine: 1.0–1.05 at every
/// speed, 1.1 from 2.8 m/s, 1.2 from 4 m/s, 1.3 and 1.4 at 4.5 m/s within 10 cycles; 1.5
/// runs 100 cycles clean at 0.05–4.5 m/s).
pub const PRESSURE_RATIO_RANGE: (f64, f64) = (1.5, 6.0);
/// Accepted peak speeds, m/s (and never above the model's `limits.max_speed_mps`).
pub const SPEED_RANGE_MPS: (f64, f64) = (0.05, 4.5);
/// Accepted `--cycles`: at least one; the upper bound keeps a run's wall time within about
/// an hour at the slowest speed.
pub const CYCLES_RANGE: (u32, u32) = (1, 10_000);
/// Homing creeps at about this speed, m/s: the time it may take is the travel at this
/// speed, plus [`STALL_SPARE_S`].
pub const HOMING_SPEED_MPS: f64 = 0.01;
/// Spare time for each stage of a run (homing, a cycle, the stop), s simulated: a stage
/// that takes longer than its expected time plus this has stalled, and the run ends
/// saying so rather than running out the whole run's time.
pub const STALL_SPARE_S: f64 = 2.0;

/// How far the section forces in a run-log row lag its position, s (`# force_delay_s`):
/// the firmware's convention ([`fpc::link::telemetry::FORCE_DELAY_PERIODS`], one control
/// period — its status reports each section's force from the current measured in the
/// previous cycle), the same its telemetry declares.
pub const FIRMWARE_FORCE_DELAY_S: f64 = (fpc::link::telemetry::FORCE_DELAY_PERIODS
    * fpc::link::telemetry::CONTROL_PERIOD_US) as f64
    / 1e6;

/// The control rate, Hz: one run-log row per control cycle at most.
pub const CONTROL_RATE_HZ: u32 = 1_000_000 / fpc::units::CONTROL_PERIOD_US;

/// Accepted design pressure ratios of a fixed volume ratio (`--volume-ratio fixed:PR`): the
/// firmware's own range for `SetVolumeRatio` (a ratio of 1 would open the discharge at the
/// bottom dead point).
pub const FIXED_RATIO_RANGE: (f64, f64) = (1.05, 10.0);

/// Parses a volume-ratio mode: `adaptive` (follow the measured pressure ratio, the machine's
/// purpose) or `fixed:PR` (a conventional compressor's built-in volume ratio, designed for
/// the pressure ratio PR).
pub fn parse_volume_ratio(text: &str) -> Result<RatioTarget, String> {
    let bad = |why: &str| format!("--volume-ratio {}: {why}", crate::output::clip(text, 40));
    let t = text.trim();
    if t == "adaptive" {
        return Ok(RatioTarget::FollowMeasured);
    }
    let Some(pr) = t.strip_prefix("fixed:") else {
        return Err(bad(
            "must be `adaptive` or `fixed:PR` (PR the design pressure ratio)",
        ));
    };
    let (lo, hi) = FIXED_RATIO_RANGE;
    match pr.trim().parse::<f64>() {
        Ok(v) if v.is_finite() && (lo..=hi).contains(&v) => Ok(RatioTarget::Fixed {
            pressure_ratio: v as f32,
        }),
        _ => Err(bad(&format!(
            "the design pressure ratio must be a number in [{lo}, {hi}]"
        ))),
    }
}

/// Parses the machine's mode (`run --rotation`, the sweep's `rotation` axis): `compressor`
/// (the rotation times the ports to compress, the default) or `expander` (the firmware's
/// `SetRotation` command before the first stroke: the same ports timed the other way round).
pub fn parse_rotation(text: &str) -> Result<fpc::motion::synchroniser::Rotation, String> {
    use fpc::motion::synchroniser::Rotation;
    match text.trim() {
        "compressor" => Ok(Rotation::Compressor),
        "expander" => Ok(Rotation::Expander),
        other => Err(format!(
            "--rotation {}: must be `compressor` or `expander`",
            crate::output::clip(other, 40)
        )),
    }
}

/// Runs `opts` with the machine in `rotation`'s mode: an expander is told so before the
/// first stroke, as the fault sweeps run it. The published drives' program knows no
/// expander: refused.
pub fn set_rotation(
    opts: &mut RunOptions,
    rotation: fpc::motion::synchroniser::Rotation,
) -> Result<(), String> {
    use fpc::motion::synchroniser::Rotation;
    if rotation == Rotation::Compressor {
        return Ok(());
    }
    if opts.controller == Controller::Published {
        return Err(
            "--rotation expander: the published drives' program times the ports as a \
             compressor only (give --controller ours)"
                .into(),
        );
    }
    opts.schedule.insert(
        0,
        (0, HostAction::Command(Command::SetRotation { rotation })),
    );
    Ok(())
}

/// How a volume-ratio mode is written (`--volume-ratio`, the log's `# volume_ratio`).
pub fn volume_ratio_name(target: RatioTarget) -> String {
    match target {
        RatioTarget::FollowMeasured => "adaptive".into(),
        RatioTarget::Fixed { pressure_ratio } => format!("fixed:{pressure_ratio}"),
    }
}

/// Which controller drives the plant.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Controller {
    /// This project's firmware, its task bodies on the simulated board.
    #[default]
    Ours,
    /// The published rig's master/slave drives ([`crate::published`]), from the model's
    /// `[published]` section.
    Published,
}

impl Controller {
    /// Parses `ours` or `published` (`--controller`, the sweep's `controller` axis).
    pub fn parse(text: &str) -> Result<Controller, String> {
        match text.trim() {
            "ours" => Ok(Controller::Ours),
            "published" => Ok(Controller::Published),
            other => Err(format!(
                "--controller {}: must be `ours` (this firmware) or `published` (the paper's \
                 master/slave drives)",
                crate::output::clip(other, 40)
            )),
        }
    }

    /// Its name, as `--controller` takes it.
    pub fn name(self) -> &'static str {
        match self {
            Controller::Ours => "ours",
            Controller::Published => "published",
        }
    }
}

/// Options of a run.
#[derive(Clone, Debug)]
pub struct RunOptions {
    /// The machine.
    pub model: MachineModel,
    /// Where the model came from (for the log's metadata).
    pub model_name: String,
    /// Target pressure ratio.
    pub pressure_ratio: f64,
    /// Peak speed, m/s (`None`: from the pressure ratio as in Fig. 3).
    pub speed_mps: Option<f64>,
    /// Compression cycles (A → B → A) to run.
    pub cycles: u32,
    /// Noise seed.
    pub seed: u64,
    /// What the board's µs time base reads at the start (to exercise its wrap).
    pub start_us: u32,
    /// Where the piston rests at power-up, m from head A.
    pub start_position_m: f64,
    /// Telemetry: one frame every this many control cycles, captured in
    /// [`RunOutcome::telemetry`]; 0 = off.
    pub telemetry_decimation: u16,
    /// The channels the telemetry frames carry (the firmware's default: the seven a run log
    /// needs).
    pub telemetry_channels: fpc::link::telemetry::ChannelSet,
    /// Relative error of the controller's model against the plant: its mass and friction
    /// are (1 + this) × the plant's (the acceptance runs use 0.05).
    pub model_error: f64,
    /// The controller's configuration is otherwise the reference; this may change it (tests
    /// switch the feed-forward off with it).
    pub configure: Option<fn(&mut ControlConfig)>,
    /// What the host does during the run, by completed compression cycle.
    pub schedule: Vec<(u32, HostAction)>,
    /// Faults injected during the run (`--fault`; `docs/faults.md` scenarios). With faults the
    /// run does not end at the first latched fault: it runs on until each fault's outcome
    /// (the stop, the piston at rest, homing's end) is known.
    pub faults: Vec<FaultSpec>,
    /// Timeout of the board's independent watchdog, µs (the board's
    /// [`crate::board::exec::WATCHDOG_TIMEOUT_US`]; a run may try another).
    pub watchdog_timeout_us: u64,
    /// Time from a reset of the MCU to its first control cycle, µs (the board's
    /// [`crate::board::exec::BOOT_US`]; a run may try another).
    pub boot_us: u64,
    /// How the volume ratio is chosen (`--volume-ratio`): sent to the firmware before the
    /// first stroke when fixed.
    pub volume_ratio: RatioTarget,
    /// Rows of the run log per second (`--log-rate`): the control rate or a whole divisor
    /// of it.
    pub log_rate_hz: u32,
    /// A stored calibration (`--calibration`): the board's flash holds it and the firmware
    /// loads it at boot, instead of the controller being handed the model's true cogging.
    pub calibration: Option<fpc::control::calibration::record::CalibrationRecord>,
    /// Which controller drives the plant (`--controller`).
    pub controller: Controller,
    /// The paper's closed-port test instead of compression cycles (`--closed-port`; the
    /// published drives only).
    pub closed_port: Option<super::closed::ClosedPort>,
}

/// Something the host does at the start of a given cycle.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum HostAction {
    /// Change the discharge-line pressure to this ratio over the suction pressure (the load).
    SetLinePressureRatio(f64),
    /// Send a command to the firmware.
    Command(Command),
    /// Open both chambers to the suction line whatever the rotation (the start-up bypass
    /// kept open: strokes without compression, the paper's Figs. 5 and 6 "no compression").
    UnloadPorts,
}

impl RunOptions {
    /// Defaults on the reference machine.
    pub fn reference() -> Self {
        RunOptions {
            model: MachineModel::reference(),
            model_name: "reference".into(),
            pressure_ratio: 3.1,
            speed_mps: None,
            cycles: 10,
            seed: 1,
            start_us: 0,
            start_position_m: 0.005,
            telemetry_decimation: 0,
            telemetry_channels: fpc::link::telemetry::DEFAULT_CHANNELS,
            model_error: 0.0,
            configure: None,
            schedule: Vec::new(),
            faults: Vec::new(),
            watchdog_timeout_us: WATCHDOG_TIMEOUT_US,
            boot_us: crate::board::exec::BOOT_US,
            volume_ratio: RatioTarget::FollowMeasured,
            log_rate_hz: CONTROL_RATE_HZ,
            calibration: None,
            controller: Controller::Ours,
            closed_port: None,
        }
    }

    /// Peak speed to use, m/s.
    pub fn peak_speed_mps(&self) -> f64 {
        self.speed_mps
            .unwrap_or_else(|| speed_for_pressure_ratio(self.pressure_ratio))
    }

    /// The longest the run may last, s simulated: homing creeps at 10 mm/s over at most the
    /// travel; a cycle is two strokes of the sinusoidal reference (mean speed 2/π of the
    /// peak), with 2 s to spare each.
    pub fn time_limit_s(&self) -> f64 {
        self.homing_limit_s() + f64::from(self.cycles) * self.cycle_limit_s() + STALL_SPARE_S
    }

    /// The longest homing may take, s simulated: the whole travel at [`HOMING_SPEED_MPS`]
    /// and [`STALL_SPARE_S`].
    pub fn homing_limit_s(&self) -> f64 {
        STALL_SPARE_S + self.model.piston.travel_m / HOMING_SPEED_MPS
    }

    /// The longest one compression cycle may take, s simulated: twice two strokes of the
    /// sinusoidal reference (mean speed 2/π of the peak; a cycle measured at 0.05 m/s takes
    /// 1.35 times that) and [`STALL_SPARE_S`].
    pub fn cycle_limit_s(&self) -> f64 {
        STALL_SPARE_S
            + 2.0 * std::f64::consts::PI * self.model.piston.travel_m / self.peak_speed_mps()
    }

    /// Checks the options; the error names the flag at fault.
    pub fn validate(&self) -> Result<(), String> {
        let (lo, hi) = PRESSURE_RATIO_RANGE;
        if !(self.pressure_ratio.is_finite() && (lo..=hi).contains(&self.pressure_ratio)) {
            return Err(format!(
                "--pressure-ratio {} is outside [{lo}, {hi}] (below {lo} the rotation cannot \
                 time the ports at speed)",
                num(self.pressure_ratio)
            ));
        }
        let suction = self.model.lines.suction_pa;
        if suction * self.pressure_ratio > PRESSURE_FULL_SCALE_PA {
            return Err(format!(
                "--pressure-ratio {} with the model's `lines.suction_pa` = {} Pa puts the \
                 discharge line beyond the pressure sensors' full scale {} Pa (at most {:.2})",
                num(self.pressure_ratio),
                num(suction),
                num(PRESSURE_FULL_SCALE_PA),
                PRESSURE_FULL_SCALE_PA / suction
            ));
        }
        let (lo, hi) = SPEED_RANGE_MPS;
        if let Some(v) = self.speed_mps {
            if !(v.is_finite() && (lo..=hi).contains(&v)) {
                return Err(format!("--speed {} is outside [{lo}, {hi}] m/s", num(v)));
            }
        }
        let max = self.model.limits.max_speed_mps;
        let v = self.peak_speed_mps();
        if v > max {
            let flag = match self.speed_mps {
                Some(_) => format!("--speed {}", num(v)),
                None => format!(
                    "--pressure-ratio {} asks for {} m/s (Fig. 3; give --speed) and",
                    num(self.pressure_ratio),
                    num(v)
                ),
            };
            return Err(format!(
                "{flag} is above the model's `limits.max_speed_mps` = {} m/s: the machine \
                 may not go that fast (range [{lo}, {}] m/s)",
                num(max),
                num(max.min(hi))
            ));
        }
        if self.log_rate_hz == 0
            || self.log_rate_hz > CONTROL_RATE_HZ
            || !CONTROL_RATE_HZ.is_multiple_of(self.log_rate_hz)
        {
            return Err(format!(
                "--log-rate {}: must divide the control rate {CONTROL_RATE_HZ} Hz into whole \
                 cycles (e.g. 20000, 10000, 5000, 1000)",
                self.log_rate_hz
            ));
        }
        if let RatioTarget::Fixed { pressure_ratio } = self.volume_ratio {
            let (lo, hi) = FIXED_RATIO_RANGE;
            let pr = f64::from(pressure_ratio);
            if !(pr.is_finite() && (lo..=hi).contains(&pr)) {
                return Err(format!(
                    "--volume-ratio fixed:{}: the design pressure ratio must be in [{lo}, {hi}]",
                    num(pr)
                ));
            }
        }
        if self.controller == Controller::Published {
            let refuse = |what: &str| {
                Err(format!(
                    "--controller published: {what} (the published drives have none of this \
                     firmware's machinery)"
                ))
            };
            if !self.faults.is_empty() {
                return refuse("no --fault: the drives have no supervision to react");
            }
            if self.calibration.is_some() {
                return refuse("no --calibration: the drives do not load this firmware's record");
            }
            if self.telemetry_decimation != 0 {
                return refuse("no --telemetry: the drives send no telemetry frames");
            }
            if self.model.motor.slave_follows_master || self.model.effects.slave_lag.is_some() {
                return refuse(
                    "the model's `motor.slave_follows_master` / `[effects.slave_lag]` would \
                     impose the slave's current; the slave drive is simulated here, its lag \
                     is `published.slave_lag_s`",
                );
            }
        }
        if let Some(test) = &self.closed_port {
            if self.controller != Controller::Published {
                return Err(
                    "--closed-port: the paper's closed-port test runs the published drives \
                     (give --controller published)"
                        .into(),
                );
            }
            test.validate(self)?;
        }
        let (lo, hi) = CYCLES_RANGE;
        if !(lo..=hi).contains(&self.cycles) {
            return Err(format!("--cycles {} is outside [{lo}, {hi}]", self.cycles));
        }
        let limit = self.time_limit_s();
        if let Some(late) = self.faults.iter().find(|f| f.at_s > limit) {
            return Err(format!(
                "--fault {}@{}: the run lasts at most {limit:.1} s simulated ({} cycles at \
                 {} m/s); it would never be injected",
                late.kind.name(),
                num(late.at_s),
                self.cycles,
                num(v)
            ));
        }
        Ok(())
    }
}

/// Peak speed for a pressure ratio, interpolated (and held at the ends) in Fig. 3's table.
pub fn speed_for_pressure_ratio(pr: f64) -> f64 {
    let mut prev = FIG3_SPEEDS[0];
    if pr <= prev.0 {
        return prev.1;
    }
    for &(p, v) in &FIG3_SPEEDS[1..] {
        if pr <= p {
            return prev.1 + (v - prev.1) * (pr - prev.0) / (p - prev.0);
        }
        prev = (p, v);
    }
    prev.1
}

/// The controller's configuration for a model: the firmware's tuning for the model's machine
/// (`ControlConfig::for_machine` of [`MachineModel::machine`]), with the model's cogging as
/// the compensation map (what the calibration would find).
pub fn control_config(model: &MachineModel) -> ControlConfig {
    let mut c = ControlConfig::for_machine(&model.machine());
    if let Some(cog) = model.cogging() {
        let mut map = fpc::physics::cogging::HarmonicMap::none();
        map.period_m = cog.period_m as f32;
        // A·sin(θ + φ) = A·cos φ·sin θ + A·sin φ·cos θ.
        map.sin_n[0] = (cog.amplitude_n * cog.phase_rad.cos()) as f32;
        map.cos_n[0] = (cog.amplitude_n * cog.phase_rad.sin()) as f32;
        c.allocation.cogging = map;
    }
    c
}

/// The simulated board for a model.
///
/// The chambers start unloaded (both open to the suction line, the rig's start-up bypass):
/// during homing the rotation is at rest and the port timing would seal a chamber. The run
/// closes the bypass (`world.plant.port_mode = PortMode::Timed`) when compression starts.
pub fn world(model: &MachineModel, seed: u64, start_us: u32, start_position_m: f64) -> World {
    let mut w = World::from_model(model, seed, start_us, start_position_m);
    w.plant.port_mode = PortMode::Unloaded;
    w
}
