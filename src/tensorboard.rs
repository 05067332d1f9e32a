//! A minimal TensorBoard event-file writer (scalars only) and the matching reader.
//!
//! No maintained Rust crate writes TensorBoard event files, and the format is small: a file of
//! TFRecords, each `u64 length (LE) | u32 masked CRC-32C of the length | data | u32 masked
//! CRC-32C of the data`, whose data is a serialized `tensorflow.Event` protocol buffer. The first
//! record carries `file_version = "brain.Event:2"`; every later one a `Summary` of scalar values
//! (`Summary.Value { tag, simple_value }`) at a `step` and `wall_time`.
//!
//! Only the protobuf fields written here are encoded, by hand:
//!
//! | message        | field          | number | wire type        |
//! |----------------|----------------|--------|------------------|
//! | Event          | wall_time      | 1      | 64-bit (double)  |
//! | Event          | step           | 2      | varint (int64)   |
//! | Event          | file_version   | 3      | length-delimited |
//! | Event          | summary        | 5      | length-delimited |
//! | Summary        | value          | 1      | length-delimited |
//! | Summary.Value  | tag            | 1      | length-delimited |
//! | Summary.Value  | simple_value   | 2      | 32-bit (float)   |
//!
//! The reader understands exactly what the writer writes (and skips unknown fields), so tests
//! can check a file by reading it back; it rejects bad CRCs and truncated records with errors.

use std::fs::File;
use std::io::{BufWriter, Read, Seek, SeekFrom, Write};
use std::path::{Path, PathBuf};
use std::time::{SystemTime, UNIX_EPOCH};

use anyhow::{bail, ensure, Context};

/// The version string of the first event of every file.
const FILE_VERSION: &str = "brain.Event:2";

/// CRC-32C (Castagnoli), reflected polynomial.
const CRC32C_POLY: u32 = 0x82F6_3B78;

/// The 256-entry lookup table of [`crc32c`], built at compile time.
const CRC32C_TABLE: [u32; 256] = {
    let mut table = [0u32; 256];
    let mut i = 0;
    while i < 256 {
        let mut crc = i as u32;
        let mut bit = 0;
        while bit < 8 {
            crc = if crc & 1 != 0 {
                (crc >> 1) ^ CRC32C_POLY
            } else {
                crc >> 1
            };
            bit += 1;
        }
        table[i] = crc;
        i += 1;
    }
    table
};

/// CRC-32C of `data`.
pub fn crc32c(data: &[u8]) -> u32 {
    let mut crc = !0u32;
    for &byte in data {
        crc = CRC32C_TABLE[((crc ^ byte as u32) & 0xff) as usize] ^ (crc >> 8);
    }
    !crc
}

/// TFRecord's masked CRC: rotate right by 15 bits and add a constant.
pub fn masked_crc32c(data: &[u8]) -> u32 {
    let crc = crc32c(data);
    crc.rotate_right(15).wrapping_add(0xa282_ead8)
}

/// Appends scalar summaries to one `events.out.tfevents.*` file in a directory.
pub struct EventWriter {
    path: PathBuf,
    out: BufWriter<File>,
}

impl EventWriter {
    /// Creates `dir` if needed and a new event file in it, named as TensorBoard expects
    /// (`events.out.tfevents.<unix seconds>.<host>`), and writes the file-version record.
    pub fn create(dir: &Path) -> anyhow::Result<Self> {
        std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
        let now = SystemTime::now()
            .duration_since(UNIX_EPOCH)
            .unwrap_or_default();
        let host = hostname();
        let path = dir.join(format!("events.out.tfevents.{}.{host}", now.as_secs()));
        let file = File::create(&path).with_context(|| format!("creating {}", path.display()))?;
        let mut writer = Self {
            path,
            out: BufWriter::new(file),
        };
        let mut event = Vec::new();
        put_double(&mut event, 1, now.as_secs_f64());
        put_bytes(&mut event, 3, FILE_VERSION.as_bytes());
        writer.write_record(&event)?;
        writer.out.flush()?;
        Ok(writer)
    }

