//! The sense stage: what the samples say about the machine, and what a failed encoder
//! changes in the position frame (the other encoder stands in for it; the safe state drops
//! its section).

use super::publish::Previous;
use crate::control::config::ControlConfig;
use crate::drive::foc::CurrentController;
use crate::ports::{EncoderCodes, PressureCodes};
use crate::real::clamp_f32;
use crate::sensing::differentiator::{Derivatives, SavitzkyGolay};
use crate::sensing::encoder::{EncoderReading, PositionCounts, SinCosDecoder};
use crate::sensing::pressure::{PressureSample, StuckConfig, StuckMonitor};
use crate::sensing::quadrature::QuadratureCounter;
use crate::units::{AdcCode, PerSection, Section, Ticks, CONTROL_PERIOD_US};

/// The sense stage's state: both decoders, the differentiator, the rotation's counter, the
/// homed frame, the stand-in after a lost encoder and the pressure monitor.
/// `repr(C)`: the scalars the step reads field by field first, next to the rest of the step's
/// hot state, the large decoders and the differentiator's window last (see [`ControlStep`]).
#[derive(Clone, Debug)]
#[repr(C)]
pub(super) struct Sensing {
    /// The sampling instant of the last cycle (the deadline check).
    pub last_t: Option<Ticks>,
    /// Raw master position at x = 0 (set by homing), m.
    pub zero_raw_m: Option<f32>,
    /// Raw slave position at x = 0, m.
    pub zero_slave_raw_m: f32,
    /// The encoder that failed while the other still gives the position (its section is
    /// dropped); `None` while both are good.
    pub lost_encoder: Option<Section>,
    /// Master minus slave position, counts, when the master encoder was lost (the slave
    /// stands in for it at this offset).
    pub slave_offset_counts: PositionCounts,
    pub pressures: PressureMonitor,
    pub quadrature: QuadratureCounter,
    pub encoders: PerSection<SinCosDecoder>,
    pub differentiator: SavitzkyGolay,
}

impl Sensing {
    pub(super) fn new(config: &ControlConfig, differentiator: SavitzkyGolay) -> Self {
        Sensing {
            encoders: PerSection {
                master: SinCosDecoder::new(config.encoder_master),
                slave: SinCosDecoder::new(crate::control::calibration::encoder_map::slave_encoder(
                    config,
                )),
            },
            differentiator,
            quadrature: QuadratureCounter::new(),
            last_t: None,
            zero_raw_m: None,
            zero_slave_raw_m: 0.0,
            lost_encoder: None,
            slave_offset_counts: PositionCounts::ZERO,
            pressures: PressureMonitor::new(),
        }
    }

    /// The step missed cycles (`gap_us` since the last one): the encoders moved on
    /// meanwhile, and their decoders expect one period per sample. Feed each decoder (and
    /// the differentiator) the samples it missed as the last velocity predicts them, so the
    /// real sample that follows is judged against where the piston now is, not rejected as
    /// a jump. Up to 40 missed samples (2 ms); beyond that the extrapolation means nothing
    /// and the decoders judge the new sample as they would after a glitch. `config` gives
    /// the encoders and the period, `previous` the last cycle's positions and velocity.
    #[cold]
    #[inline(never)]
    pub(super) fn catch_up(&mut self, gap_us: i32, config: &ControlConfig, previous: &Previous) {
        let status = previous;
        let period = CONTROL_PERIOD_US as i32;
        let missed = ((gap_us + period / 2) / period - 1).clamp(0, CATCH_UP_SAMPLES as i32) as u32;
        let v = status.velocity_mps;
        let zero = self.zero_raw_m.unwrap_or(0.0);
        for section in Section::ALL {
            let (encoder, decoder, raw_m) = match section {
                Section::Master => (
                    config.encoder_master,
                    &mut self.encoders.master,
                    status.position_m + zero,
                ),
                Section::Slave => (
                    config.encoder_slave,
                    &mut self.encoders.slave,
                    status.slave_position_m + self.zero_slave_raw_m,
                ),
            };
            // The last angle from the last position (its 20 fraction bits are the angle's top
            // bits), and the step per period, in 2⁻³² periods (wrapping).
            let counts = (raw_m / encoder.m_per_count()) as i32;
            let mut angle = (counts as u32) << (32 - crate::sensing::encoder::POSITION_FRAC_BITS);
            let turns = v * config.sample_time_s / encoder.period_m;
            let step = (turns * 4_294_967_296.0) as i64 as u32;
            for _ in 0..missed {
                angle = angle.wrapping_add(step);
                let theta_rad = angle as f32 * (core::f32::consts::TAU / 4_294_967_296.0);
                let (s, c) = encoder.calibration.codes_at(theta_rad);
                let code = |x: f32| AdcCode(clamp_f32(x + 0.5, 0.0, 4095.0) as u16);
                let reading = decoder.update(crate::ports::SinCosCodes {
                    sin: code(s),
                    cos: code(c),
                });
                if section == Section::Master {
                    self.differentiator.push(reading.position);
                }
            }
        }
    }
}

