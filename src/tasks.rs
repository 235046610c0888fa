//! The task bodies, generic over the ports: the firmware wraps each in a concrete embassy
//! task, and `hal-sim` runs the very same futures against the simulated plant.

use core::convert::Infallible;
use core::task::Poll;

use embassy_sync::blocking_mutex::raw::RawMutex;

use embedded_storage_async::nor_flash::NorFlash;

use crate::control::calibration::record::CalibrationRecord;
use crate::control::calibration::store::{CalibrationStore, LoadError};
use crate::control::command::Refusal;
use crate::control::command::Reply;
use crate::control::config::ControlConfig;
use crate::control::step::{ControlStep, CycleInputs};
use crate::link::commands::{
    encode_rejection, encode_reply, encode_transfer_reply, Request, RequestReader, Transfer,
    TransferReply, TransferState, TransferStep, MAX_REPLY_WIRE,
};
#[cfg(feature = "bench")]
use crate::link::report::{encode_report, ReportAnswer, MAX_REPORT_WIRE};
use crate::link::scope::{
    encode_chunk, encode_header, CHUNK_SAMPLES, MAX_SCOPE_WIRE, SAMPLE_BYTES,
};
#[cfg(feature = "bench")]
use crate::link::settings::LinkRequest;
use crate::link::telemetry::WIRE_BYTES;
use crate::ports::{
    ByteSource, Clock, ControlPorts, CurrentInput, CycleTrigger, EncoderInput, EventLog, FrameSink,
    PressureInput, PwmOutput, QuadratureInput, Sleep, SupplyMonitor, TorqueOutput, Watchdog,
};
use crate::safety::faults::ResetCause;
use crate::shared::{task_bits, Shared};
#[cfg(feature = "bench")]
use crate::status::ModeKind;
use crate::units::{DacCode, PerSection, PhaseDuties, Section};

/// Period of the supervision task, µs.
pub const SUPERVISION_PERIOD_US: u32 = 1000;

/// Timeout of the independent watchdog once running, µs: two supervision periods. A hung
/// control task leaves its last duties applied until the reset takes the outputs off, then
/// the boot (`hal_sim::board::exec::BOOT_US`, the release ELF's on the counted timeline) and
/// the first velocity pass before the brake: at 4 m/s a held full force must not carry the
/// piston into a head first. With 20 ms it could (−0.07 mm in the simulator); with 2 ms the
/// clearance stays above 0.3 mm at every phase of a stroke and over the random fault sweep in
/// both rotations (`tests/faults_are_caught_and_the_machine_stays_safe.rs`, #12;
/// `tests/random_faults_keep_the_head_clearance.rs`).
pub const WATCHDOG_TIMEOUT_US: u32 = 2_000;

/// Timeout of the watchdog from power-up to its first feed, µs: board bring-up and
/// building the control step (≈ 14,000 instructions, `bench/cm4`) come before the control
/// task's first check-in; the outputs are off all that time.
pub const BOOT_WATCHDOG_TIMEOUT_US: u32 = 20_000;

/// The 20 kHz control task: wait for the sampling burst, read every port, run one
/// [`ControlStep`], write both sections' PWM and the servo command, publish the status.
///
/// `reset_cause` is why the MCU started: after a watchdog reset the machine boots into the
/// fault state. `stored` is the calibration read from flash at boot
/// ([`CalibrationStore::load`]; `None` where there is no store and `config` is the
/// calibration, as in the simulator): missing or invalid, the machine refuses `Start` until
/// calibrated. Each routine that succeeds hands its record to [`calibration_store_run`]. An invalid configuration keeps the outputs off for good (and keeps checking
/// in, so the watchdog does not reset the board into the same configuration).
pub async fn control_run<M, T, E, C, P, Q, S, R>(
    mut ports: ControlPorts<T, E, C, P, Q, S, R>,
    shared: &Shared<M>,
    config: ControlConfig,
    reset_cause: ResetCause,
    stored: Option<Result<CalibrationRecord, LoadError>>,
) -> Infallible
where
    M: RawMutex,
    T: CycleTrigger,
    E: EncoderInput,
    C: CurrentInput,
    P: PwmOutput,
    Q: QuadratureInput,
    S: TorqueOutput,
    R: PressureInput,
{
    ports.pwm.disable();
    ports.servo.write(DacCode::MID);
    let mut step = match ControlStep::new(config) {
        Ok(step) => step,
        Err(_) => loop {
            ports.cycle.next_cycle().await;
            shared.check_in(task_bits::CONTROL);
        },
    };
    step.boot(reset_cause);
    if let Some(loaded) = stored {
        step.load_calibration(loaded);
    }
    shared.publish_calibration(step.calibration_record());
    shared.publish(step.status());
    // Which sections' outputs are switching (None: all off).
    let mut switching: Option<PerSection<bool>> = None;
    loop {
        let t = ports.cycle.next_cycle().await;
        control_cycle(&mut step, &mut ports, shared, t, &mut switching);
    }
}

