//! The simulated board: simulated time, the sampling burst, the latched outputs, and the
//! port-trait implementations the firmware's task bodies run against.
//!
//! Time advances only in [`World::advance`], one control period at a time, so a run is
//! deterministic: the same seed gives the same samples bit for bit. What the sensors make of
//! the plant (errors, noise, lag, quantisation) is [`crate::board::sensors`], after the laws
//! of [`crate::plant::sensing`].
//!
//! # When the duties act (the board's timers, RM0440 §29.3)
//! The burst is sampled at the PWM counter peak that starts period k (TIM1's OC4REF, one
//! timer clock before it). The control task computes its duties from that burst and writes
//! them to TIM1/TIM8 CCR1..3, whose preload is on (CCMRx.OCxPE = 1): a written value goes to
//! the preload register, and the compare uses it only from the next update event, when the
//! preload registers are transferred to the shadow ones. With the repetition counter at 1
//! (written after the counter starts, so the update falls on the overflow) the update
//! events are the peaks only. The duties written in period k therefore drive the bridge over
//! period k + 1, from peak k + 1 to peak k + 2 — one whole period after the sampling, the
//! high-side pulse centred on the trough 1.5 periods after it. [`World::duties`] is the
//! preload the task writes, [`World::duties_in_force`] the shadow the bridge applies;
//! [`World::advance`] runs the plant over a period with the shadow, then makes the update
//! event (shadow ← preload). MOE (enable/disable) and the DAC are not preloaded: they act
//! at once, as on the chip. A compare register holds a whole number of timer steps
//! ([`fpc::units::PWM_COMPARE_STEPS`] a period), so a written duty is rounded to one
//! ([`Duty::as_switched`]) as the board's conversion does.

use std::cell::RefCell;
use std::future::poll_fn;
use std::rc::Rc;
use std::task::Poll;

use fpc::control::step::CycleInputs;
use fpc::drive::servo::torque_of_code;
use fpc::ports::{
    Clock, CurrentInput, CycleTrigger, EncoderCodes, EncoderInput, PhaseCurrentCodes,
    PressureCodes, PressureInput, PwmOutput, QuadratureInput, SinCosCodes, Sleep, SupplyMonitor,
    TorqueOutput, Watchdog,
};
use fpc::units::{DacCode, Duty, PerSection, PhaseDuties, Section, Ticks, CONTROL_PERIOD_US};

pub use crate::board::sensors::Sensors;
use crate::board::sensors::{adc, EncoderModel};
use crate::plant::dynamics::{Drive, Plant, PlantParams};
use crate::plant::fastmath::{floor_i64, sin_cos};
use crate::plant::model::MachineModel;
use crate::plant::noise::Noise;
use crate::plant::sensing::{FirstOrderLag, PRESSURE_CHANNELS};

/// Everything the simulated board holds.
#[derive(Clone)]
pub struct World {
    /// The physical plant.
    pub plant: Plant,
    /// Sensor models.
    pub sensors: Sensors,
    cycle: u64,
    start_us: u32,
    burst: Burst,
    /// Duties the control task wrote: the timers' preload registers (CCR1..3).
    pub duties: PerSection<PhaseDuties>,
    /// Duties the bridges apply this period: the shadow registers, loaded from
    /// [`World::duties`] at each update event (the end of every [`World::advance`]).
    pub duties_in_force: PerSection<PhaseDuties>,
    /// Motor outputs enabled.
    pub enabled: bool,
    /// While enabled, which sections' bridges switch (a section out of service is off).
    pub sections_on: PerSection<bool>,
    /// Servo command latched by the control task.
    pub servo_code: DacCode,
    /// Simulated time of the last watchdog feed, µs since the start.
    pub watchdog_fed_us: u64,
    /// The watchdog has been fed since the last boot (its running window is in force).
    pub watchdog_fed_since_boot: bool,
    /// What the firmware's supervision task reported (the board logs it with defmt).
    pub events: Vec<Event>,
    /// Sensor faults injected into every burst right after sampling (`fpc-sim run --fault`;
    /// none by default).
    pub corruption: crate::board::corruption::SensorCorruption,
    /// Wiring faults between the board and the machine (`fpc-sim calibrate --swap-phases`,
    /// `--reverse-encoder`; none by default).
    pub wiring: crate::board::wiring::Wiring,
    /// What the firmware's telemetry task sent up the (simulated) RTT channel.
    pub telemetry: crate::board::capture::TelemetryCapture,
    /// The board's RAM: the firmware's RTT control block and channels, set up at each boot.
    pub ram: crate::board::ram::SimRam,
    noise: Noise,
    /// The pressure sensors' lagged readings, Pa (A, B, suction, discharge).
    pressure_lagged_pa: [f64; PRESSURE_CHANNELS],
    /// The pressure sensors' first-order lag, stepped once a period.
    pressure_lag: FirstOrderLag,
}

