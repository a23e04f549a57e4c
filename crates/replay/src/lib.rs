//! FIFO replay memory over flat transition storage, with uniform or
//! prioritized (Ape-X, Schaul et al. 2016: proportional, a sum-tree)
//! sampling of minibatches. Pure data structure: the `hive replay` role feeds it from the
//! transport and serves minibatches from it. Rows are `u16` words (packed
//! transitions: 16-bit depth, see `rotorhive_msg::PACKED_LEN`), so a
//! transition costs half the bytes to insert, hold and sample.

use std::io::{BufReader, BufWriter, Read, Write};
use std::path::{Path, PathBuf};

use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64Mcg;

mod journal;
mod sumtree;
pub use journal::Journal;
pub use rotorhive_msg::Pick;
pub use sumtree::SumTree;

/// Snapshot header: rows of `u16` words.
const MAGIC: &[u8; 8] = b"RHRPLU16";
/// Header of snapshots of `f32` rows, written before rows were packed.
const MAGIC_F32: &[u8; 8] = b"RHREPLAY";

/// Why a replay snapshot could not be written or read.
#[derive(Debug, thiserror::Error)]
pub enum SnapshotError {
    /// Reading or writing the file failed.
    #[error("replay snapshot {file}: {cause}")]
    Io {
        /// The file.
        file: String,
        /// The I/O error (in the text; not `source()`).
        cause: std::io::Error,
    },
    /// The file is not a snapshot of transitions of this width.
    #[error("replay snapshot {file}: {message}")]
    Format {
        /// The file.
        file: String,
        /// What is wrong.
        message: String,
    },
}

/// A snapshot being written a chunk at a time, so that inserts and samples
/// go on between chunks (rows written later may be newer than the header's
/// count says: every row is still a whole transition).
#[derive(Debug)]
pub struct Snapshot {
    out: BufWriter<std::fs::File>,
    tmp: PathBuf,
    path: PathBuf,
    next: usize,
    rows: usize,
}

/// A fixed-capacity FIFO of equally long transitions (rows of `u16` words)
/// stored back to back.
#[derive(Debug, Clone)]
pub struct Replay {
    data: Vec<u16>,
    /// Per row: the weight version the transition was acted with (0:
    /// unknown, e.g. restored from a snapshot), for the policy lag.
    versions: Vec<u32>,
    width: usize,
    capacity: usize,
    len: usize,
    head: usize,
    inserted: u64,
    sampled: u64,
    rng: Pcg64Mcg,
    /// Per row: the insert count when it was written (low 32 bits;
    /// `u32::MAX`: restored, unknown), so a priority for a row overwritten
    /// since it was sampled is recognised.
    stamps: Vec<u32>,
    prio: Option<Priorities>,
}

/// Prioritized replay's state: the rows' priorities^alpha in a sum-tree.
#[derive(Debug, Clone)]
struct Priorities {
    tree: SumTree,
    alpha: f64,
    eps: f64,
    /// The largest priority seen: new rows get it, so each is sampled soon.
    max: f64,
}

impl Replay {
    /// A memory of `capacity` transitions of `width` words each.
    pub fn new(capacity: usize, width: usize, seed: u64) -> Self {
        assert!(capacity > 0 && width > 0, "replay capacity and width must be positive");
        let mut data = vec![0u16; capacity * width];
        // Touch every page now: the first writes into fresh pages would
        // otherwise fault one by one while the actors are inserting.
        for page in data.chunks_mut(2048) {
            // SAFETY: a plain write to an element of our own buffer; volatile
            // so the allocator's zeroed pages are really touched.
            unsafe { std::ptr::write_volatile(page.as_mut_ptr(), 0) };
        }
        Self {
            data,
            versions: vec![0; capacity],
            width,
            capacity,
            len: 0,
            head: 0,
            inserted: 0,
            sampled: 0,
            rng: Pcg64Mcg::seed_from_u64(seed),
            stamps: vec![u32::MAX; capacity],
            prio: None,
        }
    }

    /// Samples in proportion to priority^`alpha` from now on (priority =
    /// |TD error| + `eps`, set by [`Replay::set_priority`]); the rows held
    /// now and every row inserted later start at the largest priority seen
    /// (1 at first).
    pub fn set_prioritized(&mut self, alpha: f64, eps: f64) {
        let mut tree = SumTree::new(self.capacity);
        for r in 0..self.len {
            tree.set(r, 1.0);
        }
        self.prio = Some(Priorities { tree, alpha, eps, max: 1.0 });
    }

    /// Whether sampling is prioritized.
    pub fn prioritized(&self) -> bool {
        self.prio.is_some()
    }