/// One control cycle once its sampling burst is in (the body of [`control_run`]'s loop):
/// take the commands, read every port, run the step, write both sections' PWM and the servo
/// command, publish. `switching` is which sections' outputs are switching (None: all off).
///
/// Never inlined: the firmware runs it, with everything it inlines, from CCM SRAM (zero
/// wait states), and `memory.x` finds it there by its symbol, `fpc::tasks::control_cycle`.
#[inline(never)]
pub fn control_cycle<M, T, E, C, P, Q, S, R>(
    step: &mut ControlStep,
    ports: &mut ControlPorts<T, E, C, P, Q, S, R>,
    shared: &Shared<M>,
    t: crate::units::Ticks,
    switching: &mut Option<PerSection<bool>>,
) where
    M: RawMutex,
    E: EncoderInput,
    C: CurrentInput,
    P: PwmOutput,
    Q: QuadratureInput,
    S: TorqueOutput,
    R: PressureInput,
{
    serve_commands(step, shared);
    // The supervision task's last look at the power-good input (one load and a branch).
    step.supply(shared.supply_good());
    // The bridges' hardware over-current trip, before anything may switch them on again.
    let tripped = ports.pwm.tripped();
    if tripped.master || tripped.slave || step.trip_latched() {
        let rearm = step.hardware_trip(tripped);
        if rearm.master || rearm.slave {
            ports.pwm.rearm(rearm);
        }
    }
    let inputs = CycleInputs {
        t,
        encoders: ports.encoders.read(),
        currents: PerSection {
            master: ports.currents.read(Section::Master),
            slave: ports.currents.read(Section::Slave),
        },
        quadrature: ports.quadrature.count(),
        pressures: ports.pressures.read(),
    };
    // The duties go out as soon as the drive stage has them (their deadline is the next
    // PWM update); the rotation and the status follow.
    let mut written = false;
    let out = step.step_then(&inputs, |pwm, sections| {
        drive_bridges(&mut ports.pwm, switching, pwm, sections);
        written = true;
    });
    if !written {
        drive_bridges(&mut ports.pwm, switching, out.pwm.as_ref(), out.sections);
    }
    ports.servo.write(out.servo);
    if let Some(record) = step.take_calibration_to_save() {
        shared.post_calibration(record);
    }
    // Before the status: a host that reads the mode no longer `calibrating` finds the
    // routine's end reported.
    #[cfg(feature = "bench")]
    if step.routine_report_changed() {
        post_routine_report(step, shared);
    }
    let status = step.status();
    shared.publish(status);
    shared.queue_telemetry(&status);
    shared.record_scope(&status);
    shared.check_in(task_bits::CONTROL);
}

/// Hands the last routine's report to the command task. Out of line (in flash, not the
/// control cycle's CCM SRAM): it runs twice a routine. The bench build's.
#[cfg(feature = "bench")]
#[inline(never)]
fn post_routine_report<M: RawMutex>(step: &mut ControlStep, shared: &Shared<M>) {
    if let Some(report) = step.take_routine_report() {
        shared.post_routine_report(report);
    }
}

/// Writes both sections' duties (`None`: all outputs off) and switches the bridges of
/// `sections` on if they are not (`switching`: which sections' outputs are switching).
#[inline(always)]
fn drive_bridges<P: PwmOutput>(
    pwm: &mut P,
    switching: &mut Option<PerSection<bool>>,
    duties: Option<&PerSection<PhaseDuties>>,
    sections: PerSection<bool>,
) {
    match duties {
        Some(duties) => {
            // Both sections in the same cycle, from the same force command.
            pwm.write(Section::Master, duties.master);
            pwm.write(Section::Slave, duties.slave);
            if *switching != Some(sections) {
                pwm.enable(sections);
                *switching = Some(sections);
            }
        }
        None => {
            if switching.is_some() {
                pwm.disable();
                *switching = None;
            }
        }
    }
}

