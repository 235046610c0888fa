//! Telemetry through the real path: the firmware's control task queues frames, its
//! telemetry task encodes them into the RTT up-channel in the simulated board's RAM, a host
//! reads them there through the RTT transport as a probe does, and the decoder turns the
//! capture back into a run log — which equals the simulator's own run log sample for
//! sample, bit for bit, with no frame dropped, and carries the metadata `gap` reads.

use fpc::link::telemetry::ChannelSet;
use fpc::link::telemetry::{DEFAULT_CHANNELS, DEFAULT_DECIMATION};
use hal_sim::board::capture::{decode_capture, decoded_columns};
use hal_sim::run::{run, RunOptions, RunOutcome};

/// Compression cycles that take the reference run past 10 s of simulated time at 20 kHz.
const CYCLES_FOR_10_S: u32 = 29;

fn run_with_telemetry(decimation: u16, channels: ChannelSet) -> RunOutcome {
    run(&RunOptions {
        cycles: CYCLES_FOR_10_S,
        telemetry_decimation: decimation,
        telemetry_channels: channels,
        ..RunOptions::reference()
    })
    .unwrap()
}

/// The acceptance run: 10 s of simulated time at 20 kHz, stroking without a fault.
fn assert_ten_seconds_clean(outcome: &RunOutcome) {
    let s = &outcome.summary;
    assert!(s.sim_time_s >= 10.0 && s.faults.is_empty(), "{s:?}");
}

/// Every column a frame carries equals `run.csv`'s, row `i·step` against decoded row `i`,
/// bit for bit. (The simulator's log has more columns — the plant's true pressures and
/// volumes — which the firmware cannot know and telemetry does not carry.)
fn assert_matches(outcome: &RunOutcome, step: usize, channels: ChannelSet) {
    let d = decode_capture(&outcome.telemetry, |_| {}).unwrap();
    assert_eq!(d.stats.rejected, 0);
    assert_eq!((d.gaps, d.left_out, d.dropped), (0, 0, 0));
    assert_eq!(d.decimation as usize, step);
    let rows = outcome.log.len();
    assert_eq!(d.log.len(), rows.div_ceil(step), "rows");
    let mut compared = 0;
    assert_eq!(d.channels, channels);
    for key in ["force_delay_s", "theta_source", "ports", "ports_from_s"] {
        assert_eq!(
            d.log.meta(key).is_some(),
            outcome.log.meta(key).is_some(),
            "{key}"
        );
    }
    assert_eq!(
        d.log.meta("force_delay_s"),
        outcome.log.meta("force_delay_s")
    );
    assert_eq!(d.log.meta("theta_source"), outcome.log.meta("theta_source"));
    assert_eq!(d.log.meta("ports"), outcome.log.meta("ports"));
    // The bypass closes in a cycle's host step; the first frame declared timed is the next
    // due one, within one frame of it (the time bases are the same: `t_s` matches below).
    let from =
        |l: &hal_sim::runlog::RunLog| -> f64 { l.meta("ports_from_s").unwrap().parse().unwrap() };
    let lag = from(&d.log) - from(&outcome.log);
    assert!(
        lag > 0.0 && lag <= step as f64 * 50e-6 + 1e-9,
        "ports_from_s lags by {lag} s"
    );
    for name in decoded_columns(channels) {
        let Some(want) = outcome.log.column(name) else {
            assert_eq!(name, "mode", "run.csv lacks {name}");
            continue;
        };
        let got = d.log.column(name).unwrap();
        for (i, g) in got.iter().enumerate() {
            let w = want[i * step];
            assert_eq!(
                g.to_bits(),
                w.to_bits(),
                "{name} row {}: {g} vs {w}",
                i * step
            );
        }
        compared += 1;
    }
    assert_eq!(
        compared,
        1 + channels.len() + 1,
        "t_s, the channels carried and the fault code"
    );
}

#[test]
fn telemetry_capture_matches_run_log_at_full_rate() {
    let outcome = run_with_telemetry(1, ChannelSet::ALL);
    // One 58-byte frame per control cycle.
    assert_eq!(
        outcome.telemetry.len(),
        outcome.log.len() * fpc::link::telemetry::WIRE_BYTES
    );
    assert_matches(&outcome, 1, ChannelSet::ALL);
    assert_ten_seconds_clean(&outcome);
    assert!(outcome.log.len() >= 200_000, "{}", outcome.log.len());
}

#[test]
fn telemetry_capture_matches_run_log_at_the_default_decimation() {
    // The firmware's default: 2 kHz, the seven channels a run log needs (46-byte frames).
    let outcome = run_with_telemetry(DEFAULT_DECIMATION, DEFAULT_CHANNELS);
    assert_eq!(
        outcome.telemetry.len() % DEFAULT_CHANNELS.wire_bytes(),
        0,
        "46-byte frames only"
    );
    assert_matches(&outcome, usize::from(DEFAULT_DECIMATION), DEFAULT_CHANNELS);
    assert_ten_seconds_clean(&outcome);
}

#[test]
fn telemetry_is_off_unless_asked_for() {
    let outcome = run(&RunOptions {
        cycles: 1,
        ..RunOptions::reference()
    })
    .unwrap();
    assert!(outcome.telemetry.is_empty());
}
