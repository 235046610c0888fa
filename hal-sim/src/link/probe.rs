//! The probe transport (cargo feature `probe`): the board's RTT channels through a debug
//! probe, with the `probe-rs` library. Thin on purpose: attach, find the RTT control block,
//! read and write channels by number; everything else is the session's.
//!
//! It attaches to the running target without resetting or halting it (the firmware keeps
//! controlling the machine). The control block is looked up in the firmware ELF when one is
//! given (`_SEGGER_RTT`), otherwise searched for in RAM.

use std::io;
use std::path::Path;

use probe_rs::rtt::{Rtt, ScanRegion};
use probe_rs::{Permissions, Session, SessionConfig};

use super::Channels;

/// An attached board.
pub struct ProbeChannels {
    session: Session,
    rtt: Rtt,
}

fn other(e: impl std::fmt::Display) -> io::Error {
    io::Error::other(e.to_string())
}

/// `e` with its causes, on one line (probe-rs's top-level messages are vague: "An error with
/// the usage of the probe occurred" hides "the selected debug probe was not found").
fn chain(e: &dyn std::error::Error) -> String {
    let mut parts = vec![e.to_string()];
    let mut cause = e.source();
    while let Some(c) = cause {
        parts.push(c.to_string());
        cause = c.source();
    }
    parts
        .iter()
        .map(|p| p.split_whitespace().collect::<Vec<_>>().join(" "))
        .map(|p| p.trim_end_matches('.').to_string())
        .collect::<Vec<_>>()
        .join(": ")
}

impl ProbeChannels {
    /// Attaches to the first probe found, to a running `chip`, and to its RTT control block
    /// (at the address the ELF `elf` names, if given).
    pub fn attach(chip: &str, elf: Option<&Path>) -> Result<ProbeChannels, String> {
        let config = SessionConfig {
            permissions: Permissions::default(),
            ..SessionConfig::default()
        };
        let mut session = Session::auto_attach(chip, config)
            .map_err(|e| format!("cannot attach to {chip} through a probe: {}", chain(&e)))?;
        let region = match elf {
            Some(path) => {
                let bytes = std::fs::read(path)
                    .map_err(|e| format!("cannot read {}: {e}", crate::output::show(path)))?;
                match probe_rs::rtt::find_rtt_control_block_in_raw_file(&bytes) {
                    Ok(Some(address)) => ScanRegion::Exact(address),
                    _ => ScanRegion::Ram,
                }
            }
            None => ScanRegion::Ram,
        };
        let mut core = session
            .core(0)
            .map_err(|e| format!("cannot open the core of {chip}: {}", chain(&e)))?;
        let rtt = Rtt::attach_region(&mut core, &region).map_err(|e| {
            format!(
                "no RTT control block found on {chip} (is the fpc firmware running?): {}",
                chain(&e)
            )
        })?;
        drop(core);
        Ok(ProbeChannels { session, rtt })
    }
}

impl Channels for ProbeChannels {
    fn read_up(&mut self, channel: usize, buf: &mut [u8]) -> io::Result<usize> {
        let mut core = self.session.core(0).map_err(other)?;
        let up = self
            .rtt
            .up_channel(channel)
            .ok_or_else(|| other(format!("the firmware has no RTT up-channel {channel}")))?;
        up.read(&mut core, buf).map_err(|e| other(chain(&e)))
    }

    fn write_down(&mut self, channel: usize, bytes: &[u8]) -> io::Result<usize> {
        let mut core = self.session.core(0).map_err(other)?;
        let down = self
            .rtt
            .down_channel(channel)
            .ok_or_else(|| other(format!("the firmware has no RTT down-channel {channel}")))?;
        down.write(&mut core, bytes).map_err(|e| other(chain(&e)))
    }
}
