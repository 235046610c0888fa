//! The run log as the loop records it: compact rows, streamed to the CSV in chunks or kept
//! whole, and made into the log's columns.

use std::io::Write;
use std::time::Instant;

use fpc::status::Status;
use fpc::units::{CONTROL_PERIOD_S, CONTROL_PERIOD_US};

use super::{text, COLUMNS};
use crate::board::world::World;
use crate::runlog::RunLog;

/// The run log as the loop records it, made into [`COLUMNS`] after the loop (with the CSV),
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

/// The CSV a streamed [`Capture`] writes, and the decimated copy it keeps.
struct Stream<'s> {
    out: &'s mut dyn Write,
    /// The first write error; later chunks are not written.
    error: Option<std::io::Error>,
    /// Whether the head (metadata and column names) is out.
    head_written: bool,
    /// Text not yet written (reused; room for [`WRITE_BYTES`] and a line).
    text: text::Line,
    /// Every `stride`-th row of the run, for plots.
    kept: RunLog,
    stride: usize,
    /// Rows written before the current chunk.
    written: usize,
    /// Wall time spent writing, s (kept out of the loop's real-time factor).
    writing_s: f64,
}

/// One control cycle of [`Capture`].
#[derive(Clone, Copy, Debug)]
pub(super) struct CapturedRow {
    /// x, x_slave, θ, F_master, F_slave, p_A, p_B, x_ref, θ_ref, v as in [`COLUMNS`].
    status: [f32; 10],
    cycle: u32,
    fault: u8,
    /// p_A, p_B, V_A, V_B (plant truth) as in [`COLUMNS`].
    truth: [f64; 4],
}

/// Rows [`Capture`] reserves at most (80 MB of address space; it grows beyond).
const MAX_RESERVED_ROWS: usize = 1 << 20;

/// Rows a streamed run writes at a time (0.4 s of simulated time, 650 kB: the rows are
/// still in the cache when they are written out, and few fresh pages are touched).
pub const STREAM_CHUNK_ROWS: usize = 1 << 13;

/// Most rows a streamed run holds back, waiting for homing to end, before it writes its
/// head without the `ports` keys (26 s: longer than homing may take on the reference
/// travel; ≈ 40 MB).
const HEAD_WAIT_ROWS: usize = 1 << 19;

/// Bytes of CSV text a streamed run hands to its writer at a time (above a `BufWriter`'s
/// 1 MiB, so it goes straight through).
const WRITE_BYTES: usize = 1 << 20;

/// Most rows a streamed run keeps for its plots (≈ 0.4 s at the control rate; every 16th
/// row of the default 10-cycle run: still ≈ 5000 points over 4.4 s, more than a plot draws
/// (`plot::lines` keeps ≈ 4000 a series); 1.2 MB, reserved at once so it never moves).
/// Halved as soon as it is outgrown, so a chunk's rows are kept only at the stride in force.
pub const KEPT_ROWS: usize = 1 << 13;

impl<'s> Capture<'s> {
    /// Room for a run of at most `limit_s` simulated seconds (untouched capacity costs no
    /// memory), or for one chunk when streamed to `csv` (whose head, the metadata and
    /// column names of `log` with [`Capture::ports_meta`], goes out with the first chunk,
    /// once homing has ended).
    pub(super) fn new(limit_s: f64, csv: Option<&'s mut dyn Write>, log: &RunLog) -> Self {
        let rows = (limit_s / f64::from(CONTROL_PERIOD_S)) as usize;
        let stream = csv.map(|out| {
            let mut kept = RunLog::with_columns(&COLUMNS);
            kept.meta = log.meta.clone();
            kept.names = log.names.clone();
            for column in &mut kept.columns {
                column.reserve_exact(KEPT_ROWS + 1);
            }
            Stream {
                out,
                error: None,
                head_written: false,
                text: text::Line::with_room(WRITE_BYTES),
                kept,
                stride: 1,
                written: 0,
                writing_s: 0.0,
            }
        });
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
        let (c, l) = (&w.plant.chambers, &w.plant.lines);
        let line_pa = (l.suction_pa, l.discharge_pa);
        if self.lines.last().is_none_or(|&(_, s, d)| (s, d) != line_pa) {
            self.lines.push((self.rows.len(), line_pa.0, line_pa.1));
        }
        self.rows.push(CapturedRow {
            status: [
                status.position_m,
                status.slave_position_m,
                status.theta_rad,
                status.force_master_n,
                status.force_slave_n,
                status.pressure_a_pa,
                status.pressure_b_pa,
                status.reference_m,
                status.theta_reference_rad,
                status.velocity_mps,
            ],
            cycle: u32::try_from(w.cycle()).unwrap_or(u32::MAX),
            fault: status.faults.first().map_or(0, |f| f as u8),
            truth: [
                c.a.pressure_pa,
                c.b.pressure_pa,
                c.a.volume_m3,
                c.b.volume_m3,
            ],
        });
        let head_known = self.ports_from_s.is_some() || self.rows.len() >= HEAD_WAIT_ROWS;
        let head_written = self.stream.as_ref().is_some_and(|s| s.head_written);
        if self.stream.is_some()
            && self.rows.len() >= STREAM_CHUNK_ROWS
            && (head_written || head_known)
        {
            self.flush();
        }
    }

