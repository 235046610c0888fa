//! Cortex-M4 instruction counts of the `fpc` control logic, measured in QEMU.
//!
//! Runs on QEMU's `mps2-an386` (Cortex-M4F) under `-icount shift=10`: every guest instruction
//! then advances virtual time by exactly 1024 ns, and CMSDK timer0 (25 MHz, 40 ns a tick)
//! counts 25.6 ticks per instruction, so rounding a tick difference gives the *exact* number
//! of instructions between two reads — deterministic, run after run. (DWT CYCCNT reads 0
//! under QEMU.) These are instructions, not cycles: the M4 needs ~1.2–1.5 cycles each.
//!
//! Each function is called out of line through an opaque function pointer, once per input,
//! over [`CALLS`] varied inputs; the same loop over an empty function is subtracted, so a
//! figure is the cost of one call (call, body, return) as the 20 kHz step would pay it. The
//! whole control step runs in closed loop with an ideal plant instead, each call timed alone
//! (the plant's work is not counted), so that it stays in the regime measured.
//! Output: one line per function, `bench NAME: 123.4 instructions/call`; the process exits
//! non-zero (semihosting) if a figure exceeds its budget or the calibration is off.
//!
//! Run: `scripts/bench-cm4.sh` from the repository root (builds in release and runs QEMU), or
//! `cargo run --release` in this directory. To add a function: one `ok &= bench(...)` call in
//! `main`; to enforce a budget, change its `Budget::Watch` to `Budget::Enforce`.

#![no_std]
#![no_main]

use core::future::Future;
use core::hint::black_box;
use core::pin::pin;
use core::task::{Context, Waker};

use cortex_m_rt::{entry, exception, ExceptionFrame};
use cortex_m_semihosting::{debug, hprintln};
use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex;
use fpc::control::command::Command;
use fpc::control::config::ControlConfig;
use fpc::control::step::{ControlStep, CycleInputs, CycleOutputs};
use fpc::drive::foc::CurrentController;
use fpc::link::scope::Trigger;
use fpc::link::settings::LinkRequest;
use fpc::physics::cogging::HarmonicMap;
use fpc::physics::motor::{inverse_clarke, inverse_park, Dq};
use fpc::ports::{EncoderCodes, PhaseCurrentCodes, PressureCodes, SinCosCodes};
use fpc::real::Real;
use fpc::sensing::differentiator::{SavitzkyGolay, SgConfig};
use fpc::sensing::encoder::{
    EncoderReading, PositionCounts, SinCosDecoder, NOMINAL_AMPLITUDE_CODES,
};
use fpc::sensing::pressure::PressureCalibration;
use fpc::shared::Shared;
use fpc::status::{ModeKind, Status};
use fpc::units::{AdcCode, PerSection, PhaseDuties, Ticks, CONTROL_PERIOD_US};
// Only for its interrupt vector table, which cortex-m-rt requires here (see Cargo.toml).
use embassy_stm32 as _;
use panic_semihosting as _;

/// Calls per measurement: the figure is a total over these, so its resolution is 1/CALLS.
const CALLS: usize = 1000;

// Budgets from the issues, instructions per call. `Watch` prints the budget beside the
// figure; `Enforce` also fails the run above it. Enforcing one is a one-word change here.
/// Savitzky–Golay velocity + acceleration over a 21-sample window, per sample.
const SG_DIFFERENTIATOR_21: Budget = Budget::Enforce(120);
/// Sin/cos decode, per encoder.
const ENCODER_DECODE: Budget = Budget::Enforce(150);
/// Field-oriented control of both sections, per cycle.
const FOC_BOTH_SECTIONS: Budget = Budget::Enforce(900);
/// The whole 20 kHz control step, compressing (continuous strokes): its worst regime, with
/// every feature (a calibrated cogging map, the load observer, the supervision, the
/// synchronised rotation). A quarter of the period's deadline kept spare needs ≤ 1,700.
const CONTROL_STEP_RUNNING: Budget = Budget::Enforce(1700);
/// The whole 20 kHz control step, holding at the park position: ≤ 1,500.
const CONTROL_STEP_HOLDING: Budget = Budget::Enforce(1500);
/// Building the control step at boot, once: it must end well inside the watchdog's 20 ms
/// boot window (`fpc::tasks::BOOT_WATCHDOG_TIMEOUT_US`, 3.4 M cycles at 170 MHz); 1 M
/// instructions leaves room for flash wait states and the rest of the bring-up.
const CONTROL_STEP_NEW: Budget = Budget::Enforce(1_000_000);
/// What the control task pays after each step for the link (#29): the telemetry frame
/// queued when due and the scope's sample, outside the step's budget, after the outputs are
/// written. Watched, not enforced: the figures say what the decimation and the recording
/// cost; 250 keeps the whole control task near 2,150 (≈ 2,800 cycles, 16 µs of the 50 µs
/// period at 170 MHz) in the worst case, every frame sent and the scope armed.
const TELEMETRY_AND_SCOPE: Budget = Budget::Watch(250);

