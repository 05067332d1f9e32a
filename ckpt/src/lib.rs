//! Checkpoint folders on disk, shared by the learner (`learner::learner::checkpoint`) and the
//! graph-service (`graph_service::checkpoint`); each writes its own parts and manifest, this
//! crate does the file work both need.
//!
//! A checkpoint is a folder `<prefix>NNNNNN` (sequence number, 6 digits) holding files and a
//! manifest that lists each file with its size and [`checksum`]. Invariants:
//! - Atomic: [`TmpFolder`] writes every file into a hidden `<tmp_prefix>NNNNNN` folder, syncs
//!   it, then renames it; a folder named `<prefix>N` is complete. A temporary folder left by an
//!   interrupted write is never read, and is removed by the next write of the same number.
//! - Checked: [`read_checked`] refuses a file whose size or checksum differs from its entry.
//!   The checksum is CRC-64 ([`checksum`]) in the current manifest formats; format 1 of every
//!   manifest listed word-wise FNV-1a ([`fingerprint`]), which is still read ([`Checksum`]).
//! - Rotation: after a commit only the newest `keep` checkpoints remain.
//!
//! The safetensors helpers write string metadata as one sorted JSON entry ([`META_KEY`]), so
//! equal states give equal bytes, and read typed 1-D arrays back with their length checked.

use std::borrow::Cow;
use std::collections::{BTreeMap, HashMap};
use std::fs;
use std::io::Write;
use std::path::{Path, PathBuf};

use safetensors::{Dtype, SafeTensors, View};
use serde::de::DeserializeOwned;
use serde::{Deserialize, Serialize};

/// The safetensors metadata key of our metadata (a JSON object of strings).
pub const META_KEY: &str = "asi_checkpoint";

/// Why a checkpoint folder could not be written, read or used. The learner's and the
/// graph-service's `CheckpointError`s wrap it and add what only they can fail at.
#[derive(Debug, thiserror::Error)]
pub enum FileError {
    /// A file or folder could not be read or written.
    #[error("checkpoint {}: {source}", path.display())]
    Io {
        /// The file or folder.
        path: PathBuf,
        /// The I/O error.
        #[source]
        source: std::io::Error,
    },
    /// A file is missing, truncated, fails its checksum or holds something unexpected.
    #[error("checkpoint file {} is corrupt: {problem}", path.display())]
    Corrupt {
        /// The file.
        path: PathBuf,
        /// What is wrong with it.
        problem: String,
    },
    /// The checkpoint was written by another format, protocol, network layout or config (its
    /// manifest says which).
    #[error(
        "checkpoint {} is incompatible: its {what} is {found}, this run needs {expected}",
        path.display()
    )]
    Incompatible {
        /// The manifest.
        path: PathBuf,
        /// Which property differs.
        what: String,
        /// The value this run needs.
        expected: String,
        /// The checkpoint's value.
        found: String,
    },
}

/// [`FileError::Io`] of `path`.
pub fn io_error(path: &Path, source: std::io::Error) -> FileError {
    FileError::Io {
        path: path.to_path_buf(),
        source,
    }
}

/// [`FileError::Corrupt`] of `path`.
pub fn corrupt(path: &Path, problem: impl Into<String>) -> FileError {
    FileError::Corrupt {
        path: path.to_path_buf(),
        problem: problem.into(),
    }
}

/// [`FileError::Incompatible`]: the manifest at `path` has `found` for `what`, this run needs
/// `expected`.
pub fn incompatible(
    path: &Path,
    what: impl Into<String>,
    expected: String,
    found: String,
) -> FileError {
    FileError::Incompatible {
        path: path.to_path_buf(),
        what: what.into(),
        expected,
        found,
    }
}

/// One file of a checkpoint, as listed in its manifest.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct FileEntry {
    /// File name inside the checkpoint folder.
    pub name: String,
    /// Size in bytes.
    pub bytes: u64,
    /// [`checksum`] of the contents (16 hex digits); [`fingerprint`] in a format-1 manifest.
    pub checksum: String,
}