#[derive(Clone, Copy, Debug, Default)]
struct Burst {
    encoders: EncoderCodes,
    currents: PerSection<PhaseCurrentCodes>,
    quadrature: u16,
    pressures: PressureCodes,
}

impl World {
    /// A world at simulated time zero (the time base reads `start_us`, to exercise its wrap).
    pub fn new(plant: Plant, sensors: Sensors, seed: u64, start_us: u32) -> Self {
        let period_s = f64::from(CONTROL_PERIOD_US) * 1e-6;
        let pressure_lag = sensors.pressure.sensor.lag(period_s);
        let mut w = World {
            pressure_lagged_pa: true_pressures(&plant),
            plant,
            sensors,
            cycle: 0,
            start_us,
            burst: Burst::default(),
            duties: PerSection::default(),
            duties_in_force: PerSection::default(),
            enabled: false,
            sections_on: PerSection {
                master: true,
                slave: true,
            },
            servo_code: DacCode::MID,
            watchdog_fed_us: 0,
            watchdog_fed_since_boot: false,
            events: Vec::new(),
            corruption: Default::default(),
            wiring: Default::default(),
            telemetry: Default::default(),
            ram: crate::board::ram::SimRam::new(),
            noise: Noise::new(seed),
            pressure_lag,
        };
        w.sample();
        w
    }

    /// The simulated board of a machine model, with the piston resting at
    /// `start_position_m`.
    pub fn from_model(
        model: &MachineModel,
        seed: u64,
        start_us: u32,
        start_position_m: f64,
    ) -> Self {
        let plant = Plant::new(PlantParams::from_model(model), start_position_m);
        World::new(plant, Sensors::from_model(model), seed, start_us)
    }

    /// Wires the board to the machine as `wiring` says, from the next sample on (the
    /// present burst sampled again, so the firmware never sees the rewiring as a jump).
    pub fn set_wiring(&mut self, wiring: crate::board::wiring::Wiring) {
        self.wiring = wiring;
        self.sample();
    }

    /// Control cycles simulated so far.
    pub fn cycle(&self) -> u64 {
        self.cycle
    }

    /// Simulated time, s.
    pub fn time_s(&self) -> f64 {
        Self::time_s_at(self.cycle)
    }

    /// Simulated time at the start of control cycle `cycle`, s.
    pub fn time_s_at(cycle: u64) -> f64 {
        // Divide (correctly rounded) rather than multiply by 1e-6, so times print short.
        (cycle * u64::from(CONTROL_PERIOD_US)) as f64 / 1e6
    }

    /// Simulated time, µs since the start.
    pub fn time_us(&self) -> u64 {
        self.cycle * u64::from(CONTROL_PERIOD_US)
    }

    /// What the board's time base reads now.
    pub fn ticks(&self) -> Ticks {
        Ticks(self.start_us.wrapping_add(self.time_us() as u32))
    }

