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
//! | ADC1 / ADC2 | IN4 / IN11 | PA3 / PC5 | master encoder sin / cos |
//! | ADC1 / ADC2 | IN12 / IN12 | PB1 / PB2 | slave encoder sin / cos |
//! | ADC1 / ADC2 | IN11 / IN7 | PB12 / PC1 | chamber A / chamber B pressure |
//! | ADC1 / ADC2 | IN6 / IN8 | PC0 / PC2 | suction / discharge pressure |
//!
//! The over-current comparators' inputs (`src/board/trip.rs`): U1 on PA0 (COMP3), V1 on PA1
//! (COMP1) and V2 on PA7 (COMP2), the pins the ADCs read; W1, U2 and W2 by second traces to
//! PB0 (COMP4), PB11 (COMP6) and PB13 (COMP5). A sensor's voltage is its code over 4095 of
//! VREF+.
//!
//! TIM1 CH1–3 drive section 1's bridge, TIM8 CH1–3 section 2's, as their output stages say
//! ([`crate::chip::output_stage`]): switching, a phase's average voltage over a period is
//! its compare value over ARR (centre-aligned PWM mode 1; the period less it for a pair
//! inverted by its polarity bits), or off. The bridge needs at least
//! [`MIN_DEAD_TIME_NS`] of dead time. DAC1 OUT1 is the servo's torque command. TIM4 counts the servo
//! encoder. PB5 (GPIOB_IDR bit 5) reads the DC link's power-good comparator.

use fpc::units::{DacCode, Duty, PerSection, PhaseDuties};
use hal_sim::board::world::World;

/// The least dead time the bridge takes, ns: its switches' turn-off and the gate driver's
/// propagation mismatch (an assumption of the board model; `docs/bring-up.md` 2.3 measures
/// the margin). The firmware inserts 500 ns.
pub const MIN_DEAD_TIME_NS: f64 = 300.0;

/// What one bridge's six gates do over the coming period: the board's side of the gate
/// drive, which the timer's output stage decides from its registers
/// ([`crate::chip::output_stage::bridge`]) and [`Board::step`] applies to the plant.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Bridge {
    /// Switching complementarily: the compare values drive the phases; `inverted` marks the
    /// phases whose outputs are both inverted (CCxP = CCxNP = 1: the high side's on-time is
    /// then the period less the compare value).
    Switching {
        /// Phases U, V, W with both outputs inverted.
        inverted: [bool; 3],
    },
    /// Every gate low (MOE = 0, OSSI = 1, idle levels low): off.
    Off,
    /// Something the board cannot take: the reason, for the operator.
    Unsafe(&'static str),
}

/// A phase current stepped above what the machine draws (a winding short, say), as the
/// sensor reports it from `at_s` on.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CurrentStep {
    /// 0: section 1, 1: section 2.
    pub section: usize,
    /// 0, 1, 2: phase U, V, W.
    pub phase: usize,
    /// The sensed current, A.
    pub amps: f64,
}

/// The board and the plant.
pub struct Board {
    /// The plant and its sensors (hal-sim).
    pub world: World,
    /// What the DMA has moved, to be written to RAM before the core runs on: (address,
    /// data, bytes).
    pub dma_writes: Vec<(u32, u32, u32)>,
    /// The duties in force from the last update event.
    duties: PerSection<PhaseDuties>,
    /// A bare bench: nothing connected to the board but the probe — the DC link off (PB5
    /// low), the encoders' inputs flat at mid-scale, the pressure inputs at 0 V.
    pub bare: bool,
    /// An injected over-current, if any.
    pub current_step: Option<CurrentStep>,
}