impl FileEntry {
    /// The entry of a file `name` holding `bytes`, with the current [`checksum`].
    pub fn of(name: &str, bytes: &[u8]) -> Self {
        Self {
            name: name.to_owned(),
            bytes: bytes.len() as u64,
            checksum: format!("{:016x}", checksum(bytes)),
        }
    }
}

/// Which function a manifest's file checksums were computed with, by the manifest's format
/// version: the learner's, the graph-service's and the serial checkpoints all wrote
/// [`Checksum::Fnv1aWords`] in format 1 and write [`Checksum::Crc64`] from format 2 on.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Checksum {
    /// [`fingerprint`]: format 1, read only. It misses some two-bit errors (flipping the top
    /// bit of any two 8-byte words cancels), which is why format 2 replaced it.
    Fnv1aWords,
    /// [`checksum`]: CRC-64/XZ, format 2 on.
    Crc64,
}

impl Checksum {
    /// The checksum of a manifest of `format_version`, read by a reader whose own format is
    /// `current` (a format from 2 on, which writes CRC-64): `None` for a version it cannot
    /// read (newer than `current`, or 0).
    pub fn of_format(format_version: u32, current: u32) -> Option<Self> {
        match format_version {
            1 => Some(Self::Fnv1aWords),
            v if (2..=current).contains(&v) => Some(Self::Crc64),
            _ => None,
        }
    }

    /// The checksum of `bytes`.
    pub fn of(self, bytes: &[u8]) -> u64 {
        match self {
            Self::Fnv1aWords => fingerprint(bytes),
            Self::Crc64 => checksum(bytes),
        }
    }
}

/// The versions of the manifest at `path`, `(format, protocol)`, against the reader's
/// `current` format (from 2 on) and `protocol` version: the checksum its files are listed
/// with, or [`FileError::Incompatible`] naming the version that differs.
pub fn check_versions(
    path: &Path,
    (format, protocol_found): (u32, u32),
    current: u32,
    protocol: u32,
) -> Result<Checksum, FileError> {
    let sum = Checksum::of_format(format, current).ok_or_else(|| {
        incompatible(
            path,
            "format version",
            format!("1 to {current}"),
            format.to_string(),
        )
    })?;
    if protocol_found != protocol {
        return Err(incompatible(
            path,
            "protocol version",
            protocol.to_string(),
            protocol_found.to_string(),
        ));
    }
    Ok(sum)
}

/// The reflected ECMA-182 polynomial of CRC-64/XZ.
const CRC64_POLY: u64 = 0xc96c_5795_d787_0f42;

/// Slicing-by-16 tables of CRC-64/XZ: `T[0]` is the byte-wise table, `T[j][b]` the CRC of
/// byte `b` followed by `j` zero bytes.
static CRC64_TABLES: [[u64; 256]; 16] = crc64_tables();

const fn crc64_tables() -> [[u64; 256]; 16] {
    let mut tables = [[0u64; 256]; 16];
    let mut i = 0;
    while i < 256 {
        let mut crc = i as u64;
        let mut bit = 0;
        while bit < 8 {
            crc = if crc & 1 == 1 {
                (crc >> 1) ^ CRC64_POLY
            } else {
                crc >> 1
            };
            bit += 1;
        }
        tables[0][i] = crc;
        i += 1;
    }
    let mut i = 0;
    while i < 256 {
        let mut j = 1;
        while j < 16 {
            let prev = tables[j - 1][i];
            tables[j][i] = (prev >> 8) ^ tables[0][(prev & 0xff) as usize];
            j += 1;
        }
        i += 1;
    }
    tables
}

