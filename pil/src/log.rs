//! The firmware's defmt log (RTT up-channel 0), decoded with the ELF's own table.

use defmt_decoder::{DecodeError, StreamDecoder, Table};

/// A decoder of the defmt stream of one ELF, and the lines decoded so far.
pub struct DefmtLog {
    table: &'static Table,
    decoder: Box<dyn StreamDecoder + 'static>,
    /// Every message decoded, in order, with the emulated time it was read at (s).
    pub lines: Vec<(f64, String)>,
    /// Frames that did not decode.
    pub malformed: usize,
    /// Lines a reader has already looked at (its own bookmark).
    pub seen: usize,
}

impl DefmtLog {
    /// A decoder for the ELF `elf`; `None` if it has no defmt table.
    pub fn new(elf: &[u8]) -> Result<DefmtLog, String> {
        let table = Table::parse(elf)
            .map_err(|e| format!("the ELF's defmt table: {e}"))?
            .ok_or("the ELF has no defmt table")?;
        // One table per run, kept for the decoder's lifetime.
        let table: &'static Table = Box::leak(Box::new(table));
        Ok(DefmtLog {
            table,
            decoder: table.new_stream_decoder(),
            lines: Vec::new(),
            malformed: 0,
            seen: 0,
        })
    }

    /// Feeds bytes read from up 0 at emulated time `t_s`.
    pub fn push(&mut self, t_s: f64, bytes: &[u8]) {
        self.decoder.received(bytes);
        loop {
            match self.decoder.decode() {
                Ok(frame) => self.lines.push((t_s, frame.display_message().to_string())),
                Err(DecodeError::UnexpectedEof) => break,
                Err(DecodeError::Malformed) => {
                    self.malformed += 1;
                    if !self.table.encoding().can_recover() {
                        break;
                    }
                }
            }
        }
    }

    /// The chip reset: the firmware's stream starts afresh (a frame torn by the reset is
    /// dropped).
    pub fn restart(&mut self) {
        self.decoder = self.table.new_stream_decoder();
    }

    /// Whether a line containing `text` was logged.
    pub fn contains(&self, text: &str) -> bool {
        self.lines.iter().any(|(_, l)| l.contains(text))
    }
}