    /// The file being written.
    #[cfg_attr(not(test), allow(dead_code))]
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Writes one event holding every `(tag, value)` scalar at `step`. Non-finite values are
    /// written as they are (TensorBoard shows them as NaN/inf), tags must be non-empty.
    pub fn add_scalars(
        &mut self,
        step: i64,
        wall_time: f64,
        scalars: &[(&str, f32)],
    ) -> anyhow::Result<()> {
        let mut summary = Vec::new();
        let mut value = Vec::new();
        for (tag, scalar) in scalars {
            ensure!(
                !tag.is_empty(),
                "a TensorBoard scalar needs a non-empty tag"
            );
            value.clear();
            put_bytes(&mut value, 1, tag.as_bytes());
            put_float(&mut value, 2, *scalar);
            put_bytes(&mut summary, 1, &value);
        }
        let mut event = Vec::new();
        put_double(&mut event, 1, wall_time);
        put_varint_field(&mut event, 2, step as u64);
        put_bytes(&mut event, 5, &summary);
        self.write_record(&event)
    }

    /// Flushes buffered records to the file.
    pub fn flush(&mut self) -> anyhow::Result<()> {
        self.out
            .flush()
            .with_context(|| format!("writing {}", self.path.display()))
    }

    /// Flushes, then moves the write position to the file's current end: after the file was
    /// cut shorter underneath the writer ([`crate::run::move_metrics_past`]), the next record
    /// follows the last one kept instead of leaving a hole of zeros.
    pub fn continue_at_end(&mut self) -> anyhow::Result<()> {
        self.flush()?;
        self.out
            .get_mut()
            .seek(SeekFrom::End(0))
            .with_context(|| format!("seeking to the end of {}", self.path.display()))?;
        Ok(())
    }

    fn write_record(&mut self, data: &[u8]) -> anyhow::Result<()> {
        let len = (data.len() as u64).to_le_bytes();
        self.out.write_all(&len)?;
        self.out.write_all(&masked_crc32c(&len).to_le_bytes())?;
        self.out.write_all(data)?;
        self.out.write_all(&masked_crc32c(data).to_le_bytes())?;
        Ok(())
    }
}

fn hostname() -> String {
    std::fs::read_to_string("/proc/sys/kernel/hostname")
        .ok()
        .map(|h| {
            h.trim()
                .chars()
                .filter(|c| c.is_ascii_alphanumeric() || *c == '-')
                .collect::<String>()
        })
        .filter(|h| !h.is_empty())
        .unwrap_or_else(|| "localhost".to_owned())
}

fn put_varint(out: &mut Vec<u8>, mut value: u64) {
    while value >= 0x80 {
        out.push((value as u8) | 0x80);
        value >>= 7;
    }
    out.push(value as u8);
}

fn put_key(out: &mut Vec<u8>, field: u32, wire_type: u8) {
    put_varint(out, ((field as u64) << 3) | wire_type as u64);
}

fn put_varint_field(out: &mut Vec<u8>, field: u32, value: u64) {
    put_key(out, field, 0);
    put_varint(out, value);
}

fn put_double(out: &mut Vec<u8>, field: u32, value: f64) {
    put_key(out, field, 1);
    out.extend_from_slice(&value.to_le_bytes());
}

fn put_bytes(out: &mut Vec<u8>, field: u32, bytes: &[u8]) {
    put_key(out, field, 2);
    put_varint(out, bytes.len() as u64);
    out.extend_from_slice(bytes);
}

fn put_float(out: &mut Vec<u8>, field: u32, value: f32) {
    put_key(out, field, 5);
    out.extend_from_slice(&value.to_le_bytes());
}