/// The most missed samples the decoders are caught up over (2 ms): beyond it the
/// extrapolation means nothing.
pub(super) const CATCH_UP_SAMPLES: u32 = 40;

/// The chamber and line pressures as last seen valid, and whether they may still be used.
#[derive(Clone, Debug)]
pub(super) struct PressureMonitor {
    /// Last valid pressures: chamber A, chamber B, suction, discharge, Pa (NaN: none yet).
    pub last_pa: [f32; 4],
    /// Consecutive cycles with an invalid chamber-pressure sample.
    pub bad_cycles: u8,
    /// Chamber A and B readings watched for following the volume while running (a stuck
    /// sensor); one of the two is updated per cycle.
    pub stuck: [StuckMonitor; 2],
    /// Cycles counted for the plausibility check (it runs every 8th cycle).
    pub stuck_cycles: u8,
    /// The chamber pressures may be used in the feed-forward (false once one is found stuck).
    pub trusted: bool,
}

impl PressureMonitor {
    fn new() -> Self {
        PressureMonitor {
            last_pa: [f32::NAN; 4],
            bad_cycles: 0,
            stuck: [StuckMonitor::new(StuckConfig::reference()); 2],
            stuck_cycles: 0,
            trusted: true,
        }
    }

    /// The chamber pressures may be used: not found stuck, and this cycle's sample valid.
    pub(super) fn usable(&self) -> bool {
        self.trusted && self.bad_cycles == 0
    }

    /// One cycle's converted samples (chamber A, chamber B, suction, discharge): the valid
    /// ones become the last seen.
    #[inline]
    pub(super) fn remember(&mut self, samples: [PressureSample; 4]) {
        for (slot, sample) in self.last_pa.iter_mut().zip(samples) {
            if let Some(p) = sample.valid() {
                *slot = p;
            }
        }
    }

    /// Counts a cycle whose chamber samples were not both valid (`chambers_valid` false).
    /// True once two cycles in a row had one (one glitch is tolerated): the sensor fault
    /// ([`Fault::PressureSensor`]).
    #[inline]
    pub(super) fn count_invalid(&mut self, chambers_valid: bool) -> bool {
        self.bad_cycles = if chambers_valid {
            0
        } else {
            self.bad_cycles.saturating_add(1)
        };
        self.bad_cycles >= 2
    }

    /// A run starts: the stuck-sensor monitors judge its strokes afresh.
    pub(super) fn restart_stroke_watch(&mut self) {
        for m in &mut self.stuck {
            m.reset();
        }
    }

    /// One running cycle: every 8th, [`Self::check_follow_volume`] on the raw chamber codes
    /// at the master position `position_m`, m. True when a chamber sensor is found stuck.
    #[inline]
    pub(super) fn watch_stroke(&mut self, codes: &PressureCodes, position_m: f32) -> bool {
        self.stuck_cycles = self.stuck_cycles.wrapping_add(1);
        if self.stuck_cycles & 7 == 0 {
            self.check_follow_volume(codes, position_m)
        } else {
            false
        }
    }

