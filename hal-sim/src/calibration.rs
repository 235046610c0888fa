//! Calibration files: the firmware's calibration record as TOML a person can read and diff,
//! the simulated commissioning that produces one (`fpc-sim calibrate`), the wiring check
//! (`fpc-sim calibrate --check-wiring`, the firmware's `commission` routine) and the
//! simulated board's flash holding one (`fpc-sim run --calibration`).
//!
//! The file carries exactly what [`CalibrationRecord`] does, in the units an operator reads:
//! angle offsets in electrical degrees (converted exactly: a wrapping u32 angle is a whole
//! multiple of 360°/2³², which an f64 holds), everything else in the record's own units
//! (ADC codes, m, N, rad). Every section and key is required and an unknown one is refused,
//! so a file that loads is a complete calibration.

use std::path::Path;

use fpc::control::calibration::record::CalibrationRecord;
use fpc::control::calibration::{Calibrated, Commissioning, Misalignment, Routine};
use fpc::control::command::Command;
use fpc::control::config::ControlConfig;
use fpc::control::step::{ControlStep, CycleInputs};
use fpc::physics::cogging::{HarmonicMap, MAP_HARMONICS};
use fpc::ports::{
    CurrentInput, EncoderInput, PressureInput, PwmOutput, QuadratureInput, TorqueOutput,
};
use fpc::sensing::encoder::SinCosCalibration;
use fpc::status::ModeKind;
use fpc::units::{PerSection, Section};
use serde::{Deserialize, Serialize};

use crate::board::wiring::Wiring;
use crate::board::world::peripherals;
use crate::plant::model::MachineModel;

pub use crate::board::flash::{holding as flash_holding, store, STORE_PAGES};

/// Largest calibration file read, bytes (a real one is about 1.5 KiB).
pub const MAX_FILE_BYTES: u64 = 64 * 1024;

#[derive(Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct File {
    format_version: u16,
    current_sense: CurrentSenseToml,
    alignment: AlignmentToml,
    misalignment: MisalignmentToml,
    cogging: CoggingToml,
    encoder: PerSectionToml<SinCosToml>,
}

#[derive(Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct CurrentSenseToml {
    master_offset_codes: [f64; 3],
    slave_offset_codes: [f64; 3],
}

#[derive(Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct AlignmentToml {
    master_angle_offset_deg: f64,
    slave_angle_offset_deg: f64,
}

#[derive(Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct MisalignmentToml {
    slave_angle_offset_deg: f64,
    correction_periods: f64,
    misalignment_m: f64,
    encoder_offset_m: f64,
}

#[derive(Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct CoggingToml {
    period_m: f64,
    sin_n: [f64; MAP_HARMONICS],
    cos_n: [f64; MAP_HARMONICS],
}

#[derive(Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct PerSectionToml<T> {
    master: T,
    slave: T,
}

#[derive(Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct SinCosToml {
    sin_offset_codes: f64,
    cos_offset_codes: f64,
    sin_amplitude_codes: f64,
    cos_amplitude_codes: f64,
    phase_rad: f64,
}

/// The f32 as the shortest decimal that reads back to it (what a person wants to see).
fn short(v: f32) -> f64 {
    v.to_string().parse().unwrap_or(f64::from(v))
}

fn deg(angle: u32) -> f64 {
    f64::from(angle as i32) * 360.0 / 4_294_967_296.0
}

fn angle(deg: f64) -> u32 {
    (deg / 360.0 * 4_294_967_296.0).round() as i64 as u32
}