/// One event read back from a file.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Event {
    /// Seconds since the Unix epoch.
    pub wall_time: f64,
    /// The global step.
    pub step: i64,
    /// Set on the first event of a file.
    pub file_version: Option<String>,
    /// Scalar values `(tag, value)` of the event's summary.
    pub scalars: Vec<(String, f32)>,
}

/// Reads every event of a file written by [`EventWriter`], checking both CRCs of every record.
#[cfg_attr(not(test), allow(dead_code))] // the reader checks files in tests
pub fn read_events(path: &Path) -> anyhow::Result<Vec<Event>> {
    let mut events = Vec::new();
    let mut problem = None;
    scan_events(path, |_, event| match event {
        Ok(event) => {
            events.push(event);
            true
        }
        Err(err) => {
            problem = Some(err);
            false
        }
    })?;
    match problem {
        Some(err) => Err(err),
        None => Ok(events),
    }
}

/// Streams the records of the event file at `path`, one at a time (files of long runs are
/// large), calling `visit` with each record's byte offset and its event, or the problem with
/// it (a truncated or corrupt record: the scan ends there); `visit` returns whether to go on.
/// `Err` only when the file cannot be read.
pub fn scan_events(
    path: &Path,
    mut visit: impl FnMut(u64, anyhow::Result<Event>) -> bool,
) -> anyhow::Result<()> {
    let file = File::open(path).with_context(|| format!("reading {}", path.display()))?;
    let mut input = std::io::BufReader::new(file);
    let (mut offset, mut record) = (0u64, 0usize);
    let mut data = Vec::new();
    loop {
        let mut header = [0u8; 12];
        let n = read_up_to(&mut input, &mut header)
            .with_context(|| format!("reading {}", path.display()))?;
        if n == 0 {
            return Ok(());
        }
        let read = (|| {
            ensure!(n == 12, "truncated header ({n} bytes left)");
            let len_bytes: [u8; 8] = header[..8].try_into()?;
            let len_crc = u32::from_le_bytes(header[8..].try_into()?);
            ensure!(masked_crc32c(&len_bytes) == len_crc, "length CRC mismatch");
            let len = usize::try_from(u64::from_le_bytes(len_bytes))?;
            data.resize(len + 4, 0);
            let got = read_up_to(&mut input, &mut data)?;
            ensure!(got == len + 4, "truncated data ({len} bytes announced)");
            let data_crc = u32::from_le_bytes(data[len..].try_into()?);
            ensure!(masked_crc32c(&data[..len]) == data_crc, "data CRC mismatch");
            Ok((len, decode_event(&data[..len])?))
        })()
        .with_context(|| format!("record {record}"));
        let start = offset;
        let event = match read {
            Ok((len, event)) => {
                offset += 12 + len as u64 + 4;
                Ok(event)
            }
            Err(err) => Err(err),
        };
        let failed = event.is_err();
        if !visit(start, event) || failed {
            return Ok(());
        }
        record += 1;
    }
}

/// Fills `buf` from `input` as far as the input goes; returns the bytes read.
fn read_up_to(input: &mut impl Read, buf: &mut [u8]) -> std::io::Result<usize> {
    let mut filled = 0;
    while filled < buf.len() {
        match input.read(&mut buf[filled..])? {
            0 => break,
            n => filled += n,
        }
    }
    Ok(filled)
}

/// A protobuf field as read: number and value.
enum Field<'a> {
    Varint(u64),
    Fixed64([u8; 8]),
    Bytes(&'a [u8]),
    Fixed32([u8; 4]),
}

fn take_varint(data: &mut &[u8]) -> anyhow::Result<u64> {
    let mut value = 0u64;
    for shift in (0..64).step_by(7) {
        let (&byte, rest) = data.split_first().context("truncated varint")?;
        *data = rest;
        value |= u64::from(byte & 0x7f) << shift;
        if byte & 0x80 == 0 {
            return Ok(value);
        }
    }
    bail!("varint longer than 10 bytes")
}

