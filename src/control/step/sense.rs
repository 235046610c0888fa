//! The sense stage: what the samples say about the machine, and what a failed encoder
//! changes (the other stands in for it, its section is dropped).

use super::{ControlStep, CycleInputs};
use crate::real::clamp_f32;
use crate::safety::faults::{Fault, Reaction};
use crate::sensing::differentiator::Derivatives;
use crate::sensing::encoder::{EncoderReading, PositionCounts, SinCosDecoder};
use crate::units::{AdcCode, Section, Ticks, CONTROL_PERIOD_US};

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

impl ControlStep {
    /// The deadline check: a gap of more than 1.5 periods since the last cycle means at
    /// least one was missed (the decoders are caught up, the fault latched).
    pub(super) fn check_deadline(&mut self, t: Ticks) {
        if let Some(last) = self.last_t {
            let gap_us = t.since_us(last);
            if gap_us > (CONTROL_PERIOD_US * 3 / 2) as i32 {
                self.latch(Fault::Deadline);
                self.catch_up(gap_us);
            }
        }
        self.last_t = Some(t);
    }

    /// The sense stage: both encoders decoded (a failed one replaced by the other), the
    /// master position differentiated, the pressures converted and checked, the rotation's
    /// count read, and the section forces of the last cycle's currents.
    pub(super) fn sense(&mut self, inputs: &CycleInputs) -> Sensed {
        let mut master = self.encoders.master.update(inputs.encoders.master);
        let mut slave = self.encoders.slave.update(inputs.encoders.slave);
        if master.signal_fault || slave.signal_fault || self.lost_encoder.is_some() {
            (master.position, slave.position) = self.encoder_fault(&master, &slave);
        }
        let derivatives = self.differentiator.push(master.position);
        let m_per_count = self.config.encoder_master.m_per_count();
        let raw_m = master.position.to_bits() as f32 * m_per_count;
        let slave_raw_m = self.config.encoder_slave.metres(slave.position);
        let zero = self.zero_raw_m.unwrap_or(0.0);
        let position_m = raw_m - zero;

        let cal = self.config.pressure;
        let pa = cal.convert(inputs.pressures.chamber_a);
        let pb = cal.convert(inputs.pressures.chamber_b);
        let gas_force_n = match (pa.valid(), pb.valid()) {
            (Some(a), Some(b)) if self.pressures_trusted => self.config.cylinder.gas_force_n(a, b),
            _ => 0.0,
        };

        let ps = cal.convert(inputs.pressures.suction);
        let pd = cal.convert(inputs.pressures.discharge);
        for (slot, sample) in self.pressures_pa.iter_mut().zip([pa, pb, ps, pd]) {
            if let Some(p) = sample.valid() {
                *slot = p;
            }
        }

        let count = self.quadrature.update(inputs.quadrature);
        self.servo.observe(count);

        // Measured section forces (before this cycle's FOC step: last cycle's state).
        let kf = self.config.motor.force_constant_n_per_a;
        let force_master_n = self.currents.master.state().current.q * kf;
        let force_slave_n = self.currents.slave.state().current.q * kf;

        // Invalid pressure samples never reach the control law (the gas feed-forward above
        // falls back to zero); two in a row latch the fault (one glitch is tolerated).
        let pressures_valid = pa.valid().is_some() && pb.valid().is_some();
        self.pressure_bad = if pressures_valid {
            0
        } else {
            self.pressure_bad.saturating_add(1)
        };
        if self.pressure_bad >= 2 {
            self.latch(Fault::PressureSensor);
        }
        if self.running() {
            self.stuck_cycles = self.stuck_cycles.wrapping_add(1);
            if self.stuck_cycles & 7 == 0 {
                self.check_pressures_follow_volume(inputs, position_m);
            }
        }
        Sensed {
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
        }
    }

    /// An encoder's error-rate filter tripped, or one was lost before; returns the master
    /// and slave positions, counts, to use from now on. One encoder lost while the other is
    /// good: the good one gives both positions, at the offset between them when the other
    /// was lost (it had extrapolated its last rejected samples, so the position runs on
    /// without a jump and the master/slave cross-check, which has nothing left to compare,
    /// stays quiet); the lost one's section is dropped (its commutation angle is gone) and
    /// the other section stops the piston (SS1). Both lost: nothing tells where the piston
    /// is: STO, then braking without position ([`Reaction::BrakeWithoutPosition`]).
    #[cold]
    #[inline(never)]
    pub(super) fn encoder_fault(
        &mut self,
        master: &EncoderReading,
        slave: &EncoderReading,
    ) -> (PositionCounts, PositionCounts) {
        let both = (master.position, slave.position);
        let failed = match (master.signal_fault, slave.signal_fault) {
            (true, true) => {
                self.latch(Fault::EncoderSignal);
                return both;
            }
            (true, false) => Some(Section::Master),
            (false, true) => Some(Section::Slave),
            // Lost earlier by the cross-check.
            (false, false) => None,
        };
        match (failed, self.lost_encoder) {
            (Some(f), Some(lost)) if f != lost => {
                // The other one was lost before: none is left.
                self.latch(Fault::EncoderSignal);
                return both;
            }
            (Some(f), None) => {
                // The other stands in: SS1 on its section, unless the two disagreed before
                // (then neither is trusted: STO).
                let reaction = if self.faults.contains(Fault::EncoderMismatch) {
                    Reaction::Sto
                } else {
                    Reaction::Ss1
                };
                self.lose_encoder(f, master, slave);
                self.react(Fault::EncoderSignal, reaction);
            }
            _ => {}
        }
        let offset = self.slave_offset_counts;
        match self.lost_encoder {
            Some(Section::Master) => (slave.position.wrapping_add(offset), slave.position),
            Some(Section::Slave) => (master.position, master.position.wrapping_sub(offset)),
            None => both,
        }
    }