/// The control task's part of the command link, before each step: every pending command
/// is handled and answered, and a calibration record written over the link is loaded (or
/// refused) and the verdict handed back to the command task. The record is already checked
/// (the command task decoded it), so this is a copy into the configuration, as at boot.
pub fn serve_commands<M: RawMutex>(step: &mut ControlStep, shared: &Shared<M>) {
    while let Some(command) = shared.take_command() {
        let result = step.command(command);
        shared.post_reply(Reply { command, result });
    }
    if let Some(record) = shared.take_calibration_to_load() {
        shared.post_calibration_loaded(step.load_calibration_from_link(record));
    }
}

/// The supervision task (thread mode, 1 kHz): feeds the independent watchdog only when
/// every task has checked in since the last feed, so a hung task resets the board; reads the
/// power-good input for the control task (a supply loss is found within a period, which
/// the DC link outlasts by far: `docs/firmware.md`); and reports what an operator must know
/// — a fault latched, a limit that became active, a mode change, the parts absent since
/// boot — to `log` (the 20 kHz
/// path never logs).
pub async fn supervision_run<M, L, K, W, G, U>(
    mut sleep: L,
    clock: K,
    mut watchdog: W,
    mut log: G,
    mut supply: U,
    shared: &Shared<M>,
) -> Infallible
where
    M: RawMutex,
    L: Sleep,
    K: Clock,
    W: Watchdog,
    G: EventLog,
    U: SupplyMonitor,
{
    let mut next = clock.now();
    let mut seen = shared.status();
    loop {
        next = next.add_us(SUPERVISION_PERIOD_US);
        sleep.until(next).await;
        if shared.take_checkins(task_bits::ALL) {
            watchdog.feed();
        }
        shared.report_supply(supply.power_good());
        let now = shared.status();
        for fault in now.faults.iter().filter(|f| !seen.faults.contains(*f)) {
            log.fault_latched(fault);
        }
        let l = now.limits;
        let before = seen.limits;
        if (l.force && !before.force)
            || (l.voltage && !before.voltage)
            || (l.envelope && !before.envelope)
        {
            log.limit_active(l);
        }
        if now.mode != seen.mode {
            log.mode_changed(now.mode);
        }
        if now.absent != seen.absent {
            log.absent_changed(now.absent);
        }
        seen = now;
    }
}

/// Yields to a sink that is partly full this many times before a frame is given up.
const SINK_STALL_LIMIT: u32 = 64;

/// The telemetry task (thread mode): turns telemetry on at one frame every `decimation`
/// control cycles (a link request may change it, and the channels sent, at any time), then
/// encodes each frame the control task queues, with the channels chosen, and writes it to
/// `sink` (the RTT up-channel). It never holds up the control task: frames that find the
/// queue full, or a sink that takes nothing, are dropped and counted in
/// [`Shared::telemetry_dropped`], and the count rides in every frame.
pub async fn telemetry_run<M, S>(mut sink: S, shared: &Shared<M>, decimation: u16) -> Infallible
where
    M: RawMutex,
    S: FrameSink,
{
    shared.start_telemetry(decimation);
    let mut buf = [0u8; WIRE_BYTES];
    loop {
        let mut frame = shared.next_frame().await;
        frame.channels = shared.telemetry_channels();
        let Ok(n) = frame.encode(&mut buf) else {
            shared.count_telemetry_drop();
            continue;
        };
        let mut rest = buf.get(..n).unwrap_or_default();
        let mut stalls = 0;
        while !rest.is_empty() {
            let taken = sink.write(rest).min(rest.len());
            if taken == 0 {
                // Nothing of it sent yet: skip it whole (host absent or behind). Part sent:
                // finish it after letting the host read, so the stream stays decodable.
                if rest.len() == n || stalls >= SINK_STALL_LIMIT {
                    shared.count_telemetry_drop();
                    break;
                }
                stalls += 1;
                yield_now().await;
            }
            rest = rest.get(taken..).unwrap_or_default();
        }
        // At a frame every control cycle the next is always ready: without a turn for the
        // other thread-mode tasks here, the supervision task would never run again and the
        // watchdog would reset the board.
        yield_now().await;
    }
}