/// A function's instruction budget, per call.
#[derive(Clone, Copy)]
#[allow(dead_code)] // which variants are used changes as budgets are enforced
enum Budget {
    /// None set: the figure alone is printed.
    None,
    /// Printed, and an excess reported, without failing the run.
    Watch(u32),
    /// An excess fails the run.
    Enforce(u32),
}

#[entry]
fn main() -> ! {
    timer::start();
    let mut rng = XorShift(0x2545_f491);

    // A check of the method itself: a body of exactly 100 instructions must count 100.0,
    // which fails loudly if QEMU runs without -icount shift=10 or the timer is not there.
    // Nothing else would be worth printing then.
    if !calibrate() {
        exit(false);
    }
    let mut ok = true;

    // A calibrated machine: the reference configuration with a cogging map as `Calibrate`
    // fits it (every harmonic non-zero), so the allocation's compensation is counted; an
    // empty map would skip it and understate the step.
    let mut config = ControlConfig::reference();
    config.allocation.cogging = HarmonicMap {
        period_m: config.allocation.cogging.period_m,
        sin_n: [27.6, 1.4, -0.6, 0.3],
        cos_n: [11.9, -0.9, 0.4, -0.2],
    };

    // Velocities over the whole stroke's range, both signs, including the Stribeck region.
    let velocities: [f32; CALLS] = core::array::from_fn(|_| rng.uniform(-4.0, 4.0));
    ok &= bench(
        "friction_force_f32",
        Budget::None,
        &mut (config.friction, 0.0),
        &velocities,
        |(p, out), v| *out = p.force_n(*v),
    );

    // One stroke cycle, sampled at 20 kHz: every phase of motion and every encoder angle.
    let encoder = config.encoder_master;
    let stroke: [Sample; CALLS] = core::array::from_fn(|k| Sample::at(k, &config, &mut rng));

    ok &= bench(
        "encoder_decode",
        ENCODER_DECODE,
        &mut (SinCosDecoder::new(encoder), EncoderReading::default()),
        &stroke,
        |(d, out), s| *out = d.update(s.codes),
    );

    let sg = SavitzkyGolay::new(SgConfig {
        window: 21,
        order: config.sg_order,
        lag: config.sg_lag,
        sample_time_s: config.sample_time_s,
        m_per_count: encoder.m_per_count(),
    })
    .expect("valid differentiator configuration");
    ok &= bench(
        "sg_differentiator_21",
        SG_DIFFERENTIATOR_21,
        &mut (sg, Default::default()),
        &stroke,
        |(d, out), s| *out = d.push(s.position),
    );

    let current_loop =
        CurrentController::new(&config.motor, config.current_gains, config.sample_time_s);
    ok &= bench(
        "foc_both_sections",
        FOC_BOTH_SECTIONS,
        &mut (
            PerSection {
                master: current_loop.clone(),
                slave: current_loop,
            },
            config.current_sense.master,
            PerSection::<PhaseDuties>::default(),
        ),
        &stroke,
        |(c, sense, out), s| {
            let reference = Dq { d: 0.0, q: 30.0 };
            let (amps, v) = (sense.amps(&s.currents), s.velocity_mps);
            out.master = c.master.step(amps, s.angle, reference, v);
            out.slave = c.slave.step(amps, s.angle, reference, v);
        },
    );

    // Start-up: the control task builds its step (the differentiator's coefficients in f64
    // soft-float among it) before its first check-in, while the watchdog already runs.
    let start = timer::now();
    let built = black_box(ControlStep::new(black_box(config.clone())));
    let startup = timer::instructions_since(start);
    drop(built);
    ok &= report("control_step_new", CONTROL_STEP_NEW, startup, 1);

    // The whole step, in closed loop with an ideal plant (its work is not counted), in its
    // two steady regimes: holding at the park position, and compressing (continuous strokes
    // at 4 m/s peak; 4000 cycles ≈ one cycle of the machine, both dead points included).
    // Both current loops, the position loop with feed-forward, the supervisor and the servo
    // loop run in both.
    let (control, mut plant) = holding_control_step(&config, &mut rng);
    let mut state = (control, None::<CycleOutputs>);
    ok &= bench_closed_loop(
        "control_step_holding",
        CONTROL_STEP_HOLDING,
        CALLS,
        &mut state,
        |(c, _)| plant.next(&config, &c.status(), &mut rng),
        |(c, out), i| *out = Some(c.step(i)),
    );
    ok &= regime_kept("control_step_holding", &state.0, ModeKind::Holding);

    let mut control = state.0;
    control
        .command(Command::Start {
            peak_speed_mps: 4.0,
        })
        .expect("start accepted when holding");
    // The first stroke starts from the park position, not a dead point: not counted.
    for _ in 0..2 * CALLS {
        let inputs = plant.next(&config, &control.status(), &mut rng);
        control.step(&inputs);
    }
    let mut state = (control, None::<CycleOutputs>);
    ok &= bench_closed_loop(
        "control_step_running",
        CONTROL_STEP_RUNNING,
        4 * CALLS,
        &mut state,
        |(c, _)| plant.next(&config, &c.status(), &mut rng),
        |(c, out), i| *out = Some(c.step(i)),
    );
    ok &= regime_kept("control_step_running", &state.0, ModeKind::Running);

    ok &= bench_link_extras();

    exit(ok)
}

