//! `fpc-sim run` logs carry the `ports` metadata of `formats.md` §1: the ports are timed by
//! the rotation (`open`) from the moment the start-up bypass closes (`ports_from_s`), so the
//! model-gap workflow replays the chambers as the machine ran them. Without `ports_from_s`
//! the replay assumed timed ports through homing too and left a 28 kPa pressure residual on
//! the simulator's own null runs (issue #18).

use hal_sim::gap::{analyse, GapOptions};
use hal_sim::run::{run, RunOptions};

const REFERENCE: &str = include_str!("../hal-sim/src/plant/model/reference.toml");

#[test]
fn the_run_log_names_its_ports_and_the_pressure_replay_follows_it() {
    for seed in [1, 7] {
        let opts = RunOptions {
            cycles: 4,
            seed,
            ..RunOptions::reference()
        };
        let outcome = run(&opts).expect("the run completes");
        let log = &outcome.log;
        assert_eq!(log.meta("ports"), Some("open"));
        let from: f64 = log
            .meta("ports_from_s")
            .and_then(|v| v.parse().ok())
            .expect("ports_from_s");
        // The bypass closes once homing is done: after the start, well before the end.
        let t = log.column("t_s").unwrap_or_default();
        assert!(
            from > 0.1 && from < t.last().copied().unwrap_or(0.0) - 1.0,
            "{from}"
        );
        let gap = analyse(REFERENCE, log, &GapOptions::default()).expect("gap runs");
        let pressure = gap
            .json
            .channels
            .iter()
            .find(|c| c.name == "pressure")
            .expect("the pressure channel is compared");
        println!(
            "seed {seed}: ports open from {from} s; pressure residual {:.0} Pa; named: {:?}",
            pressure.rms_before,
            gap.json
                .effects
                .iter()
                .map(|e| e.name.as_str())
                .collect::<Vec<_>>()
        );
        // One code of the 12-bit, 10 bar sensor is 244 Pa: the replay agrees to about one
        // code (28 kPa when the homing phase was replayed with timed ports).
        assert!(pressure.rms_before < 500.0, "{} Pa", pressure.rms_before);
    }
}