/// Completes on the second poll, after waking itself: lets the executor run other tasks.
async fn yield_now() {
    let mut yielded = false;
    core::future::poll_fn(|cx| {
        if yielded {
            Poll::Ready(())
        } else {
            yielded = true;
            cx.waker().wake_by_ref();
            Poll::Pending
        }
    })
    .await
}

/// The calibration storage task (thread mode): saves each record the control task hands
/// over to flash through `store`, and logs the outcome. A save erases and writes flash pages
/// (tens of ms), which is why it never runs in the control task; a power cut during it
/// leaves the previous record ([`CalibrationStore`]).
pub async fn calibration_store_run<M, F, G>(
    mut store: CalibrationStore<F>,
    shared: &Shared<M>,
    mut log: G,
) -> Infallible
where
    M: RawMutex,
    F: NorFlash,
    G: EventLog,
{
    loop {
        let record = shared.calibration_to_save().await;
        let result = store.save(&record).await;
        log.calibration_saved(result);
    }
}

/// Longest answer the command task writes, bytes (the bench build's routine report).
#[cfg(not(feature = "bench"))]
const ANSWER_WIRE: usize = MAX_REPLY_WIRE;
/// Longest answer the command task writes, bytes (the bench build's routine report).
#[cfg(feature = "bench")]
const ANSWER_WIRE: usize = if MAX_REPORT_WIRE > MAX_REPLY_WIRE {
    MAX_REPORT_WIRE
} else {
    MAX_REPLY_WIRE
};

/// Period of the command task, µs: the RTT down-channel is polled at 1 kHz.
pub const COMMAND_POLL_US: u32 = 1000;

/// The command task (thread mode): reads the down-channel, decodes and validates frames
/// ([`RequestReader`]), answers calibration reads and writes itself ([`TransferState`]; a
/// checked commit goes to the control task, [`serve_commands`]), applies link requests
/// (telemetry, ports, scope: [`Shared::apply`]; the last routine's report it answers from
/// what the control task posted, [`ReportAnswer`]), posts the commands for the control task and
/// writes every answer to `replies` — the control task's accept/refuse reply for each command,
/// a `Busy` refusal when the mailbox is full, and a rejection (with its reason) for each
/// malformed frame. A finished scope recording goes to `replies` too, header then chunks,
/// each retried until the channel has room ([`ScopeSender`]). Nothing here blocks the
/// control task: it only ever `try_`s the shared mailboxes.
pub async fn command_run<M, B, S, L, K>(
    mut source: B,
    mut replies: S,
    mut sleep: L,
    clock: K,
    shared: &Shared<M>,
) -> Infallible
where
    M: RawMutex,
    B: ByteSource,
    S: FrameSink,
    L: Sleep,
    K: Clock,
{
    let mut reader = RequestReader::new();
    let mut transfer = TransferState::new();
    // The commit the controller is loading (answered once its verdict comes back).
    let mut committing: Option<Transfer> = None;
    let mut input = [0u8; 64];
    let mut out = [0u8; ANSWER_WIRE];
    // The last routine's report (the control task posts each change).
    #[cfg(feature = "bench")]
    let mut report = None;
    let mut scope = ScopeSender::default();
    let mut next = clock.now();
    loop {
        next = next.add_us(COMMAND_POLL_US);
        sleep.until(next).await;
        if let Some(record) = shared.take_current_calibration() {
            transfer.set_current(record.encode());
        }
        let n = source.read(&mut input);
        for &byte in input.get(..n).unwrap_or_default() {
            let encoded = match reader.push(byte) {
                None => continue,
                Some(Ok(Request::Calibration(t))) => {
                    let reply = match transfer.handle(t) {
                        TransferStep::Reply(reply) => reply,
                        TransferStep::Load(record) => {
                            if committing.is_none() && shared.post_calibration_to_load(record) {
                                committing = Some(t);
                                continue;
                            }
                            TransferReply::Verdict {
                                transfer: t.id(),
                                result: Err(Refusal::Busy),
                            }
                        }
                    };
                    encode_transfer_reply(&reply, &mut out)
                }
                #[cfg(feature = "bench")]
                Some(Ok(Request::Link(LinkRequest::RoutineReport))) => {
                    // The mode before the report: a routine's end is posted before the
                    // status that leaves `calibrating`.
                    let calibrating = shared.status().mode == ModeKind::Calibrating;
                    if let Some(r) = shared.take_routine_report() {
                        report = Some(r);
                    }
                    encode_report(&ReportAnswer::of(report, calibrating), &mut out)
                }
                Some(Ok(Request::Link(request))) => encode_transfer_reply(
                    &TransferReply::Verdict {
                        transfer: request.id(),
                        result: shared.apply(request),
                    },
                    &mut out,
                ),
                Some(Ok(Request::Command(command))) => match shared.post_command(command) {
                    Ok(()) => continue,
                    Err(command) => encode_reply(
                        &Reply {
                            command,
                            result: Err(Refusal::Busy),
                        },
                        &mut out,
                    ),
                },
                Some(Err(reason)) => encode_rejection(reason, &mut out),
            };
            if let Ok(len) = encoded {
                // A host that does not read its replies loses them, never the machine.
                let _ = replies.write(out.get(..len).unwrap_or_default());
            }
        }
        while let Some(reply) = shared.take_reply() {
            if let Ok(len) = encode_reply(&reply, &mut out) {
                let _ = replies.write(out.get(..len).unwrap_or_default());
            }
        }
        if let Some(result) = shared.take_calibration_loaded() {
            if let Some(t) = committing.take() {
                let reply = TransferReply::Verdict {
                    transfer: t.id(),
                    result,
                };
                if let Ok(len) = encode_transfer_reply(&reply, &mut out) {
                    let _ = replies.write(out.get(..len).unwrap_or_default());
                }
            }
        }
        scope.send(shared, &mut replies);
    }
}