/// The shared state of the link benchmarks (a static, as on the board).
static SHARED: Shared<CriticalSectionRawMutex> = Shared::new();

/// The control task's per-cycle link work after the step: `queue_telemetry` (one frame every
/// `decimation` cycles) and `record_scope`, in four regimes. The queue is emptied between
/// calls (not counted), as the telemetry task does.
fn bench_link_extras() -> bool {
    let shared: &'static Shared<CriticalSectionRawMutex> = &SHARED;
    let status = |i: u32| Status {
        t: Ticks(50 * i),
        mode: ModeKind::Running,
        position_m: 0.1 + 1e-5 * i as f32,
        slave_position_m: 0.1 + 1.1e-5 * i as f32,
        velocity_mps: 2.0,
        theta_rad: 1e-3 * i as f32,
        force_master_n: 300.0,
        force_slave_n: 301.0,
        pressure_a_pa: 2.0e5,
        pressure_b_pa: 3.0e5,
        ..Status::INIT
    };
    let mut ok = true;
    let mut i = 0u32;
    let mut regime = |name: &str, decimation: u16, arm: Option<Trigger>| {
        shared.start_telemetry(decimation);
        let _ = shared.apply(LinkRequest::ScopeDisarm);
        if let Some(trigger) = arm {
            let _ = shared.apply(LinkRequest::ScopeArm { trigger, pre: 100 });
        }
        let mut state = shared;
        bench_closed_loop(
            name,
            TELEMETRY_AND_SCOPE,
            CALLS,
            &mut state,
            |s| {
                drain(s);
                i += 1;
                status(i)
            },
            |s, st| {
                s.queue_telemetry(st);
                s.record_scope(st);
            },
        )
    };
    ok &= regime("telemetry_d20_scope_off", 20, None);
    ok &= regime("telemetry_d10_scope_off", 10, None);
    ok &= regime("telemetry_d1_scope_off", 1, None);
    // Armed: every sample kept, the trigger checked (a stroke count: the velocity test runs).
    ok &= regime(
        "telemetry_d10_scope_armed",
        10,
        Some(Trigger::Strokes(1000)),
    );
    ok &= regime("telemetry_d1_scope_armed", 1, Some(Trigger::Strokes(1000)));
    let _ = shared.apply(LinkRequest::ScopeDisarm);
    ok
}

