//! The run's newest policy weights on disk, for `asi eval`: `run_dir/weights/latest.safetensors`
//! (the weights message's payload: encoder, high and low policies) and `latest.json` (its
//! header: versions, layout hash, schedule, size, and an FNV-1a checksum of the bytes).
//!
//! The evaluator process writes them (and serial mode), at most every
//! [`WeightsSaver::INTERVAL`] and before every evaluation, so they trail the learner by
//! seconds. Each file is replaced atomically (temp file + rename); the bytes go first and the
//! JSON names their checksum, so a reader that meets a half-updated pair (bytes of the next
//! version, JSON of the previous) gets a checksum error and can simply read again.

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use anyhow::{bail, Context};
use protocol::{PhiVersion, PolicyVersion, RunSchedule, WeightsHeader};
use serde::{Deserialize, Serialize};

/// Folder of the weights files inside a run folder.
pub const WEIGHTS_DIR: &str = "weights";
const BYTES_FILE: &str = "latest.safetensors";
const HEADER_FILE: &str = "latest.json";
/// Version of `latest.json`'s fields.
const FORMAT_VERSION: u32 = 1;

/// `latest.json`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct HeaderFile {
    format_version: u32,
    protocol_version: u32,
    policy_version: u64,
    phi_version: u64,
    layout_hash: u64,
    train_episodes: u64,
    count_prob: f32,
    fr_prob: f32,
    byte_len: u64,
    /// FNV-1a (64 bit) of `latest.safetensors`, 16 hex digits.
    checksum: String,
}

/// FNV-1a, 64 bit: enough to tell a torn or damaged file from the one the header describes.
fn fnv1a64(bytes: &[u8]) -> String {
    let mut hash: u64 = 0xcbf2_9ce4_8422_2325;
    for &b in bytes {
        hash ^= u64::from(b);
        hash = hash.wrapping_mul(0x0000_0100_0000_01b3);
    }
    format!("{hash:016x}")
}

fn write_file_atomically(path: &Path, bytes: &[u8]) -> anyhow::Result<()> {
    let mut tmp = path.as_os_str().to_owned();
    tmp.push(format!(".tmp-{}", std::process::id()));
    let tmp = PathBuf::from(tmp);
    std::fs::write(&tmp, bytes).with_context(|| format!("writing {}", tmp.display()))?;
    std::fs::rename(&tmp, path)
        .with_context(|| format!("renaming {} to {}", tmp.display(), path.display()))
}

/// Writes one weights message as the run's newest weights.
pub fn save(run_dir: &Path, header: &WeightsHeader, bytes: &[u8]) -> anyhow::Result<()> {
    let dir = run_dir.join(WEIGHTS_DIR);
    std::fs::create_dir_all(&dir).with_context(|| format!("creating {}", dir.display()))?;
    let file = HeaderFile {
        format_version: FORMAT_VERSION,
        protocol_version: header.protocol_version,
        policy_version: header.policy_version.0,
        phi_version: header.phi_version.0,
        layout_hash: header.layout_hash,
        train_episodes: header.schedule.train_episodes,
        count_prob: header.schedule.count_prob,
        fr_prob: header.schedule.fr_prob,
        byte_len: bytes.len() as u64,
        checksum: fnv1a64(bytes),
    };
    write_file_atomically(&dir.join(BYTES_FILE), bytes)?;
    write_file_atomically(
        &dir.join(HEADER_FILE),
        serde_json::to_string_pretty(&file)?.as_bytes(),
    )
}

/// Reads the run's newest weights: the header (as the learner sent it) and the bytes. A
/// missing, damaged or mismatched pair is an error that says which file and why.
pub fn load(run_dir: &Path) -> anyhow::Result<(WeightsHeader, Vec<u8>)> {
    let dir = run_dir.join(WEIGHTS_DIR);
    let header_path = dir.join(HEADER_FILE);
    let text = match std::fs::read_to_string(&header_path) {
        Ok(text) => text,
        Err(err) if err.kind() == std::io::ErrorKind::NotFound => bail!(
            "{} does not exist: no weights were saved in this run folder yet (the evaluator \
             saves them; runs with eval.n_episodes = 0 have none)",
            header_path.display()
        ),
        Err(err) => return Err(err).with_context(|| format!("reading {}", header_path.display())),
    };
    let file: HeaderFile = serde_json::from_str(&text)
        .with_context(|| format!("{} is not a weights header", header_path.display()))?;
    if file.format_version != FORMAT_VERSION {
        bail!(
            "{} has format version {}, this build reads {FORMAT_VERSION}",
            header_path.display(),
            file.format_version
        );
    }
    let bytes_path = dir.join(BYTES_FILE);
    let bytes =
        std::fs::read(&bytes_path).with_context(|| format!("reading {}", bytes_path.display()))?;
    if bytes.len() as u64 != file.byte_len || fnv1a64(&bytes) != file.checksum {
        bail!(
            "{} ({} bytes, checksum {}) does not match {} ({} bytes, checksum {}): damaged, or \
             replaced while it was read (read again)",
            bytes_path.display(),
            bytes.len(),
            fnv1a64(&bytes),
            header_path.display(),
            file.byte_len,
            file.checksum
        );
    }
    let mut header = WeightsHeader::new(
        PolicyVersion(file.policy_version),
        PhiVersion(file.phi_version),
        file.layout_hash,
        bytes.len(),
    )
    .with_schedule(RunSchedule {
        train_episodes: file.train_episodes,
        count_prob: file.count_prob,
        fr_prob: file.fr_prob,
    });
    header.protocol_version = file.protocol_version;
    Ok((header, bytes))
}

