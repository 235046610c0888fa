//! The streamed run log: the CSV text of each chunk of rows made on a thread of its own while
//! the loop runs on (the text is about a fifth of a run's work), written out in order by the
//! loop's thread, and an evenly decimated copy of the rows kept for the plots.
//!
//! The text is the same, byte for byte, whichever thread makes it and however it is split
//! into pieces: the rows are formatted in order by one maker.

use std::io::Write;
use std::sync::mpsc::{channel, sync_channel, Receiver, Sender, SyncSender, TrySendError};
use std::thread::JoinHandle;
use std::time::Instant;

use fpc::units::CONTROL_PERIOD_US;

use super::super::{text, COLUMNS};
use super::row::CapturedRow;
use crate::runlog::RunLog;

/// Most rows a streamed run keeps for its plots (≈ 0.4 s at the control rate; every 16th
/// row of the default 10-cycle run: still ≈ 5000 points over 4.4 s, more than a plot draws
/// (`plot::lines` keeps ≈ 4000 a series); 1.2 MB, reserved at once so it never moves).
/// Halved as soon as it is outgrown, so a chunk's rows are kept only at the stride in force.
pub const KEPT_ROWS: usize = 1 << 13;

/// Bytes of CSV text handed on at a time (a chunk's text is one or two such pieces; each
/// buffer in flight is this size, so few fresh pages are touched).
const WRITE_BYTES: usize = 1 << 18;

/// Text buffers ([`WRITE_BYTES`] each) the maker uses at most: a chunk far longer than
/// usual (the rows held back until the head is known) reuses them rather than touching
/// fresh pages for all its text.
const TEXT_BUFFERS: usize = 3;

/// Chunks waiting for the maker beyond the one it is making: the loop waits when it is that
/// far ahead, so the rows in flight stay a few chunks.
const CHUNKS_QUEUED: usize = 1;

/// A chunk of rows for the CSV, with the line pressures' changes (first row index in the
/// chunk, suction, discharge; the first at row 0).
pub struct Chunk {
    pub rows: Vec<CapturedRow>,
    pub lines: Vec<(usize, f64, f64)>,
}

/// The CSV a streamed run writes, the head first (the log's metadata and column names, once
/// the rows' metadata is known), then each chunk's rows as the maker returns them.
pub struct Stream<'s> {
    out: &'s mut dyn Write,
    /// The first write error; later text is not written.
    error: Option<std::io::Error>,
    /// The log's metadata and column names (no rows).
    head: RunLog,
    /// Whether the head is out.
    head_written: bool,
    maker: Maker,
    /// Row buffers back from the maker, for the next chunks.
    spare_rows: Vec<Vec<CapturedRow>>,
    /// Wall time the loop's thread spent on the log, s (kept out of its real-time factor).
    writing_s: f64,
}

/// Who makes the text: a thread of its own, or the loop's thread if none could be started.
enum Maker {
    Thread {
        chunks: SyncSender<Chunk>,
        made: Receiver<Made>,
        spare_text: Sender<text::Line>,
        handle: JoinHandle<Decimated>,
    },
    Inline {
        decimated: Decimated,
        text: text::Line,
    },
}

/// What the maker thread hands back, in order.
enum Made {
    Text(text::Line),
    Rows(Vec<CapturedRow>),
}

/// The maker's own state: the kept copy of the rows and how far the run has come.
struct Decimated {
    /// Every `stride`-th row of the run, for plots.
    kept: RunLog,
    stride: usize,
    /// Rows made before the current chunk.
    made: usize,
}

impl<'s> Stream<'s> {
    /// A stream to `out` of a log with `log`'s metadata and column names ([`COLUMNS`]).
    pub fn new(out: &'s mut dyn Write, log: &RunLog) -> Self {
        Self::with_maker(out, log, Maker::start())
    }