/// CRC-64/XZ of `bytes` (the check of `.xz` files; ECMA-182 polynomial, reflected, initial
/// value and final XOR all ones): the file checksum of checkpoint manifests. It detects every
/// error of one or two bits and every burst of up to 64 bits, unlike [`fingerprint`].
pub fn checksum(bytes: &[u8]) -> u64 {
    let t = &CRC64_TABLES;
    let mut crc = !0u64;
    let (blocks, tail) = bytes.as_chunks::<16>();
    for block in blocks {
        let both = u128::from_le_bytes(*block);
        let lo = crc ^ both as u64;
        let hi = (both >> 64) as u64;
        let byte = |v: u64, k: u32| ((v >> (8 * k)) & 0xff) as usize;
        crc = t[15][byte(lo, 0)]
            ^ t[14][byte(lo, 1)]
            ^ t[13][byte(lo, 2)]
            ^ t[12][byte(lo, 3)]
            ^ t[11][byte(lo, 4)]
            ^ t[10][byte(lo, 5)]
            ^ t[9][byte(lo, 6)]
            ^ t[8][byte(lo, 7)]
            ^ t[7][byte(hi, 0)]
            ^ t[6][byte(hi, 1)]
            ^ t[5][byte(hi, 2)]
            ^ t[4][byte(hi, 3)]
            ^ t[3][byte(hi, 4)]
            ^ t[2][byte(hi, 5)]
            ^ t[1][byte(hi, 6)]
            ^ t[0][byte(hi, 7)];
    }
    for &b in tail {
        crc = t[0][((crc ^ u64::from(b)) & 0xff) as usize] ^ (crc >> 8);
    }
    !crc
}

/// 64-bit FNV-1a over the little-endian 8-byte words of `bytes` (then the remaining bytes one
/// by one), XORed with the length: a fast fingerprint for telling contents apart (the config
/// fingerprint of learner checkpoints, the config and binary of `launches.jsonl`), and the
/// file checksum of format-1 manifests. Not for detecting damage: a flip of bit k of a word
/// only reaches bits k and up of the result, so flipping the top bit of two words cancels.
/// Its values must never change, or recorded fingerprints stop matching.
pub fn fingerprint(bytes: &[u8]) -> u64 {
    const OFFSET: u64 = 0xcbf2_9ce4_8422_2325;
    const PRIME: u64 = 0x0000_0100_0000_01b3;
    let mut hash = OFFSET;
    let words = bytes.chunks_exact(8);
    let tail = words.remainder();
    for word in words {
        let mut w = [0u8; 8];
        w.copy_from_slice(word);
        hash = (hash ^ u64::from_le_bytes(w)).wrapping_mul(PRIME);
    }
    for &b in tail {
        hash = (hash ^ u64::from(b)).wrapping_mul(PRIME);
    }
    hash ^ bytes.len() as u64
}

/// Complete checkpoints `<prefix>N` in `dir`, oldest first, with their sequence numbers;
/// empty when `dir` does not exist.
pub fn list(dir: &Path, prefix: &str) -> Result<Vec<(u64, PathBuf)>, FileError> {
    let entries = match fs::read_dir(dir) {
        Ok(entries) => entries,
        Err(err) if err.kind() == std::io::ErrorKind::NotFound => return Ok(Vec::new()),
        Err(source) => return Err(io_error(dir, source)),
    };
    let mut out = Vec::new();
    for entry in entries {
        let entry = entry.map_err(|source| io_error(dir, source))?;
        let name = entry.file_name();
        let Some(seq) = name
            .to_str()
            .and_then(|n| n.strip_prefix(prefix))
            .and_then(|n| n.parse::<u64>().ok())
        else {
            continue;
        };
        out.push((seq, entry.path()));
    }
    out.sort();
    Ok(out)
}

/// A checkpoint being written: a temporary folder that [`TmpFolder::commit`] renames.
#[derive(Debug)]
pub struct TmpFolder {
    dir: PathBuf,
    prefix: String,
    tmp: PathBuf,
    sequence: u64,
    existing: Vec<(u64, PathBuf)>,
    files: Vec<FileEntry>,
}

impl TmpFolder {
    /// Starts checkpoint N+1 in `dir` (created if missing), N the newest `<prefix>N` there, in
    /// `<tmp_prefix>N+1` (a leftover folder of that name, from an interrupted write, is
    /// removed first).
    pub fn begin(dir: &Path, prefix: &str, tmp_prefix: &str) -> Result<Self, FileError> {
        fs::create_dir_all(dir).map_err(|source| io_error(dir, source))?;
        let existing = list(dir, prefix)?;
        let sequence = existing.last().map_or(1, |(seq, _)| seq + 1);
        let tmp = dir.join(format!("{tmp_prefix}{sequence:06}"));
        if tmp.exists() {
            fs::remove_dir_all(&tmp).map_err(|source| io_error(&tmp, source))?;
        }
        fs::create_dir(&tmp).map_err(|source| io_error(&tmp, source))?;
        Ok(Self {
            dir: dir.to_path_buf(),
            prefix: prefix.to_owned(),
            tmp,
            sequence,
            existing,
            files: Vec::new(),
        })
    }