    /// The chamber pressures must follow the volume while the piston strokes: a reading that
    /// stays flat over half a stroke each way is stuck (`pressure::StuckMonitor`), and from
    /// then on neither chamber pressure feeds the control law. Called every 8th cycle, for
    /// chamber A and B in turn (each every 0.8 ms: 3 mm of travel at 4 m/s, nothing next to
    /// the 0.1 m the check needs) to keep the 20 kHz step cheap. True when one is found stuck
    /// (the caller latches [`Fault::PressurePlausibility`]).
    #[cold]
    #[inline(never)]
    fn check_follow_volume(&mut self, codes: &PressureCodes, position_m: f32) -> bool {
        let (monitor, code) = if self.stuck_cycles & 8 == 0 {
            (&mut self.stuck[0], codes.chamber_a)
        } else {
            (&mut self.stuck[1], codes.chamber_b)
        };
        if monitor.update(code, position_m) {
            self.trusted = false;
            return true;
        }
        false
    }
}

/// What the sense stage found in one cycle.
#[derive(Clone, Copy, Debug)]
pub(super) struct Sensed {
    /// The master encoder's reading (its position replaced by the slave's if it failed).
    pub master: EncoderReading,
    /// The slave encoder's reading (likewise).
    pub slave: EncoderReading,
    /// Velocity and acceleration of the master position.
    pub derivatives: Derivatives,
    /// The master position in its encoder's own frame, m.
    pub raw_m: f32,
    /// The slave position in its encoder's own frame, m.
    pub slave_raw_m: f32,
    /// Master position from the homed zero, m.
    pub position_m: f32,
    /// Chamber A pressure as converted, Pa (meaningless where the sample is invalid).
    pub pressure_a_pa: f32,
    /// Chamber B pressure, likewise, Pa.
    pub pressure_b_pa: f32,
    /// Gas force for the feed-forward (0 when the pressures are not usable), N.
    pub gas_force_n: f32,
    /// The master section's force from its q-current of the last cycle, N.
    pub force_master_n: f32,
    /// The slave section's force, likewise, N.
    pub force_slave_n: f32,
}

/// What the encoder checks found this cycle.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum EncoderLoss {
    /// The encoder of this section was lost; the other stands in for it from now on.
    One(Section),
    /// Both are lost (at once, or the second after the first): nothing gives the position.
    Both,
}

impl Sensing {
    /// The deadline check: the time since the last cycle's sampling instant, µs, when it is
    /// more than 1.5 periods (at least one cycle was missed; the caller latches
    /// [`Fault::Deadline`](crate::safety::faults::Fault::Deadline) and catches the decoders
    /// up, [`Sensing::catch_up`]).
    #[inline]
    pub(super) fn overrun_us(&mut self, t: Ticks) -> Option<i32> {
        let late = self.last_t.and_then(|last| {
            let gap_us = t.since_us(last);
            (gap_us > (CONTROL_PERIOD_US * 3 / 2) as i32).then_some(gap_us)
        });
        self.last_t = Some(t);
        late
    }

    /// Both encoders' samples decoded: the master's reading and the slave's.
    ///
    /// Out of line, with both decoders inlined in it (the same layout as the drive's two
    /// current loops): no call apiece, and the decoders do not spill the step's values.
    #[inline(never)]
    pub(super) fn decode(&mut self, codes: &EncoderCodes) -> (EncoderReading, EncoderReading) {
        (
            self.encoders.master.update(codes.master),
            self.encoders.slave.update(codes.slave),
        )
    }

    /// Whether an encoder needs [`Sensing::encoder_fault`]: a filter tripped this cycle, or
    /// one was lost before.
    #[inline(always)]
    pub(super) fn encoder_trouble(&self, master: &EncoderReading, slave: &EncoderReading) -> bool {
        master.signal_fault || slave.signal_fault || self.lost_encoder.is_some()
    }