/// The record as TOML, with a header saying what it is.
pub fn to_toml(record: &CalibrationRecord, source: &str) -> Result<String, String> {
    let c = &record.calibrated;
    let missing = |r: Routine| format!("the record has no {} result", r.name());
    let sense = c
        .current_sense
        .ok_or_else(|| missing(Routine::CurrentSense))?;
    let align = c.alignment.ok_or_else(|| missing(Routine::Alignment))?;
    let mis = c
        .misalignment
        .ok_or_else(|| missing(Routine::Misalignment))?;
    let map = c.cogging.ok_or_else(|| missing(Routine::Cogging))?;
    let sin_cos = |s: SinCosCalibration| SinCosToml {
        sin_offset_codes: short(s.sin_offset),
        cos_offset_codes: short(s.cos_offset),
        sin_amplitude_codes: short(s.sin_amplitude),
        cos_amplitude_codes: short(s.cos_amplitude),
        phase_rad: short(s.phase_rad),
    };
    let file = File {
        format_version: fpc::control::calibration::record::RECORD_VERSION,
        current_sense: CurrentSenseToml {
            master_offset_codes: sense.master.map(short),
            slave_offset_codes: sense.slave.map(short),
        },
        alignment: AlignmentToml {
            master_angle_offset_deg: deg(align.master),
            slave_angle_offset_deg: deg(align.slave),
        },
        misalignment: MisalignmentToml {
            slave_angle_offset_deg: deg(mis.slave_angle_offset),
            correction_periods: short(mis.correction_periods),
            misalignment_m: short(mis.misalignment_m),
            encoder_offset_m: short(mis.encoder_offset_m),
        },
        cogging: CoggingToml {
            period_m: short(map.period_m),
            sin_n: map.sin_n.map(short),
            cos_n: map.cos_n.map(short),
        },
        encoder: PerSectionToml {
            master: sin_cos(record.sin_cos.master),
            slave: sin_cos(record.sin_cos.slave),
        },
    };
    let mut body = toml::to_string(&file).map_err(|e| e.to_string())?;
    if !body.ends_with('\n') {
        body.push('\n');
    }
    Ok(format!(
        "# fpc calibration: what the Calibrate routines found ({source}).\n\
         # current_sense: phase-current ADC zero, codes from mid-scale; alignment: each\n\
         # section's electrical-angle offset, degrees electrical; misalignment: the slave's\n\
         # refined offset and D_dif; cogging: F(x) = sum sin_n[k] sin(2pi(k+1)x/p) + cos_n[k] cos(..), N;\n\
         # encoder: sin/cos channel correction. `fpc-sim run --calibration FILE` loads it.\n\n{body}"
    ))
}