/// defmt's logger, which embassy-sync's `defmt` feature (on for the firmware) links in: the
/// bench discards the log (its figures go out by semihosting).
#[defmt::global_logger]
struct NoLog;

// SAFETY: nothing is shared: every method does nothing.
unsafe impl defmt::Logger for NoLog {
    fn acquire() {}
    unsafe fn flush() {}
    unsafe fn release() {}
    unsafe fn write(_bytes: &[u8]) {}
}

/// The critical section the shared state's mutex takes: every interrupt masked (PRIMASK),
/// as the firmware's `ControlRawMutex` does for the same state.
struct MaskAll;
critical_section::set_impl!(MaskAll);

// SAFETY: one core; `acquire` sets PRIMASK and `release` clears it only if it was clear
// before, so nothing else runs between them.
unsafe impl critical_section::Impl for MaskAll {
    unsafe fn acquire() -> u8 {
        let was_on = cortex_m::register::primask::read().is_active();
        cortex_m::interrupt::disable();
        u8::from(was_on)
    }

    unsafe fn release(was_on: u8) {
        if was_on != 0 {
            // SAFETY: interrupts were enabled when the matching `acquire` ran.
            unsafe { cortex_m::interrupt::enable() };
        }
    }
}

#[defmt::panic_handler]
fn defmt_panic() -> ! {
    panic!("defmt panic")
}

/// Takes every queued telemetry frame (what the telemetry task does, not counted).
fn drain(shared: &Shared<CriticalSectionRawMutex>) {
    let mut cx = Context::from_waker(Waker::noop());
    loop {
        let next = pin!(shared.next_frame());
        if next.poll(&mut cx).is_pending() {
            return;
        }
    }
}

/// Ends QEMU with success or failure (its exit status 0 or 1).
fn exit(success: bool) -> ! {
    debug::exit(if success {
        debug::EXIT_SUCCESS
    } else {
        debug::EXIT_FAILURE
    });
    #[allow(clippy::empty_loop)] // unreachable: the semihosting exit ends QEMU
    loop {}
}

/// Measures `call(state, input)` over every input and prints the cost per call. Returns
/// false if it exceeds an enforced budget.
fn bench<S, I>(
    name: &str,
    budget: Budget,
    state: &mut S,
    inputs: &[I],
    call: fn(&mut S, &I),
) -> bool {
    // One pass first, not counted: the figure is the steady state, without the first call's
    // start-up work (filling the differentiator's window, latching the encoder's period).
    instructions(state, inputs, call);
    let total = instructions(state, inputs, call) - instructions(state, inputs, nothing::<S, I>);
    report(name, budget, total, inputs.len() as u64)
}

/// Like [`bench`], for a function that only stays in its regime in closed loop: before each
/// call, `plant` makes the input from the state (not counted); each call is timed alone.
fn bench_closed_loop<S, I>(
    name: &str,
    budget: Budget,
    calls: usize,
    state: &mut S,
    mut plant: impl FnMut(&S) -> I,
    call: fn(&mut S, &I),
) -> bool {
    let mut total = 0;
    for _ in 0..calls {
        let input = plant(state);
        total += instructions(state, core::slice::from_ref(&input), call)
            - instructions(state, core::slice::from_ref(&input), nothing::<S, I>);
    }
    report(name, budget, total, calls as u64)
}

/// Prints the figure, `total` instructions over `n` calls; false if over an enforced budget.
fn report(name: &str, budget: Budget, total: u64, n: u64) -> bool {
    // Tenths, rounded: integer arithmetic keeps float formatting out of the binary.
    let tenths = (total * 10 + n / 2) / n;
    let (whole, tenth) = (tenths / 10, tenths % 10);
    let (limit, enforced) = match budget {
        Budget::None => {
            hprintln!("bench {}: {}.{} instructions/call", name, whole, tenth);
            return true;
        }
        Budget::Watch(limit) => (limit, false),
        Budget::Enforce(limit) => (limit, true),
    };
    let over = total > u64::from(limit) * n;
    let verdict = match (over, enforced) {
        (false, _) => "",
        (true, false) => ": over, not enforced",
        (true, true) => ": OVER BUDGET",
    };
    hprintln!(
        "bench {}: {}.{} instructions/call (budget {}{})",
        name,
        whole,
        tenth,
        limit,
        verdict
    );
    !(over && enforced)
}