    /// Sets the priority of the row a sample picked to `td_abs` + eps, unless
    /// the row has been overwritten since (its stamp differs) or is out of
    /// range; true when applied. Without prioritized sampling it does nothing.
    pub fn set_priority(&mut self, pick: &Pick) -> bool {
        let r = pick.row as usize;
        let Some(p) = &mut self.prio else {
            return false;
        };
        if r >= self.len || self.stamps[r] != pick.stamp || !pick.value.is_finite() {
            return false;
        }
        let v = pick.value.abs() as f64 + p.eps;
        p.max = p.max.max(v);
        p.tree.set(r, v.powf(p.alpha));
        true
    }

    /// Words per stored transition.
    pub fn width(&self) -> usize {
        self.width
    }

    /// Transitions held.
    pub fn len(&self) -> usize {
        self.len
    }

    /// True when empty.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// Capacity in transitions.
    pub fn capacity(&self) -> usize {
        self.capacity
    }

    /// Transitions inserted since creation.
    pub fn inserted(&self) -> u64 {
        self.inserted
    }

    /// Transitions sampled since creation.
    pub fn sampled(&self) -> u64 {
        self.sampled
    }

    /// Appends transitions (a multiple of `width` words), overwriting the oldest when full.
    pub fn insert(&mut self, transitions: &[u16]) {
        self.insert_acted(transitions, 0);
    }

    /// [`Replay::insert`] of transitions acted with weight version `version`
    /// (0: unknown), which [`Replay::sample_into`] reports for the policy lag.
    pub fn insert_acted(&mut self, transitions: &[u16], version: u64) {
        assert_eq!(
            transitions.len() % self.width,
            0,
            "transition batch is not a whole number of transitions"
        );
        let version = u32::try_from(version).unwrap_or(u32::MAX);
        for t in transitions.chunks_exact(self.width) {
            self.data[self.head * self.width..(self.head + 1) * self.width].copy_from_slice(t);
            self.versions[self.head] = version;
            self.stamps[self.head] = self.inserted as u32;
            if let Some(p) = &mut self.prio {
                p.tree.set(self.head, p.max.powf(p.alpha));
            }
            self.head = (self.head + 1) % self.capacity;
            self.len = (self.len + 1).min(self.capacity);
            self.inserted += 1;
        }
    }

    /// Physical row of the `i`-th oldest transition.
    fn row(&self, i: usize) -> usize {
        let start = if self.len < self.capacity { 0 } else { self.head };
        (start + i) % self.capacity
    }

    /// Starts writing the memory to `path` (through a temporary file that
    /// replaces it when done).
    pub fn begin_snapshot(&self, path: &Path) -> Result<Snapshot, SnapshotError> {
        let tmp = path.with_extension("tmp");
        let io = |cause| SnapshotError::Io { file: path.display().to_string(), cause };
        let mut out = BufWriter::with_capacity(1 << 20, std::fs::File::create(&tmp).map_err(io)?);
        out.write_all(MAGIC).map_err(io)?;
        for v in [self.width as u64, self.len as u64, self.inserted] {
            out.write_all(&v.to_le_bytes()).map_err(io)?;
        }
        Ok(Snapshot { out, tmp, path: path.to_path_buf(), next: 0, rows: self.len })
    }

    /// Writes up to `max_rows` more rows, oldest first; true when the
    /// snapshot is complete and in place.
    pub fn snapshot_step(&self, s: &mut Snapshot, max_rows: usize) -> Result<bool, SnapshotError> {
        let io = |cause| SnapshotError::Io { file: s.path.display().to_string(), cause };
        let end = (s.next + max_rows).min(s.rows);
        for i in s.next..end {
            let r = self.row(i);
            let bytes: Vec<u8> = self.data[r * self.width..(r + 1) * self.width]
                .iter()
                .flat_map(|v| v.to_le_bytes())
                .collect();
            s.out.write_all(&bytes).map_err(io)?;
        }
        s.next = end;
        if s.next < s.rows {
            return Ok(false);
        }
        s.out.flush().map_err(io)?;
        rotorhive_msg::durable::commit(&s.tmp, &s.path).map_err(io)?;
        Ok(true)
    }

    /// Writes the whole memory at once.
    pub fn save(&self, path: &Path) -> Result<(), SnapshotError> {
        let mut s = self.begin_snapshot(path)?;
        while !self.snapshot_step(&mut s, usize::MAX)? {}
        Ok(())
    }

