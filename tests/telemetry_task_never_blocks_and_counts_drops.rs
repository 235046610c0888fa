//! The telemetry task against sinks that cannot keep up: the control side never waits, a
//! full queue or a sink that takes nothing drops whole frames and counts them, and a sink
//! that takes frames piecewise still yields a decodable stream.

use std::future::Future;
use std::pin::pin;
use std::task::{Context, Waker};

use embassy_sync::blocking_mutex::raw::NoopRawMutex;
use fpc::link::telemetry::TelemetryDecoder;
use fpc::ports::FrameSink;
use fpc::shared::{Shared, TELEMETRY_DEPTH};
use fpc::status::Status;
use fpc::tasks::telemetry_run;

/// Takes at most `chunk` bytes per write (0: the host is gone).
struct SlowSink {
    chunk: usize,
    bytes: Vec<u8>,
}

impl FrameSink for &mut SlowSink {
    fn write(&mut self, bytes: &[u8]) -> usize {
        let n = bytes.len().min(self.chunk);
        self.bytes.extend_from_slice(&bytes[..n]);
        n
    }
}

/// Queues `cycles` control cycles, then polls the task until it has nothing left to do.
fn run(chunk: usize, cycles: usize) -> (SlowSink, u32) {
    let shared = Shared::<NoopRawMutex>::new();
    let mut sink = SlowSink {
        chunk,
        bytes: Vec::new(),
    };
    {
        let mut task = pin!(telemetry_run(&mut sink, &shared, 1));
        let mut cx = Context::from_waker(Waker::noop());
        assert!(task.as_mut().poll(&mut cx).is_pending());
        for i in 0..cycles {
            let status = Status {
                position_m: i as f32,
                ..Status::INIT
            };
            shared.queue_telemetry(&status);
        }
        for _ in 0..10_000 {
            let _ = task.as_mut().poll(&mut cx);
        }
    }
    let dropped = shared.telemetry_dropped();
    (sink, dropped)
}

#[test]
fn a_full_queue_drops_and_counts_and_the_rest_arrives_piecewise_intact() {
    let cycles = TELEMETRY_DEPTH + 8;
    let (sink, dropped) = run(10, cycles);
    assert_eq!(dropped, 8);
    let mut d = TelemetryDecoder::new();
    let frames: Vec<_> = sink
        .bytes
        .iter()
        .filter_map(|&b| d.push(b))
        .map(Result::unwrap)
        .collect();
    assert_eq!(frames.len(), TELEMETRY_DEPTH);
    for (i, f) in frames.iter().enumerate() {
        assert_eq!((f.seq as usize, f.x_m), (i, i as f32));
    }
    assert_eq!(d.stats().rejected, 0);
}

#[test]
fn a_sink_that_takes_nothing_drops_whole_frames_without_stalling() {
    let (sink, dropped) = run(0, TELEMETRY_DEPTH);
    assert!(sink.bytes.is_empty());
    assert_eq!(dropped as usize, TELEMETRY_DEPTH);
}