/// Saves weights messages no more often than [`WeightsSaver::INTERVAL`] (unless forced); a
/// failed write is logged, never fatal (the weights on disk are a convenience copy).
pub struct WeightsSaver {
    run_dir: PathBuf,
    last: Option<Instant>,
    saved_version: Option<PolicyVersion>,
}

impl WeightsSaver {
    /// Shortest gap between two writes.
    pub const INTERVAL: Duration = Duration::from_secs(10);

    pub fn new(run_dir: &Path) -> Self {
        Self {
            run_dir: run_dir.to_owned(),
            last: None,
            saved_version: None,
        }
    }

    /// Writes the message if its version is newer than the one saved and the interval has
    /// passed (or `force`). Versions only go up in a run, also across learner restarts.
    pub fn offer(&mut self, header: &WeightsHeader, bytes: &[u8], force: bool) {
        if self
            .saved_version
            .is_some_and(|saved| header.policy_version.0 <= saved.0)
        {
            return;
        }
        if !force && self.last.is_some_and(|at| at.elapsed() < Self::INTERVAL) {
            return;
        }
        match save(&self.run_dir, header, bytes) {
            Ok(()) => self.saved_version = Some(header.policy_version),
            Err(err) => tracing::warn!("could not save the latest weights: {err:#}"),
        }
        self.last = Some(Instant::now());
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn scratch(name: &str) -> PathBuf {
        let dir =
            std::env::temp_dir().join(format!("asi-weights-file-{name}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        dir
    }

    fn header(len: usize) -> WeightsHeader {
        WeightsHeader::new(PolicyVersion(7), PhiVersion(3), 0xDEAD_BEEF_0123_4567, len)
            .with_schedule(RunSchedule {
                train_episodes: 250,
                count_prob: 0.25,
                fr_prob: 0.5,
            })
    }

    #[test]
    fn a_saved_message_reads_back_identically() {
        let dir = scratch("round-trip");
        let bytes: Vec<u8> = (0..1000u32).map(|i| (i * 7 % 251) as u8).collect();
        save(&dir, &header(bytes.len()), &bytes).unwrap();
        let (read_header, read_bytes) = load(&dir).unwrap();
        assert_eq!(read_header, header(bytes.len()));
        assert_eq!(read_bytes, bytes);
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn missing_damaged_and_foreign_files_are_refused_with_reasons() {
        let dir = scratch("damaged");
        let missing = load(&dir).unwrap_err().to_string();
        assert!(missing.contains("no weights were saved"), "{missing}");
        let bytes = vec![1u8; 64];
        save(&dir, &header(bytes.len()), &bytes).unwrap();
        let mut flipped = bytes.clone();
        flipped[10] ^= 1;
        std::fs::write(dir.join(WEIGHTS_DIR).join(BYTES_FILE), &flipped).unwrap();
        let damaged = format!("{:#}", load(&dir).unwrap_err());
        assert!(damaged.contains("does not match"), "{damaged}");
        std::fs::write(dir.join(WEIGHTS_DIR).join(HEADER_FILE), "{\"policy\": 1}").unwrap();
        let foreign = format!("{:#}", load(&dir).unwrap_err());
        assert!(foreign.contains("is not a weights header"), "{foreign}");
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn the_saver_skips_repeats_and_writes_forced_new_versions() {
        let dir = scratch("saver");
        let mut saver = WeightsSaver::new(&dir);
        saver.offer(&header(4), &[1, 2, 3, 4], false);
        let mut next = header(4);
        next.policy_version = PolicyVersion(8);
        saver.offer(&next, &[5, 6, 7, 8], false); // within the interval: skipped
        assert_eq!(load(&dir).unwrap().1, [1, 2, 3, 4]);
        saver.offer(&next, &[5, 6, 7, 8], true);
        assert_eq!(load(&dir).unwrap().0.policy_version, PolicyVersion(8));
        saver.offer(&header(4), &[1, 2, 3, 4], true); // an older version: never written back
        assert_eq!(load(&dir).unwrap().1, [5, 6, 7, 8]);
        let _ = std::fs::remove_dir_all(&dir);
    }
}