    /// Sequence number of the checkpoint being written.
    pub fn sequence(&self) -> u64 {
        self.sequence
    }

    /// Where file `name` is being written.
    pub fn path_of(&self, name: &str) -> PathBuf {
        self.tmp.join(name)
    }

    /// Writes file `name` (synced) and lists it.
    pub fn add(&mut self, name: &str, bytes: &[u8]) -> Result<(), FileError> {
        write_synced(&self.tmp.join(name), bytes)?;
        self.files.push(FileEntry::of(name, bytes));
        Ok(())
    }

    /// The files written so far, in order.
    pub fn files(&self) -> &[FileEntry] {
        &self.files
    }

    /// Writes the manifest `manifest_name`, renames the folder to `<prefix>N`, syncs `dir`,
    /// then removes all but the newest `keep` checkpoints (this one included). Returns the
    /// checkpoint's folder.
    pub fn commit(
        self,
        manifest_name: &str,
        manifest: &[u8],
        keep: usize,
    ) -> Result<PathBuf, FileError> {
        self.commit_protecting(manifest_name, manifest, keep, None)
    }

    /// [`TmpFolder::commit`], but the checkpoint numbered `protected` is never removed (it is
    /// kept beside the newest `keep`): serial mode's graph-service base, which its newest
    /// serial checkpoint replays from, outlives the bases written after that checkpoint.
    pub fn commit_protecting(
        self,
        manifest_name: &str,
        manifest: &[u8],
        keep: usize,
        protected: Option<u64>,
    ) -> Result<PathBuf, FileError> {
        write_synced(&self.tmp.join(manifest_name), manifest)?;
        let path = self
            .dir
            .join(format!("{}{:06}", self.prefix, self.sequence));
        fs::rename(&self.tmp, &path).map_err(|source| io_error(&path, source))?;
        sync_dir(&self.dir)?;
        let mut existing = self.existing;
        existing.retain(|(seq, _)| Some(*seq) != protected);
        prune(existing, keep.saturating_sub(1))?;
        Ok(path)
    }
}

/// Writes `bytes` to a new file at `path` and syncs it.
fn write_synced(path: &Path, bytes: &[u8]) -> Result<(), FileError> {
    let mut file = fs::File::create(path).map_err(|source| io_error(path, source))?;
    file.write_all(bytes)
        .and_then(|()| file.sync_all())
        .map_err(|source| io_error(path, source))
}

/// Syncs a folder so a rename inside it is durable.
fn sync_dir(dir: &Path) -> Result<(), FileError> {
    fs::File::open(dir)
        .and_then(|d| d.sync_all())
        .map_err(|source| io_error(dir, source))
}

/// Removes the oldest of `existing` (oldest first) until `keep` remain.
fn prune(existing: Vec<(u64, PathBuf)>, keep: usize) -> Result<(), FileError> {
    let n_remove = existing.len().saturating_sub(keep);
    for (_, path) in existing.into_iter().take(n_remove) {
        fs::remove_dir_all(&path).map_err(|source| io_error(&path, source))?;
    }
    Ok(())
}

/// The JSON manifest `name` of the checkpoint folder `dir`.
pub fn read_manifest<M: DeserializeOwned>(dir: &Path, name: &str) -> Result<M, FileError> {
    let path = dir.join(name);
    let bytes = fs::read(&path).map_err(|source| io_error(&path, source))?;
    serde_json::from_slice(&bytes).map_err(|e| corrupt(&path, format!("unreadable manifest: {e}")))
}

