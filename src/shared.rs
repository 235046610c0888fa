//! State shared between the tasks: the command mailbox, replies, the latest status, the
//! telemetry frame queue and its settings, the ports declared, the scope, the watchdog
//! check-ins and the calibration record to save.
//!
//! Generic over the raw mutex so the firmware uses a critical-section mutex across its two
//! executors and the simulator a no-op one on its single thread. Nothing here blocks: the
//! control task only ever `try_`s, so a slow reader can never stall the 20 kHz loop.

use core::cell::{Cell, RefCell};
use core::sync::atomic::{AtomicBool, AtomicU16, AtomicU32, AtomicU8, Ordering};

use embassy_sync::blocking_mutex::raw::RawMutex;
use embassy_sync::blocking_mutex::Mutex;
use embassy_sync::channel::Channel;

use crate::control::calibration::record::CalibrationRecord;
#[cfg(feature = "bench")]
use crate::control::calibration::report::RoutineReport;
use crate::control::command::{Command, Refusal, Reply};
use crate::link::scope::{Recording, Scope, SAMPLE_BYTES};
use crate::link::settings::LinkRequest;
use crate::link::telemetry::{ChannelSet, Frame, Ports, DEFAULT_CHANNELS};
use crate::status::Status;

/// Depth of the command mailbox.
pub const COMMAND_DEPTH: usize = 8;

/// Depth of the telemetry frame queue: 32 frames (≈ 1.8 KiB) ride out 32 ms of a busy
/// thread-mode executor at the default 1 kHz frame rate.
pub const TELEMETRY_DEPTH: usize = 32;

/// Bit of each task in the watchdog check-in mask.
pub mod task_bits {
    /// The 20 kHz control task.
    pub const CONTROL: u8 = 1 << 0;
    /// Every task the supervision task expects before it feeds the watchdog.
    pub const ALL: u8 = CONTROL;
}

/// The shared state.
pub struct Shared<M: RawMutex> {
    commands: Channel<M, Command, COMMAND_DEPTH>,
    replies: Channel<M, Reply, COMMAND_DEPTH>,
    status: Mutex<M, Cell<Status>>,
    checkins: AtomicU8,
    frames: Channel<M, Frame, TELEMETRY_DEPTH>,
    /// One frame every this many control cycles; 0 = telemetry off (no task drains it).
    telemetry_decimation: AtomicU16,
    /// Control cycles since telemetry started (written by the control task only).
    telemetry_cycles: AtomicU32,
    /// Frames lost: queue full (control task) or sink full (telemetry task).
    telemetry_dropped: AtomicU32,
    /// The channels frames carry (telemetry task), XOR the default set
    /// ([`DEFAULT_CHANNELS`]): zero is the default, so `Shared` stays in `.bss` with no
    /// flash image.
    telemetry_channels_xor: AtomicU16,
    /// The ports as declared ([`Ports::code`]), stamped in each frame.
    ports: AtomicU8,
    /// The scope's ring and state (control task records, command task arms and reads).
    scope: Mutex<M, RefCell<Scope>>,
    /// The scope is armed or recording: the control task's one test while it is not.
    scope_active: AtomicBool,
    /// The supply is lost (power-good low at the supervision task's last look). Zero is
    /// "good", so a fresh boot starts with the supply good until the first look.
    supply_lost: AtomicBool,
    /// The newest calibration record not yet saved (a newer one replaces it). A channel, not
    /// a `Signal`: an empty channel is all zeros, so `Shared` stays in `.bss` (a `Signal`
    /// moved all 2.2 KiB of it to `.data`, whose initial image costs as much flash).
    calibration: Channel<M, CalibrationRecord, 1>,
    /// The record the controller now runs on, for the command task's link reads (control
    /// task → command task, the newest replaces an unread one).
    current_calibration: Channel<M, CalibrationRecord, 1>,
    /// A record written over the link and checked, for the controller to load (command
    /// task → control task), and the controller's verdict back.
    calibration_to_load: Channel<M, CalibrationRecord, 1>,
    calibration_loaded: Channel<M, Result<(), Refusal>, 1>,
    /// The last routine's report, each time it changes (control task → command task, the
    /// newest replaces an unread one). The bench build's.
    #[cfg(feature = "bench")]
    routine_report: Channel<M, RoutineReport, 1>,
}

impl<M: RawMutex> Default for Shared<M> {
    fn default() -> Self {
        Self::new()
    }
}

impl<M: RawMutex> Shared<M> {
    /// Empty mailboxes, initial status (usable in a `static`).
    pub const fn new() -> Self {
        Shared {
            commands: Channel::new(),
            replies: Channel::new(),
            status: Mutex::new(Cell::new(Status::INIT)),
            checkins: AtomicU8::new(0),
            frames: Channel::new(),
            telemetry_decimation: AtomicU16::new(0),
            telemetry_cycles: AtomicU32::new(0),
            telemetry_dropped: AtomicU32::new(0),
            telemetry_channels_xor: AtomicU16::new(0),
            ports: AtomicU8::new(Ports::Timed.code()),
            scope: Mutex::new(RefCell::new(Scope::new())),
            scope_active: AtomicBool::new(false),
            supply_lost: AtomicBool::new(false),
            calibration: Channel::new(),
            current_calibration: Channel::new(),
            calibration_to_load: Channel::new(),
            calibration_loaded: Channel::new(),
            #[cfg(feature = "bench")]
            routine_report: Channel::new(),
        }
    }

