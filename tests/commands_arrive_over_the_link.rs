//! The command path the firmware runs on the RTT down-channel: frames in, commands to the
//! control task's mailbox, every answer back — accepted, refused, busy, or rejected as
//! malformed. The task body is the firmware's own (`fpc::tasks::command_run`), polled here
//! against byte buffers and a stepped clock.

use std::future::Future;
use std::pin::pin;
use std::task::{Context, Waker};

use embassy_sync::blocking_mutex::raw::NoopRawMutex;
use fpc::control::command::Reply;
use fpc::control::command::{Command, Refusal};
use fpc::link::commands::{decode_answer, encode_command, Answer, MAX_COMMAND_WIRE};
use fpc::link::frame::{Deframer, FrameError};
use fpc::shared::{Shared, COMMAND_DEPTH};
use fpc::tasks::command_run;
use hal_sim::board::loopback::{ByteQueue, ByteSink, SteppedClock};

fn frame(command: &Command) -> Vec<u8> {
    let mut buf = [0u8; MAX_COMMAND_WIRE];
    let n = encode_command(command, &mut buf).unwrap();
    buf[..n].to_vec()
}

fn answers(bytes: &[u8]) -> Vec<Answer> {
    let mut d = Deframer::<64>::new();
    let mut out = Vec::new();
    for b in bytes {
        if let Some(frame) = d.push(*b) {
            out.push(decode_answer(frame.unwrap()).unwrap());
        }
    }
    out
}

#[test]
fn commands_are_decoded_answered_and_garbage_is_rejected() {
    let shared = Shared::<NoopRawMutex>::new();
    let input = ByteQueue::default();
    let output = ByteSink::default();
    let clock = SteppedClock::default();
    let mut task = pin!(command_run(
        input.clone(),
        output.clone(),
        clock.clone(),
        clock.clone(),
        &shared
    ));
    let mut cx = Context::from_waker(Waker::noop());
    let mut run_ms = |ms: u32| {
        for _ in 0..ms {
            clock.step(1000);
            let _ = task.as_mut().poll(&mut cx);
        }
    };

    // A valid Home, garbage, then a valid MoveTo.
    let moveto = Command::MoveTo {
        position_m: 0.1,
        peak_speed_mps: 1.0,
    };
    input.push(&frame(&Command::Home));
    input.push(&[0x55, 0x13, 0x99, 0x00]);
    input.push(&frame(&moveto));
    run_ms(3);
    assert_eq!(shared.take_command(), Some(Command::Home));
    assert_eq!(shared.take_command(), Some(moveto));
    assert_eq!(shared.take_command(), None);
    let got = answers(&output.bytes());
    assert_eq!(got.len(), 1, "one rejection for the garbage: {got:?}");
    assert!(matches!(
        got[0],
        Answer::Rejected(FrameError::Crc | FrameError::Cobs | FrameError::TooShort)
    ));

    // The control task's verdicts come back as replies.
    output.clear();
    shared.post_reply(Reply {
        command: moveto,
        result: Err(Refusal::NotHomed),
    });
    run_ms(2);
    let got = answers(&output.bytes());
    assert_eq!(
        got,
        vec![Answer::Reply(Reply {
            command: moveto,
            result: Err(Refusal::NotHomed)
        })]
    );

    // A full mailbox: the extra command is answered Busy, not lost silently.
    output.clear();
    for _ in 0..=COMMAND_DEPTH {
        input.push(&frame(&Command::Heartbeat));
    }
    run_ms(2);
    let got = answers(&output.bytes());
    assert_eq!(
        got,
        vec![Answer::Reply(Reply {
            command: Command::Heartbeat,
            result: Err(Refusal::Busy)
        })]
    );
}
