//! The command path the firmware runs on the RTT down-channel: frames in, commands to the
//! control task's mailbox, every answer back — accepted, refused, busy, or rejected as
//! malformed. The task body is the firmware's own (`fpc::tasks::command_run`), polled here
//! against byte buffers and a stepped clock.

use std::cell::{Cell, RefCell};
use std::collections::VecDeque;
use std::future::{poll_fn, Future};
use std::pin::pin;
use std::rc::Rc;
use std::task::{Context, Poll, Waker};

use embassy_sync::blocking_mutex::raw::NoopRawMutex;
use fpc::control::command::Reply;
use fpc::control::command::{Command, Refusal};
use fpc::link::commands::{decode_answer, encode_command, Answer, MAX_COMMAND_WIRE};
use fpc::link::frame::{Deframer, FrameError};
use fpc::ports::{ByteSource, Clock, FrameSink, Sleep};
use fpc::shared::{Shared, COMMAND_DEPTH};
use fpc::tasks::command_run;
use fpc::units::Ticks;

#[derive(Clone, Default)]
struct Bytes(Rc<RefCell<VecDeque<u8>>>);

impl ByteSource for Bytes {
    fn read(&mut self, buf: &mut [u8]) -> usize {
        let mut q = self.0.borrow_mut();
        let n = buf.len().min(q.len());
        for (slot, b) in buf.iter_mut().zip(q.drain(..n)) {
            *slot = b;
        }
        n
    }
}

#[derive(Clone, Default)]
struct Sink(Rc<RefCell<Vec<u8>>>);

impl FrameSink for Sink {
    fn write(&mut self, bytes: &[u8]) -> usize {
        self.0.borrow_mut().extend_from_slice(bytes);
        bytes.len()
    }
}

#[derive(Clone, Default)]
struct TestClock(Rc<Cell<u32>>);

impl Clock for TestClock {
    fn now(&self) -> Ticks {
        Ticks(self.0.get())
    }
}

impl Sleep for TestClock {
    async fn until(&mut self, deadline: Ticks) {
        poll_fn(|_| {
            if Ticks(self.0.get()).reached(deadline) {
                Poll::Ready(())
            } else {
                Poll::Pending
            }
        })
        .await
    }
}

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
    let input = Bytes::default();
    let output = Sink::default();
    let clock = TestClock::default();
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
            clock.0.set(clock.0.get().wrapping_add(1000));
            let _ = task.as_mut().poll(&mut cx);
        }
    };

    // A valid Home, garbage, then a valid MoveTo.
    let moveto = Command::MoveTo {
        position_m: 0.1,
        peak_speed_mps: 1.0,
    };
    input.0.borrow_mut().extend(frame(&Command::Home));
    input.0.borrow_mut().extend([0x55, 0x13, 0x99, 0x00]);
    input.0.borrow_mut().extend(frame(&moveto));
    run_ms(3);
    assert_eq!(shared.take_command(), Some(Command::Home));
    assert_eq!(shared.take_command(), Some(moveto));
    assert_eq!(shared.take_command(), None);
    let got = answers(&output.0.borrow());
    assert_eq!(got.len(), 1, "one rejection for the garbage: {got:?}");
    assert!(matches!(
        got[0],
        Answer::Rejected(FrameError::Crc | FrameError::Cobs | FrameError::TooShort)
    ));

    // The control task's verdicts come back as replies.
    output.0.borrow_mut().clear();
    shared.post_reply(Reply {
        command: moveto,
        result: Err(Refusal::NotHomed),
    });
    run_ms(2);
    let got = answers(&output.0.borrow());
    assert_eq!(
        got,
        vec![Answer::Reply(Reply {
            command: moveto,
            result: Err(Refusal::NotHomed)
        })]
    );

    // A full mailbox: the extra command is answered Busy, not lost silently.
    output.0.borrow_mut().clear();
    for _ in 0..=COMMAND_DEPTH {
        input.0.borrow_mut().extend(frame(&Command::Heartbeat));
    }
    run_ms(2);
    let got = answers(&output.0.borrow());
    assert_eq!(
        got,
        vec![Answer::Reply(Reply {
            command: Command::Heartbeat,
            result: Err(Refusal::Busy)
        })]
    );
}