    fn with_maker(out: &'s mut dyn Write, log: &RunLog, maker: Maker) -> Self {
        let mut head = RunLog::with_columns(&COLUMNS);
        head.meta = log.meta.clone();
        head.names = log.names.clone();
        Stream {
            out,
            error: None,
            head,
            head_written: false,
            maker,
            spare_rows: Vec::new(),
            writing_s: 0.0,
        }
    }

    /// Whether the head is out.
    pub fn head_written(&self) -> bool {
        self.head_written
    }

    /// Wall time the loop's thread spent on the log so far, s.
    pub fn writing_s(&self) -> f64 {
        self.writing_s
    }

    /// Writes the head (with `more_meta` after the log's metadata) if it is not out yet and
    /// the text made so far, and hands the maker the chunk of `rows` (left with an empty
    /// buffer for the next chunk, one the maker is done with when there is one) and `lines`
    /// (their line pressures' changes, [`Chunk::lines`]).
    pub fn send(
        &mut self,
        rows: &mut Vec<CapturedRow>,
        lines: Vec<(usize, f64, f64)>,
        more_meta: Vec<(String, String)>,
    ) {
        let started = Instant::now();
        if !self.head_written {
            self.head_written = true;
            self.head.meta.extend(more_meta);
            let mut head = String::new();
            self.head.head_to_csv(&mut head);
            self.write(head.as_bytes());
        }
        // What is made is taken before the chunk goes: its buffers are back before the
        // maker needs them.
        if let Maker::Thread {
            made, spare_text, ..
        } = &self.maker
        {
            while let Ok(m) = made.try_recv() {
                take(
                    m,
                    self.out,
                    &mut self.error,
                    spare_text,
                    &mut self.spare_rows,
                );
            }
        }
        let next = self
            .spare_rows
            .pop()
            .unwrap_or_else(|| Vec::with_capacity(rows.capacity()));
        let mut chunk = Chunk {
            rows: std::mem::replace(rows, next),
            lines,
        };
        match &mut self.maker {
            Maker::Thread {
                chunks,
                made,
                spare_text,
                ..
            } => {
                // While the maker's queue is full, what it makes is taken (it may be waiting
                // for a text buffer back). A maker that is gone has panicked: `finish`
                // reports it.
                while let Err(TrySendError::Full(c)) = chunks.try_send(chunk) {
                    chunk = c;
                    let Ok(m) = made.recv() else { break };
                    take(
                        m,
                        self.out,
                        &mut self.error,
                        spare_text,
                        &mut self.spare_rows,
                    );
                }
            }
            Maker::Inline { decimated, text } => {
                let (out, error) = (&mut *self.out, &mut self.error);
                decimated.make(&chunk, text, &mut |t| {
                    write_to(out, error, t.as_bytes());
                    t.clear();
                });
                write_to(out, error, text.as_bytes());
                text.clear();
                let mut rows = chunk.rows;
                rows.clear();
                self.spare_rows.push(rows);
            }
        }
        self.writing_s += started.elapsed().as_secs_f64();
    }

    /// Waits for the maker, writes the rest and flushes: the kept copy of the rows with the
    /// log's metadata, or the first write error.
    pub fn finish(self) -> Result<RunLog, String> {
        let Stream {
            out,
            mut error,
            head,
            maker,
            mut spare_rows,
            ..
        } = self;
        let mut decimated = match maker {
            Maker::Thread {
                chunks,
                made,
                spare_text,
                handle,
            } => {
                drop(chunks);
                for m in made {
                    take(m, out, &mut error, &spare_text, &mut spare_rows);
                }
                handle
                    .join()
                    .map_err(|_| "the run log's text maker failed".to_string())?
            }
            Maker::Inline { decimated, .. } => decimated,
        };
        if let Some(e) = error.or_else(|| out.flush().err()) {
            return Err(format!("cannot write the run log: {e}"));
        }
        decimated.kept.meta = head.meta;
        decimated.kept.names = head.names;
        Ok(decimated.kept)
    }