    /// Reads a snapshot into a memory of `capacity` transitions (the newest
    /// ones kept when the snapshot holds more).
    pub fn load(
        path: &Path,
        capacity: usize,
        width: usize,
        seed: u64,
    ) -> Result<Self, SnapshotError> {
        let file = path.display().to_string();
        let io = |cause| SnapshotError::Io { file: file.clone(), cause };
        let bad = |message: String| SnapshotError::Format { file: file.clone(), message };
        let mut r = BufReader::with_capacity(1 << 20, std::fs::File::open(path).map_err(io)?);
        let mut magic = [0u8; 8];
        r.read_exact(&mut magic).map_err(|_| bad("too short for a header".into()))?;
        if &magic == MAGIC_F32 {
            return Err(bad(
                "a snapshot of f32 rows, written by an older rotorhive; delete it (or start a new run directory) to start with an empty memory".into()
            ));
        }
        if &magic != MAGIC {
            return Err(bad("not a rotorhive replay snapshot".into()));
        }
        let mut word = || -> Result<u64, SnapshotError> {
            let mut b = [0u8; 8];
            r.read_exact(&mut b).map_err(|_| bad("truncated header".into()))?;
            Ok(u64::from_le_bytes(b))
        };
        let (w, len, inserted) = (word()?, word()?, word()?);
        if w as usize != width {
            return Err(bad(format!("transitions of {w} words, expected {width}")));
        }
        let mut mem = Self::new(capacity, width, seed);
        let mut buf = vec![0u8; width * 2];
        let mut row = vec![0u16; width];
        for i in 0..len {
            r.read_exact(&mut buf)
                .map_err(|_| bad(format!("truncated: {i} of {len} transitions")))?;
            for (v, b) in row.iter_mut().zip(buf.chunks_exact(2)) {
                *v = u16::from_le_bytes([b[0], b[1]]);
            }
            mem.insert(&row);
        }
        mem.inserted = inserted.max(mem.inserted);
        Ok(mem)
    }

    /// Fills `out` (a multiple of `width` words) with transitions drawn
    /// with replacement, uniformly or (prioritized) in proportion to their
    /// priorities, stratified over the batch as in Schaul et al.; `picks`
    /// (one per row, or empty) gets each row's place and its importance
    /// weight (N·P(i))^−beta over the batch's largest (1 with uniform
    /// sampling). Returns the weight versions the rows were acted with:
    /// their sum and how many were known. Panics when empty.
    pub fn sample_into(&mut self, out: &mut [u16], picks: &mut [Pick], beta: f64) -> Acted {
        assert!(self.len > 0, "cannot sample an empty replay memory");
        let rows = out.len() / self.width;
        let mut acted = Acted::default();
        for (k, o) in out.chunks_exact_mut(self.width).enumerate() {
            let (i, weight) = match &self.prio {
                None => (self.rng.random_range(0..self.len), 1.0),
                Some(p) => {
                    let seg = p.tree.total() / rows as f64;
                    let i =
                        p.tree.find(seg * (k as f64 + self.rng.random::<f64>())).min(self.len - 1);
                    let prob = p.tree.get(i) / p.tree.total();
                    (i, (self.len as f64 * prob).powf(-beta))
                }
            };
            if let Some(pk) = picks.get_mut(k) {
                *pk = Pick { row: i as u32, stamp: self.stamps[i], value: weight as f32 };
            }
            o.copy_from_slice(&self.data[i * self.width..(i + 1) * self.width]);
            if self.versions[i] > 0 {
                acted.version_sum += self.versions[i] as u64;
                acted.known += 1;
            }
            self.sampled += 1;
        }
        let max = picks.iter().map(|p| p.value).fold(0.0f32, f32::max);
        if max > 0.0 && max.is_finite() {
            picks.iter_mut().for_each(|p| p.value /= max);
        }
        acted
    }
}

