//! `fpc` firmware for the STM32G474RE: brings the board up and runs the library's task
//! bodies on embassy executors.
//!
//! - the 20 kHz control task ([`fpc::tasks::control_run`]) on a high-priority
//!   `InterruptExecutor`, woken by the end of each ADC burst;
//! - in thread mode: the supervision task ([`fpc::tasks::supervision_run`], 1 kHz, feeds
//!   the watchdog), the telemetry task ([`fpc::tasks::telemetry_run`], frames to RTT up 1),
//!   the command task ([`fpc::tasks::command_run`], RTT down 0 in, replies on up 2) and the
//!   calibration storage task ([`fpc::tasks::calibration_store_run`], saves each routine's
//!   result to flash).
//!
//! The calibration record is read from flash at boot, before the control task starts —
//! missing or invalid, the machine refuses `Start` until calibrated — and each routine's
//! result is saved by the storage task.
//!
//! Each embassy task is a thin concrete wrapper: embassy tasks cannot be generic, the
//! bodies are. All hardware glue is in `board` (pins, clocks, interrupts, safe state).
//!
//! Build with `cargo fw`, flash and watch defmt with `cargo fw-run`. On the host this
//! binary only says so, so that `cargo build` of the workspace keeps working.
#![cfg_attr(target_os = "none", no_std, no_main)]
#![deny(unsafe_code)]

// The one place `unsafe` is allowed, each use with a `// SAFETY:` comment.
#[cfg(target_os = "none")]
#[allow(unsafe_code)]
mod board;

/// The embassy tasks and the entry point.
#[cfg(target_os = "none")]
mod firmware {
    use core::convert::Infallible;

    use embassy_executor::Spawner;
    use fpc::control::calibration::record::CalibrationRecord;
    use fpc::control::calibration::store::LoadError;
    use fpc::control::config::ControlConfig;
    use fpc::safety::faults::ResetCause;
    use fpc::shared::Shared;

    use crate::board::{self, BoardClock, BoardSleep, BoardWatchdog};

    /// State shared by the control task and the thread-mode tasks (masks every interrupt
    /// while held: [`board::critical`]).
    static SHARED: Shared<board::critical::ControlRawMutex> = Shared::new();

    /// The 20 kHz control task (control executor, woken by each ADC burst).
    #[embassy_executor::task]
    async fn control(
        ports: board::ControlPorts,
        reset_cause: ResetCause,
        stored: Option<Result<CalibrationRecord, LoadError>>,
    ) {
        let never: Infallible = fpc::tasks::control_run(
            ports,
            &SHARED,
            ControlConfig::reference(),
            reset_cause,
            stored,
        )
        .await;
        match never {}
    }

    /// The calibration storage task (thread mode): saves each routine's record to flash.
    #[embassy_executor::task]
    async fn calibration_store(store: board::BoardCalibrationStore) {
        let never: Infallible =
            fpc::tasks::calibration_store_run(store, &SHARED, board::DefmtEvents).await;
        match never {}
    }

    /// The 1 kHz supervision task (thread mode): the only one that feeds the watchdog.
    #[embassy_executor::task]
    async fn supervision(
        sleep: BoardSleep,
        clock: BoardClock,
        watchdog: BoardWatchdog,
        power_good: board::PowerGood,
    ) {
        let never: Infallible = fpc::tasks::supervision_run(
            sleep,
            clock,
            watchdog,
            board::DefmtEvents,
            power_good,
            &SHARED,
        )
        .await;
        match never {}
    }

    /// The telemetry task (thread mode): frames from the control task to RTT up-channel 1.
    #[embassy_executor::task]
    async fn telemetry(sink: board::rtt::TelemetryChannel) {
        let never: Infallible =
            fpc::tasks::telemetry_run(sink, &SHARED, fpc::link::telemetry::DEFAULT_DECIMATION)
                .await;
        match never {}
    }

    /// The command task (thread mode): RTT down-channel 0 in, replies on up-channel 2.
    #[embassy_executor::task]
    async fn commands(
        source: board::rtt::CommandChannel,
        replies: board::rtt::ReplyChannel,
        sleep: BoardSleep,
        clock: BoardClock,
    ) {
        let never: Infallible =
            fpc::tasks::command_run(source, replies, sleep, clock, &SHARED).await;
        match never {}
    }

    /// Paints the free stack once the control task runs (≈ 80 µs for 68 KiB at 170 MHz,
    /// kept out of the boot, which delays the brake after a watchdog reset), then logs its
    /// high-water mark and whenever it grows by 256 bytes (thread mode, once a second: a scan
    /// of the painted stack, ≈ 1 ms of the core, yielding every 30 µs).
    #[embassy_executor::task]
    async fn stack_watch() {
        board::stack::paint();
        loop {
            board::stack::log_growth().await;
            embassy_time::Timer::after_secs(1).await;
        }
    }

    /// Reads the calibration from flash (memory-mapped reads, well inside the watchdog's
    /// boot window) and starts the storage task with the store.
    async fn load_calibration(
        spawner: &Spawner,
        board: &mut board::Board,
    ) -> Result<CalibrationRecord, LoadError> {
        let stored = match board.calibration.take() {
            Some(mut store) => {
                let loaded = store.load().await;
                spawner.spawn(defmt::unwrap!(calibration_store(store)));
                loaded
            }
            None => Err(LoadError::Flash),
        };
        match &stored {
            Ok(record) => defmt::info!("calibration loaded: {}", record.status().name()),
            Err(e) => defmt::warn!(
                "{} ({}): Start refused until calibrated",
                e.status().name(),
                e
            ),
        }
        stored
    }

    #[embassy_executor::main]
    async fn main(spawner: Spawner) {
        let (telemetry_sink, replies, command_source) = board::rtt::init();
        let mut reset_cause = board::take_reset_cause();
        match reset_cause {
            ResetCause::Watchdog => defmt::error!("reset by the independent watchdog: a task hung"),
            cause => defmt::info!("boot after {}", cause),
        }
        if let Some(cause) = board::take_kept_cause() {
            defmt::error!("the previous run ended on the fault path: {}", cause);
            if cause.while_running() {
                // The piston may still be moving, its outputs off since the fault: the
                // control task brakes it as after a hung task.
                reset_cause = ResetCause::Watchdog;
            }
        }
        let mut board = board::init();
        let stored = Some(load_calibration(&spawner, &mut board).await);
        board::start_control_executor().spawn(defmt::unwrap!(control(
            board.control,
            reset_cause,
            stored
        )));
        spawner.spawn(defmt::unwrap!(supervision(
            board.sleep,
            board.clock,
            board.watchdog,
            board.power_good
        )));
        spawner.spawn(defmt::unwrap!(telemetry(telemetry_sink)));
        spawner.spawn(defmt::unwrap!(commands(
            command_source,
            replies,
            BoardSleep,
            BoardClock
        )));
        spawner.spawn(defmt::unwrap!(stack_watch()));
        defmt::info!("running: control, supervision, telemetry and command tasks");
    }
}

#[cfg(not(target_os = "none"))]
fn main() {
    println!(
        "fpc: this binary is the STM32G474RE firmware; build it with `cargo fw` \
         (thumbv7em-none-eabihf). The host-side tools are in hal-sim."
    );
}
