//! The simulated board: simulated time, the sampling burst, the latched outputs, and the
//! port-trait implementations the firmware's task bodies run against.
//!
//! Time advances only in [`World::advance`], one control period at a time, so a run is
//! deterministic: the same seed gives the same samples bit for bit. As on the board, the
//! burst is sampled at the start of a period and the duties the control task writes act
//! during the next period (one period of transport delay).

use std::cell::RefCell;
use std::future::poll_fn;
use std::rc::Rc;
use std::task::Poll;

use fpc::encoder::NOMINAL_AMPLITUDE_CODES;
use fpc::foc::CurrentSense;
use fpc::ports::{
    Clock, CurrentInput, CycleTrigger, EncoderCodes, EncoderInput, PhaseCurrentCodes,
    PressureCodes, PressureInput, PwmOutput, QuadratureInput, SinCosCodes, Sleep, TorqueOutput,
    Watchdog,
};
use fpc::pressure::PressureCalibration;
use fpc::servo::torque_of_code;
use fpc::units::{AdcCode, DacCode, PerSection, PhaseDuties, Section, Ticks, CONTROL_PERIOD_US};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::StandardNormal;

use crate::plant::{Drive, Plant};

/// Sensor models of the simulated board.
#[derive(Clone, Debug, PartialEq)]
pub struct Sensors {
    /// Encoder period λ, m.
    pub encoder_period_m: f64,
    /// Encoder signal amplitude at the ADC, codes.
    pub encoder_amplitude_codes: f64,
    /// Encoder noise, codes RMS per channel.
    pub encoder_noise_codes: f64,
    /// Current sensing (same calibration as the firmware's reference).
    pub current: CurrentSense,
    /// Pressure sensing.
    pub pressure: PressureCalibration,
    /// Servo encoder counts per revolution.
    pub counts_per_rev: u32,
}

impl Sensors {
    /// Ideal reference sensors (quantisation only).
    pub fn reference() -> Self {
        Sensors {
            encoder_period_m: 0.024,
            encoder_amplitude_codes: f64::from(NOMINAL_AMPLITUDE_CODES),
            encoder_noise_codes: 0.0,
            current: CurrentSense::reference(),
            pressure: PressureCalibration::reference(),
            counts_per_rev: 4096,
        }
    }
}

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
    /// Duties latched by the control task.
    pub duties: PerSection<PhaseDuties>,
    /// Motor outputs enabled.
    pub enabled: bool,
    /// Servo command latched by the control task.
    pub servo_code: DacCode,
    /// Simulated time of the last watchdog feed, µs since the start.
    pub watchdog_fed_us: u64,
    rng: ChaCha8Rng,
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
        let mut w = World {
            plant,
            sensors,
            cycle: 0,
            start_us,
            burst: Burst::default(),
            duties: PerSection::default(),
            enabled: false,
            servo_code: DacCode::MID,
            watchdog_fed_us: 0,
            rng: ChaCha8Rng::seed_from_u64(seed),
        };
        w.sample();
        w
    }

    /// Control cycles simulated so far.
    pub fn cycle(&self) -> u64 {
        self.cycle
    }

    /// Simulated time, s.
    pub fn time_s(&self) -> f64 {
        // Divide (correctly rounded) rather than multiply by 1e-6, so times print short.
        self.time_us() as f64 / 1e6
    }

    /// Simulated time, µs since the start.
    pub fn time_us(&self) -> u64 {
        self.cycle * u64::from(CONTROL_PERIOD_US)
    }

    /// What the board's time base reads now.
    pub fn ticks(&self) -> Ticks {
        Ticks(self.start_us.wrapping_add(self.time_us() as u32))
    }

    /// Advances one control period: the plant runs with the latched outputs, then the next
    /// burst is sampled.
    pub fn advance(&mut self) {
        let drive = Drive {
            duties: self.enabled.then_some(self.duties),
            servo_torque_nm: f64::from(torque_of_code(
                self.servo_code,
                self.plant.params.servo_torque_full_scale_nm as f32,
            )),
        };
        self.plant
            .advance(&drive, f64::from(CONTROL_PERIOD_US) * 1e-6);
        self.cycle += 1;
        self.sample();
    }

    fn noise(&mut self, sigma: f64) -> f64 {
        if sigma == 0.0 {
            0.0
        } else {
            sigma * self.rng.sample::<f64, _>(StandardNormal)
        }
    }

    fn code(v: f64) -> AdcCode {
        AdcCode(v.round().clamp(0.0, 4095.0) as u16)
    }

    fn sample(&mut self) {
        let s = self.sensors.clone();
        let th = 2.0 * std::f64::consts::PI * self.plant.x_m / s.encoder_period_m;
        let channel =
            |w: &mut World, v: f64| Self::code(2048.0 + v + w.noise(s.encoder_noise_codes));
        let a = s.encoder_amplitude_codes;
        let master = SinCosCodes {
            sin: channel(self, a * th.sin()),
            cos: channel(self, a * th.cos()),
        };
        let slave = SinCosCodes {
            sin: channel(self, a * th.sin()),
            cos: channel(self, a * th.cos()),
        };
        let current =
            |i: [f64; 3]| i.map(|a| Self::code(2048.0 + a / f64::from(s.current.a_per_code)));
        let counts =
            self.plant.theta_rad / (2.0 * std::f64::consts::PI) * f64::from(s.counts_per_rev);
        let p = s
            .pressure
            .code_for(self.plant.params.chamber_pressure_pa as f32);
        self.burst = Burst {
            encoders: EncoderCodes { master, slave },
            currents: PerSection {
                master: current(self.plant.phase_currents(Section::Master)),
                slave: current(self.plant.phase_currents(Section::Slave)),
            },
            // The hardware counter wraps at 16 bits.
            quadrature: counts.floor() as i64 as u16,
            pressures: PressureCodes {
                chamber_a: p,
                chamber_b: p,
                suction: p,
                discharge: p,
            },
        };
    }
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
        *self.world.borrow_mut().duties.get_mut(section) = duties;
    }
    fn disable(&mut self) {
        self.world.borrow_mut().enabled = false;
    }
    fn enable(&mut self) {
        self.world.borrow_mut().enabled = true;
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

/// The watchdog of `world`.
pub fn watchdog(world: &WorldRef) -> SimWatchdog {
    SimWatchdog {
        world: world.clone(),
    }
}