    fn write(&mut self, bytes: &[u8]) {
        write_to(self.out, &mut self.error, bytes);
    }
}

/// Writes `bytes` to `out` unless an earlier write failed (then keeps the first error).
fn write_to(out: &mut dyn Write, error: &mut Option<std::io::Error>, bytes: &[u8]) {
    if error.is_none() {
        *error = out.write_all(bytes).err();
    }
}

/// Takes what the maker thread handed back: text is written (and its buffer returned),
/// rows buffers kept for the next chunks.
fn take(
    m: Made,
    out: &mut dyn Write,
    error: &mut Option<std::io::Error>,
    spare_text: &Sender<text::Line>,
    spare_rows: &mut Vec<Vec<CapturedRow>>,
) {
    match m {
        Made::Text(mut t) => {
            write_to(out, error, t.as_bytes());
            t.clear();
            // A maker that is gone needs no buffer.
            let _ = spare_text.send(t);
        }
        Made::Rows(mut rows) => {
            rows.clear();
            spare_rows.push(rows);
        }
    }
}

impl Maker {
    /// The maker on a thread of its own, or inline if no thread can be started.
    fn start() -> Self {
        let (chunks, chunk_in) = sync_channel::<Chunk>(CHUNKS_QUEUED);
        let (made_out, made) = channel::<Made>();
        let (spare_text, spare_in) = channel::<text::Line>();
        let started = std::thread::Builder::new()
            .name("run-log text".into())
            .spawn(move || {
                let mut decimated = Decimated::new();
                // At most TEXT_BUFFERS buffers: past that, one is waited for (the loop's
                // thread takes what is made whenever the queue is full, and at the end).
                let mut buffers = 0;
                let mut fresh = |spare: &Receiver<text::Line>| {
                    if let Ok(t) = spare.try_recv() {
                        return t;
                    }
                    if buffers >= TEXT_BUFFERS {
                        if let Ok(t) = spare.recv() {
                            return t;
                        }
                    }
                    buffers += 1;
                    text::Line::with_room(WRITE_BYTES)
                };
                // Sends fail only when the stream was dropped unfinished: nobody is waiting.
                for chunk in chunk_in {
                    let mut text = fresh(&spare_in);
                    decimated.make(&chunk, &mut text, &mut |t| {
                        let full = std::mem::replace(t, fresh(&spare_in));
                        let _ = made_out.send(Made::Text(full));
                    });
                    if !text.is_empty() {
                        let _ = made_out.send(Made::Text(text));
                    }
                    let _ = made_out.send(Made::Rows(chunk.rows));
                }
                decimated
            });
        match started {
            Ok(handle) => Maker::Thread {
                chunks,
                made,
                spare_text,
                handle,
            },
            Err(_) => Maker::inline(),
        }
    }

    /// The maker on the loop's thread.
    fn inline() -> Self {
        Maker::Inline {
            decimated: Decimated::new(),
            text: text::Line::with_room(WRITE_BYTES),
        }
    }
}

impl Decimated {
    /// Nothing kept yet; room for [`KEPT_ROWS`] reserved at once, so it never moves.
    fn new() -> Self {
        let mut kept = RunLog::with_columns(&COLUMNS);
        for column in &mut kept.columns {
            column.reserve_exact(KEPT_ROWS + 1);
        }
        Decimated {
            kept,
            stride: 1,
            made: 0,
        }
    }