    /// Advances one control period: the plant runs with the outputs in force, then the
    /// update event at the counter peak puts the written duties in force for the next
    /// period, and the next burst is sampled (see the module header).
    pub fn advance(&mut self) {
        let drive = self.drive();
        self.plant
            .advance(&drive, f64::from(CONTROL_PERIOD_US) * 1e-6);
        self.duties_in_force = self.duties;
        self.cycle += 1;
        self.sample();
    }

    /// Outputs as after a reset of the MCU (or with no supply): bridges off, the timers'
    /// compare registers (preload and shadow) at their reset value, servo command zero.
    pub fn outputs_reset(&mut self) {
        self.enabled = false;
        self.duties = PerSection::default();
        self.duties_in_force = PerSection::default();
        self.servo_code = DacCode::MID;
    }

    /// What the outputs apply to the plant during the next period: each section's duties
    /// in force while its outputs are on, and the servo torque the DAC code commands.
    pub fn drive(&self) -> Drive {
        let on = |s: Section| {
            (self.enabled && *self.sections_on.get(s))
                .then(|| self.wiring.to_windings(s, *self.duties_in_force.get(s)))
        };
        Drive {
            duties: PerSection {
                master: on(Section::Master),
                slave: on(Section::Slave),
            },
            servo_torque_nm: f64::from(torque_of_code(
                self.servo_code,
                self.plant.params.servo.torque_full_scale_nm as f32,
            )),
        }
    }

    /// What the control task reads in this period: the time base and the sampling burst.
    pub fn cycle_inputs(&self) -> CycleInputs {
        let b = &self.burst;
        CycleInputs {
            t: self.ticks(),
            encoders: b.encoders,
            currents: b.currents,
            quadrature: b.quadrature,
            pressures: b.pressures,
        }
    }

    fn sample(&mut self) {
        let s = &self.sensors;
        let plant = &self.plant;
        let noise = &mut self.noise;
        let x = plant.x_m;
        let encoder = |m: &EncoderModel, (sin, cos): (f64, f64), noise: &mut Noise| SinCosCodes {
            sin: adc(sin + noise.scaled(m.noise_codes())),
            cos: adc(cos + noise.scaled(m.noise_codes())),
        };
        let (em, es) = (&s.encoder_master, &s.encoder_slave);
        let th = em.angle_rad(x);
        // A scale of the motor's electrical period reads the motors' angle at this position,
        // already computed by the plant (the same formula: no trigonometry here).
        let sin_cos_th = match plant.motors.master_angle_at(x) {
            Some(sc) if em.period_m == plant.motors.electrical_period_m() => sc,
            _ => sin_cos(th),
        };
        let master = encoder(em, em.signals_at(th, sin_cos_th), noise);
        let slave_signals = match &s.slave_pitch_error {
            // Same scale, same position: the same angle (one sin/cos for both).
            None if es.period_m == em.period_m => es.signals_at(th, sin_cos_th),
            None => es.signals(x),
            Some(e) => es.signals(e.reading_m(x, plant.v_mps)),
        };
        let slave = encoder(es, slave_signals, noise);

        let codes_per_a = 1.0 / f64::from(s.current.a_per_code);
        let mut current = |section: Section| {
            let offsets = s.current_offsets_a(section);
            let i = plant.phase_currents(section);
            let mut codes = [adc(0.0); 3];
            for ((code, a), off) in codes.iter_mut().zip(i).zip(offsets) {
                *code =
                    adc(2048.0 + (a + off + noise.scaled(s.current_sensor.noise_a)) * codes_per_a);
            }
            codes
        };
        let w = self.wiring;
        let currents = PerSection {
            master: w.to_legs(Section::Master, current(Section::Master)),
            slave: w.to_legs(Section::Slave, current(Section::Slave)),
        };

        let counts =
            plant.rotation.servo_angle_rad / std::f64::consts::TAU * f64::from(s.counts_per_rev);

        let p = &s.pressure;
        let truth = true_pressures(plant);
        let mut codes = [adc(0.0); PRESSURE_CHANNELS];
        for (((code, lagged), t), transducer) in codes
            .iter_mut()
            .zip(self.pressure_lagged_pa.iter_mut())
            .zip(truth)
            .zip(p.sensor.transducers())
        {
            self.pressure_lag.step(lagged, t);
            *code = p.code(*lagged, transducer, noise);
        }
        let [chamber_a, chamber_b, suction, discharge] = codes;
        self.burst = Burst {
            encoders: EncoderCodes {
                master: w.encoder(Section::Master, master),
                slave: w.encoder(Section::Slave, slave),
            },
            currents,
            // The hardware counter wraps at 16 bits.
            quadrature: floor_i64(counts) as u16,
            pressures: PressureCodes {
                chamber_a,
                chamber_b,
                suction,
                discharge,
            },
        };
        if self.corruption.active() {
            let b = &mut self.burst;
            self.corruption
                .apply(&mut b.encoders, &mut b.pressures, &mut b.quadrature);
        }
    }
}