/// Parses a calibration file; the error names the key (and line) at fault.
pub fn parse(text: &str) -> Result<CalibrationRecord, String> {
    let file: File =
        toml::from_str(text).map_err(|e| crate::plant::model::describe_toml(&e, text))?;
    let version = fpc::control::calibration::record::RECORD_VERSION;
    if file.format_version != version {
        return Err(format!(
            "format_version = {}: this firmware reads version {version}; calibrate again",
            file.format_version
        ));
    }
    let finite = |key: &str, v: f64| -> Result<f32, String> {
        let f = v as f32;
        if f.is_finite() {
            Ok(f)
        } else {
            Err(format!(
                "{key} = {}: not a finite number",
                crate::failure::num(v)
            ))
        }
    };
    let angle_of = |key: &str, v: f64| -> Result<u32, String> {
        if v.is_finite() && v.abs() <= 180.0 {
            Ok(angle(v))
        } else {
            Err(format!(
                "{key} = {}: an angle offset is within [-180, 180] degrees",
                crate::failure::num(v)
            ))
        }
    };
    let codes = |key: &str, v: [f64; 3]| -> Result<[f32; 3], String> {
        Ok([finite(key, v[0])?, finite(key, v[1])?, finite(key, v[2])?])
    };
    let s = &file.current_sense;
    let a = &file.alignment;
    let m = &file.misalignment;
    let g = &file.cogging;
    let mut map = HarmonicMap {
        period_m: finite("cogging.period_m", g.period_m)?,
        sin_n: [0.0; MAP_HARMONICS],
        cos_n: [0.0; MAP_HARMONICS],
    };
    if map.period_m <= 0.0 {
        return Err(format!(
            "cogging.period_m = {}: must be positive",
            crate::failure::num(g.period_m)
        ));
    }
    for (out, v) in map.sin_n.iter_mut().zip(g.sin_n) {
        *out = finite("cogging.sin_n", v)?;
    }
    for (out, v) in map.cos_n.iter_mut().zip(g.cos_n) {
        *out = finite("cogging.cos_n", v)?;
    }
    let sin_cos = |name: &str, t: &SinCosToml| -> Result<SinCosCalibration, String> {
        let key = |k: &str| format!("encoder.{name}.{k}");
        let c = SinCosCalibration {
            sin_offset: finite(&key("sin_offset_codes"), t.sin_offset_codes)?,
            cos_offset: finite(&key("cos_offset_codes"), t.cos_offset_codes)?,
            sin_amplitude: finite(&key("sin_amplitude_codes"), t.sin_amplitude_codes)?,
            cos_amplitude: finite(&key("cos_amplitude_codes"), t.cos_amplitude_codes)?,
            phase_rad: finite(&key("phase_rad"), t.phase_rad)?,
        };
        if c.sin_amplitude <= 0.0 || c.cos_amplitude <= 0.0 {
            return Err(format!(
                "{}: amplitudes must be positive",
                key("*_amplitude_codes")
            ));
        }
        if c.phase_rad.abs() >= 0.5 {
            return Err(format!(
                "{} must be within (-0.5, 0.5) rad",
                key("phase_rad")
            ));
        }
        Ok(c)
    };
    Ok(CalibrationRecord {
        calibrated: Calibrated {
            current_sense: Some(PerSection {
                master: codes("current_sense.master_offset_codes", s.master_offset_codes)?,
                slave: codes("current_sense.slave_offset_codes", s.slave_offset_codes)?,
            }),
            alignment: Some(PerSection {
                master: angle_of(
                    "alignment.master_angle_offset_deg",
                    a.master_angle_offset_deg,
                )?,
                slave: angle_of("alignment.slave_angle_offset_deg", a.slave_angle_offset_deg)?,
            }),
            misalignment: Some(Misalignment {
                slave_angle_offset: angle_of(
                    "misalignment.slave_angle_offset_deg",
                    m.slave_angle_offset_deg,
                )?,
                correction_periods: finite(
                    "misalignment.correction_periods",
                    m.correction_periods,
                )?,
                misalignment_m: finite("misalignment.misalignment_m", m.misalignment_m)?,
                encoder_offset_m: finite("misalignment.encoder_offset_m", m.encoder_offset_m)?,
            }),
            cogging: Some(map),
            commission: None,
            last_error: None,
        },
        sin_cos: PerSection {
            master: sin_cos("master", &file.encoder.master)?,
            slave: sin_cos("slave", &file.encoder.slave)?,
        },
    })
}

/// Reads a calibration file (at most [`MAX_FILE_BYTES`]); the error names the file and
/// the key at fault.
pub fn read(path: &Path) -> Result<CalibrationRecord, String> {
    use std::io::Read;
    let fail = |what: String| format!("--calibration {}: {what}", crate::output::show(path));
    let file = std::fs::File::open(path).map_err(|e| fail(e.to_string()))?;
    let mut bytes = Vec::new();
    file.take(MAX_FILE_BYTES + 1)
        .read_to_end(&mut bytes)
        .map_err(|e| fail(e.to_string()))?;
    if bytes.len() as u64 > MAX_FILE_BYTES {
        return Err(fail(format!(
            "larger than {MAX_FILE_BYTES} bytes, which no calibration file is"
        )));
    }
    let text = String::from_utf8(bytes).map_err(|e| {
        fail(format!(
            "not UTF-8 text (byte {})",
            e.utf8_error().valid_up_to()
        ))
    })?;
    parse(&text).map_err(fail)
}