/// Checks that a closed-loop measurement stayed in the regime it claims to measure.
fn regime_kept(name: &str, control: &ControlStep, mode: ModeKind) -> bool {
    let s = control.status();
    let kept = s.mode == mode && s.faults.is_empty();
    if !kept {
        hprintln!(
            "bench {}: left the {} regime while measured ({}, {:?})",
            name,
            mode.name(),
            s.mode.name(),
            s.faults.first()
        );
    }
    kept
}

/// The baseline: the call and loop overhead that [`bench`] subtracts.
fn nothing<S, I>(_: &mut S, _: &I) {}

/// Instructions executed by calling `call` once per input (loop included).
#[inline(never)]
fn instructions<S, I>(state: &mut S, inputs: &[I], call: fn(&mut S, &I)) -> u64 {
    // Opaque pointer: the compiler can neither inline the body into the loop nor hoist work
    // out of it across calls, so each call costs what one control cycle would pay.
    let call = black_box(call);
    let start = timer::now();
    for input in inputs {
        call(state, input);
    }
    timer::instructions_since(start)
}

/// Checks the method on a body exactly 100 instructions longer than the baseline's: 100 `nop`
/// before the same return, timed over a batch and one call at a time.
fn calibrate() -> bool {
    fn hundred(_: &mut (), _: &()) {
        // SAFETY: `nop`s only; no memory, registers or flags touched.
        unsafe { core::arch::asm!(".rept 100", "nop", ".endr", options(nomem, nostack)) }
    }
    let inputs = [(); CALLS];
    let batch = instructions(&mut (), &inputs, hundred) - instructions(&mut (), &inputs, nothing);
    let single = (0..CALLS)
        .map(|_| instructions(&mut (), &[()], hundred) - instructions(&mut (), &[()], nothing))
        .sum::<u64>();
    let ok = batch == 100 * CALLS as u64 && single == batch;
    if !ok {
        hprintln!(
            "bench calibration FAILED: {} and {} instructions for {} x 100 (is QEMU run with -icount shift=10?)",
            batch,
            single,
            CALLS
        );
    }
    ok
}

/// CMSDK APB timer0 of the mps2-an386, free-running down from 2³² − 1 at 25 MHz.
mod timer {
    use core::ptr::{read_volatile, write_volatile};

    const CTRL: *mut u32 = 0x4000_0000 as *mut u32;
    const VALUE: *mut u32 = 0x4000_0004 as *mut u32;
    const RELOAD: *mut u32 = 0x4000_0008 as *mut u32;

    /// Timer tick, ns (25 MHz PCLK).
    const NS_PER_TICK: u64 = 40;
    /// Virtual time per instruction under `-icount shift=10`, ns.
    const NS_PER_INSTRUCTION: u64 = 1 << 10;

    /// Starts the timer; it wraps after 2³² ticks ≈ 168 M instructions, far more than any
    /// one measurement.
    pub fn start() {
        // SAFETY: timer0's registers on mps2-an386 (QEMU `info mtree`); nothing else uses it.
        unsafe {
            write_volatile(RELOAD, u32::MAX);
            write_volatile(VALUE, u32::MAX);
            write_volatile(CTRL, 1); // enable, no interrupt
        }
    }

    /// Current tick count (counts down).
    #[inline(always)]
    pub fn now() -> u32 {
        // SAFETY: read of timer0's VALUE register, no side effects.
        unsafe { read_volatile(VALUE) }
    }

    /// Whole instructions since `start` (a value of [`now`]). Each read is late by less than
    /// one tick (1/25.6 instruction), so rounding the difference is exact.
    #[inline(always)]
    pub fn instructions_since(start: u32) -> u64 {
        let ticks = u64::from(start.wrapping_sub(now()));
        (ticks * NS_PER_TICK + NS_PER_INSTRUCTION / 2) / NS_PER_INSTRUCTION
    }
}