impl Board {
    /// The board around `world`.
    pub fn new(world: World) -> Self {
        Board {
            world,
            dma_writes: Vec::new(),
            duties: PerSection::default(),
            bare: false,
            current_step: None,
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

    /// One PWM period of the plant with the duties in force, the bridges as their output
    /// stages drive them, and the servo command `dac`; then the sensors sample (the next
    /// burst).
    pub fn step(&mut self, bridges: [Bridge; 2], dac: u16) {
        let w = &mut self.world;
        // The chip's own timers decide what is in force (their update events): the plant
        // applies it as it stands.
        let mut duties = self.duties;
        let on = bridges.map(|b| matches!(b, Bridge::Switching { .. }));
        for (b, d) in bridges.iter().zip([&mut duties.master, &mut duties.slave]) {
            if let Bridge::Switching { inverted } = b {
                for (phase, inv) in d.iter_mut().zip(inverted) {
                    if *inv {
                        *phase = Duty(u16::MAX - phase.0);
                    }
                }
            }
        }
        w.duties = duties;
        w.duties_in_force = duties;
        w.enabled = on[0] || on[1];
        w.sections_on = PerSection {
            master: on[0],
            slave: on[1],
        };
        w.servo_code = DacCode(dac);
        w.advance();
    }

    /// Outputs low (reset, no supply): the gate drivers' pull-downs hold the gates off.
    pub fn outputs_off(&mut self) {
        self.world.enabled = false;
        self.world.servo_code = DacCode::MID;
    }

    /// The code of phase `phase` of section `section`'s current sensor now.
    fn current_code(&self, section: usize, phase: usize) -> u16 {
        if let Some(c) = self
            .current_step
            .filter(|c| (c.section, c.phase) == (section, phase))
        {
            return (2048.0 + c.amps / 100.0 * 2048.0).clamp(0.0, 4095.0) as u16;
        }
        let i = self.world.cycle_inputs();
        let codes = if section == 0 {
            i.currents.master
        } else {
            i.currents.slave
        };
        codes[phase].0
    }

    /// What the board puts on comparator `n`'s (0: COMP1) non-inverting input `inpsel`
    /// (0: IO1, 1: IO2), V; None where nothing analog is wired.
    pub fn comparator_input_v(&self, n: usize, inpsel: u32) -> Option<f64> {
        let code = match (n + 1, inpsel) {
            (1, 0) => self.current_code(0, 1),
            (2, 0) => self.current_code(1, 1),
            (3, 0) => self.current_code(0, 0),
            (4, 0) => self.current_code(0, 2),
            (5, 0) => self.current_code(1, 2),
            (6, 0) => self.current_code(1, 0),
            (1, 1) => self.analog(1, 12),
            (2, 1) => self.analog(1, 4),
            (3, 1) => self.analog(2, 7),
            _ => return None,
        };
        Some(f64::from(code) / 4095.0 * crate::chip::comp::VREF_V)
    }

    /// The code ADC `adc` (1 or 2) converts on channel `ch` (an unconnected channel reads 0).
    pub fn analog(&self, adc: u8, ch: u32) -> u16 {
        match (adc, ch) {
            (1, 1) => return self.current_code(0, 0),
            (1, 2) => return self.current_code(0, 1),
            (1, 3) => return self.current_code(0, 2),
            (2, 3) => return self.current_code(1, 0),
            (2, 4) => return self.current_code(1, 1),
            (2, 5) => return self.current_code(1, 2),
            _ => {}
        }
        if self.bare {
            return match (adc, ch) {
                (1, 4) | (2, 11) | (1, 12) | (2, 12) => 2048,
                _ => 0,
            };
        }
        let i = self.world.cycle_inputs();
        let c = match (adc, ch) {
            (1, 4) => i.encoders.master.sin,
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
    /// above its threshold (always, unless a scenario cuts the plant's mains or the bench is
    /// bare).
    pub fn power_good(&self) -> bool {
        !self.bare && self.world.plant.supply.power_good()
    }

    /// The servo encoder's count (TIM4 CNT).
    pub fn quadrature(&self) -> u16 {
        self.world.cycle_inputs().quadrature
    }
}