    /// Takes `failed` out: the other encoder stands in for it from now on, at their present
    /// offset, and its section is dropped. The slave's zero moves to where the two agree
    /// now: the master/slave cross-check has nothing left to compare.
    pub(super) fn lose_encoder(
        &mut self,
        failed: Section,
        master: &EncoderReading,
        slave: &EncoderReading,
    ) {
        self.lost_encoder = Some(failed);
        self.slave_offset_counts = master.position.wrapping_sub(slave.position);
        let master_raw_m = self.config.encoder_master.metres(master.position);
        let slave_raw_m = self.config.encoder_slave.metres(slave.position);
        self.zero_slave_raw_m = slave_raw_m - (master_raw_m - self.zero_raw_m.unwrap_or(0.0));
        self.drop_section(if failed == Section::Master { 0 } else { 1 });
    }

    /// The two encoders disagree. If one of them looks wrong — its error-rate filter is up,
    /// or its amplitude is off nominal by more than 20 % in power while the other's is within
    /// 10 % (a stuck channel passes the amplitude window near the axes and drifts before
    /// the filter trips) — and the other does not, the other is trusted: the suspect is lost
    /// as if its filter had tripped, and SS1 runs on the other (the position carries at most
    /// the disagreement, 2 mm). Otherwise nothing says which one is right: STO. Returns the
    /// reaction for the supervise stage to carry out.
    #[cold]
    #[inline(never)]
    pub(super) fn encoder_mismatch(
        &mut self,
        master: &EncoderReading,
        slave: &EncoderReading,
    ) -> Reaction {
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
        match (suspect, self.lost_encoder) {
            (Some(s), None) => {
                self.lose_encoder(s, master, slave);
                Reaction::Ss1
            }
            _ => Reaction::Sto,
        }
    }

    /// The step missed cycles (`gap_us` since the last one): the encoders moved on
    /// meanwhile, and their decoders expect one period per sample. Feed each decoder (and
    /// the differentiator) the samples it missed as the last velocity predicts them, so the
    /// real sample that follows is judged against where the piston now is, not rejected as
    /// a jump. Up to 40 missed samples (2 ms); beyond that the extrapolation means nothing
    /// and the decoders judge the new sample as they would after a glitch.
    #[cold]
    #[inline(never)]
    pub(super) fn catch_up(&mut self, gap_us: i32) {
        let period = CONTROL_PERIOD_US as i32;
        let missed = ((gap_us + period / 2) / period - 1).clamp(0, 40) as u32;
        let v = self.status.velocity_mps;
        let zero = self.zero_raw_m.unwrap_or(0.0);
        for section in Section::ALL {
            let (config, decoder, raw_m) = match section {
                Section::Master => (
                    self.config.encoder_master,
                    &mut self.encoders.master,
                    self.status.position_m + zero,
                ),
                Section::Slave => (
                    self.config.encoder_slave,
                    &mut self.encoders.slave,
                    self.status.slave_position_m + self.zero_slave_raw_m,
                ),
            };
            // The last angle from the last position (its 20 fraction bits are the angle's top
            // bits), and the step per period, in 2⁻³² periods (wrapping).
            let counts = (raw_m / config.m_per_count()) as i32;
            let mut angle = (counts as u32) << (32 - crate::sensing::encoder::POSITION_FRAC_BITS);
            let turns = v * self.config.sample_time_s / config.period_m;
            let step = (turns * 4_294_967_296.0) as i64 as u32;
            for _ in 0..missed {
                angle = angle.wrapping_add(step);
                let theta_rad = angle as f32 * (core::f32::consts::TAU / 4_294_967_296.0);
                let (s, c) = config.calibration.codes_at(theta_rad);
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

    /// The chamber pressures must follow the volume while the piston strokes: a reading that
    /// stays flat over half a stroke each way is stuck (`pressure::StuckMonitor`), and from
    /// then on neither chamber pressure feeds the control law. Called every 8th cycle, for
    /// chamber A and B in turn (each every 0.8 ms: 3 mm of travel at 4 m/s, nothing next to
    /// the 0.1 m the check needs) to keep the 20 kHz step cheap.
    #[cold]
    #[inline(never)]
    pub(super) fn check_pressures_follow_volume(&mut self, inputs: &CycleInputs, position_m: f32) {
        let (monitor, code) = if self.stuck_cycles & 8 == 0 {
            (&mut self.stuck[0], inputs.pressures.chamber_a)
        } else {
            (&mut self.stuck[1], inputs.pressures.chamber_b)
        };
        if monitor.update(code, position_m) {
            self.pressures_trusted = false;
            self.latch(Fault::PressurePlausibility);
        }
    }
}