/// The weight versions a sample's transitions were acted with.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Acted {
    /// Sum of the known versions.
    pub version_sum: u64,
    /// Transitions whose version is known.
    pub known: u32,
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_sample_reports_the_versions_it_was_acted_with() {
        let mut r = Replay::new(4, 1, 1);
        r.insert(&[9]);
        r.insert_acted(&[1, 1], 5);
        r.insert_acted(&[2], 7);
        let mut out = vec![0; 400];
        let acted = r.sample_into(&mut out, &mut [], 0.0);
        // Version 0 (unknown) rows are left out of the sum.
        let expect = out
            .iter()
            .map(|v| match v {
                1 => 5,
                2 => 7,
                _ => 0,
            })
            .sum::<u64>();
        assert_eq!(acted.version_sum, expect);
        assert_eq!(acted.known as usize, out.iter().filter(|v| **v != 9).count());
        assert!(acted.known > 0 && (acted.known as usize) < out.len());
    }

    #[test]
    fn fifo_overwrites_the_oldest() {
        let mut r = Replay::new(3, 2, 1);
        r.insert(&[1, 1, 2, 2, 3, 3, 4, 4]);
        assert_eq!(r.len(), 3);
        assert_eq!(r.inserted(), 4);
        let mut seen = std::collections::BTreeSet::new();
        let mut out = vec![0; 2 * 200];
        r.sample_into(&mut out, &mut [], 0.0);
        for t in out.chunks(2) {
            assert_eq!(t[0], t[1]);
            seen.insert(t[0] as i32);
        }
        assert_eq!(seen.into_iter().collect::<Vec<_>>(), vec![2, 3, 4]);
    }

    #[test]
    fn snapshots_round_trip_in_chunks_and_refuse_bad_files() {
        let dir = std::env::temp_dir().join(format!("rotorhive-replay-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("r.bin");
        let mut r = Replay::new(4, 3, 1);
        r.insert(&(0..18).collect::<Vec<_>>());
        let mut s = r.begin_snapshot(&path).unwrap();
        let mut steps = 0;
        while !r.snapshot_step(&mut s, 1).unwrap() {
            steps += 1;
        }
        assert_eq!(steps, 3);
        let back = Replay::load(&path, 4, 3, 2).unwrap();
        assert_eq!((back.len(), back.inserted()), (4, 6));
        // Oldest first: rows 2..6 of what went in.
        let rows: Vec<u16> = (0..4).map(|i| back.data[back.row(i) * 3]).collect();
        assert_eq!(rows, vec![6, 9, 12, 15]);
        // A smaller memory keeps the newest.
        let small = Replay::load(&path, 2, 3, 2).unwrap();
        assert_eq!((0..2).map(|i| small.data[small.row(i) * 3]).collect::<Vec<_>>(), vec![12, 15]);
        assert!(matches!(Replay::load(&path, 4, 5, 2), Err(SnapshotError::Format { .. })));
        let bytes = std::fs::read(&path).unwrap();
        std::fs::write(&path, &bytes[..bytes.len() - 5]).unwrap();
        let e = Replay::load(&path, 4, 3, 2).unwrap_err().to_string();
        assert!(e.contains("truncated"), "{e}");
        std::fs::write(&path, b"hello").unwrap();
        assert!(Replay::load(&path, 4, 3, 2).is_err());
        std::fs::write(&path, b"RHREPLAY\x03\0\0\0\0\0\0\0").unwrap();
        let e = Replay::load(&path, 4, 3, 2).unwrap_err().to_string();
        assert!(e.contains("older rotorhive"), "{e}");
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn prioritized_sampling_follows_the_priorities_and_ignores_stale_ones() {
        let mut r = Replay::new(4, 1, 3);
        r.insert(&[0, 1, 2, 3]);
        r.set_prioritized(1.0, 0.0);
        let mut out = vec![0u16; 32];
        let mut picks = vec![Pick::default(); 32];
        r.sample_into(&mut out, &mut picks, 0.4);
        // All at the same priority: every weight is 1, every pick names its row.
        assert!(
            picks.iter().zip(&out).all(|(p, v)| p.value == 1.0 && p.row as u16 == *v),
            "{picks:?}"
        );
        // Row 3 gets priority 9, the others 1: it is drawn 9 times in 12.
        let mut all = Pick { row: 0, stamp: r.stamps[0], value: 1.0 };
        for row in 0..4 {
            all.row = row;
            all.stamp = r.stamps[row as usize];
            all.value = if row == 3 { 9.0 } else { 1.0 };
            assert!(r.set_priority(&all));
        }
        let mut out = vec![0u16; 12_000];
        let mut picks = vec![Pick::default(); 12_000];
        r.sample_into(&mut out, &mut picks, 1.0);
        let threes = out.iter().filter(|v| **v == 3).count();
        assert!((8_700..9_300).contains(&threes), "{threes} of 12,000");
        // Importance weights (N·P)^−1 over the largest: 1 for the rare rows,
        // 1/9 for the frequent one.
        let w3 = picks.iter().find(|p| p.row == 3).unwrap().value;
        let w0 = picks.iter().find(|p| p.row == 0).unwrap().value;
        assert!((w0 - 1.0).abs() < 1e-6 && (w3 - 1.0 / 9.0).abs() < 1e-6, "{w0} {w3}");
        // A priority for a row overwritten since it was sampled is dropped.
        let stale = Pick { row: 0, stamp: r.stamps[0], value: 100.0 };
        r.insert(&[7]);
        assert!(!r.set_priority(&stale));
        assert!(!r.set_priority(&Pick { row: 99, stamp: 0, value: 1.0 }));
        // The new row came in at the largest priority seen (9).
        assert_eq!(r.prio.as_ref().unwrap().tree.get(0), 9.0);
    }

    #[test]
    fn sampling_is_roughly_uniform() {
        let mut r = Replay::new(10, 1, 2);
        r.insert(&(0..10).collect::<Vec<_>>());
        let mut out = vec![0; 10_000];
        r.sample_into(&mut out, &mut [], 0.0);
        let mut counts = [0; 10];
        for v in out {
            counts[v as usize] += 1;
        }
        assert!(counts.iter().all(|c| (800..1200).contains(c)), "{counts:?}");
        assert_eq!(r.sampled(), 10_000);
    }
}
