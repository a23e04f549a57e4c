//! The replay memory written through to a file as it changes, so that a
//! replay process killed at any moment restarts with every transition it had
//! inserted (the file lives in the page cache; the kernel writes it back).
//!
//! Layout: magic, then `width`, `capacity`, `head`, `len`, `inserted` as
//! little-endian `u64`, then `capacity` rows of `width` little-endian `u16`
//! words at fixed offsets: the ring of [`Replay`] as it is in memory. An
//! insert writes its rows where they sit in the ring, then the header, so the
//! header never counts a row that is not in the file. Disk use is bounded by
//! the capacity, however long the run.

use std::fs::File;
use std::os::unix::fs::FileExt;
use std::path::{Path, PathBuf};

use crate::{Replay, SnapshotError};

/// Magic of a journal file.
const JOURNAL_MAGIC: &[u8; 8] = b"RHRPJNL1";
/// Bytes before the first row: the magic and five `u64`.
const HEADER: u64 = 8 + 5 * 8;

/// The file behind a [`Replay`]: see the module documentation.
#[derive(Debug)]
pub struct Journal {
    file: File,
    path: PathBuf,
    width: usize,
    capacity: usize,
}

impl Journal {
    /// Opens the journal at `path` and the memory it holds, or creates both
    /// (empty) when there is no file. A journal of another capacity keeps its
    /// newest transitions; a snapshot of the older format (written whole by
    /// [`Replay::save`]) is read and turned into a journal.
    pub fn open(
        path: &Path,
        capacity: usize,
        width: usize,
        seed: u64,
    ) -> Result<(Replay, Journal), SnapshotError> {
        let file_name = path.display().to_string();
        let io = |cause| SnapshotError::Io { file: file_name.clone(), cause };
        let bad = |message: String| SnapshotError::Format { file: file_name.clone(), message };
        if !path.exists() {
            let mem = Replay::new(capacity, width, seed);
            let journal = Self::create(path, &mem)?;
            return Ok((mem, journal));
        }
        let file = std::fs::OpenOptions::new().read(true).write(true).open(path).map_err(io)?;
        let mut magic = [0u8; 8];
        file.read_exact_at(&mut magic, 0).map_err(|_| bad("too short for a header".into()))?;
        if &magic != JOURNAL_MAGIC {
            // An older whole-file snapshot (or not a snapshot at all: `load` names it).
            let mem = Replay::load(path, capacity, width, seed)?;
            let journal = Self::create(path, &mem)?;
            return Ok((mem, journal));
        }
        let mut words = [0u8; 40];
        file.read_exact_at(&mut words, 8).map_err(|_| bad("truncated header".into()))?;
        let word = |i: usize| {
            u64::from_le_bytes(words[8 * i..8 * i + 8].try_into().expect("8 bytes")) as usize
        };
        let (w, cap, head, len, inserted) = (word(0), word(1), word(2), word(3), word(4) as u64);
        if w != width {
            return Err(bad(format!("transitions of {w} words, expected {width}")));
        }
        if cap == 0 || head >= cap || len > cap {
            return Err(bad(format!(
                "inconsistent header (capacity {cap}, head {head}, len {len})"
            )));
        }
        let expected = HEADER + (cap * width * 2) as u64;
        let size = file.metadata().map_err(io)?.len();
        if size < expected {
            return Err(bad(format!("truncated: {size} bytes, the header needs {expected}")));
        }
        let mut old = Replay::new(cap, width, seed);
        read_words(&file, HEADER, &mut old.data).map_err(io)?;
        (old.head, old.len, old.inserted) = (head, len, inserted);
        if cap == capacity {
            return Ok((old, Self { file, path: path.to_path_buf(), width, capacity }));
        }
        // Another capacity: the newest transitions, oldest first, into a new ring.
        let mut mem = Replay::new(capacity, width, seed);
        let keep = len.min(capacity);
        for i in len - keep..len {
            let r = old.row(i);
            mem.insert(&old.data[r * width..(r + 1) * width]);
        }
        mem.inserted = inserted.max(mem.inserted);
        drop(file);
        let journal = Self::create(path, &mem)?;
        Ok((mem, journal))
    }

    /// Writes `mem` whole as a new journal (through a temporary file that
    /// replaces `path`).
    fn create(path: &Path, mem: &Replay) -> Result<Self, SnapshotError> {
        let tmp = path.with_extension("tmp");
        let io = |cause| SnapshotError::Io { file: path.display().to_string(), cause };
        let file = std::fs::OpenOptions::new()
            .read(true)
            .write(true)
            .create(true)
            .truncate(true)
            .open(&tmp)
            .map_err(io)?;
        file.set_len(HEADER + (mem.capacity * mem.width * 2) as u64).map_err(io)?;
        file.write_all_at(JOURNAL_MAGIC, 0).map_err(io)?;
        let j = Self { file, path: path.to_path_buf(), width: mem.width, capacity: mem.capacity };
        for (w, v) in [mem.width, mem.capacity].into_iter().enumerate() {
            j.file.write_all_at(&(v as u64).to_le_bytes(), 8 + 8 * w as u64).map_err(io)?;
        }
        if mem.len > 0 {
            write_words(&j.file, HEADER, &mem.data[..mem.len.max(mem.head) * mem.width])
                .map_err(io)?;
        }
        j.write_header(mem)?;
        rotorhive_msg::durable::commit(&tmp, path).map_err(io)?;
        Ok(j)
    }

