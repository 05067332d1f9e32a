//! How many times each process of a run folder has been started, over all its launches
//! (`run_dir/process_starts.json`, [`STARTS_FILE`]).
//!
//! A process's *incarnation* is the number of its earlier starts in the folder. An actor
//! starts its episodes at `incarnation << 28` and seeds its generator from that start
//! (`actor::seeds`), so an actor restarted after a crash *or started by a resumed launch* never
//! repeats the episode ids, env seeds, action noise or random warm-up of an earlier start.
//! Before this book, every launch numbered its processes from 0: a resumed process-mode run
//! ran the first launch's env seeds and noise again and repeated the whole random warm-up.
//!
//! Invariants:
//! - The count is written (atomically) before the process is spawned, so a launcher killed
//!   right after a spawn never hands the same incarnation out twice.
//! - A folder resumed without the file (a run started by a build before it) numbers every
//!   process from 1: incarnation 0 is the one its first launch certainly used.
//! - An unreadable file is an error naming it, never silently reset (a reset would hand out
//!   used incarnations again).

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use anyhow::Context;

/// The book's file name inside the run folder.
pub const STARTS_FILE: &str = "process_starts.json";

/// Starts per process name (`ChildKind::name`: `learner`, `graph-service`, `actor-3`, …).
#[derive(Debug)]
pub struct StartBook {
    path: PathBuf,
    starts: BTreeMap<String, u32>,
    /// The count of a process the file does not name (1 in a pre-book folder being resumed).
    unrecorded: u32,
}

impl StartBook {
    /// The book of `run_dir`; `resume` says whether this launch continues an earlier one.
    pub fn open(run_dir: &Path, resume: bool) -> anyhow::Result<Self> {
        let path = run_dir.join(STARTS_FILE);
        match std::fs::read_to_string(&path) {
            Ok(text) => {
                let starts = serde_json::from_str(&text).with_context(|| {
                    format!(
                        "{} is not a table of process start counts; it numbers the processes \
                         of this run folder over all launches (so that a resumed actor does not \
                         repeat episode ids and env seeds). Fix it or move it aside; without it \
                         a resume numbers every process from 1",
                        path.display()
                    )
                })?;
                Ok(Self {
                    path,
                    starts,
                    unrecorded: 0,
                })
            }
            Err(err) if err.kind() == std::io::ErrorKind::NotFound => {
                if resume {
                    tracing::warn!(
                        "{} is missing (a run started by an older build): numbering this \
                         launch's processes from 1, so its actors skip the random warm-up and \
                         do not repeat the first launch's episode ids",
                        path.display()
                    );
                }
                Ok(Self {
                    path,
                    starts: BTreeMap::new(),
                    unrecorded: u32::from(resume),
                })
            }
            Err(err) => Err(err).with_context(|| format!("reading {}", path.display())),
        }
    }

    /// The incarnation of the next start of `process` (its earlier starts), counted in the
    /// file before it returns.
    pub fn next(&mut self, process: &str) -> anyhow::Result<u32> {
        let earlier = self.starts.get(process).copied().unwrap_or(self.unrecorded);
        let count = earlier.checked_add(1).with_context(|| {
            format!(
                "{process} has been started {earlier} times in this run folder ({})",
                self.path.display()
            )
        })?;
        self.starts.insert(process.to_owned(), count);
        let text = serde_json::to_string_pretty(&self.starts)?;
        crate::run::write_atomically(&self.path, &text)?;
        Ok(earlier)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    struct Folder(PathBuf);

    impl Folder {
        fn new(name: &str) -> Self {
            let dir =
                std::env::temp_dir().join(format!("asi-starts-{}-{name}", std::process::id()));
            let _ = std::fs::remove_dir_all(&dir);
            std::fs::create_dir_all(&dir).unwrap();
            Self(dir)
        }
    }

    impl Drop for Folder {
        fn drop(&mut self) {
            let _ = std::fs::remove_dir_all(&self.0);
        }
    }

    #[test]
    fn incarnations_go_on_across_launches_of_one_folder() {
        let dir = Folder::new("launches");
        let mut first = StartBook::open(&dir.0, false).unwrap();
        assert_eq!(first.next("actor-0").unwrap(), 0);
        assert_eq!(first.next("actor-1").unwrap(), 0);
        assert_eq!(first.next("actor-0").unwrap(), 1, "a crash restart");
        assert_eq!(first.next("learner").unwrap(), 0);
        drop(first);
        let mut resumed = StartBook::open(&dir.0, true).unwrap();
        assert_eq!(resumed.next("actor-0").unwrap(), 2);
        assert_eq!(resumed.next("actor-1").unwrap(), 1);
        assert_eq!(resumed.next("learner").unwrap(), 1);
        assert_eq!(
            resumed.next("actor-2").unwrap(),
            0,
            "an actor id the earlier launches did not have"
        );
        let saved: BTreeMap<String, u32> =
            serde_json::from_str(&std::fs::read_to_string(dir.0.join(STARTS_FILE)).unwrap())
                .unwrap();
        assert_eq!(
            saved,
            BTreeMap::from([
                ("actor-0".to_owned(), 3),
                ("actor-1".to_owned(), 2),
                ("actor-2".to_owned(), 1),
                ("learner".to_owned(), 2),
            ])
        );
    }

    #[test]
    fn a_resumed_folder_without_the_book_numbers_from_1_and_a_fresh_one_from_0() {
        let dir = Folder::new("legacy");
        let mut legacy = StartBook::open(&dir.0, true).unwrap();
        assert_eq!(legacy.next("actor-0").unwrap(), 1);
        assert_eq!(legacy.next("actor-0").unwrap(), 2);
        let fresh_dir = Folder::new("fresh");
        let mut fresh = StartBook::open(&fresh_dir.0, false).unwrap();
        assert_eq!(fresh.next("actor-0").unwrap(), 0);
    }

    #[test]
    fn a_damaged_book_is_an_error_naming_it_and_is_left_as_it_was() {
        let dir = Folder::new("damaged");
        let path = dir.0.join(STARTS_FILE);
        std::fs::write(&path, "{\"actor-0\": 3,").unwrap();
        let err = format!("{:#}", StartBook::open(&dir.0, true).unwrap_err());
        assert!(
            err.contains(STARTS_FILE) && err.contains("move it aside"),
            "{err}"
        );
        assert_eq!(std::fs::read_to_string(&path).unwrap(), "{\"actor-0\": 3,");
    }
}