    /// Streamed: writes the captured rows to the CSV (each column at its resolution,
    /// [`super::text`]), keeps every `stride`-th for the plots (halving the copy and doubling
    /// the stride when it outgrows [`KEPT_ROWS`]) and starts the next chunk with the line
    /// pressures in force.
    pub(super) fn flush(&mut self) {
        let ports = self.ports_meta();
        let Some(s) = self.stream.as_mut() else {
            return;
        };
        let started = Instant::now();
        if !s.head_written {
            s.head_written = true;
            s.kept.meta.extend(ports);
            let mut head = String::new();
            s.kept.head_to_csv(&mut head);
            if s.error.is_none() {
                s.error = s.out.write_all(head.as_bytes()).err();
            }
        }
        let mut change = 0;
        for (i, r) in self.rows.iter().enumerate() {
            while self.lines.get(change + 1).is_some_and(|l| l.0 <= i) {
                change += 1;
            }
            let (suction, discharge) = self
                .lines
                .get(change)
                .map_or((f64::NAN, f64::NAN), |l| (l.1, l.2));
            let v = values(r, suction, discharge);
            s.text
                .row(u64::from(r.cycle), u64::from(CONTROL_PERIOD_US), &v);
            s.text.push(b'\n');
            if (s.written + i) % s.stride == 0 {
                s.kept.push_row(&v);
                if s.kept.len() > KEPT_ROWS {
                    halve(&mut s.kept);
                    s.stride *= 2;
                }
            }
            // Written a piece at a time, so the text stays in the cache.
            if s.text.len() >= WRITE_BYTES {
                if s.error.is_none() {
                    s.error = s.out.write_all(s.text.as_bytes()).err();
                }
                s.text.clear();
            }
        }
        if s.error.is_none() {
            s.error = s.out.write_all(s.text.as_bytes()).err();
        }
        s.text.clear();
        s.written += self.rows.len();
        s.writing_s += started.elapsed().as_secs_f64();
        let in_force = self.lines.last().map(|&(_, su, di)| (0, su, di));
        self.rows.clear();
        self.lines.clear();
        self.lines.extend(in_force);
    }

    /// Wall time spent writing the streamed CSV so far, s.
    pub(super) fn writing_s(&self) -> f64 {
        self.stream.as_ref().map_or(0.0, |s| s.writing_s)
    }

    /// The log of the run: all rows into `log` (which has [`COLUMNS`]); streamed, the rest
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
        if let Some(e) = s.error.or_else(|| s.out.flush().err()) {
            return Err(format!("cannot write the run log: {e}"));
        }
        *log = s.kept;
        Ok(())
    }
}

/// Keeps every other row of `log` (row 2k moves to k, in place: the capacity stays).
fn halve(log: &mut RunLog) {
    for column in &mut log.columns {
        let half = column.len().div_ceil(2);
        for k in 0..half {
            if let Some(v) = column.get(2 * k).copied() {
                if let Some(slot) = column.get_mut(k) {
                    *slot = v;
                }
            }
        }
        column.truncate(half);
    }
}

/// Row `r`'s values in [`COLUMNS`]' order, with the line pressures in force.
fn values(r: &CapturedRow, suction_pa: f64, discharge_pa: f64) -> [f64; 18] {
    let [a, b, c, d, e, f, g, h, i, j] = r.status.map(f64::from);
    let [pa, pb, va, vb] = r.truth;
    [
        World::time_s_at(u64::from(r.cycle)),
        a,
        b,
        c,
        d,
        e,
        f,
        g,
        h,
        i,
        j,
        f64::from(r.fault),
        pa,
        pb,
        va,
        vb,
        suction_pa,
        discharge_pa,
    ]
}

/// Appends the captured `rows` to `log` (which has [`COLUMNS`]), one column at a time; `lines`
/// are the line-pressure changes (first row index, suction, discharge).
pub(super) fn fill_columns(rows: &[CapturedRow], lines: &[(usize, f64, f64)], log: &mut RunLog) {
    let n = rows.len();
    for (j, column) in log.columns.iter_mut().enumerate() {
        column.reserve_exact(n);
        match j {
            0 => column.extend(rows.iter().map(|r| World::time_s_at(u64::from(r.cycle)))),
            1..=10 => column.extend(
                rows.iter()
                    .map(|r| r.status.get(j - 1).copied().map_or(f64::NAN, f64::from)),
            ),
            11 => column.extend(rows.iter().map(|r| f64::from(r.fault))),
            12..=15 => column.extend(
                rows.iter()
                    .map(|r| r.truth.get(j - 12).copied().unwrap_or(f64::NAN)),
            ),
            _ => {
                // Each line pressure holds from its change to the next.
                let ends = lines.iter().skip(1).map(|l| l.0).chain([n]);
                for (&(start, suction, discharge), end) in lines.iter().zip(ends) {
                    let v = if j == 16 { suction } else { discharge };
                    column.extend(std::iter::repeat_n(v, end.saturating_sub(start)));
                }
            }
        }
    }
}