/// Every file of `files` in `dir`, checked against its size and its checksum (computed with
/// `sum`, the manifest format's [`Checksum`]), by name; `manifest` (the manifest's path) is
/// named when an entry is not a plain file name.
pub fn read_checked(
    dir: &Path,
    files: &[FileEntry],
    manifest: &Path,
    sum: Checksum,
) -> Result<HashMap<String, Vec<u8>>, FileError> {
    let mut out = HashMap::new();
    for entry in files {
        if entry.name.contains(['/', '\\']) || entry.name.starts_with('.') {
            return Err(corrupt(
                manifest,
                format!("file name {:?} is not a plain file name", entry.name),
            ));
        }
        let path = dir.join(&entry.name);
        let bytes = fs::read(&path).map_err(|source| io_error(&path, source))?;
        if bytes.len() as u64 != entry.bytes {
            return Err(corrupt(
                &path,
                format!(
                    "{} bytes, the manifest says {} (truncated?)",
                    bytes.len(),
                    entry.bytes
                ),
            ));
        }
        let found = format!("{:016x}", sum.of(&bytes));
        if found != entry.checksum {
            return Err(corrupt(
                &path,
                format!("checksum {found}, the manifest says {}", entry.checksum),
            ));
        }
        out.insert(entry.name.clone(), bytes);
    }
    Ok(out)
}

/// Safetensors bytes of named tensors with string metadata (stored as one sorted JSON
/// entry under [`META_KEY`]).
pub fn serialize<V: View>(
    tensors: Vec<(String, V)>,
    metadata: HashMap<String, String>,
) -> Result<Vec<u8>, String> {
    // Sorted: safetensors writes its metadata map in hash order, which would make equal
    // states give different bytes.
    let sorted: BTreeMap<String, String> = metadata.into_iter().collect();
    let json = serde_json::to_string(&sorted).map_err(|e| e.to_string())?;
    let metadata = HashMap::from([(META_KEY.to_owned(), json)]);
    safetensors::serialize(tensors, Some(metadata)).map_err(|e| e.to_string())
}

/// The parsed safetensors file and its metadata (written by [`serialize`]).
pub fn parse(bytes: &[u8]) -> Result<(SafeTensors<'_>, HashMap<String, String>), String> {
    let (_, meta) = SafeTensors::read_metadata(bytes).map_err(|e| e.to_string())?;
    let json = meta
        .metadata()
        .as_ref()
        .and_then(|m| m.get(META_KEY))
        .ok_or(format!("metadata `{META_KEY}` is missing"))?;
    let metadata = serde_json::from_str(json).map_err(|e| format!("metadata: {e}"))?;
    let st = SafeTensors::deserialize(bytes).map_err(|e| e.to_string())?;
    Ok((st, metadata))
}

/// A metadata value parsed from its string.
pub fn meta<T: std::str::FromStr>(
    metadata: &HashMap<String, String>,
    key: &str,
) -> Result<T, String> {
    let value = metadata
        .get(key)
        .ok_or_else(|| format!("metadata `{key}` is missing"))?;
    value
        .parse()
        .map_err(|_| format!("metadata `{key}` = {value:?} is not valid"))
}

/// A number type stored in safetensors arrays (little-endian).
pub trait Element: Copy {
    /// Its safetensors dtype.
    const DTYPE: Dtype;
    /// Bytes per element.
    const SIZE: usize;
    /// Appends its little-endian bytes.
    fn put(self, out: &mut Vec<u8>);
    /// Reads it from `SIZE` little-endian bytes.
    fn get(bytes: &[u8]) -> Self;
}

macro_rules! element {
    ($t:ty, $dtype:ident) => {
        impl Element for $t {
            const DTYPE: Dtype = Dtype::$dtype;
            const SIZE: usize = std::mem::size_of::<$t>();
            fn put(self, out: &mut Vec<u8>) {
                out.extend_from_slice(&self.to_le_bytes());
            }
            fn get(bytes: &[u8]) -> Self {
                let mut b = [0u8; std::mem::size_of::<$t>()];
                b.copy_from_slice(bytes);
                <$t>::from_le_bytes(b)
            }
        }
    };
}

element!(u8, U8);
element!(u32, U32);
element!(u64, U64);
element!(i32, I32);
element!(i64, I64);
element!(f32, F32);
element!(f64, F64);

/// A tensor to serialise: dtype, shape and little-endian bytes.
#[derive(Debug, Clone, PartialEq)]
pub struct Array {
    dtype: Dtype,
    shape: Vec<usize>,
    data: Vec<u8>,
}

