//! The firmware ELF: its loadable segments, its symbols (the vector table, the RTT control
//! block, the `.uninit` fault record) and its raw bytes (for the defmt table).

use std::collections::HashMap;
use std::path::Path;

use object::{Object, ObjectSegment, ObjectSymbol};

/// A firmware image.
#[derive(Clone, Debug)]
pub struct Image {
    /// (physical address, bytes) of each loaded segment.
    pub segments: Vec<(u32, Vec<u8>)>,
    /// Symbol addresses by name.
    pub symbols: HashMap<String, u32>,
    /// The file.
    pub bytes: Vec<u8>,
}

impl Image {
    /// Reads `path`; the error names the file and what is wrong with it.
    pub fn read(path: &Path) -> Result<Image, String> {
        let bytes = std::fs::read(path).map_err(|e| {
            format!(
                "--elf {}: {e} (build the firmware first: `cargo fw`)",
                path.display()
            )
        })?;
        Image::parse(bytes).map_err(|e| format!("--elf {}: {e}", path.display()))
    }

    /// The ELF the environment variable `var` names, else `default` (a path from the
    /// repository's root, where CI builds it): the PIL's tests' way to find their firmware.
    /// A missing file panics with `hint`, how to build it.
    pub fn built(var: &str, default: &str, hint: &str) -> Image {
        let path = std::env::var_os(var)
            .map(std::path::PathBuf::from)
            .unwrap_or_else(|| {
                Path::new(env!("CARGO_MANIFEST_DIR"))
                    .join("..")
                    .join(default)
            });
        Image::read(&path).unwrap_or_else(|e| panic!("{e} ({hint}, or set {var})"))
    }

    /// Parses an ELF already read.
    pub fn parse(bytes: Vec<u8>) -> Result<Image, String> {
        let file = object::File::parse(&*bytes).map_err(|e| format!("not an ELF file: {e}"))?;
        if file.architecture() != object::Architecture::Arm {
            return Err(format!(
                "an ELF for {:?}, not for the Cortex-M4 (thumbv7em)",
                file.architecture()
            ));
        }
        let mut segments = Vec::new();
        for seg in file.segments() {
            let data = seg.data().map_err(|e| e.to_string())?;
            if data.is_empty() {
                continue;
            }
            // The load address (LMA): .data's initial values live in flash.
            let (offset, _) = seg.file_range();
            let paddr = physical_address(&bytes, offset).unwrap_or(seg.address());
            segments.push((paddr as u32, data.to_vec()));
        }
        let symbols = file
            .symbols()
            .filter_map(|s| Some((s.name().ok()?.to_string(), s.address() as u32)))
            .collect();
        Ok(Image {
            segments,
            symbols,
            bytes,
        })
    }

    /// The address of symbol `name`.
    pub fn symbol(&self, name: &str) -> Option<u32> {
        self.symbols.get(name).copied()
    }
}

/// The p_paddr of the ELF32 program header whose p_offset is `offset`.
fn physical_address(bytes: &[u8], offset: u64) -> Option<u64> {
    let u32_at = |at: usize| -> Option<u32> {
        Some(u32::from_le_bytes(bytes.get(at..at + 4)?.try_into().ok()?))
    };
    let u16_at = |at: usize| -> Option<u16> {
        Some(u16::from_le_bytes(bytes.get(at..at + 2)?.try_into().ok()?))
    };
    let phoff = u32_at(0x1C)? as usize;
    let phentsize = usize::from(u16_at(0x2A)?);
    let phnum = usize::from(u16_at(0x2C)?);
    (0..phnum).find_map(|i| {
        let ph = phoff + i * phentsize;
        (u32_at(ph)? == 1 && u64::from(u32_at(ph + 4)?) == offset)
            .then(|| u64::from(u32_at(ph + 12).unwrap_or(0)))
    })
}