/// The true pressures the four sensors see: chamber A, chamber B, suction, discharge, Pa.
fn true_pressures(plant: &Plant) -> [f64; PRESSURE_CHANNELS] {
    [
        plant.chambers.a.pressure_pa,
        plant.chambers.b.pressure_pa,
        plant.lines.suction_pa,
        plant.lines.discharge_pa,
    ]
}

/// A shared handle on the world, as every simulated peripheral holds one.
pub type WorldRef = Rc<RefCell<World>>;

/// The control-cycle trigger: ready once per simulated period.
pub struct SimCycle {
    world: WorldRef,
    seen: u64,
}

impl CycleTrigger for SimCycle {
    async fn next_cycle(&mut self) -> Ticks {
        poll_fn(|_| {
            let w = self.world.borrow();
            if w.cycle > self.seen {
                self.seen = w.cycle;
                Poll::Ready(w.ticks())
            } else {
                Poll::Pending
            }
        })
        .await
    }
}

/// The simulated time base and sleeper.
pub struct SimClock {
    world: WorldRef,
}

impl Clock for SimClock {
    fn now(&self) -> Ticks {
        self.world.borrow().ticks()
    }
}

impl Sleep for SimClock {
    async fn until(&mut self, deadline: Ticks) {
        poll_fn(|_| {
            if self.world.borrow().ticks().reached(deadline) {
                Poll::Ready(())
            } else {
                Poll::Pending
            }
        })
        .await
    }
}

/// The simulated board's peripherals: one handle implementing every sampling/output port.
pub struct SimPeripherals {
    world: WorldRef,
}

/// The power-good comparator on the DC link (`[supply] power_good_voltage_v`).
impl SupplyMonitor for SimPeripherals {
    fn power_good(&mut self) -> bool {
        self.world.borrow().plant.supply.power_good()
    }
}

impl EncoderInput for SimPeripherals {
    fn read(&mut self) -> EncoderCodes {
        self.world.borrow().burst.encoders
    }
}

impl CurrentInput for SimPeripherals {
    fn read(&mut self, section: Section) -> PhaseCurrentCodes {
        *self.world.borrow().burst.currents.get(section)
    }
}

impl PwmOutput for SimPeripherals {
    fn write(&mut self, section: Section, duties: PhaseDuties) {
        // The compare registers hold whole timer steps (the board rounds each duty to one).
        *self.world.borrow_mut().duties.get_mut(section) = duties.map(Duty::as_switched);
    }
    fn disable(&mut self) {
        self.world.borrow_mut().enabled = false;
    }
    fn enable(&mut self, sections: PerSection<bool>) {
        let mut w = self.world.borrow_mut();
        w.enabled = true;
        w.sections_on = sections;
    }
}

impl QuadratureInput for SimPeripherals {
    fn count(&mut self) -> u16 {
        self.world.borrow().burst.quadrature
    }
}