    /// Appends `chunk`'s rows to `text` as CSV (each column at its resolution,
    /// [`super::super::text`]), handing it to `full` whenever it holds [`WRITE_BYTES`] (which
    /// leaves it empty), and keeps every `stride`-th row, halving the copy and doubling the
    /// stride when it outgrows [`KEPT_ROWS`].
    fn make(
        &mut self,
        chunk: &Chunk,
        text: &mut text::Line,
        full: &mut dyn FnMut(&mut text::Line),
    ) {
        let mut change = 0;
        for (i, r) in chunk.rows.iter().enumerate() {
            while chunk.lines.get(change + 1).is_some_and(|l| l.0 <= i) {
                change += 1;
            }
            let (suction, discharge) = chunk
                .lines
                .get(change)
                .map_or((f64::NAN, f64::NAN), |l| (l.1, l.2));
            let v = r.values(suction, discharge);
            text.row(r.cycle(), u64::from(CONTROL_PERIOD_US), &v);
            text.push(b'\n');
            if (self.made + i).is_multiple_of(self.stride) {
                self.kept.push_row(&v);
                if self.kept.len() > KEPT_ROWS {
                    halve(&mut self.kept);
                    self.stride *= 2;
                }
            }
            // Handed on a piece at a time, so the text stays in the cache.
            if text.len() >= WRITE_BYTES {
                full(text);
            }
        }
        self.made += chunk.rows.len();
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

#[cfg(test)]
mod tests {
    use super::*;

    /// Streams `chunks` chunks of rows (the line pressures changing within some) through
    /// `maker`: the CSV text and the kept log.
    fn stream(maker: Maker, chunks: usize) -> (Vec<u8>, RunLog) {
        let mut log = RunLog::with_columns(&COLUMNS);
        log.meta.push(("model".into(), "test".into()));
        let mut out = Vec::new();
        let mut s = Stream::with_maker(&mut out, &log, maker);
        // The first chunk long (rows held back for the head): more text than the maker's
        // buffers hold.
        let length = |c: usize| if c == 0 { 20_000 } else { 3000 };
        let mut first = 0;
        for c in 0..chunks {
            let rows_per_chunk = length(c);
            let mut rows = (first..first + rows_per_chunk)
                .map(|k| CapturedRow::synthetic(k as u32))
                .collect();
            let lines = vec![
                (0, 1e5 + c as f64, 3e5),
                (rows_per_chunk / 3, 1e5 + c as f64 + 0.5, 3.1e5),
            ];
            s.send(&mut rows, lines, vec![("ports".into(), "open".into())]);
            assert!(rows.is_empty());
            first += rows_per_chunk;
        }
        let kept = s.finish().unwrap();
        (out, kept)
    }

    #[test]
    fn the_text_and_the_kept_rows_are_the_same_on_the_makers_thread_and_inline() {
        // 12 chunks: many text pieces, more than the maker's buffers at once, and the kept
        // copy halved three times.
        let (threaded, kept_t) = stream(Maker::start(), 12);
        let (inline, kept_i) = stream(Maker::inline(), 12);
        assert!(
            threaded.len() > 12 * WRITE_BYTES,
            "{} bytes",
            threaded.len()
        );
        assert!(threaded == inline, "the two makers' texts differ");
        assert_eq!(kept_t.columns, kept_i.columns);
        assert_eq!(kept_t.meta, kept_i.meta);
        assert!(kept_t.len() <= KEPT_ROWS && kept_t.len() > KEPT_ROWS / 2);
        // The head once, with the extra metadata, then one line per row in order.
        let text = String::from_utf8(threaded).unwrap();
        assert_eq!(text.matches("# ports = open").count(), 1);
        let rows: Vec<&str> = text
            .lines()
            .filter(|l| !l.starts_with('#'))
            .skip(1)
            .collect();
        assert_eq!(rows.len(), 20_000 + 11 * 3000);
        let cycle = |l: &str| l.split(',').next().unwrap().parse::<f64>().unwrap();
        assert!(rows.windows(2).all(|w| cycle(w[1]) > cycle(w[0])));
        // The line pressures change where the chunk says.
        assert!(rows[0].ends_with(",100000,300000"), "{}", rows[0]);
        assert!(rows[7000].ends_with(",100000.5,310000"), "{}", rows[7000]);
    }
}