    /// Posts a command for the control task; returns it back if the mailbox is full.
    pub fn post_command(&self, command: Command) -> Result<(), Command> {
        self.commands.try_send(command).map_err(|e| match e {
            embassy_sync::channel::TrySendError::Full(c) => c,
        })
    }

    /// The next pending command, if any (control task).
    pub fn take_command(&self) -> Option<Command> {
        self.commands.try_receive().ok()
    }

    /// Posts a reply; a reply nobody collects is dropped rather than blocking.
    pub fn post_reply(&self, reply: Reply) {
        let _ = self.replies.try_send(reply);
    }

    /// The next reply, if any (host side).
    pub fn take_reply(&self) -> Option<Reply> {
        self.replies.try_receive().ok()
    }

    /// Publishes the latest status (control task).
    pub fn publish(&self, status: Status) {
        self.status.lock(|s| s.set(status));
    }

    /// The latest status.
    pub fn status(&self) -> Status {
        self.status.lock(|s| s.get())
    }

    /// The supervision task reports what the power-good input reads.
    pub fn report_supply(&self, good: bool) {
        self.supply_lost.store(!good, Ordering::Relaxed);
    }

    /// Whether the supply was lost at the supervision task's last look (one load in the
    /// control task's cycle).
    #[inline]
    pub fn supply_good(&self) -> bool {
        !self.supply_lost.load(Ordering::Relaxed)
    }

    /// A task reports that it ran.
    pub fn check_in(&self, task_bit: u8) {
        self.checkins.fetch_or(task_bit, Ordering::Relaxed);
    }

    /// Takes the check-ins: true if every task in `expected` checked in since the last take.
    pub fn take_checkins(&self, expected: u8) -> bool {
        self.checkins.swap(0, Ordering::Relaxed) & expected == expected
    }

    /// Turns telemetry on at one frame every `decimation` control cycles (0 = off); the
    /// telemetry task calls this as it starts, so without it the control task queues nothing.
    pub fn start_telemetry(&self, decimation: u16) {
        self.telemetry_cycles.store(0, Ordering::Relaxed);
        self.telemetry_decimation
            .store(decimation, Ordering::Relaxed);
    }

    /// Control task, once per cycle: queues this cycle's frame if it is due. Never waits: a
    /// full queue drops the frame and counts it.
    pub fn queue_telemetry(&self, status: &Status) {
        let decimation = self.telemetry_decimation.load(Ordering::Relaxed);
        if decimation == 0 {
            return;
        }
        // Only the control task writes this counter, so load + store is race-free.
        let cycle = self.telemetry_cycles.load(Ordering::Relaxed);
        self.telemetry_cycles
            .store(cycle.wrapping_add(1), Ordering::Relaxed);
        if !cycle.is_multiple_of(u32::from(decimation)) {
            return;
        }
        let dropped = u16::try_from(self.telemetry_dropped()).unwrap_or(u16::MAX);
        // The sequence number is the cycle count modulo 2¹⁶: gaps show as steps ≠ decimation.
        let mut frame = Frame::from_status(cycle as u16, dropped, status);
        frame.ports = self.ports();
        if self.frames.try_send(frame).is_err() {
            self.count_telemetry_drop();
        }
    }

    /// Telemetry task: waits for the next queued frame.
    pub async fn next_frame(&self) -> Frame {
        self.frames.receive().await
    }

    /// Counts a frame lost on its way to the host.
    pub fn count_telemetry_drop(&self) {
        self.telemetry_dropped.fetch_add(1, Ordering::Relaxed);
    }

    /// Frames lost so far (queue full or sink full).
    pub fn telemetry_dropped(&self) -> u32 {
        self.telemetry_dropped.load(Ordering::Relaxed)
    }

    /// The channels frames carry now (telemetry task, as it encodes).
    pub fn telemetry_channels(&self) -> ChannelSet {
        ChannelSet(self.telemetry_channels_xor.load(Ordering::Relaxed) ^ DEFAULT_CHANNELS.0)
    }

    /// One frame every `decimation` cycles now (0 = off).
    pub fn telemetry_decimation(&self) -> u16 {
        self.telemetry_decimation.load(Ordering::Relaxed)
    }

    /// The ports as declared.
    pub fn ports(&self) -> Ports {
        Ports::from_code(self.ports.load(Ordering::Relaxed)).unwrap_or(Ports::Timed)
    }

    /// Declares how the chambers are connected (the simulator's host, or a link request).
    pub fn declare_ports(&self, ports: Ports) {
        self.ports.store(ports.code(), Ordering::Relaxed);
    }