fn take<'a>(data: &mut &'a [u8], n: usize) -> anyhow::Result<&'a [u8]> {
    ensure!(
        data.len() >= n,
        "field of {n} bytes truncated ({} left)",
        data.len()
    );
    let (head, rest) = data.split_at(n);
    *data = rest;
    Ok(head)
}

fn next_field<'a>(data: &mut &'a [u8]) -> anyhow::Result<(u64, Field<'a>)> {
    let key = take_varint(data)?;
    let field = match key & 7 {
        0 => Field::Varint(take_varint(data)?),
        1 => Field::Fixed64(take(data, 8)?.try_into()?),
        2 => {
            let len = usize::try_from(take_varint(data)?)?;
            Field::Bytes(take(data, len)?)
        }
        5 => Field::Fixed32(take(data, 4)?.try_into()?),
        other => bail!("unsupported protobuf wire type {other}"),
    };
    Ok((key >> 3, field))
}

fn decode_event(mut data: &[u8]) -> anyhow::Result<Event> {
    let mut event = Event::default();
    while !data.is_empty() {
        match next_field(&mut data)? {
            (1, Field::Fixed64(b)) => event.wall_time = f64::from_le_bytes(b),
            (2, Field::Varint(v)) => event.step = v as i64,
            (3, Field::Bytes(b)) => event.file_version = Some(String::from_utf8(b.to_vec())?),
            (5, Field::Bytes(summary)) => decode_summary(summary, &mut event.scalars)?,
            _ => {}
        }
    }
    Ok(event)
}

