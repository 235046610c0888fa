//! The defmt log of up 0 as text lines.
//!
//! defmt frames carry only indices into the firmware ELF's string table, so they decode
//! only with that ELF. With the cargo feature `probe` and `--elf`, [`DefmtLog`] decodes them
//! with the `defmt-decoder` library; otherwise it shows the bytes as hex, and the capture
//! keeps them raw (`up0.bin`) for `defmt-print -e ELF < up0.bin` later.

/// Turns up-0 bytes into the lines to show.
pub struct DefmtLog {
    inner: Inner,
}

enum Inner {
    Hex,
    #[cfg(feature = "probe")]
    Decoded(Box<dyn defmt_decoder::StreamDecoder + Send + Sync + 'static>),
}

/// Longest hex line shown for undecoded defmt bytes, bytes.
const HEX_LINE: usize = 24;

impl DefmtLog {
    /// Undecoded: every piece of bytes is shown as hex.
    pub fn hex() -> DefmtLog {
        DefmtLog { inner: Inner::Hex }
    }

    /// Decoding with the defmt table of the firmware ELF `elf`.
    #[cfg(feature = "probe")]
    pub fn from_elf(elf: &[u8]) -> Result<DefmtLog, String> {
        let table = defmt_decoder::Table::parse(elf)
            .map_err(|e| format!("cannot read the defmt table: {e}"))?
            .ok_or("the ELF holds no defmt table (is it the fpc firmware?)")?;
        // One table per process, kept for its lifetime: the decoder borrows it.
        let table: &'static defmt_decoder::Table = Box::leak(Box::new(table));
        Ok(DefmtLog {
            inner: Inner::Decoded(table.new_stream_decoder()),
        })
    }

    /// Whether frames are decoded (otherwise shown as hex).
    pub fn decodes(&self) -> bool {
        !matches!(self.inner, Inner::Hex)
    }

    /// Feeds bytes from up 0; returns the lines they complete.
    pub fn push(&mut self, bytes: &[u8]) -> Vec<String> {
        match &mut self.inner {
            Inner::Hex => bytes
                .chunks(HEX_LINE)
                .map(|c| {
                    let hex: Vec<String> = c.iter().map(|b| format!("{b:02x}")).collect();
                    format!("defmt (undecoded): {}", hex.join(" "))
                })
                .collect(),
            #[cfg(feature = "probe")]
            Inner::Decoded(decoder) => {
                decoder.received(bytes);
                let mut lines = Vec::new();
                loop {
                    match decoder.decode() {
                        Ok(frame) => lines.push(frame.display(false).to_string()),
                        Err(defmt_decoder::DecodeError::UnexpectedEof) => break,
                        Err(defmt_decoder::DecodeError::Malformed) => {
                            lines.push("defmt: malformed frame skipped".to_string())
                        }
                    }
                }
                lines
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn undecoded_bytes_show_as_hex_lines() {
        let mut log = DefmtLog::hex();
        assert!(!log.decodes());
        let lines = log.push(&[0u8; 30]);
        assert_eq!(lines.len(), 2);
        assert!(
            lines[0].starts_with("defmt (undecoded): 00 00"),
            "{lines:?}"
        );
        assert!(log.push(&[]).is_empty());
    }

    /// With the feature: the firmware's defmt table loads and garbage on up 0 never stops
    /// the decoder. Needs a firmware ELF, named by `FPC_FIRMWARE_ELF` (skipped without).
    #[cfg(feature = "probe")]
    #[test]
    fn the_firmware_table_loads_and_garbage_does_not_stop_the_decoder() {
        let Some(path) = std::env::var_os("FPC_FIRMWARE_ELF") else {
            eprintln!("skipped: set FPC_FIRMWARE_ELF to the firmware ELF");
            return;
        };
        let elf = std::fs::read(path).unwrap();
        let mut log = DefmtLog::from_elf(&elf).unwrap();
        assert!(log.decodes());
        let mut seed = 0x9E37_79B9u32;
        for _ in 0..2000 {
            let bytes: Vec<u8> = (0..64)
                .map(|_| {
                    seed ^= seed << 13;
                    seed ^= seed >> 17;
                    seed ^= seed << 5;
                    seed as u8
                })
                .collect();
            let _ = log.push(&bytes);
        }
        assert!(DefmtLog::from_elf(b"not an elf").is_err());
    }
}