/// A control step homed and holding at its park position, brought there by the ideal plant.
fn holding_control_step(config: &ControlConfig, rng: &mut XorShift) -> (ControlStep, IdealPlant) {
    let mut control = ControlStep::new(config.clone()).expect("reference is valid");
    let mut plant = IdealPlant {
        t: Ticks(0),
        raw_m: 0.002,
        zero_m: None,
        count: 0,
        mode: ModeKind::Idle,
    };
    // One cycle to start the decoders, then home: detection, the move to park and settling
    // take about 0.3 s of machine time.
    control.step(&plant.next(config, &control.status(), rng));
    control.command(Command::Home).expect("home accepted");
    for _ in 0..40_000 {
        if control.status().mode == ModeKind::Holding || !control.status().faults.is_empty() {
            break;
        }
        control.step(&plant.next(config, &control.status(), rng));
    }
    if !regime_kept("control_step (homing)", &control, ModeKind::Holding) {
        exit(false);
    }
    (control, plant)
}

/// The ideal plant: the piston is where the step's last reference put it, the rotation where
/// its reference is, and the phase currents are those of the commanded force. Homing
/// publishes no creep reference, so the piston stays put and homing pushes on it as on the
/// head.
struct IdealPlant {
    /// Time of the last cycle.
    t: Ticks,
    /// Piston position in the encoder's frame, m.
    raw_m: f32,
    /// The step's zero in that frame, m, once homed.
    zero_m: Option<f32>,
    /// Servo quadrature count, wide.
    count: i64,
    /// Mode of the previous status.
    mode: ModeKind,
}

impl IdealPlant {
    /// Follows the step's last `status`, then samples the next cycle.
    fn next(&mut self, config: &ControlConfig, status: &Status, rng: &mut XorShift) -> CycleInputs {
        let driven = !matches!(
            status.mode,
            ModeKind::Idle | ModeKind::Homing | ModeKind::Faulted
        );
        // Not on the cycle the mode changed: the status of the cycle that ends homing still
        // gives the position before the zero was set. The zero is read once: re-reading it
        // each cycle would feed the encoder noise back into the plant (and trip the glitch
        // gate).
        if driven && status.mode == self.mode {
            let zero = *self.zero_m.get_or_insert(self.raw_m - status.position_m);
            self.raw_m = status.reference_m + zero;
        }
        self.mode = status.mode;
        // Angles are relative to the same base (the step re-bases by whole turns).
        let counts = (status.theta_reference_rad - status.theta_rad) / config.servo.rad_per_count();
        self.count += (counts + 0.5 * counts.signum()) as i64;
        self.t = self.t.add_us(CONTROL_PERIOD_US);
        cycle_inputs(
            config,
            self.t,
            self.raw_m,
            status.force_command_n,
            self.count as u16,
            rng,
        )
    }
}