    /// Records the last `rows` transitions inserted into `mem` (call it after
    /// every [`Replay::insert`]).
    pub fn record(&mut self, mem: &Replay, rows: usize) -> Result<(), SnapshotError> {
        debug_assert!(
            mem.width == self.width && mem.capacity == self.capacity,
            "a journal records the memory it was opened with"
        );
        let io = |cause| SnapshotError::Io { file: self.path.display().to_string(), cause };
        let k = rows.min(self.capacity);
        let (w, head) = (self.width, mem.head);
        // The k newest rows end at `head` (exclusive), wrapping at most once.
        let runs = if head >= k {
            [(head - k, head), (0, 0)]
        } else {
            [(self.capacity - (k - head), self.capacity), (0, head)]
        };
        for (a, b) in runs {
            if b > a {
                write_words(&self.file, HEADER + (a * w * 2) as u64, &mem.data[a * w..b * w])
                    .map_err(io)?;
            }
        }
        self.write_header(mem)
    }

    fn write_header(&self, mem: &Replay) -> Result<(), SnapshotError> {
        let mut h = [0u8; 24];
        for (i, v) in [mem.head as u64, mem.len as u64, mem.inserted].into_iter().enumerate() {
            h[8 * i..8 * i + 8].copy_from_slice(&v.to_le_bytes());
        }
        self.file
            .write_all_at(&h, 24)
            .map_err(|cause| SnapshotError::Io { file: self.path.display().to_string(), cause })
    }

    /// Asks the kernel to put the file on disk (a process crash loses nothing
    /// without it; a machine crash loses what was not synced).
    pub fn sync(&self) -> Result<(), SnapshotError> {
        self.file
            .sync_data()
            .map_err(|cause| SnapshotError::Io { file: self.path.display().to_string(), cause })
    }

    /// The journal's file.
    pub fn path(&self) -> &Path {
        &self.path
    }
}

// Rows go to the file as their bytes are in memory: little-endian words.
#[cfg(target_endian = "little")]
fn write_words(file: &File, at: u64, words: &[u16]) -> std::io::Result<()> {
    file.write_all_at(bytemuck::cast_slice(words), at)
}

#[cfg(target_endian = "little")]
fn read_words(file: &File, at: u64, words: &mut [u16]) -> std::io::Result<()> {
    file.read_exact_at(bytemuck::cast_slice_mut(words), at)
}

#[cfg(not(target_endian = "little"))]
compile_error!("the replay journal writes words as they are in memory: little-endian targets only");

#[cfg(test)]
mod tests {
    use super::*;

    fn rows(from: u16, n: usize, width: usize) -> Vec<u16> {
        (0..n).flat_map(|i| std::iter::repeat_n(from + i as u16, width)).collect()
    }

    #[test]
    fn a_reopened_journal_holds_every_insert_across_wraps() {
        let dir = std::env::temp_dir().join(format!("rotorhive-journal-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("replay.bin");
        let _ = std::fs::remove_file(&path);
        let (mut mem, mut j) = Journal::open(&path, 5, 3, 1).unwrap();
        // 3 + 4 + 1 rows into a ring of 5: the second batch wraps.
        for (from, n) in [(0u16, 3usize), (3, 4), (7, 1)] {
            mem.insert(&rows(from, n, 3));
            j.record(&mem, n).unwrap();
        }
        drop(j);
        let (back, _) = Journal::open(&path, 5, 3, 1).unwrap();
        assert_eq!((back.len(), back.inserted(), back.head), (5, 8, mem.head));
        assert_eq!(back.data, mem.data);
        // Reopened with a smaller capacity: the newest transitions, in order.
        let (small, _) = Journal::open(&path, 2, 3, 1).unwrap();
        assert_eq!(small.len(), 2);
        let firsts: Vec<u16> = (0..2).map(|i| small.data[small.row(i) * 3]).collect();
        assert_eq!(firsts, vec![6, 7]);
        // The wrong width is refused by name.
        let e = Journal::open(&path, 2, 4, 1).unwrap_err().to_string();
        assert!(e.contains("replay.bin") && e.contains("expected 4"), "{e}");
        // An old whole-file snapshot is read and becomes a journal.
        mem.save(&path).unwrap();
        let (conv, _) = Journal::open(&path, 5, 3, 1).unwrap();
        assert_eq!(conv.len(), 5);
        let (again, _) = Journal::open(&path, 5, 3, 1).unwrap();
        assert_eq!(again.len(), 5);
        let _ = std::fs::remove_dir_all(&dir);
    }
}