impl TorqueOutput for SimPeripherals {
    fn write(&mut self, code: DacCode) {
        self.world.borrow_mut().servo_code = code;
    }
}

impl PressureInput for SimPeripherals {
    fn read(&mut self) -> PressureCodes {
        self.world.borrow().burst.pressures
    }
}

/// The simulated independent watchdog.
pub struct SimWatchdog {
    world: WorldRef,
}

impl Watchdog for SimWatchdog {
    fn feed(&mut self) {
        let mut w = self.world.borrow_mut();
        w.watchdog_fed_us = w.time_us();
        w.watchdog_fed_since_boot = true;
    }
}

/// The cycle trigger of `world`.
pub fn cycle(world: &WorldRef) -> SimCycle {
    SimCycle {
        world: world.clone(),
        seen: world.borrow().cycle,
    }
}

/// The peripherals of `world`.
pub fn peripherals(world: &WorldRef) -> SimPeripherals {
    SimPeripherals {
        world: world.clone(),
    }
}

/// The time base of `world`.
pub fn clock(world: &WorldRef) -> SimClock {
    SimClock {
        world: world.clone(),
    }
}

/// What the firmware's supervision task reported, with the simulated time, µs.
#[derive(Clone, Debug, PartialEq)]
pub enum Event {
    /// A fault was latched.
    FaultLatched(u64, fpc::safety::faults::Fault),
    /// A limit became active.
    LimitActive(u64, fpc::safety::supervisor::LimitFlags),
    /// The mode changed.
    ModeChanged(u64, fpc::status::ModeKind),
    /// The parts absent since boot changed.
    AbsentChanged(u64, fpc::safety::absent::Absent),
    /// A calibration record was saved (or the save failed).
    CalibrationSaved(u64, Result<(), fpc::control::calibration::store::SaveError>),
}

/// The simulated board's event log: it records what the board would log with defmt.
pub struct SimEventLog {
    world: WorldRef,
}

impl fpc::ports::EventLog for SimEventLog {
    fn fault_latched(&mut self, fault: fpc::safety::faults::Fault) {
        let mut w = self.world.borrow_mut();
        let t = w.time_us();
        w.events.push(Event::FaultLatched(t, fault));
    }
    fn limit_active(&mut self, limits: fpc::safety::supervisor::LimitFlags) {
        let mut w = self.world.borrow_mut();
        let t = w.time_us();
        w.events.push(Event::LimitActive(t, limits));
    }
    fn mode_changed(&mut self, mode: fpc::status::ModeKind) {
        let mut w = self.world.borrow_mut();
        let t = w.time_us();
        w.events.push(Event::ModeChanged(t, mode));
    }
    fn absent_changed(&mut self, absent: fpc::safety::absent::Absent) {
        let mut w = self.world.borrow_mut();
        let t = w.time_us();
        w.events.push(Event::AbsentChanged(t, absent));
    }
    fn calibration_saved(
        &mut self,
        result: Result<(), fpc::control::calibration::store::SaveError>,
    ) {
        let mut w = self.world.borrow_mut();
        let t = w.time_us();
        w.events.push(Event::CalibrationSaved(t, result));
    }
}

/// The event log of `world`.
pub fn event_log(world: &WorldRef) -> SimEventLog {
    SimEventLog {
        world: world.clone(),
    }
}

