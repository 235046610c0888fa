//! The loads of the force balance at every row — gas, cogging and friction by the model's
//! laws ([`super::residuals::force_terms`]) — kept per model for one log.
//!
//! The selection fits the mass, the actuator lag, the discovered terms and the log's force
//! alignment again and again on models whose loads are the same, and judges several
//! candidates on one model at every step; the loads (the friction law's transcendental
//! functions at every row) are most of a force residual's cost. A force residual made from
//! kept loads is the same, bit for bit, as one made afresh: the same terms in the same
//! order ([`fpc::physics::balance::PistonForces::unexplained_n`]).

use std::sync::{Arc, Mutex};

use fpc::physics::balance::PistonForces;

use crate::plant::model::extra_force::{ExtraForce, ExtraForceEffect};
use crate::plant::model::{ForceSensor, MachineModel};

/// Gas, cogging and friction force at every row, N (as [`PistonForces`] has them).
#[derive(Debug)]
pub struct Loads {
    gas_n: Vec<f64>,
    cogging_n: Vec<f64>,
    friction_n: Vec<f64>,
}

impl Loads {
    /// The loads of `terms` (the forces of the balance at every row), taken one row at a
    /// time: only the three columns are ever held.
    pub fn of_terms(terms: impl ExactSizeIterator<Item = PistonForces<f64>>) -> Self {
        let n = terms.len();
        let mut loads = Loads {
            gas_n: Vec::with_capacity(n),
            cogging_n: Vec::with_capacity(n),
            friction_n: Vec::with_capacity(n),
        };
        for f in terms {
            loads.gas_n.push(f.gas_n);
            loads.cogging_n.push(f.cogging_n);
            loads.friction_n.push(f.friction_n);
        }
        loads
    }

    /// The forces at row `i` with the motors' `motor_n` acting (none beyond the log).
    #[inline]
    fn at(&self, i: usize, motor_n: f64) -> PistonForces<f64> {
        let g = |v: &[f64]| v.get(i).copied().unwrap_or(0.0);
        PistonForces {
            motor_n,
            gas_n: g(&self.gas_n),
            cogging_n: g(&self.cogging_n),
            external_n: 0.0,
            friction_n: g(&self.friction_n),
        }
    }

    /// The raw force-balance residual, N: `m·ẍ` (`mass_kg`, `accel_mps2` per row) less the
    /// motor forces as they act (`acting_n`) and the loads, less the `extra_n` force where
    /// the model has one ([`PistonForces::unexplained_n`]).
    pub fn force_raw(
        &self,
        mass_kg: f64,
        accel_mps2: &[f64],
        acting_n: &[f64],
        extra_n: Option<&[f64]>,
    ) -> Vec<f64> {
        acting_n
            .iter()
            .zip(accel_mps2)
            .enumerate()
            .map(|(i, (motor, a))| {
                self.at(i, *motor).unexplained_n(mass_kg, *a)
                    - extra_n.and_then(|e| e.get(i)).unwrap_or(&0.0)
            })
            .collect()
    }

    /// The motor force that closes the balance at every row, N
    /// ([`PistonForces::motor_needed_n`]).
    pub fn motor_needed_n(&self, mass_kg: f64, accel_mps2: &[f64]) -> Vec<f64> {
        accel_mps2
            .iter()
            .enumerate()
            .map(|(i, a)| self.at(i, 0.0).motor_needed_n(mass_kg, *a))
            .collect()
    }
}

/// Loads kept by the model they were computed for, for one log (the rows of one
/// measured run, whatever its force alignment: the loads do not read the motor forces).
/// Shared between threads; a clone starts empty.
#[derive(Default)]
pub struct LoadCache {
    entries: Mutex<Vec<(MachineModel, Arc<Loads>)>>,
    extras: Mutex<Vec<(ExtraKey, Arc<Vec<f64>>)>>,
}

/// What an extra force at every row depends on beyond the log: the effect, the bits of the
/// actuator lag and of the log's force alignment, and the force readings (its `f_motor` term
/// is the motor forces as they act).
type ExtraKey = (ExtraForceEffect, u64, u64, ForceSensor);

impl LoadCache {
    /// Most models (and extra forces) kept, the least recently used dropped first: a step's
    /// model and the candidates being judged on it. Each is three (one) columns of the log's
    /// length.
    pub const CAPACITY: usize = 4;

    /// The loads of `model`, made by `make` (outside the lock) if not kept.
    pub fn of(&self, model: &MachineModel, make: impl FnOnce() -> Loads) -> Arc<Loads> {
        kept_or_made(&self.entries, load_key(model), make)
    }

    /// Drops every model's loads and extra force (they are made again when asked for).
    pub fn clear(&self) {
        if let Ok(mut e) = self.entries.lock() {
            e.clear();
        }
        if let Ok(mut e) = self.extras.lock() {
            e.clear();
        }
    }

    /// The extra force `effect` at every row with the actuator lag `delay_s`, the force
    /// alignment `align_s` and the force readings `sensor`, N, made by `make` (outside the
    /// lock) if not kept.
    pub fn extra(
        &self,
        effect: &ExtraForceEffect,
        (delay_s, align_s): (f64, f64),
        sensor: &ForceSensor,
        make: impl FnOnce() -> Vec<f64>,
    ) -> Arc<Vec<f64>> {
        // A force that does not read the motor forces is the same for every reading,
        // alignment and lag.
        let key = if ExtraForce::from(effect).reads_motor() {
            (
                effect.clone(),
                delay_s.to_bits(),
                align_s.to_bits(),
                *sensor,
            )
        } else {
            (effect.clone(), 0, 0, ForceSensor::default())
        };
        kept_or_made(&self.extras, key, make)
    }
}

/// The value kept under `key` in `entries` (then the most recently used), or made by `make`
/// outside the lock and kept, the least recently used dropped beyond
/// [`LoadCache::CAPACITY`].
fn kept_or_made<K: PartialEq, V>(
    entries: &Mutex<Vec<(K, Arc<V>)>>,
    key: K,
    make: impl FnOnce() -> V,
) -> Arc<V> {
    if let Ok(mut e) = entries.lock() {
        if let Some(i) = e.iter().position(|(k, _)| *k == key) {
            let hit = e.remove(i);
            let v = Arc::clone(&hit.1);
            e.push(hit);
            return v;
        }
    }
    let made = Arc::new(make());
    if let Ok(mut e) = entries.lock() {
        if !e.iter().any(|(k, _)| *k == key) {
            if e.len() >= LoadCache::CAPACITY {
                e.remove(0);
            }
            e.push((key, Arc::clone(&made)));
        }
    }
    made
}

impl Clone for LoadCache {
    fn clone(&self) -> Self {
        LoadCache::default()
    }
}

impl std::fmt::Debug for LoadCache {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let n = self.entries.lock().map_or(0, |e| e.len());
        write!(f, "LoadCache({n} models)")
    }
}

/// What the loads depend on: the model less the parameters they do not read (the mass, the
/// force readings, the actuator lag and the extra force enter the residual beside them).
fn load_key(model: &MachineModel) -> MachineModel {
    let mut k = model.clone();
    k.piston.mass_kg = 0.0;
    k.sensors.force = ForceSensor::default();
    k.effects.actuator_lag = None;
    k.effects.extra_force = None;
    k
}
