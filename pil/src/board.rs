//! The PCB around the emulated chip, and the plant it drives: what each ADC pin carries,
//! what the bridges make of the compare registers, what the servo makes of the DAC, and
//! what the servo encoder's counter reads. The plant and its sensor models are `hal-sim`'s
//! simulated board ([`World`]): the same plant, the same sensor errors and noise, the same
//! seed as `fpc-sim run`.
//!
//! Wiring (the board's pin table, `src/board/mod.rs`, and the STM32G474 datasheet's pin
//! functions):
//!
//! | ADC | channel | pin | signal |
//! |---|---|---|---|
//! | ADC1 | IN1, IN2, IN3 | PA0, PA1, PA2 | section 1 phase currents U, V, W |
//! | ADC2 | IN3, IN4, IN5 | PA6, PA7, PC4 | section 2 phase currents U, V, W |
//! | ADC1 / ADC2 | IN15 / IN11 | PB0 / PC5 | master encoder sin / cos |
//! | ADC1 / ADC2 | IN12 / IN12 | PB1 / PB2 | slave encoder sin / cos |
//! | ADC1 / ADC2 | IN11 / IN7 | PB12 / PC1 | chamber A / chamber B pressure |
//! | ADC1 / ADC2 | IN6 / IN8 | PC0 / PC2 | suction / discharge pressure |
//!
//! TIM1 CH1–3 drive section 1's bridge, TIM8 CH1–3 section 2's: a phase's average voltage
//! over a period is its compare value over ARR (centre-aligned PWM mode 1), and a bridge
//! whose MOE is 0 is off. DAC1 OUT1 is the servo's torque command. TIM4 counts the servo
//! encoder. PB5 (GPIOB_IDR bit 5) reads the DC link's power-good comparator.

use fpc::units::{DacCode, Duty, PerSection, PhaseDuties};
use hal_sim::board::world::World;

/// The board and the plant.
#[derive(Clone)]
pub struct Board {
    /// The plant and its sensors (hal-sim).
    pub world: World,
    /// Words the DMA has moved, to be written to RAM before the core runs on.
    pub dma_writes: Vec<(u32, u32)>,
    /// The duties in force from the last update event.
    duties: PerSection<PhaseDuties>,
}

impl Board {
    /// The board around `world`.
    pub fn new(world: World) -> Self {
        Board {
            world,
            dma_writes: Vec::new(),
            duties: PerSection::default(),
        }
    }

    /// The compare values a timer put in force at its update event (CCR1..4), with its
    /// ARR: the phase duties of its section (`timer` 0: TIM1, section 1; 1: TIM8, section 2)
    /// for the next period.
    pub fn latch_duties(&mut self, timer: usize, ccr: [u32; 4], arr: u32) {
        let phases = [ccr[0], ccr[1], ccr[2]].map(|c| Duty::of_compare(c, arr));
        if timer == 0 {
            self.duties.master = phases;
        } else {
            self.duties.slave = phases;
        }
    }

    /// One PWM period of the plant with the duties in force, bridges on where `moe`, and the
    /// servo command `dac`; then the sensors sample (the next burst).
    pub fn step(&mut self, moe: [bool; 2], dac: u16) {
        let w = &mut self.world;
        // The chip's own timers decide what is in force (their update events): the plant
        // applies it as it stands.
        w.duties = self.duties;
        w.duties_in_force = self.duties;
        w.enabled = moe[0] || moe[1];
        w.sections_on = PerSection {
            master: moe[0],
            slave: moe[1],
        };
        w.servo_code = DacCode(dac);
        w.advance();
    }

    /// Outputs low (reset, no supply): the gate drivers' pull-downs hold the gates off.
    pub fn outputs_off(&mut self) {
        self.world.enabled = false;
        self.world.servo_code = DacCode::MID;
    }

    /// The code ADC `adc` (1 or 2) converts on channel `ch` (an unconnected channel reads 0).
    pub fn analog(&self, adc: u8, ch: u32) -> u16 {
        let i = self.world.cycle_inputs();
        let c = match (adc, ch) {
            (1, 1) => i.currents.master[0],
            (1, 2) => i.currents.master[1],
            (1, 3) => i.currents.master[2],
            (2, 3) => i.currents.slave[0],
            (2, 4) => i.currents.slave[1],
            (2, 5) => i.currents.slave[2],
            (1, 15) => i.encoders.master.sin,
            (2, 11) => i.encoders.master.cos,
            (1, 12) => i.encoders.slave.sin,
            (2, 12) => i.encoders.slave.cos,
            (1, 11) => i.pressures.chamber_a,
            (2, 7) => i.pressures.chamber_b,
            (1, 6) => i.pressures.suction,
            (2, 8) => i.pressures.discharge,
            _ => return 0,
        };
        c.0
    }

    /// What the DC link's power-good comparator drives onto PB5: high while the link is
    /// above its threshold (always, unless a scenario cuts the plant's mains).
    pub fn power_good(&self) -> bool {
        self.world.plant.supply.power_good()
    }

    /// The servo encoder's count (TIM4 CNT).
    pub fn quadrature(&self) -> u16 {
        self.world.cycle_inputs().quadrature
    }
}
