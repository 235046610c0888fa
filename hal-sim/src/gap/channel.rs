//! The channels the workflow compares, and what their sensors resolve: the yardsticks below
//! which a change of a channel's residual is the sensors' own rounding, not an effect
//! ([`super::judge`] judges every candidate by them; the position offset's bound and the
//! pressure replay's angle mask use the encoder's and the pressure sensor's).

use crate::plant::model::MachineModel;

/// The channels compared.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum ChannelId {
    /// The force balance on the piston.
    Force,
    /// Slave-section force against the master's.
    SlaveForce,
    /// Slave encoder against the master encoder.
    Encoder,
    /// Chamber pressures against the replay.
    Pressure,
}

impl ChannelId {
    /// Every channel, in report order.
    pub const ALL: [ChannelId; 4] = [
        ChannelId::Force,
        ChannelId::SlaveForce,
        ChannelId::Encoder,
        ChannelId::Pressure,
    ];

    /// Name in the JSON and the report.
    pub fn name(self) -> &'static str {
        match self {
            ChannelId::Force => "force",
            ChannelId::SlaveForce => "slave_force",
            ChannelId::Encoder => "encoder",
            ChannelId::Pressure => "pressure",
        }
    }

    /// Unit of the residual.
    pub fn unit(self) -> &'static str {
        match self {
            ChannelId::Force | ChannelId::SlaveForce => "N",
            ChannelId::Encoder => "m",
            ChannelId::Pressure => "Pa",
        }
    }
}

/// Smallest RMS change of the force channels an effect must make, N: below the force the
/// drives can resolve (one current-sensor code is 4 N per phase) averaged over the band.
pub const FORCE_RESOLUTION_N: f64 = 2.0;

/// Smallest RMS change of the pressure channel, Pa (a third of the reference sensor's
/// 305 Pa code).
pub const PRESSURE_RESOLUTION_PA: f64 = 100.0;

/// The smallest RMS change of a channel's residual worth naming: what its sensors resolve.
/// The encoder's is one step of the sin/cos interpolation, `λ/(2π·amplitude)` (≈ 2.4 µm
/// on the reference encoder): patterns below it are the interpolation's own rounding.
pub fn resolution(ch: ChannelId, model: &MachineModel) -> f64 {
    match ch {
        ChannelId::Force | ChannelId::SlaveForce => FORCE_RESOLUTION_N,
        ChannelId::Encoder => {
            let amp = model.sensors.encoder_master.amplitude_codes.max(1.0);
            model.encoder.period_m / (std::f64::consts::TAU * amp)
        }
        ChannelId::Pressure => PRESSURE_RESOLUTION_PA,
    }
}

/// The smallest change of one kept sample selection's sparse test counts ([`super::judge`]): one code
/// of the sensor behind the channel. Force: one current-sensor code (`a_per_code` of the
/// reference current sense, 100/2048 A) times the force constant, ≈ 3.9 N on the reference
/// drives. Pressure: one code of the reference pressure sensor, ≈ 305 Pa. Encoder: one step
/// of the sin/cos interpolation, as [`resolution`] (already a per-sample yardstick).
pub fn sample_resolution(ch: ChannelId, model: &MachineModel) -> f64 {
    match ch {
        ChannelId::Force | ChannelId::SlaveForce => {
            f64::from(fpc::drive::foc::CurrentSense::reference().a_per_code)
                * model.motor.force_constant_n_per_a
        }
        ChannelId::Encoder => resolution(ch, model),
        ChannelId::Pressure => {
            f64::from(fpc::sensing::pressure::PressureCalibration::reference().pa_per_code)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn one_sample_is_judged_by_a_whole_code_and_an_rms_by_a_fraction_of_one() {
        let m = MachineModel::reference();
        for ch in ChannelId::ALL {
            assert!(
                sample_resolution(ch, &m) >= resolution(ch, &m),
                "{ch:?}: a single sample cannot resolve more finely than an RMS"
            );
        }
        // The relation of the two yardsticks (the selection's rules, `super::judge`): the averaged yardstick is a third of a pressure
        // code and half a current code (within the codes' rounding to whole pascal/newtons).
        let near = |a: f64, b: f64| (a - b).abs() <= 0.05 * b;
        let p = ChannelId::Pressure;
        let f = ChannelId::Force;
        assert!(near(3.0 * resolution(p, &m), sample_resolution(p, &m)));
        assert!(near(2.0 * resolution(f, &m), sample_resolution(f, &m)));
    }
}
