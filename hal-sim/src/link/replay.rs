//! The replay transport: recorded channel contents played back in small uneven pieces, as a
//! probe delivers them, so the session's streaming code sees frames split anywhere.
//!
//! A recording is a directory with `up0.bin`, `up1.bin` and `up2.bin` (raw bytes of each
//! up-channel; a missing file is an empty channel). What is written to the down-channels
//! is kept in [`Replay::down`].

use std::io;
use std::path::Path;

use super::Channels;

/// File name of up-channel `channel` in a recording.
pub fn up_file(channel: usize) -> String {
    format!("up{channel}.bin")
}

/// Sizes of the successive pieces a replayed channel is read in, cycled.
const PIECES: [usize; 8] = [1, 7, 56, 3, 250, 13, 55, 4096];

/// Recorded up-channels and the bytes written down.
#[derive(Clone, Debug, Default)]
pub struct Replay {
    up: Vec<(Vec<u8>, usize, usize)>,
    /// Bytes written to each down-channel, by number.
    pub down: Vec<Vec<u8>>,
}

impl Replay {
    /// Replays `up[i]` as up-channel `i`.
    pub fn new(up: Vec<Vec<u8>>) -> Replay {
        Replay {
            up: up.into_iter().map(|bytes| (bytes, 0, 0)).collect(),
            down: Vec::new(),
        }
    }

    /// Replays the recording in `dir` (`up0.bin`, `up1.bin`, `up2.bin`; at least one).
    pub fn from_dir(dir: &Path) -> Result<Replay, String> {
        if !dir.is_dir() {
            return Err(format!(
                "{}: not a directory of recorded channels (up0.bin, up1.bin, up2.bin)",
                crate::output::show(dir)
            ));
        }
        let mut up = Vec::new();
        let mut found = 0;
        for channel in 0..3 {
            let path = dir.join(up_file(channel));
            match std::fs::read(&path) {
                Ok(bytes) => {
                    found += 1;
                    up.push(bytes);
                }
                Err(e) if e.kind() == io::ErrorKind::NotFound => up.push(Vec::new()),
                Err(e) => return Err(format!("cannot read {}: {e}", crate::output::show(&path))),
            }
        }
        if found == 0 {
            return Err(format!(
                "{} holds no recorded channel (up0.bin, up1.bin, up2.bin)",
                crate::output::show(dir)
            ));
        }
        Ok(Replay::new(up))
    }
}

impl Channels for Replay {
    fn read_up(&mut self, channel: usize, buf: &mut [u8]) -> io::Result<usize> {
        let Some((bytes, at, piece)) = self.up.get_mut(channel) else {
            return Err(io::ErrorKind::UnexpectedEof.into());
        };
        let rest = bytes.get(*at..).unwrap_or_default();
        if rest.is_empty() {
            return Err(io::ErrorKind::UnexpectedEof.into());
        }
        let want = PIECES.get(*piece % PIECES.len()).copied().unwrap_or(1);
        *piece += 1;
        let n = want.min(buf.len()).min(rest.len());
        if let (Some(dst), Some(src)) = (buf.get_mut(..n), rest.get(..n)) {
            dst.copy_from_slice(src);
        }
        *at += n;
        Ok(n)
    }

    fn write_down(&mut self, channel: usize, bytes: &[u8]) -> io::Result<usize> {
        if self.down.len() <= channel {
            self.down.resize(channel + 1, Vec::new());
        }
        if let Some(d) = self.down.get_mut(channel) {
            d.extend_from_slice(bytes);
        }
        Ok(bytes.len())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_replay_gives_every_byte_once_in_uneven_pieces_then_ends() {
        let data: Vec<u8> = (0..1000u32).map(|i| i as u8).collect();
        let mut r = Replay::new(vec![Vec::new(), data.clone()]);
        let mut got = Vec::new();
        let mut sizes = Vec::new();
        let mut buf = [0u8; 512];
        loop {
            match r.read_up(1, &mut buf) {
                Ok(n) => {
                    sizes.push(n);
                    got.extend_from_slice(&buf[..n]);
                }
                Err(e) => {
                    assert!(crate::link::is_end(&e));
                    break;
                }
            }
        }
        assert_eq!(got, data);
        assert!(sizes.contains(&1) && sizes.contains(&7), "{sizes:?}");
        assert!(crate::link::is_end(&r.read_up(0, &mut buf).unwrap_err()));
        assert!(crate::link::is_end(&r.read_up(5, &mut buf).unwrap_err()));
        assert_eq!(r.write_down(0, &[1, 2]).unwrap(), 2);
        assert_eq!(r.down, vec![vec![1, 2]]);
    }
}
