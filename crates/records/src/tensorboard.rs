//! TensorBoard event files (`RUN_DIR/tb/events.out.tfevents.*`), written by
//! hand through `rotorhive_msg::protobuf`: no maintained Rust crate writes
//! them (the `tensorboard-rs` crate, last released in 2022 on protobuf 2,
//! says it is not active), and scalars need only a few bytes of protobuf.
//!
//! A file is a sequence of records, each `u64` length, its masked CRC-32C,
//! the data, and the data's masked CRC-32C (TFRecord). Each record's data
//! is a `tensorflow.Event` protobuf: `wall_time` (field 1, double), `step`
//! (2, int64), and either `file_version` (3, string; the first record,
//! `brain.Event:2`) or `summary` (5), a `Summary` whose repeated `value`
//! (1) each carry a `tag` (1, string) and a `simple_value` (2, float).
//! TensorBoard's own reader reads them back in the tests.

use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};

use rotorhive_msg::protobuf;

/// Appends scalar events to one new event file of a directory.
#[derive(Debug)]
pub struct EventWriter {
    path: PathBuf,
    out: BufWriter<File>,
}

impl EventWriter {
    /// Creates `dir` if needed and a new event file in it, named as
    /// TensorBoard expects (`events.out.tfevents.SECONDS.HOST.PID`); a resumed
    /// run adds a file beside the old ones, which TensorBoard reads together.
    pub fn create(dir: &Path, host: &str) -> std::io::Result<Self> {
        std::fs::create_dir_all(dir)?;
        let now =
            std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).unwrap_or_default();
        let path = dir.join(format!(
            "events.out.tfevents.{}.{host}.{}",
            now.as_secs(),
            std::process::id()
        ));
        let mut w = Self { out: BufWriter::new(File::create(&path)?), path };
        let mut event = Vec::new();
        event_head(&mut event, now.as_secs_f64(), 0);
        protobuf::bytes(&mut event, 3, b"brain.Event:2");
        w.record(&event)?;
        w.flush()?;
        Ok(w)
    }

    /// The file written to.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// One event at `step` holding every `(tag, value)` scalar; non-finite
    /// values are left out (TensorBoard draws them as gaps anyway).
    pub fn scalars(
        &mut self,
        step: i64,
        wall_time: f64,
        values: &[(&str, f64)],
    ) -> std::io::Result<()> {
        let mut summary = Vec::new();
        for (tag, v) in values.iter().filter(|(_, v)| v.is_finite()) {
            let mut value = Vec::with_capacity(tag.len() + 8);
            protobuf::bytes(&mut value, 1, tag.as_bytes());
            protobuf::float(&mut value, 2, *v as f32);
            protobuf::bytes(&mut summary, 1, &value);
        }
        if summary.is_empty() {
            return Ok(());
        }
        let mut event = Vec::with_capacity(summary.len() + 24);
        event_head(&mut event, wall_time, step);
        protobuf::bytes(&mut event, 5, &summary);
        self.record(&event)
    }

    /// Pushes what is buffered to the file (TensorBoard reads it while the
    /// run goes on).
    pub fn flush(&mut self) -> std::io::Result<()> {
        self.out.flush()
    }

    fn record(&mut self, data: &[u8]) -> std::io::Result<()> {
        let len = (data.len() as u64).to_le_bytes();
        self.out.write_all(&len)?;
        self.out.write_all(&masked_crc(&len).to_le_bytes())?;
        self.out.write_all(data)?;
        self.out.write_all(&masked_crc(data).to_le_bytes())
    }
}

/// TFRecord's masked CRC-32C.
fn masked_crc(bytes: &[u8]) -> u32 {
    let c = crc32c::crc32c(bytes);
    c.rotate_right(15).wrapping_add(0xa282_ead8)
}

/// `wall_time` (field 1, double) and `step` (field 2, varint).
fn event_head(out: &mut Vec<u8>, wall_time: f64, step: i64) {
    protobuf::double(out, 1, wall_time);
    protobuf::int(out, 2, step as u64);
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn crc_and_varint_match_known_values() {
        // CRC-32C of "123456789" is 0xE3069283 (RFC 3720's check value).
        assert_eq!(crc32c::crc32c(b"123456789"), 0xe306_9283);
        let mut v = Vec::new();
        protobuf::varint(&mut v, 300);
        assert_eq!(v, [0xac, 0x02]);
    }

    #[test]
    fn records_are_framed_and_checksummed() {
        let dir = std::env::temp_dir().join(format!("rotorhive-tb-{}", std::process::id()));
        let mut w = EventWriter::create(&dir, "test").unwrap();
        w.scalars(7, 1.5, &[("a/b", 2.0), ("skipped", f64::NAN)]).unwrap();
        w.flush().unwrap();
        let bytes = std::fs::read(w.path()).unwrap();
        let mut at = 0;
        let mut records = 0;
        while at < bytes.len() {
            let len = u64::from_le_bytes(bytes[at..at + 8].try_into().unwrap()) as usize;
            assert_eq!(
                u32::from_le_bytes(bytes[at + 8..at + 12].try_into().unwrap()),
                masked_crc(&bytes[at..at + 8])
            );
            let data = &bytes[at + 12..at + 12 + len];
            assert_eq!(
                u32::from_le_bytes(bytes[at + 12 + len..at + 16 + len].try_into().unwrap()),
                masked_crc(data)
            );
            at += 16 + len;
            records += 1;
        }
        assert_eq!(records, 2);
        assert!(!bytes.windows(7).any(|w| w == b"skipped"));
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
