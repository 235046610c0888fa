//! Force allocation: one total force command per cycle, split over the two motor sections.
//!
//! The published rig fed the slave drive the master's force second-hand (0.75 ms late); here
//! both sections get their share of the same command in the same cycle. The split is equal
//! by default and weighted when a section is derated or lost; the cogging the calibrated map
//! predicts at the current position is cancelled in the same step. Each section's share is
//! then limited to what that section can deliver.

use crate::physics::cogging::HarmonicMap;
use crate::real::clamp_f32;
use crate::units::PerSection;

/// Allocation parameters.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AllocationConfig {
    /// Relative capability of each section as built, within [0, 1] (1 = nominal, 0 = not
    /// fitted; `ControlStep::new` refuses others, so [`allocate`] does not clamp it every
    /// cycle). The sections in service are the step's state: a section taken out after a
    /// fault is allocated 0 until the fault is cleared.
    pub capability: PerSection<f32>,
    /// Peak force one nominal section can deliver, N.
    pub section_limit_n: f32,
    /// Calibrated cogging map, cancelled by feed-forward.
    pub cogging: HarmonicMap,
}

impl AllocationConfig {
    /// Both sections nominal, 5 kN each, no cogging compensation.
    pub const fn reference() -> Self {
        AllocationConfig {
            capability: PerSection {
                master: 1.0,
                slave: 1.0,
            },
            section_limit_n: 5000.0,
            cogging: HarmonicMap::none(),
        }
    }
}

/// The forces to command, per section, for a total `force_n` at position `x_m`, shared in
/// proportion to `capability` (each section's, within [0, 1]: 0 out of service). NaN in, zero
/// out; each share saturates at its section's limit. Always inlined: it is part of the
/// control step (the calibration calls it too).
#[inline(always)]
pub fn allocate(
    config: &AllocationConfig,
    capability: PerSection<f32>,
    force_n: f32,
    x_m: f32,
) -> PerSection<f32> {
    let wanted = force_n - config.cogging.force_n(x_m);
    let (cm, cs) = (capability.master, capability.slave);
    let total = cm + cs;
    if wanted.is_nan() || total.is_nan() || total <= 0.0 {
        return PerSection::default();
    }
    let share = |c: f32| {
        let limit = config.section_limit_n * c;
        clamp_f32(wanted * c / total, -limit, limit)
    };
    PerSection {
        master: share(cm),
        slave: share(cs),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn equal_split_by_default_and_all_to_the_healthy_section() {
        let mut c = AllocationConfig::reference();
        let f = allocate(&c, c.capability, 3000.0, 0.1);
        assert_eq!((f.master, f.slave), (1500.0, 1500.0));
        c.capability.slave = 0.0;
        let f = allocate(&c, c.capability, 3000.0, 0.1);
        assert_eq!((f.master, f.slave), (3000.0, 0.0));
        let f = allocate(&c, c.capability, 9000.0, 0.1);
        assert_eq!(f.master, 5000.0);
        assert_eq!(
            allocate(&c, c.capability, f32::NAN, 0.1),
            PerSection::default()
        );
    }

    #[test]
    fn cogging_is_cancelled() {
        let mut c = AllocationConfig::reference();
        c.cogging.sin_n[0] = 30.0;
        // At a quarter period the map predicts +30 N: the motors supply 30 N less.
        let f = allocate(&c, c.capability, 0.0, 0.006);
        assert!((f.master + f.slave + 30.0).abs() < 0.1);
    }

    #[test]
    fn both_sections_lost_or_nan_capability_commands_nothing() {
        let mut c = AllocationConfig::reference();
        c.capability = PerSection {
            master: 0.0,
            slave: 0.0,
        };
        assert_eq!(
            allocate(&c, c.capability, 3000.0, 0.1),
            PerSection::default()
        );
        c.capability.master = f32::NAN;
        assert_eq!(
            allocate(&c, c.capability, 3000.0, 0.1),
            PerSection::default()
        );
    }

    #[test]
    fn the_step_refuses_a_capability_outside_zero_to_one() {
        use crate::control::config::{ConfigError, ControlConfig};
        use crate::control::step::ControlStep;
        for bad in [-0.1, 1.5, f32::NAN, f32::INFINITY] {
            let mut config = ControlConfig::reference();
            config.allocation.capability.slave = bad;
            assert_eq!(
                ControlStep::new(config).err(),
                Some(ConfigError::OutOfRange("allocation.capability.slave")),
                "{bad}"
            );
        }
    }
}
