//! The run log as the loop records it: compact rows, streamed to the CSV in chunks or kept
//! whole, and made into the log's columns.

mod row;
mod stream;

use std::io::Write;

use fpc::status::Status;
use fpc::units::CONTROL_PERIOD_S;

use crate::board::world::World;
use crate::runlog::RunLog;
use row::{fill_columns, CapturedRow};
use stream::Stream;

/// The run log as the loop records it, made into [`COLUMNS`](super::COLUMNS) after the loop (with the CSV),
/// or chunk by chunk into the CSV while it runs ([`run_streamed`]).
///
/// A row is 80 bytes instead of 18 separate `f64` pushes (144): the status fields as the
/// firmware has them (`f32`), the cycle instead of the time, the line pressures only when
/// they change. Each fresh page costs a fault, which costs more than the rest of the
/// recording; the buffer is reserved for the longest run so it never moves.
pub(super) struct Capture<'s> {
    rows: Vec<CapturedRow>,
    /// (first row, p_suction, p_discharge) at each change of the line pressures.
    lines: Vec<(usize, f64, f64)>,
    /// Where the rows go while the run goes on, when streamed.
    stream: Option<Stream<'s>>,
    /// When the start-up bypass closed (the rotation times the ports from the next row), s.
    ports_from_s: Option<f64>,
}

/// Rows [`Capture`] reserves at most (80 MB of address space; it grows beyond).
const MAX_RESERVED_ROWS: usize = 1 << 20;

/// Rows a streamed run hands on at a time (0.1 s of simulated time, 160 kB: the rows are
/// still in the cache when their text is made, the buffers in flight touch few fresh pages,
/// and the text of the last chunks, made after the loop, is short).
pub const STREAM_CHUNK_ROWS: usize = 1 << 11;

/// Most rows a streamed run holds back, waiting for homing to end, before it writes its
/// head without the `ports` keys (26 s: longer than homing may take on the reference
/// travel; ≈ 40 MB).
const HEAD_WAIT_ROWS: usize = 1 << 19;

impl<'s> Capture<'s> {
    /// Room for a run of at most `limit_s` simulated seconds (untouched capacity costs no
    /// memory), or for one chunk when streamed to `csv` (whose head, the metadata and
    /// column names of `log` with [`Capture::ports_meta`], goes out with the first chunk,
    /// once homing has ended).
    pub(super) fn new(limit_s: f64, csv: Option<&'s mut dyn Write>, log: &RunLog) -> Self {
        let rows = (limit_s / f64::from(CONTROL_PERIOD_S)) as usize;
        let stream = csv.map(|out| Stream::new(out, log));
        let reserve = if stream.is_some() {
            STREAM_CHUNK_ROWS
        } else {
            rows.min(MAX_RESERVED_ROWS)
        };
        Capture {
            rows: Vec::with_capacity(reserve),
            lines: Vec::new(),
            stream,
            ports_from_s: None,
        }
    }

    /// The start-up bypass closed at `t_s` (after the row of that time): the rotation times
    /// the ports from the next row on.
    pub(super) fn ports_timed_from(&mut self, t_s: f64) {
        self.ports_from_s.get_or_insert(t_s);
    }

    /// The log's metadata on what times the ports (`docs/formats.md` §1): once the bypass has
    /// closed, `ports = open` from `ports_from_s`, and `theta_rad` is the servo encoder's
    /// count (the piston follows through the spline's play, which the model states). A run
    /// that never got there says nothing, and its pressures are not replayed.
    fn ports_meta(&self) -> Vec<(String, String)> {
        match self.ports_from_s {
            Some(t) => vec![
                ("ports".into(), "open".into()),
                ("ports_from_s".into(), format!("{t}")),
                ("theta_source".into(), "servo_encoder".into()),
            ],
            None => Vec::new(),
        }
    }

    #[inline]
    pub(super) fn push(&mut self, status: &Status, w: &World) {
        let l = &w.plant.lines;
        let line_pa = (l.suction_pa, l.discharge_pa);
        if self.lines.last().is_none_or(|&(_, s, d)| (s, d) != line_pa) {
            self.lines.push((self.rows.len(), line_pa.0, line_pa.1));
        }
        self.rows.push(CapturedRow::new(status, w));
        let head_known = self.ports_from_s.is_some() || self.rows.len() >= HEAD_WAIT_ROWS;
        let head_written = self.stream.as_ref().is_some_and(Stream::head_written);
        if self.stream.is_some()
            && self.rows.len() >= STREAM_CHUNK_ROWS
            && (head_written || head_known)
        {
            self.flush();
        }
    }

    /// Streamed: hands the captured rows to the CSV's stream (the head first, once) and
    /// starts the next chunk with the line pressures in force.
    fn flush(&mut self) {
        let ports = self.ports_meta();
        let Some(s) = self.stream.as_mut() else {
            return;
        };
        let in_force = self.lines.last().map(|&(_, su, di)| (0, su, di));
        let lines = std::mem::replace(&mut self.lines, in_force.into_iter().collect());
        s.send(&mut self.rows, lines, ports);
    }

    /// Wall time spent writing the streamed CSV so far, s.
    pub(super) fn writing_s(&self) -> f64 {
        self.stream.as_ref().map_or(0.0, Stream::writing_s)
    }

    /// The log of the run: all rows into `log` (which has [`COLUMNS`](super::COLUMNS)); streamed, the rest
    /// written and the kept copy in `log`, or the first write error.
    pub(super) fn finish(mut self, log: &mut RunLog) -> Result<(), String> {
        if self.stream.is_none() {
            log.meta.extend(self.ports_meta());
            fill_columns(&self.rows, &self.lines, log);
            return Ok(());
        }
        self.flush();
        let Some(s) = self.stream.take() else {
            return Ok(());
        };
        *log = s.finish()?;
        Ok(())
    }
}
