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

/// How the total force is split this cycle: each section's fraction of it and the force it
/// may be given, N. Taken where the sections in service change ([`Split::of`]), not formed
/// every cycle.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Split {
    /// Each section's fraction of the total, `c/(c_master + c_slave)` (0 for both when no
    /// section is in service).
    pub fraction: PerSection<f32>,
    /// Each section's limit, `section_limit_n·c`, N.
    pub limit_n: PerSection<f32>,
}

impl Split {
    /// The split in proportion to `capability` (each section's, within [0, 1]: 0 out of
    /// service) of sections that can each deliver `section_limit_n`, N. No section in
    /// service (or a NaN capability): nothing to anyone.
    pub fn of(section_limit_n: f32, capability: PerSection<f32>) -> Split {
        let (cm, cs) = (capability.master, capability.slave);
        let total = cm + cs;
        if total.is_nan() || total <= 0.0 {
            return Split {
                fraction: PerSection::default(),
                limit_n: PerSection::default(),
            };
        }
        Split {
            fraction: PerSection {
                master: cm / total,
                slave: cs / total,
            },
            limit_n: PerSection {
                master: section_limit_n * cm,
                slave: section_limit_n * cs,
            },
        }
    }
}

/// The forces to command, per section, for a total `force_n` at position `x_m`, shared in
/// proportion to `capability` (each section's, within [0, 1]: 0 out of service). NaN in, zero
/// out; each share saturates at its section's limit.
pub fn allocate(
    config: &AllocationConfig,
    capability: PerSection<f32>,
    force_n: f32,
    x_m: f32,
) -> PerSection<f32> {
    let split = Split::of(config.section_limit_n, capability);
    allocate_split(&config.cogging, &split, force_n, x_m)
}

/// [`allocate`] with the split taken ([`Split::of`]): the total `force_n` less the cogging
/// `cogging` predicts at `x_m`, times each section's fraction, within its limit. NaN in,
/// zero out. Always inlined: it is part of the control step.
#[inline(always)]
pub fn allocate_split(
    cogging: &HarmonicMap,
    split: &Split,
    force_n: f32,
    x_m: f32,
) -> PerSection<f32> {
    let wanted = force_n - cogging.force_n(x_m);
    if wanted.is_nan() {
        return PerSection::default();
    }
    let share = |fraction: f32, limit: f32| clamp_f32(wanted * fraction, -limit, limit);
    PerSection {
        master: share(split.fraction.master, split.limit_n.master),
        slave: share(split.fraction.slave, split.limit_n.slave),
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