impl Array {
    /// The array of `values` with `shape` (whose product must be the number of values, else
    /// an error).
    pub fn new<T: Element>(shape: Vec<usize>, values: &[T]) -> Result<Self, String> {
        Self::from_iter(shape, values.iter().copied())
    }

    /// [`Array::new`] of the values an iterator yields.
    pub fn from_iter<T: Element>(
        shape: Vec<usize>,
        values: impl IntoIterator<Item = T>,
    ) -> Result<Self, String> {
        let n: usize = shape.iter().product();
        let mut data = Vec::with_capacity(n * T::SIZE);
        for v in values {
            v.put(&mut data);
        }
        if data.len() != n * T::SIZE {
            return Err(format!(
                "shape {shape:?} does not hold {} values",
                data.len() / T::SIZE
            ));
        }
        Ok(Self {
            dtype: T::DTYPE,
            shape,
            data,
        })
    }

    /// The 1-D array of `values`.
    pub fn flat<T: Element>(values: &[T]) -> Self {
        let mut data = Vec::with_capacity(values.len() * T::SIZE);
        for &v in values {
            v.put(&mut data);
        }
        Self {
            dtype: T::DTYPE,
            shape: vec![values.len()],
            data,
        }
    }
}

impl View for &Array {
    fn dtype(&self) -> Dtype {
        self.dtype
    }
    fn shape(&self) -> &[usize] {
        &self.shape
    }
    fn data(&self) -> Cow<'_, [u8]> {
        Cow::Borrowed(&self.data)
    }
    fn data_len(&self) -> usize {
        self.data.len()
    }
}