/// One routine (or homing) of a commissioning, and how long it took on the machine.
#[derive(Clone, Debug, Serialize)]
pub struct Stage {
    /// `current_sense`, `alignment`, `home`, `misalignment` or `cogging`.
    pub name: &'static str,
    /// Simulated time it took, s.
    pub duration_s: f64,
}

/// Commissions the simulated `model` as on a new machine: the firmware's control step,
/// configured with the model's machine parameters but nothing the calibration finds
/// (no cogging map, zero offsets), runs current sense, alignment, homing, misalignment and
/// cogging; the record it hands for saving is returned with the stages' durations.
pub fn commission(
    model: &MachineModel,
    seed: u64,
) -> Result<(CalibrationRecord, Vec<Stage>), String> {
    let mut config = crate::run::control_config(model);
    config.allocation.cogging = HarmonicMap::none();
    let plan: [(&'static str, Command); 5] = [
        ("current_sense", calibrate(Routine::CurrentSense)),
        ("alignment", calibrate(Routine::Alignment)),
        ("home", Command::Home),
        ("misalignment", calibrate(Routine::Misalignment)),
        ("cogging", calibrate(Routine::Cogging)),
    ];
    let (_, record, stages) = run_plan(model, config, seed, &plan, &Wiring::default(), 0.05)?;
    let record = record.ok_or("no routine handed a record to save")?;
    if !record.is_complete() {
        return Err("the commissioning left the record incomplete".into());
    }
    Ok((record, stages))
}

/// Maps the slave encoder's difference from the master's on the simulated `model` (the
/// firmware's `EncoderMap` routine after homing, the controller configured with the model's
/// own parameters, as `fpc-sim run` configures it).
pub fn map_encoders(
    model: &MachineModel,
    seed: u64,
) -> Result<fpc::control::calibration::EncoderMap, String> {
    let plan = [
        ("home", Command::Home),
        ("encoder_map", calibrate(Routine::EncoderMap)),
    ];
    let config = crate::run::control_config(model);
    let (step, _, _) = run_plan(model, config, seed, &plan, &Wiring::default(), 0.05)?;
    step.config()
        .encoder_map
        .ok_or_else(|| "the encoder map routine loaded no map".to_string())
}

/// Checks the wiring of the simulated `model`, wired as `wiring` says, with the piston
/// resting at `start_m`: the firmware's current-sense and commissioning routines, the
/// controller configured with the model's machine parameters (as `fpc-sim run` configures
/// it). What the commissioning found, and the stages' durations.
pub fn check_wiring(
    model: &MachineModel,
    wiring: &Wiring,
    seed: u64,
    start_m: f64,
) -> Result<(Commissioning, Vec<Stage>), String> {
    let plan = [
        ("current_sense", calibrate(Routine::CurrentSense)),
        ("commission", calibrate(Routine::Commission)),
    ];
    let config = crate::run::control_config(model);
    let (step, _, stages) = run_plan(model, config, seed, &plan, wiring, start_m)?;
    let found = step
        .calibrated()
        .commission
        .ok_or("the commissioning reported nothing")?;
    Ok((found, stages))
}

/// What the commissioning found, a line each, as the host prints them: each section's
/// phase order and each encoder's direction (or the two explanations that cannot be told
/// apart), then each section's pitch against `config`'s electrical period.
pub fn commission_lines(found: &Commissioning, config: &ControlConfig) -> Vec<String> {
    crate::link::report::findings_lines(
        found,
        config.motor.electrical_period_m,
        config.calibration.commission_pitch_tolerance,
    )
}

/// Runs the firmware's control step, configured with `config`, on the simulated `model`
/// wired as `wiring` says, with the piston resting at `start_m`, through `plan` (each
/// command run until the machine leaves its mode and returns); the step, the last record it
/// handed for saving, and the stages' durations.
fn run_plan(
    model: &MachineModel,
    config: ControlConfig,
    seed: u64,
    plan: &[(&'static str, Command)],
    wiring: &Wiring,
    start_m: f64,
) -> Result<(ControlStep, Option<CalibrationRecord>, Vec<Stage>), String> {
    let mut step = ControlStep::new(config).map_err(|e| format!("configuration: {e:?}"))?;
    let mut world = crate::run::world(model, seed, 0, start_m);
    world.set_wiring(*wiring);
    let world = std::rc::Rc::new(std::cell::RefCell::new(world));
    let mut io = peripherals(&world);
    let mut enabled = false;
    let mut stages = Vec::new();
    let mut record = None;
    for &(name, command) in plan {
        step.command(command)
            .map_err(|r| format!("{name} refused: {}", r.reason()))?;
        let t0 = world.borrow().time_s();
        let limit_s = 60.0;
        let mut left = false;
        loop {
            // One control period, as the control task runs it.
            let t = world.borrow().ticks();
            let inputs = CycleInputs {
                t,
                encoders: EncoderInput::read(&mut io),
                currents: PerSection {
                    master: CurrentInput::read(&mut io, Section::Master),
                    slave: CurrentInput::read(&mut io, Section::Slave),
                },
                quadrature: QuadratureInput::count(&mut io),
                pressures: PressureInput::read(&mut io),
            };
            let out = step.step(&inputs);
            match out.pwm {
                Some(d) => {
                    PwmOutput::write(&mut io, Section::Master, d.master);
                    PwmOutput::write(&mut io, Section::Slave, d.slave);
                    PwmOutput::enable(&mut io, out.sections);
                    enabled = true;
                }
                None if enabled => {
                    PwmOutput::disable(&mut io);
                    enabled = false;
                }
                None => {}
            }
            TorqueOutput::write(&mut io, out.servo);
            if let Some(r) = step.take_calibration_to_save() {
                record = Some(r);
            }
            world.borrow_mut().advance();
            let s = step.status();
            if let Some(f) = s.faults.first() {
                return Err(format!("{name}: fault {} latched", f.name()));
            }
            let busy = matches!(s.mode, ModeKind::Calibrating | ModeKind::Homing)
                || (name == "home" && s.mode != ModeKind::Holding);
            left |= busy;
            if left && !busy {
                break;
            }
            if world.borrow().time_s() - t0 > limit_s {
                return Err(format!("{name} did not end within {limit_s} s simulated"));
            }
        }
        if let Some((routine, e)) = step.calibrated().last_error {
            return Err(format!("{} failed: {e}", routine.name()));
        }
        stages.push(Stage {
            name,
            duration_s: world.borrow().time_s() - t0,
        });
    }
    Ok((step, record, stages))
}

fn calibrate(routine: Routine) -> Command {
    Command::Calibrate { routine }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_file_round_trips_the_record_bit_for_bit() {
        let r = CalibrationRecord::example();
        let text = to_toml(&r, "test").unwrap();
        assert_eq!(parse(&text), Ok(r), "{text}");
    }

    #[test]
    fn a_bad_file_is_refused_naming_the_key() {
        let text = to_toml(&CalibrationRecord::example(), "test").unwrap();
        let cases = [
            ("misalignment_m = ", "misalignment_mm = ", "misalignment_mm"),
            ("period_m = 0.024", "period_m = -0.024", "cogging.period_m"),
            ("format_version = 1", "format_version = 7", "format_version"),
            ("phase_rad = 0.0\n", "phase_rad = nan\n", "phase_rad"),
            ("[cogging]", "[coggin]", "coggin"),
        ];
        for (from, to, named) in cases {
            assert!(text.contains(from), "{from}");
            let bad = text.replacen(from, to, 1);
            let e = parse(&bad).unwrap_err();
            assert!(e.contains(named), "{named}: {e}");
        }
    }
}