/// One burst of samples for the piston at raw position `raw_m` with a total motor force of
/// `force_n` (split evenly), the servo at `quadrature`, the chamber pressures following the
/// piston and the lines at 1 bar, a little noise on the encoder and current channels.
fn cycle_inputs(
    config: &ControlConfig,
    t: Ticks,
    raw_m: f32,
    force_n: f32,
    quadrature: u16,
    rng: &mut XorShift,
) -> CycleInputs {
    let theta = 2.0 * f32::PI * raw_m / config.encoder_master.period_m;
    let (sin, cos) = (Real::sin(theta), Real::cos(theta));
    // ±1 code on the encoder channels: ~1 µm of position noise, the encoder's own (a noisier
    // signal trips the supervisor's braking envelope right after homing, at the head).
    let mut code = |v: f32, noise: f32| AdcCode((2048.0 + v + rng.uniform(-noise, noise)) as u16);
    let encoder = SinCosCodes {
        sin: code(NOMINAL_AMPLITUDE_CODES * sin, 1.0),
        cos: code(NOMINAL_AMPLITUDE_CODES * cos, 1.0),
    };
    let q_a = 0.5 * force_n / config.motor.force_constant_n_per_a;
    let amps = inverse_clarke(inverse_park(Dq { d: 0.0, q: q_a }, sin, cos));
    let currents = amps.map(|a| code(a / config.current_sense.master.a_per_code, 3.0));
    let cal = PressureCalibration::reference();
    let bar = cal.code_for(1.0e5);
    // The chamber pressures follow the piston (±0.2 bar per 0.1 m from where it homes, each
    // chamber its own way): live sensors. Readings that stay flat while the piston strokes
    // are a stuck sensor, and the step latches `pressure_plausibility` for them.
    let dp = 2.0e5 * (raw_m - 0.002);
    let chamber_a = cal.code_for(1.0e5 + dp);
    let chamber_b = cal.code_for(1.0e5 - dp);
    CycleInputs {
        t,
        encoders: EncoderCodes {
            master: encoder,
            slave: encoder,
        },
        currents: PerSection {
            master: currents,
            slave: currents,
        },
        quadrature,
        pressures: PressureCodes {
            chamber_a,
            chamber_b,
            suction: bar,
            discharge: bar,
        },
    }
}

/// One control cycle's samples on a sinusoidal stroke (±40 mm at 20 Hz, [`CALLS`] cycles:
/// 5 m/s peak, just under the encoder's 6 m/s plausibility limit) with ±1 code of noise on
/// the encoder and ±3 on the current channels.
#[derive(Clone, Copy)]
struct Sample {
    /// Encoder channels.
    codes: SinCosCodes,
    /// Position, counts (what the differentiator is fed).
    position: PositionCounts,
    /// Electrical angle, 2³² = one period.
    angle: u32,
    /// Velocity, m/s.
    velocity_mps: f32,
    /// Phase currents of a 30 A q-current at that angle.
    currents: PhaseCurrentCodes,
}

impl Sample {
    fn at(k: usize, config: &ControlConfig, rng: &mut XorShift) -> Sample {
        let encoder = &config.encoder_master;
        let phase = 2.0 * f32::PI * k as f32 / CALLS as f32;
        let x_m = 0.04 * Real::sin(phase);
        // d/dt of 0.04·sin(2π·k/CALLS), one period taking CALLS control cycles.
        let velocity_mps =
            0.04 * Real::cos(phase) * 2.0 * f32::PI / (CALLS as f32 * config.sample_time_s);
        let periods = x_m / encoder.period_m;
        let theta = 2.0 * f32::PI * periods;
        let (sin, cos) = (Real::sin(theta), Real::cos(theta));
        // ±1 code on the encoder channels: ~1 µm of position noise, the encoder's own (a noisier
        // signal trips the supervisor's braking envelope right after homing, at the head).
        let mut code =
            |v: f32, noise: f32| AdcCode((2048.0 + v + rng.uniform(-noise, noise)) as u16);
        let amps = inverse_clarke(inverse_park(Dq { d: 0.0, q: 30.0 }, sin, cos));
        Sample {
            codes: SinCosCodes {
                sin: code(NOMINAL_AMPLITUDE_CODES * sin, 1.0),
                cos: code(NOMINAL_AMPLITUDE_CODES * cos, 1.0),
            },
            position: PositionCounts::from_bits((x_m / encoder.m_per_count()) as i32),
            angle: (periods * 4_294_967_296.0) as i64 as u32,
            velocity_mps,
            currents: amps.map(|a| code(a / config.current_sense.master.a_per_code, 3.0)),
        }
    }
}

/// Deterministic input generator (xorshift32), so every run sees the same inputs.
struct XorShift(u32);

impl XorShift {
    fn next(&mut self) -> u32 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 17;
        self.0 ^= self.0 << 5;
        self.0
    }

    /// Uniform in [lo, hi).
    fn uniform(&mut self, lo: f32, hi: f32) -> f32 {
        lo + (hi - lo) * ((self.next() >> 8) as f32 / (1u32 << 24) as f32)
    }
}

#[exception]
unsafe fn HardFault(frame: &ExceptionFrame) -> ! {
    hprintln!("bench HardFault: {:?}", frame);
    exit(false)
}
