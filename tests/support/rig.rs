//! A bench session on the simulated board, reached only through its RAM as a probe reaches
//! the real one (`hal_sim::link::simprobe`): the host declares the ports, sets the
//! telemetry, homes the machine, runs a campaign and arms the scope, all over the link, and
//! takes home the raw channels, the decoded telemetry and the scope recordings.

use fpc::control::command::Command;
use fpc::link::scope::Trigger;
use fpc::link::settings::LinkRequest;
use fpc::link::telemetry::{ChannelSet, Ports};
use fpc::status::ModeKind;
use hal_sim::board::capture::{decode_capture, Decoded};
use hal_sim::board::exec::{LinkedBoard, SimShared};
use hal_sim::link::session::Counters;
use hal_sim::link::simprobe::SimProbe;
use hal_sim::plant::chambers::PortMode;
use hal_sim::plant::model::MachineModel;
use hal_sim::run::{control_config, world, RunOptions};
use hal_sim::runlog::RunLog;

/// What the bench session does with the machine.
#[derive(Clone, Copy)]
pub enum Campaign {
    /// Compressing: strokes at this peak speed for this long, the scope armed for the 4th
    /// reversal.
    Running {
        /// Peak speed, m/s.
        speed_mps: f32,
        /// How long, s.
        seconds: f64,
    },
    /// The paper's closed-port campaign: the ports blanked, the piston moved to three
    /// positions and held while the pressures leak.
    Sealed,
}

/// What the host took home.
pub struct Captured {
    /// The telemetry capture decoded.
    pub decoded: Decoded,
    /// The scope recordings decoded.
    pub scope: Vec<RunLog>,
    /// Raw bytes of up 0, up 1 and up 2, as `fpc-sim link capture` writes them.
    pub raw: [Vec<u8>; 3],
    /// What the link counted.
    pub counters: Counters,
}

/// One bench session on the plant of `truth`, telemetry at `decimation` with the firmware's
/// default channels.
pub fn bench(truth: &str, seed: u64, decimation: u16, campaign: Campaign) -> Captured {
    bench_with(
        truth,
        seed,
        decimation,
        fpc::link::telemetry::DEFAULT_CHANNELS,
        None,
        campaign,
    )
}

/// [`bench`] with the channels chosen and the probe reading at most `poll_bytes` per
/// millisecond (`None`: as fast as the firmware sends).
pub fn bench_with(
    truth: &str,
    seed: u64,
    decimation: u16,
    channels: ChannelSet,
    poll_bytes: Option<usize>,
    campaign: Campaign,
) -> Captured {
    let model = MachineModel::parse(truth).expect("truth model loads");
    let opts = RunOptions::reference();
    let mut w = world(&model, seed, 0, opts.start_position_m);
    w.plant.lines.set_pressure_ratio(opts.pressure_ratio);
    let shared = SimShared::new();
    let board = LinkedBoard::boot(
        w,
        control_config(&model),
        &shared,
        fpc::link::telemetry::DEFAULT_DECIMATION,
    );
    let mut probe = SimProbe::attach(board).expect("the control block is found in RAM");
    probe.poll_bytes = poll_bytes;
    let run = |probe: &mut SimProbe| -> Result<(), String> {
        probe.request_ok(&LinkRequest::DeclarePorts(Ports::Bypassed))?;
        probe.request_ok(&LinkRequest::SetTelemetry {
            decimation,
            channels,
        })?;
        probe.command_ok(&Command::Home)?;
        probe.run_until("homed and holding", 30.0, |s| {
            s.last_frame()
                .is_some_and(|f| f.homed && f.mode == ModeKind::Holding)
        })?;
        match campaign {
            Campaign::Running { speed_mps, seconds } => {
                // The operator closes the bypass and says so.
                probe.world().plant.port_mode = PortMode::Timed;
                probe.request_ok(&LinkRequest::DeclarePorts(Ports::Timed))?;
                probe.command_ok(&Command::Start {
                    peak_speed_mps: speed_mps,
                })?;
                probe.request_ok(&LinkRequest::ScopeArm {
                    trigger: Trigger::Strokes(4),
                    pre: 256,
                })?;
                probe.run_for(seconds)?;
                probe.command_ok(&Command::Stop)?;
                probe.run_until("stopped", 5.0, |s| {
                    s.last_frame().is_some_and(|f| f.mode == ModeKind::Holding)
                })?;
            }
            Campaign::Sealed => {
                let travel = model.piston.travel_m as f32;
                let mid = 0.5 * travel;
                probe.command_ok(&Command::MoveTo {
                    position_m: mid,
                    peak_speed_mps: 0.5,
                })?;
                probe.run_for(1.0)?;
                // The operator blanks the ports and says so.
                probe.world().plant.port_mode = PortMode::Closed;
                probe.request_ok(&LinkRequest::DeclarePorts(Ports::Sealed))?;
                probe.request_ok(&LinkRequest::ScopeArm {
                    trigger: Trigger::ModeChange,
                    pre: 128,
                })?;
                for (to, hold_s) in [(0.82, 0.5), (0.5, 0.2), (0.18, 0.5), (0.5, 0.2)] {
                    probe.command_ok(&Command::MoveTo {
                        position_m: to * travel,
                        peak_speed_mps: 1.6,
                    })?;
                    probe.run_for(0.1 + hold_s)?;
                }
            }
        }
        Ok(())
    };
    if let Err(e) = run(&mut probe) {
        panic!("bench session: {e}; counters: {}", probe.counters());
    }
    let counters = probe.counters();
    eprintln!("link: {counters}");
    let decoded = decode_capture(&probe.raw[1], |_| {}).expect("the capture decodes");
    let raw = probe.raw.clone();
    let scope = probe
        .session()
        .scope()
        .recordings()
        .iter()
        .map(|r| r.to_log().expect("the recording decodes"))
        .collect();
    Captured {
        decoded,
        scope,
        raw,
        counters,
    }
}
