//! A debug probe on the emulated board: a `probe-rs` probe whose wire transfers — DP and AP
//! register reads and writes — are served by the chip's debug port ([`crate::chip::dap`]).
//! probe-rs's own ARM debug interface (its debug-port setup and power-up, its MEM-AP
//! accesses) drives it, so the host's link runs over it exactly as over a CMSIS-DAP probe.
//!
//! The host runs on a thread of its own, in turns: at each of the emulator's polls it is
//! given a turn ([`Turn::Go`]), makes its transfers — each served at once, the core
//! running or halted as the debug registers say — and gives the turn back
//! ([`ToChip::Done`]). The last turn ([`Turn::Last`]) is the host's detach.

use std::sync::mpsc::{Receiver, Sender};
use std::sync::Arc;

use probe_rs::architecture::arm::dp::DpRegisterAddress;
use probe_rs::architecture::arm::sequences::ArmDebugSequence;
use probe_rs::architecture::arm::{
    ArmCommunicationInterface, ArmDebugInterface, ArmError, DapError, DapProbe, RawDapAccess,
    RegisterAddress,
};
use probe_rs::probe::{DebugProbe, DebugProbeError, Probe, WireProtocol};

use crate::chip::dap::{DapFault, DapRegister};
use crate::chip::Chip;

/// From the host's probe to the chip.
#[derive(Clone, Copy, Debug)]
pub enum ToChip {
    /// A register read.
    Read(DapRegister),
    /// A register write.
    Write(DapRegister, u32),
    /// The host's turn is over.
    Done,
}

/// The answer to one transfer.
pub type Answer = Result<u32, DapFault>;

/// A turn given to the host.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Turn {
    /// Poll the link.
    Go,
    /// Poll once more and detach.
    Last,
}

/// The probe, as probe-rs sees it.
#[derive(Debug)]
pub struct EmulatedProbe {
    to_chip: Sender<ToChip>,
    answers: Receiver<Answer>,
    speed_khz: u32,
    protocol: WireProtocol,
}

impl EmulatedProbe {
    /// A probe sending its transfers on `to_chip`, their answers coming on `answers`.
    pub fn new(to_chip: Sender<ToChip>, answers: Receiver<Answer>) -> EmulatedProbe {
        EmulatedProbe {
            to_chip,
            answers,
            speed_khz: 4_000,
            protocol: WireProtocol::Swd,
        }
    }

    /// As a probe-rs [`Probe`].
    pub fn into_probe(self) -> Probe {
        Probe::from_specific_probe(Box::new(self))
    }

    fn transfer(&mut self, request: ToChip) -> Result<u32, ArmError> {
        let gone = || ArmError::Probe(DebugProbeError::Other("the emulator has stopped".into()));
        self.to_chip.send(request).map_err(|_| gone())?;
        match self.answers.recv().map_err(|_| gone())? {
            Ok(v) => Ok(v),
            Err(DapFault::Fault) => Err(ArmError::Dap(DapError::FaultResponse)),
        }
    }
}

fn register(address: RegisterAddress) -> DapRegister {
    match address {
        RegisterAddress::DpRegister(DpRegisterAddress { address, bank }) => {
            DapRegister::Dp { address, bank }
        }
        RegisterAddress::ApRegister(a) => DapRegister::Ap(a),
    }
}

impl RawDapAccess for EmulatedProbe {
    fn raw_read_register(&mut self, address: RegisterAddress) -> Result<u32, ArmError> {
        self.transfer(ToChip::Read(register(address)))
    }

    fn raw_write_register(&mut self, address: RegisterAddress, value: u32) -> Result<(), ArmError> {
        self.transfer(ToChip::Write(register(address), value))
            .map(|_| ())
    }

    fn jtag_sequence(&mut self, _cycles: u8, _tms: bool, _tdi: u64) -> Result<(), DebugProbeError> {
        Err(DebugProbeError::CommandNotSupportedByProbe {
            command_name: "jtag_sequence",
        })
    }

    /// Line resets and the JTAG-to-SWD switch: the SW-DP is always in SWD here.
    fn swj_sequence(&mut self, _bit_len: u8, _bits: u64) -> Result<(), DebugProbeError> {
        Ok(())
    }

    fn swj_pins(&mut self, _out: u32, _select: u32, _wait: u32) -> Result<u32, DebugProbeError> {
        Err(DebugProbeError::CommandNotSupportedByProbe {
            command_name: "swj_pins",
        })
    }

    fn into_probe(self: Box<Self>) -> Box<dyn DebugProbe> {
        self
    }

    fn core_status_notification(
        &mut self,
        _state: probe_rs::CoreStatus,
    ) -> Result<(), DebugProbeError> {
        Ok(())
    }
}

impl DebugProbe for EmulatedProbe {
    fn get_name(&self) -> &str {
        "the emulated board's SWD port"
    }

    fn speed_khz(&self) -> u32 {
        self.speed_khz
    }

    fn set_speed(&mut self, speed_khz: u32) -> Result<u32, DebugProbeError> {
        self.speed_khz = speed_khz;
        Ok(speed_khz)
    }

    fn attach(&mut self) -> Result<(), DebugProbeError> {
        Ok(())
    }

    fn detach(&mut self) -> Result<(), probe_rs::Error> {
        Ok(())
    }

    fn target_reset(&mut self) -> Result<(), DebugProbeError> {
        Err(DebugProbeError::CommandNotSupportedByProbe {
            command_name: "target_reset",
        })
    }

    fn target_reset_assert(&mut self) -> Result<(), DebugProbeError> {
        Err(DebugProbeError::CommandNotSupportedByProbe {
            command_name: "target_reset_assert",
        })
    }

    fn target_reset_deassert(&mut self) -> Result<(), DebugProbeError> {
        Ok(())
    }

    fn select_protocol(&mut self, protocol: WireProtocol) -> Result<(), DebugProbeError> {
        self.protocol = protocol;
        Ok(())
    }

    fn active_protocol(&self) -> Option<WireProtocol> {
        Some(self.protocol)
    }

    fn into_probe(self: Box<Self>) -> Box<dyn DebugProbe> {
        self
    }

    fn has_arm_interface(&self) -> bool {
        true
    }

    fn try_get_arm_debug_interface<'probe>(
        self: Box<Self>,
        sequence: Arc<dyn ArmDebugSequence>,
    ) -> Result<Box<dyn ArmDebugInterface + 'probe>, (Box<dyn DebugProbe>, ArmError)> {
        Ok(ArmCommunicationInterface::create(self, sequence, false))
    }

    fn try_as_dap_probe(&mut self) -> Option<&mut dyn DapProbe> {
        Some(self)
    }
}

impl DapProbe for EmulatedProbe {}

/// The emulator's side of a host turn: gives the host `turn` on `turns`, then serves its
/// transfers from `requests` on `chip` until it gives the turn back. False if the host has
/// gone (its thread ended).
pub fn serve(
    chip: &mut Chip,
    turn: Turn,
    turns: &Sender<Turn>,
    requests: &Receiver<ToChip>,
    answers: &Sender<Answer>,
) -> bool {
    if turns.send(turn).is_err() {
        return false;
    }
    loop {
        let answer = match requests.recv() {
            Ok(ToChip::Read(reg)) => chip.dap_read(reg),
            Ok(ToChip::Write(reg, value)) => chip.dap_write(reg, value).map(|()| 0),
            Ok(ToChip::Done) => return true,
            Err(_) => return false,
        };
        if answers.send(answer).is_err() {
            return false;
        }
    }
}