    /// Command task: applies a link request (checked first: a refused one changes
    /// nothing). The scope is armed against the latest status.
    pub fn apply(&self, request: LinkRequest) -> Result<(), Refusal> {
        request.check()?;
        match request {
            LinkRequest::SetTelemetry {
                decimation,
                channels,
            } => {
                self.telemetry_channels_xor
                    .store(channels.0 ^ DEFAULT_CHANNELS.0, Ordering::Relaxed);
                // The cycle counter runs on: frames fall on the multiples of the new
                // decimation, and the sequence's step says which one.
                self.telemetry_decimation
                    .store(decimation, Ordering::Relaxed);
                Ok(())
            }
            LinkRequest::DeclarePorts(ports) => {
                self.declare_ports(ports);
                Ok(())
            }
            LinkRequest::ScopeArm { trigger, pre } => {
                let now = self.status();
                self.with_scope(|s| s.arm(trigger, pre, &now))
            }
            LinkRequest::ScopeFire => self.with_scope(Scope::fire),
            // Answered by the command task from the report it keeps: nothing to apply.
            LinkRequest::RoutineReport => Ok(()),
            LinkRequest::ScopeDisarm => {
                self.with_scope(Scope::disarm);
                Ok(())
            }
        }
    }

    fn with_scope<R>(&self, f: impl FnOnce(&mut Scope) -> R) -> R {
        self.scope.lock(|cell| {
            let mut scope = cell.borrow_mut();
            let r = f(&mut scope);
            self.scope_active.store(scope.active(), Ordering::Relaxed);
            r
        })
    }

    /// Control task, once per cycle after the outputs are written: the scope keeps this
    /// cycle's sample while armed or recording. Disarmed, one flag test.
    #[inline]
    pub fn record_scope(&self, status: &Status) {
        if !self.scope_active.load(Ordering::Relaxed) {
            return;
        }
        let ports = self.ports();
        self.scope.lock(|cell| {
            if let Ok(mut scope) = cell.try_borrow_mut() {
                if !scope.record(status, ports) {
                    self.scope_active.store(false, Ordering::Relaxed);
                }
            }
        });
    }

    /// The finished recording waiting to be sent, if any.
    pub fn scope_recording(&self) -> Option<Recording> {
        self.scope.lock(|cell| cell.borrow().recording())
    }

    /// Sample `i` (oldest first) of the finished recording, encoded (one short lock each).
    pub fn scope_sample(&self, i: usize) -> Option<[u8; SAMPLE_BYTES]> {
        self.scope.lock(|cell| cell.borrow().sample_bytes(i))
    }

    /// The finished recording has been sent: the scope may be armed again.
    pub fn scope_release(&self) {
        self.with_scope(Scope::release);
    }

    /// Control task, after a calibration routine succeeded (or a record written over the
    /// link was loaded): hands the record to the storage task (never waits; a record not yet
    /// saved is replaced by this newer one), and to the command task as the current one.
    pub fn post_calibration(&self, record: CalibrationRecord) {
        replace(&self.calibration, record);
        self.publish_calibration(record);
    }

    /// Control task: the controller runs on `record` (at boot, and with each new one).
    pub fn publish_calibration(&self, record: CalibrationRecord) {
        replace(&self.current_calibration, record);
    }

    /// Command task: the record the controller runs on, if it changed since the last call.
    pub fn take_current_calibration(&self) -> Option<CalibrationRecord> {
        self.current_calibration.try_receive().ok()
    }

    /// Command task: a checked record written over the link, for the controller to load;
    /// `false` if one is still waiting (the command task sends one at a time).
    pub fn post_calibration_to_load(&self, record: CalibrationRecord) -> bool {
        self.calibration_to_load.try_send(record).is_ok()
    }

    /// Control task: the record to load, if one was written.
    pub fn take_calibration_to_load(&self) -> Option<CalibrationRecord> {
        self.calibration_to_load.try_receive().ok()
    }

    /// Control task: its verdict on the record it was given to load.
    pub fn post_calibration_loaded(&self, result: Result<(), Refusal>) {
        let _ = self.calibration_loaded.try_send(result);
    }

    /// Command task: the controller's verdict on the record it was given, once.
    pub fn take_calibration_loaded(&self) -> Option<Result<(), Refusal>> {
        self.calibration_loaded.try_receive().ok()
    }

    /// Control task: a routine started or ended ([`RoutineReport`]).
    #[cfg(feature = "bench")]
    pub fn post_routine_report(&self, report: RoutineReport) {
        replace(&self.routine_report, report);
    }

    /// Command task: the last routine's report, if it changed since the last call.
    #[cfg(feature = "bench")]
    pub fn take_routine_report(&self) -> Option<RoutineReport> {
        self.routine_report.try_receive().ok()
    }

    /// Storage task: waits for the next record to save.
    pub async fn calibration_to_save(&self) -> CalibrationRecord {
        self.calibration.receive().await
    }
}

/// Sends `record` into a one-slot channel that only one task sends to, replacing a value
/// not yet taken (never waits).
fn replace<M: RawMutex, T>(channel: &Channel<M, T, 1>, record: T) {
    if let Err(embassy_sync::channel::TrySendError::Full(record)) = channel.try_send(record) {
        // Only one task sends: after taking the older one the slot is free.
        let _ = channel.try_receive();
        let _ = channel.try_send(record);
    }
}