    /// The sense stage proper, once the encoders are decoded: the master position (`positions`,
    /// counts: the decoders' or the stand-in's) differentiated, both positions in metres, the
    /// pressures converted and checked, the sections' forces from their current loops'
    /// (`currents`) last q-currents. The second value: the chamber samples were invalid two cycles in
    /// a row (one glitch is tolerated), the sensor fault
    /// ([`Fault::PressureSensor`](crate::safety::faults::Fault::PressureSensor)).
    #[inline(always)]
    pub(super) fn measure(
        &mut self,
        c: &ControlConfig,
        (master, slave): (EncoderReading, EncoderReading),
        positions: (PositionCounts, PositionCounts),
        pressures: &PressureCodes,
        currents: &PerSection<CurrentController>,
    ) -> (Sensed, bool) {
        let (mut master, mut slave) = (master, slave);
        (master.position, slave.position) = positions;
        let derivatives = self.differentiator.push(master.position);
        let m_per_count = c.encoder_master.m_per_count();
        let raw_m = master.position.to_bits() as f32 * m_per_count;
        let mut slave_raw_m = c.encoder_slave.metres(slave.position);
        if let Some(map) = &c.encoder_map {
            // The slave's mapped difference from the master (paper §4.2), taken out of its
            // reading and of its section's commutation angle.
            map.correct(
                master.angle,
                derivatives.velocity_mps,
                &mut slave_raw_m,
                &mut slave.angle,
            );
        }
        let zero = self.zero_raw_m.unwrap_or(0.0);
        let position_m = raw_m - zero;

        let cal = c.pressure;
        let pa = cal.convert(pressures.chamber_a);
        let pb = cal.convert(pressures.chamber_b);
        let gas_force_n = match (pa.valid(), pb.valid()) {
            (Some(a), Some(b)) if self.pressures.trusted => c.cylinder.gas_force_n(a, b),
            _ => 0.0,
        };

        let ps = cal.convert(pressures.suction);
        let pd = cal.convert(pressures.discharge);
        self.pressures.remember([pa, pb, ps, pd]);

        // Measured section forces (before this cycle's FOC step: last cycle's state).
        let kf = c.motor.force_constant_n_per_a;
        let force_master_n = currents.master.state().current.q * kf;
        let force_slave_n = currents.slave.state().current.q * kf;

        // Invalid pressure samples never reach the control law (the gas feed-forward above
        // falls back to zero); two in a row are the sensor fault (one glitch is tolerated).
        let chambers_valid = pa.valid().is_some() && pb.valid().is_some();
        let pressures_failed = self.pressures.count_invalid(chambers_valid);
        let sensed = Sensed {
            master,
            slave,
            derivatives,
            raw_m,
            slave_raw_m,
            position_m,
            pressure_a_pa: pa.pressure_pa,
            pressure_b_pa: pb.pressure_pa,
            gas_force_n,
            force_master_n,
            force_slave_n,
        };
        (sensed, pressures_failed)
    }

    /// The rotation's quadrature count from the counter's `raw` 16 bits (unwrapped).
    #[inline(always)]
    pub(super) fn rotation_count(&mut self, raw: u16) -> i64 {
        self.quadrature.update(raw)
    }