/// Chunks of a scope recording sent per command-task period at most (each ≈ 265 bytes on
/// the wire).
const SCOPE_CHUNKS_PER_POLL: usize = 2;

/// The command task's sending of a finished scope recording: its header, then its chunks in
/// order, each written whole once the reply channel has room for it (a recording is never
/// dropped for a slow host; it waits), then the scope is released for the next one.
#[derive(Clone, Copy, Debug, Default)]
pub struct ScopeSender {
    /// The recording being sent and the next message (0 = header, k = chunk k − 1).
    sending: Option<(u8, usize)>,
}

impl ScopeSender {
    /// Sends what fits of a finished recording to `sink`.
    pub fn send<M: RawMutex, S: FrameSink>(&mut self, shared: &Shared<M>, sink: &mut S) {
        let Some(recording) = shared.scope_recording() else {
            // Disarmed while sending, or nothing recorded.
            self.sending = None;
            return;
        };
        let (id, mut next) = match self.sending {
            Some((id, next)) if id == recording.id => (id, next),
            _ => (recording.id, 0),
        };
        let samples = usize::from(recording.samples);
        let chunks = samples.div_ceil(CHUNK_SAMPLES);
        let mut wire = [0u8; MAX_SCOPE_WIRE];
        for _ in 0..SCOPE_CHUNKS_PER_POLL {
            let encoded = if next == 0 {
                encode_header(&recording, &mut wire)
            } else {
                let first = (next - 1) * CHUNK_SAMPLES;
                let mut bytes = [[0u8; SAMPLE_BYTES]; CHUNK_SAMPLES];
                let mut n = 0;
                for (slot, i) in bytes
                    .iter_mut()
                    .zip(first..samples.min(first + CHUNK_SAMPLES))
                {
                    if let Some(b) = shared.scope_sample(i) {
                        *slot = b;
                        n += 1;
                    }
                }
                encode_chunk(
                    id,
                    (next - 1) as u16,
                    bytes.get(..n).unwrap_or_default(),
                    &mut wire,
                )
            };
            let Ok(len) = encoded else {
                // Cannot happen with the buffers above; give the recording up rather than
                // loop on it.
                shared.scope_release();
                self.sending = None;
                return;
            };
            let frame = wire.get(..len).unwrap_or_default();
            if sink.write(frame) != frame.len() {
                // No room now (the sink takes a frame whole or not at all): again next time.
                break;
            }
            next += 1;
            if next > chunks {
                shared.scope_release();
                self.sending = None;
                return;
            }
        }
        self.sending = Some((id, next));
    }
}