/// The array `name` of `st` as `T`s, checked to have `len` elements (`None`: any length).
pub fn array<T: Element>(
    st: &SafeTensors,
    name: &str,
    len: Option<usize>,
) -> Result<Vec<T>, String> {
    let view = st
        .tensor(name)
        .map_err(|_| format!("tensor `{name}` is missing"))?;
    if view.dtype() != T::DTYPE {
        return Err(format!(
            "tensor `{name}` is {:?}, not {:?}",
            view.dtype(),
            T::DTYPE
        ));
    }
    let data = view.data();
    let n = data.len() / T::SIZE;
    if let Some(len) = len.filter(|&len| len != n) {
        return Err(format!("tensor `{name}` has {n} elements, expected {len}"));
    }
    Ok(data.chunks_exact(T::SIZE).map(T::get).collect())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn scratch(name: &str) -> PathBuf {
        let dir = std::env::temp_dir().join(format!("ckpt-test-{name}-{}", std::process::id()));
        let _ = fs::remove_dir_all(&dir);
        dir
    }

    /// The 1,003-byte test buffer of the reference values below.
    fn test_buffer() -> Vec<u8> {
        (0..1003u64)
            .map(|i| ((i * i * 31 + 7 * i + 3) % 251) as u8)
            .collect()
    }

    /// CRC-64/XZ one bit at a time, straight from its definition.
    fn crc64_bitwise(bytes: &[u8]) -> u64 {
        let mut crc = !0u64;
        for &b in bytes {
            crc ^= u64::from(b);
            for _ in 0..8 {
                crc = if crc & 1 == 1 {
                    (crc >> 1) ^ CRC64_POLY
                } else {
                    crc >> 1
                };
            }
        }
        !crc
    }

    #[test]
    fn check_versions_reads_formats_1_to_the_current_one_and_names_what_differs() {
        let path = Path::new("/run/checkpoints/ckpt-000003/manifest.json");
        assert_eq!(
            check_versions(path, (1, 7), 3, 7).unwrap(),
            Checksum::Fnv1aWords
        );
        assert_eq!(check_versions(path, (2, 7), 3, 7).unwrap(), Checksum::Crc64);
        assert_eq!(check_versions(path, (3, 7), 3, 7).unwrap(), Checksum::Crc64);
        for (versions, differs, expected, found) in [
            ((0, 7), "format version", "1 to 3", "0"),
            ((4, 7), "format version", "1 to 3", "4"),
            ((3, 6), "protocol version", "7", "6"),
            // An unreadable format is named before the protocol.
            ((4, 6), "format version", "1 to 3", "4"),
        ] {
            match check_versions(path, versions, 3, 7) {
                Err(FileError::Incompatible {
                    path: p,
                    what,
                    expected: e,
                    found: f,
                }) => {
                    assert_eq!(p, path, "{versions:?}");
                    assert_eq!(
                        (what.as_str(), e.as_str(), f.as_str()),
                        (differs, expected, found)
                    );
                }
                other => panic!("{versions:?}: {other:?}"),
            }
        }
    }

    #[test]
    fn checksum_is_crc64_xz() {
        // The CRC catalogue's check value of CRC-64/XZ, and the check xz 5 (liblzma) stores
        // for the test buffer (`xz --check=crc64`, read back with `xz --robot -lvv`).
        assert_eq!(checksum(b"123456789"), 0x995d_c9bb_df19_39fa);
        assert_eq!(checksum(&test_buffer()), 0xce81_d968_d13b_2eb2);
        assert_eq!(checksum(&[]), 0);
        // Slicing-by-16 against the definition for every split into 16-byte blocks and a tail.
        let buffer = test_buffer();
        for len in 0..=40 {
            assert_eq!(
                checksum(&buffer[..len]),
                crc64_bitwise(&buffer[..len]),
                "{len}"
            );
        }
    }

    #[test]
    fn checksum_catches_every_one_and_two_bit_error_where_the_fingerprint_misses_some() {
        let bytes = &test_buffer()[..64];
        let sum = checksum(bytes);
        let flip = |bits: &[usize]| {
            let mut flipped = bytes.to_vec();
            for &bit in bits {
                flipped[bit / 8] ^= 1 << (bit % 8);
            }
            flipped
        };
        for i in 0..bytes.len() * 8 {
            assert_ne!(checksum(&flip(&[i])), sum, "bit {i}");
            for j in i + 1..bytes.len() * 8 {
                assert_ne!(checksum(&flip(&[i, j])), sum, "bits {i} and {j}");
            }
        }
        assert_ne!(checksum(&bytes[..63]), sum);
        // Format 1's checksum: the top bits of words 0 and 3 (bits 63 and 255) cancel.
        assert_eq!(fingerprint(&flip(&[63, 255])), fingerprint(bytes));
        assert_ne!(checksum(&flip(&[63, 255])), sum);
    }

    #[test]
    fn the_fingerprint_keeps_its_values() {
        // Computed by format 1's function (word-wise FNV-1a XOR length) as recorded in
        // existing checkpoints and launch records; a change here orphans all of them.
        assert_eq!(fingerprint(b"123456789"), 0xa6cd_6bd6_7708_1ab6);
        assert_eq!(fingerprint(&test_buffer()), 0x014e_c1e7_b91c_4593);
        assert_eq!(Checksum::Fnv1aWords.of(b"123456789"), 0xa6cd_6bd6_7708_1ab6);
        assert_eq!(Checksum::Crc64.of(b"123456789"), 0x995d_c9bb_df19_39fa);
    }

    #[test]
    fn each_format_reads_with_its_checksum() {
        assert_eq!(Checksum::of_format(1, 2), Some(Checksum::Fnv1aWords));
        assert_eq!(Checksum::of_format(2, 2), Some(Checksum::Crc64));
        assert_eq!(Checksum::of_format(3, 2), None);
        assert_eq!(Checksum::of_format(0, 2), None);
        // A reader of format 3 reads format 2 (CRC-64 too), not format 4.
        assert_eq!(Checksum::of_format(2, 3), Some(Checksum::Crc64));
        assert_eq!(Checksum::of_format(3, 3), Some(Checksum::Crc64));
        assert_eq!(Checksum::of_format(4, 3), None);
        // A format-1 entry (fingerprint) reads with its own checksum, not with format 2's.
        let dir = scratch("format1");
        let folder = TmpFolder::begin(&dir, "ckpt-", ".tmp-ckpt-").unwrap();
        let path = folder.commit("manifest.json", b"{}", 2).unwrap();
        fs::write(path.join("a.bin"), b"0123456789").unwrap();
        let entry = FileEntry {
            name: "a.bin".to_owned(),
            bytes: 10,
            checksum: format!("{:016x}", fingerprint(b"0123456789")),
        };
        let manifest = path.join("manifest.json");
        let files = [entry];
        let read = read_checked(&path, &files, &manifest, Checksum::Fnv1aWords).unwrap();
        assert_eq!(read["a.bin"], b"0123456789");
        let err = read_checked(&path, &files, &manifest, Checksum::Crc64).unwrap_err();
        assert!(err.to_string().contains("checksum"), "{err}");
        fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn commits_are_numbered_rotated_and_leave_no_temporary_folder() {
        let dir = scratch("rotate");
        for seq in 1..=3u64 {
            let mut folder = TmpFolder::begin(&dir, "ckpt-", ".tmp-ckpt-").unwrap();
            assert_eq!(folder.sequence(), seq);
            folder.add("a.bin", &[seq as u8; 5]).unwrap();
            let files = folder.files().to_vec();
            let path = folder.commit("manifest.json", b"{}", 2).unwrap();
            let read =
                read_checked(&path, &files, &path.join("manifest.json"), Checksum::Crc64).unwrap();
            assert_eq!(read["a.bin"], vec![seq as u8; 5]);
        }
        let names: Vec<_> = list(&dir, "ckpt-")
            .unwrap()
            .into_iter()
            .map(|(s, _)| s)
            .collect();
        assert_eq!(names, vec![2, 3]);
        assert_eq!(fs::read_dir(&dir).unwrap().count(), 2);
        // A protected checkpoint stays however many are written after it; the others rotate.
        for _ in 4..=6u64 {
            let folder = TmpFolder::begin(&dir, "ckpt-", ".tmp-ckpt-").unwrap();
            folder
                .commit_protecting("manifest.json", b"{}", 2, Some(3))
                .unwrap();
        }
        let names: Vec<_> = list(&dir, "ckpt-")
            .unwrap()
            .into_iter()
            .map(|(s, _)| s)
            .collect();
        assert_eq!(names, vec![3, 5, 6]);
        fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn a_file_that_differs_from_its_entry_is_refused() {
        let dir = scratch("corrupt");
        let mut folder = TmpFolder::begin(&dir, "ckpt-", ".tmp-ckpt-").unwrap();
        folder.add("a.bin", b"0123456789").unwrap();
        let files = folder.files().to_vec();
        let path = folder.commit("manifest.json", b"{}", 2).unwrap();
        fs::write(path.join("a.bin"), b"0123456780").unwrap();
        let err =
            read_checked(&path, &files, &path.join("manifest.json"), Checksum::Crc64).unwrap_err();
        assert!(err.to_string().contains("checksum"), "{err}");
        fs::write(path.join("a.bin"), b"01234").unwrap();
        let err =
            read_checked(&path, &files, &path.join("manifest.json"), Checksum::Crc64).unwrap_err();
        assert!(err.to_string().contains("truncated"), "{err}");
        fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn arrays_round_trip_with_their_dtype_and_length_checked() {
        let a = Array::new(vec![2, 2], &[1.5f64, -2.0, 3.0, 4.25]).unwrap();
        let b = Array::flat(&[u64::MAX, 7]);
        let metadata = HashMap::from([("k".to_owned(), "9".to_owned())]);
        let bytes = serialize(vec![("a".to_owned(), &a), ("b".to_owned(), &b)], metadata).unwrap();
        let (st, metadata) = parse(&bytes).unwrap();
        assert_eq!(meta::<u32>(&metadata, "k"), Ok(9));
        assert_eq!(
            array::<f64>(&st, "a", Some(4)).unwrap(),
            vec![1.5, -2.0, 3.0, 4.25]
        );
        assert_eq!(array::<u64>(&st, "b", None).unwrap(), vec![u64::MAX, 7]);
        assert!(array::<u32>(&st, "b", None)
            .unwrap_err()
            .contains("not U32"));
        assert!(array::<f64>(&st, "a", Some(3))
            .unwrap_err()
            .contains("expected 3"));
        assert!(Array::new(vec![3], &[1u8, 2]).is_err());
    }
}