    /// An encoder's error-rate filter tripped, or one was lost before; returns the master
    /// and slave positions, counts, to use from now on, and the loss found this cycle. One
    /// encoder lost while the other is good: the good one gives both positions, at the
    /// offset between them when the other was lost (it had extrapolated its last rejected
    /// samples, so the position runs on without a jump and the master/slave cross-check,
    /// which has nothing left to compare, stays quiet); its section is dropped (its
    /// commutation angle is gone) and the other section stops the piston
    /// ([`Trip::encoder_lost`](crate::safety::faults::Trip::encoder_lost)). Both lost:
    /// nothing tells where the piston is ([`EncoderLoss::Both`]: braking without position).
    #[cold]
    #[inline(never)]
    pub(super) fn encoder_fault(
        &mut self,
        c: &ControlConfig,
        master: &EncoderReading,
        slave: &EncoderReading,
    ) -> ((PositionCounts, PositionCounts), Option<EncoderLoss>) {
        let both = (master.position, slave.position);
        let failed = match (master.signal_fault, slave.signal_fault) {
            (true, true) => return (both, Some(EncoderLoss::Both)),
            (true, false) => Some(Section::Master),
            (false, true) => Some(Section::Slave),
            // Lost earlier by the cross-check.
            (false, false) => None,
        };
        let loss = match (failed, self.lost_encoder) {
            // The other one was lost before: none is left.
            (Some(f), Some(lost)) if f != lost => return (both, Some(EncoderLoss::Both)),
            (Some(f), None) => {
                self.lose_encoder(c, f, master, slave);
                Some(EncoderLoss::One(f))
            }
            _ => None,
        };
        let offset = self.slave_offset_counts;
        let positions = match self.lost_encoder {
            Some(Section::Master) => (slave.position.wrapping_add(offset), slave.position),
            Some(Section::Slave) => (master.position, master.position.wrapping_sub(offset)),
            None => both,
        };
        (positions, loss)
    }

    /// Takes `failed` out: the other encoder stands in for it from now on, at their present
    /// offset. The slave's zero moves to where the two agree now: the master/slave
    /// cross-check has nothing left to compare.
    pub(super) fn lose_encoder(
        &mut self,
        c: &ControlConfig,
        failed: Section,
        master: &EncoderReading,
        slave: &EncoderReading,
    ) {
        self.lost_encoder = Some(failed);
        self.slave_offset_counts = master.position.wrapping_sub(slave.position);
        let master_raw_m = c.encoder_master.metres(master.position);
        let slave_raw_m = c.encoder_slave.metres(slave.position);
        self.zero_slave_raw_m = slave_raw_m - (master_raw_m - self.zero_raw_m.unwrap_or(0.0));
    }

    /// The two encoders disagree: the one whose readings show it is wrong, if one does and
    /// no encoder was lost before — its error-rate filter is up, or its amplitude is off
    /// nominal by more than 20 % in power while the other's is within 10 % (a stuck channel
    /// passes the amplitude window near the axes and drifts before the filter trips) — and
    /// the other does not.
    #[cold]
    #[inline(never)]
    pub(super) fn suspect(
        &self,
        master: &EncoderReading,
        slave: &EncoderReading,
    ) -> Option<Section> {
        let odd = |r: &EncoderReading, d: &SinCosDecoder| {
            d.cause_present() || (r.amplitude_squared - 1.0).abs() > 0.2
        };
        let sound = |r: &EncoderReading, d: &SinCosDecoder| {
            !d.cause_present() && (r.amplitude_squared - 1.0).abs() < 0.1
        };
        let (dm, ds) = (&self.encoders.master, &self.encoders.slave);
        let suspect = if odd(master, dm) && sound(slave, ds) {
            Some(Section::Master)
        } else if odd(slave, ds) && sound(master, dm) {
            Some(Section::Slave)
        } else {
            None
        };
        suspect.filter(|_| self.lost_encoder.is_none())
    }

    /// Faults cleared: both decoders' filters reset, the stand-in ends, the chamber
    /// pressures are trusted again; after an encoder fault (`encoder_fault` true) the zero
    /// is lost and homing is required again.
    pub(super) fn clear_faults(&mut self, encoder_fault: bool) {
        self.encoders.master.clear_fault();
        self.encoders.slave.clear_fault();
        if encoder_fault {
            self.zero_raw_m = None;
        }
        self.lost_encoder = None;
        self.pressures.trusted = true;
    }

    /// Whether an encoder's signal is absent now (its error-rate filter above half its
    /// limit).
    pub(super) fn encoders_absent(&self) -> bool {
        self.encoders.master.cause_present() || self.encoders.slave.cause_present()
    }

    /// Whether a cause of a latched fault is still present: an encoder's, or an invalid
    /// chamber pressure.
    pub(super) fn cause_present(&self) -> bool {
        self.encoders.master.cause_present()
            || self.encoders.slave.cause_present()
            || self.pressures.bad_cycles > 0
    }
}