/// The watchdog of `world`.
pub fn watchdog(world: &WorldRef) -> SimWatchdog {
    SimWatchdog {
        world: world.clone(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn model_with(extra: &str) -> MachineModel {
        MachineModel::parse(&format!("{}\n{extra}", crate::plant::model::REFERENCE_TOML)).unwrap()
    }

    /// Position within a period read back from sin/cos codes, m.
    fn decode(codes: SinCosCodes, period_m: f64) -> f64 {
        let (s, c) = (
            f64::from(codes.sin.0) - 2048.0,
            f64::from(codes.cos.0) - 2048.0,
        );
        s.atan2(c).rem_euclid(std::f64::consts::TAU) / std::f64::consts::TAU * period_m
    }

    #[test]
    fn the_slave_encoder_reads_the_pitch_error() {
        let mut m =
            model_with("[effects.encoder_pitch_error]\namplitude_m = 2e-4\nperiod_m = 0.024\n");
        m.sensors.encoder_master.noise_codes = 0.0;
        m.sensors.encoder_slave.noise_codes = 0.0;
        let w = World::from_model(&m, 1, 0, 0.006); // a quarter period: sin = 1
        let e = w.burst.encoders;
        let diff = decode(e.slave, 0.024) - decode(e.master, 0.024);
        assert!((diff - 2e-4).abs() < 5e-6, "{diff}");
    }

    #[test]
    fn pressure_sensors_lag_and_carry_their_offset() {
        let mut m = MachineModel::reference();
        m.sensors.pressure.noise_pa = 0.0;
        m.sensors.pressure.time_constant_s = 1e-3;
        m.sensors.pressure.offset_a_pa = 2e4;
        let mut w = World::from_model(&m, 1, 0, 0.1);
        let cal = w.sensors.pressure.calibration;
        let p0 = w.plant.chambers.a.pressure_pa;
        let read = |w: &World| f64::from(cal.convert(w.burst.pressures.chamber_a).pressure_pa);
        assert!((read(&w) - (p0 + 2e4)).abs() < 400.0);
        // A step of the true pressure: after one 50 µs period the sensor has moved ≈ 5 %.
        w.plant.port_mode = crate::plant::chambers::PortMode::Closed;
        w.plant.chambers.a.pressure_pa = p0 + 4e5;
        w.sample();
        let moved = (read(&w) - (p0 + 2e4)) / 4e5;
        assert!((moved - (1.0 - (-0.05f64).exp())).abs() < 0.01, "{moved}");
    }

    #[test]
    fn a_duty_written_in_a_period_drives_the_next_one() {
        let world: WorldRef = Rc::new(RefCell::new(World::from_model(
            &MachineModel::reference(),
            1,
            0,
            0.1,
        )));
        let mut pwm = peripherals(&world);
        let first = [Duty(40_000), Duty(30_000), Duty(32_768)];
        PwmOutput::write(&mut pwm, Section::Master, first);
        pwm.enable(PerSection {
            master: true,
            slave: false,
        });
        // MOE acts at once; the compare values only from the update event.
        let w = world.borrow().drive();
        assert_eq!(
            w.duties.master,
            Some(PerSection::<PhaseDuties>::default().master)
        );
        assert_eq!(w.duties.slave, None);
        world.borrow_mut().advance();
        PwmOutput::write(&mut pwm, Section::Master, [Duty::HALF; 3]);
        let switched = first.map(Duty::as_switched);
        assert_eq!(world.borrow().drive().duties.master, Some(switched));
        assert_ne!(switched, first, "rounded to the timer's steps");
        world.borrow_mut().advance();
        assert_eq!(
            world.borrow().drive().duties.master,
            Some([Duty::HALF.as_switched(); 3])
        );
        pwm.disable();
        assert_eq!(world.borrow().drive().duties.master, None);
    }

    #[test]
    fn the_quadrature_counter_counts_the_servo_angle_and_wraps() {
        let mut w = World::from_model(&MachineModel::reference(), 1, 0, 0.1);
        w.plant.rotation.servo_angle_rad = 20.0 * std::f64::consts::TAU + 0.5;
        w.sample();
        // 20 turns and 0.5 rad: 82 245 counts, which the 16-bit counter shows modulo 65 536.
        let expected = (20.0 * 4096.0 + 0.5 / std::f64::consts::TAU * 4096.0).floor() as i64 as u16;
        assert_eq!(w.burst.quadrature, expected);
    }
}