fn decode_summary(mut data: &[u8], scalars: &mut Vec<(String, f32)>) -> anyhow::Result<()> {
    while !data.is_empty() {
        if let (1, Field::Bytes(mut value)) = next_field(&mut data)? {
            let (mut tag, mut scalar) = (String::new(), None);
            while !value.is_empty() {
                match next_field(&mut value)? {
                    (1, Field::Bytes(b)) => tag = String::from_utf8(b.to_vec())?,
                    (2, Field::Fixed32(b)) => scalar = Some(f32::from_le_bytes(b)),
                    _ => {}
                }
            }
            scalars.push((tag, scalar.context("summary value without simple_value")?));
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A fresh, empty directory under the system temp dir, removed on drop.
    struct TempDir(PathBuf);

    impl TempDir {
        fn new() -> Self {
            static NEXT: std::sync::atomic::AtomicU32 = std::sync::atomic::AtomicU32::new(0);
            let n = NEXT.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
            let dir = std::env::temp_dir().join(format!("asi-tb-test-{}-{n}", std::process::id()));
            let _ = std::fs::remove_dir_all(&dir);
            std::fs::create_dir_all(&dir).unwrap();
            Self(dir)
        }

        fn path(&self) -> &Path {
            &self.0
        }
    }

    impl Drop for TempDir {
        fn drop(&mut self) {
            let _ = std::fs::remove_dir_all(&self.0);
        }
    }

    #[test]
    fn crc32c_matches_the_standard_check_values() {
        // The CRC catalogue's check value for CRC-32C, and RFC 3720 (iSCSI) B.4 vectors.
        assert_eq!(crc32c(b"123456789"), 0xE306_9283);
        assert_eq!(crc32c(&[0u8; 32]), 0x8A91_36AA);
        assert_eq!(crc32c(&[0xffu8; 32]), 0x62A8_AB43);
        let ascending: Vec<u8> = (0u8..32).collect();
        assert_eq!(crc32c(&ascending), 0x46DD_794E);
    }

    #[test]
    // The rotation is written out on purpose: an independent form of what the code computes.
    #[allow(clippy::manual_rotate)]
    fn masked_crc_is_rotation_plus_constant() {
        let crc = crc32c(b"abc");
        assert_eq!(
            masked_crc32c(b"abc"),
            ((crc >> 15) | (crc << 17)).wrapping_add(0xa282_ead8)
        );
    }

    #[test]
    fn varints_encode_as_protobuf_does() {
        // Protobuf's documentation example: 150 = 0x96 0x01; 300 = 0xAC 0x02.
        let mut out = Vec::new();
        put_varint(&mut out, 150);
        put_varint(&mut out, 300);
        assert_eq!(out, [0x96, 0x01, 0xAC, 0x02]);
        let mut slice = out.as_slice();
        assert_eq!(take_varint(&mut slice).unwrap(), 150);
        assert_eq!(take_varint(&mut slice).unwrap(), 300);
    }

    #[test]
    fn scalar_event_bytes_are_exact() {
        // Event { wall_time: 1.5, step: 3, summary { value { tag: "a", simple_value: 2.0 } } }:
        // Value = 0a 01 "a" 15 <f32> (8 bytes); Summary = 0a 08 <Value> (10 bytes).
        let dir = TempDir::new();
        let mut w = EventWriter::create(dir.path()).unwrap();
        w.add_scalars(3, 1.5, &[("a", 2.0)]).unwrap();
        w.flush().unwrap();
        let bytes = std::fs::read(w.path()).unwrap();
        let first_len = u64::from_le_bytes(bytes[..8].try_into().unwrap()) as usize;
        let second = &bytes[8 + 4 + first_len + 4..];
        let len = u64::from_le_bytes(second[..8].try_into().unwrap()) as usize;
        let data = &second[12..12 + len];
        let mut expected = vec![0x09];
        expected.extend_from_slice(&1.5f64.to_le_bytes());
        expected.extend_from_slice(&[0x10, 0x03, 0x2a, 0x0a, 0x0a, 0x08, 0x0a, 0x01, b'a', 0x15]);
        expected.extend_from_slice(&2.0f32.to_le_bytes());
        assert_eq!(data, expected.as_slice());
        assert_eq!(second.len(), 12 + len + 4, "exactly two records");
    }

    #[test]
    fn written_events_read_back() {
        let dir = TempDir::new();
        let mut w = EventWriter::create(dir.path()).unwrap();
        assert!(w
            .path()
            .file_name()
            .unwrap()
            .to_str()
            .unwrap()
            .starts_with("events.out.tfevents."));
        w.add_scalars(
            10,
            100.25,
            &[("eval/success", 0.5), ("learner/losses/critic", -3.25)],
        )
        .unwrap();
        w.add_scalars(1 << 40, 101.0, &[("x", f32::NAN)]).unwrap();
        w.flush().unwrap();
        let events = read_events(w.path()).unwrap();
        assert_eq!(events.len(), 3);
        assert_eq!(events[0].file_version.as_deref(), Some(FILE_VERSION));
        assert_eq!(events[1].step, 10);
        assert_eq!(events[1].wall_time, 100.25);
        assert_eq!(
            events[1].scalars,
            vec![
                ("eval/success".to_owned(), 0.5),
                ("learner/losses/critic".to_owned(), -3.25)
            ]
        );
        assert_eq!(events[2].step, 1 << 40);
        assert!(events[2].scalars[0].1.is_nan());
    }

    #[test]
    fn corruption_and_truncation_are_errors() {
        let dir = TempDir::new();
        let mut w = EventWriter::create(dir.path()).unwrap();
        w.add_scalars(1, 1.0, &[("a", 1.0)]).unwrap();
        w.flush().unwrap();
        let bytes = std::fs::read(w.path()).unwrap();
        let bad = dir.path().join("bad");
        let mut flipped = bytes.clone();
        let last = flipped.len() - 6;
        flipped[last] ^= 1;
        std::fs::write(&bad, &flipped).unwrap();
        assert!(format!("{:#}", read_events(&bad).unwrap_err()).contains("CRC"));
        std::fs::write(&bad, &bytes[..bytes.len() - 3]).unwrap();
        assert!(format!("{:#}", read_events(&bad).unwrap_err()).contains("truncated"));
        assert!(w.add_scalars(1, 1.0, &[("", 1.0)]).is_err());
    }
}
