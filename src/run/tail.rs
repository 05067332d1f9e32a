//! A resumed run's record files end where its checkpoint was written. A run killed between
//! checkpoints (SIGKILL, power loss, a crash-looping launcher) wrote metrics and evaluations
//! past its newest checkpoint; the resumed run trains that stretch again and writes those lines
//! anew, so appending to the old files would repeat a stretch of every curve (`metrics.jsonl`,
//! `metrics.csv`, `eval.jsonl`, and the plots drawn from them). Before a resume the launch
//! moves each file's lines past the checkpoint — and a last line left half-written — into a
//! side file next to it (`<file>.past-ckpt-<N>-<unix seconds>`): nothing is deleted.
//!
//! TensorBoard event files (`tensorboard/`, process mode) are cut the same way, by each
//! event's step (env steps); their tails go to a folder `tensorboard.past-ckpt-<N>-<unix
//! seconds>/` (a file beside them would still be read as part of the run). A side name that
//! is taken (two cuts in one second) gets `-2`, `-3`, … appended.
//!
//! A process-mode learner that crashes and is restarted inside one launch goes back to its
//! checkpoint the same way; the launcher then cuts its own records (`metrics.jsonl`,
//! `metrics.csv`, its TensorBoard file: [`move_metrics_past`]) at that checkpoint, or at the
//! start (`past-start`) when there was none. `eval.jsonl` stays: the evaluator keeps running
//! and does not evaluate those episode counts again.
//!
//! A line is past the checkpoint when its learner env-step count is above the checkpoint's
//! (`metrics.jsonl`: key `learner/ingest/env_steps`; `metrics.csv`: the column of that name),
//! or, for `eval.jsonl`, when it evaluated weights of more training episodes than the
//! checkpoint holds (`train_episodes`; left alone for checkpoints that do not record episodes).
//! Everything from the first such line on is moved: within a launch these counters only grow,
//! and every line of an earlier launch that went further than the newest checkpoint is past it
//! too. Lines without the counter (a process-mode launcher's first lines, before the learner
//! reported) are judged by where they lie.
//!
//! The files are streamed, not read whole: a week-long process-mode run's `metrics.jsonl`
//! grows by a line a second.

use std::fs::File;
use std::io::{BufRead, BufReader, Seek, SeekFrom};
use std::path::{Path, PathBuf};

use anyhow::Context;

/// Where a resume starts: the learner checkpoint's sequence number and counters.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ResumePoint {
    /// N of `ckpt-N` (names the side files); `None`: no checkpoint, the learner starts over.
    pub sequence: Option<u64>,
    /// Env steps the learner had ingested.
    pub env_steps: u64,
    /// Episodes it had completed, when the checkpoint records them.
    pub episodes: Option<u64>,
}

impl ResumePoint {
    /// The learner's start without a checkpoint: every counted line is past it.
    pub const START: Self = Self {
        sequence: None,
        env_steps: 0,
        episodes: Some(0),
    };

    /// The middle of the side files' names: `past-ckpt-N` or `past-start`.
    fn side_label(&self) -> String {
        match self.sequence {
            Some(n) => format!("past-ckpt-{n}"),
            None => "past-start".to_owned(),
        }
    }
}

/// One file's lines moved aside.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct MovedTail {
    /// The record file.
    pub file: PathBuf,
    /// Whole lines (event files: whole records) moved; a half-written last one is moved too,
    /// not counted here.
    pub lines: u64,
    /// What `lines` counts: "lines" or "events".
    pub unit: &'static str,
    /// The side file that holds them.
    pub side_file: PathBuf,
}

/// Moves the lines past `point` of the run's `metrics.jsonl`, `metrics.csv` and `eval.jsonl`,
/// and the events past it of its TensorBoard files, into side files; returns what was moved
/// (nothing for files that end at the checkpoint).
pub fn move_lines_past(run_dir: &Path, point: ResumePoint) -> anyhow::Result<Vec<MovedTail>> {
    let mut moved = move_metrics_past(run_dir, point)?;
    if let Some(episodes) = point.episodes {
        let eval = run_dir.join(crate::proc::evaluator::EVAL_FILE);
        moved.extend(move_tail(&eval, point, |line, _| {
            Ok(json_number(line, "train_episodes").is_some_and(|e| e > episodes as f64))
        })?);
    }
    Ok(moved)
}

/// [`move_lines_past`] for the launcher's own records only (`metrics.jsonl`, `metrics.csv`,
/// TensorBoard), not `eval.jsonl`: what a learner restarted inside a launch makes stale.
pub fn move_metrics_past(run_dir: &Path, point: ResumePoint) -> anyhow::Result<Vec<MovedTail>> {
    const STEPS_KEY: &str = "learner/ingest/env_steps";
    let mut moved = Vec::new();
    let jsonl = run_dir.join("metrics.jsonl");
    moved.extend(move_tail(&jsonl, point, |line, _| {
        Ok(json_number(line, STEPS_KEY).is_some_and(|s| s > point.env_steps as f64))
    })?);
    let csv = run_dir.join("metrics.csv");
    let mut column = None;
    moved.extend(move_tail(&csv, point, |line, index| {
        if index == 0 {
            column = line.trim_end().split(',').position(|c| c == STEPS_KEY);
            return Ok(false);
        }
        Ok(column
            .and_then(|c| line.trim_end().split(',').nth(c))
            .and_then(|field| field.parse::<f64>().ok())
            .is_some_and(|s| s > point.env_steps as f64))
    })?);
    moved.extend(move_events_past(run_dir, point)?);
    Ok(moved)
}

/// TensorBoard event files (process mode; one per launch, x axis env steps): the records past
/// `point` (step above its env steps), or from a truncated or corrupt record on, move into
/// `tensorboard.past-ckpt-N-<unix seconds>/` under the file's name — a folder TensorBoard
/// shows as a run of its own, outside `tensorboard/`, whose curves then end at the checkpoint.
fn move_events_past(run_dir: &Path, point: ResumePoint) -> anyhow::Result<Vec<MovedTail>> {
    let dir = run_dir.join("tensorboard");
    let entries = match std::fs::read_dir(&dir) {
        Ok(entries) => entries,
        Err(err) if err.kind() == std::io::ErrorKind::NotFound => return Ok(Vec::new()),
        Err(err) => return Err(err).with_context(|| format!("reading {}", dir.display())),
    };
    let mut files: Vec<PathBuf> = entries
        .flatten()
        .map(|e| e.path())
        .filter(|p| p.is_file())
        .collect();
    files.sort();
    let mut side_dir = None;
    let mut moved = Vec::new();
    for path in files {
        // The first record past the point (or unreadable), and the whole records from it on.
        let (mut cut, mut past) = (None, 0u64);
        crate::tensorboard::scan_events(&path, |offset, event| {
            let beyond = event
                .as_ref()
                .map_or(true, |e| e.step > point.env_steps as i64);
            if beyond && cut.is_none() {
                cut = Some(offset);
            }
            past += u64::from(cut.is_some() && event.is_ok());
            true
        })?;
        let Some(at) = cut else { continue };
        let side_dir = match &side_dir {
            Some(dir) => dir,
            None => {
                let name = format!("tensorboard.{}-{}", point.side_label(), unix_secs());
                let dir = unused_name(&run_dir.join(name));
                std::fs::create_dir(&dir).with_context(|| format!("creating {}", dir.display()))?;
                side_dir.insert(dir)
            }
        };
        let side_file = side_dir.join(path.file_name().unwrap_or_default());
        split_off(&path, at, &side_file)?;
        moved.push(MovedTail {
            file: path,
            lines: past,
            unit: "events",
            side_file,
        });
    }
    Ok(moved)
}

/// `path`, or when something is there already, the first of `path-2`, `path-3`, … that is
/// free (the caller still creates it exclusively).
fn unused_name(path: &Path) -> PathBuf {
    let taken = |p: &Path| std::fs::symlink_metadata(p).is_ok();
    let mut candidate = path.to_path_buf();
    let mut n = 2u64;
    while taken(&candidate) {
        let mut name = path.as_os_str().to_owned();
        name.push(format!("-{n}"));
        candidate = PathBuf::from(name);
        n += 1;
    }
    candidate
}

fn unix_secs() -> u64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_secs())
}

/// Copies `path` from byte `at` on into the new file `side_file` (synced), then cuts `path`
/// at `at`: a crash in between leaves the bytes in both places, never in neither.
fn split_off(path: &Path, at: u64, side_file: &Path) -> anyhow::Result<()> {
    let mut source = File::open(path).with_context(|| format!("opening {}", path.display()))?;
    source.seek(SeekFrom::Start(at))?;
    let mut side =
        File::create_new(side_file).with_context(|| format!("creating {}", side_file.display()))?;
    std::io::copy(&mut source, &mut side).with_context(|| {
        format!(
            "copying the tail of {} to {}",
            path.display(),
            side_file.display()
        )
    })?;
    side.sync_all()?;
    let record = File::options()
        .write(true)
        .open(path)
        .with_context(|| format!("opening {} to cut it", path.display()))?;
    record
        .set_len(at)
        .with_context(|| format!("cutting {} at byte {at}", path.display()))?;
    Ok(record.sync_all()?)
}

/// The number at `key` in a JSON object line; `None` when the line is not one or lacks it.
fn json_number(line: &str, key: &str) -> Option<f64> {
    let value: serde_json::Value = serde_json::from_str(line).ok()?;
    value.get(key)?.as_f64()
}

/// Streams `path` line by line and moves everything from the first line `is_past` accepts
/// (called with the line and its index), or a half-written last line, into a side file, then
/// cuts the file there. `Ok(None)` when the file is missing or nothing is past.
fn move_tail(
    path: &Path,
    point: ResumePoint,
    mut is_past: impl FnMut(&str, u64) -> anyhow::Result<bool>,
) -> anyhow::Result<Option<MovedTail>> {
    let file = match File::open(path) {
        Ok(file) => file,
        Err(err) if err.kind() == std::io::ErrorKind::NotFound => return Ok(None),
        Err(err) => return Err(err).with_context(|| format!("opening {}", path.display())),
    };
    let mut reader = BufReader::new(file);
    let mut line = String::new();
    let (mut offset, mut index) = (0u64, 0u64);
    let mut cut: Option<(u64, u64)> = None; // (byte offset, line index) of the first line moved
    loop {
        line.clear();
        let n = reader
            .read_line(&mut line)
            .with_context(|| format!("reading {}", path.display()))?;
        if n == 0 {
            break;
        }
        let whole = line.ends_with('\n');
        if cut.is_none() && (!whole || is_past(&line, index)?) {
            cut = Some((offset, index));
        }
        offset += n as u64;
        index += u64::from(whole);
    }
    let Some((at, first)) = cut else {
        return Ok(None);
    };
    let name = path
        .file_name()
        .map_or_else(String::new, |n| n.to_string_lossy().into_owned());
    let side_file =
        unused_name(&path.with_file_name(format!("{name}.{}-{}", point.side_label(), unix_secs())));
    drop(reader);
    split_off(path, at, &side_file)?;
    Ok(Some(MovedTail {
        file: path.to_path_buf(),
        lines: index - first,
        unit: "lines",
        side_file,
    }))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn scratch(test: &str) -> PathBuf {
        let dir = std::env::temp_dir().join(format!("asi-tail-{test}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        dir
    }

    fn side_files(dir: &Path) -> Vec<(String, String)> {
        let mut out: Vec<(String, String)> = std::fs::read_dir(dir)
            .unwrap()
            .flatten()
            .filter(|e| e.file_name().to_string_lossy().contains(".past-ckpt-"))
            .map(|e| {
                let name = e.file_name().to_string_lossy().into_owned();
                let prefix = name.split(".past-ckpt-").next().unwrap().to_owned();
                (prefix, std::fs::read_to_string(e.path()).unwrap())
            })
            .collect();
        out.sort();
        out
    }

    #[test]
    fn lines_past_the_checkpoint_move_to_side_files_and_the_rest_stays_byte_for_byte() {
        let dir = scratch("cut");
        // Two launches: the first went to 400 steps and was resumed from 200 (its lines past
        // 200 were repeated, as before this module), the second was killed at 500 after a
        // checkpoint at 300. A line without the counter sits before the cut.
        let jsonl = [
            r#"{"wall_secs":1,"learner/ingest/env_steps":100}"#,
            r#"{"wall_secs":2,"learner/ingest/env_steps":200}"#,
            r#"{"wall_secs":0.5}"#,
            r#"{"wall_secs":3,"learner/ingest/env_steps":300}"#,
            r#"{"wall_secs":4,"learner/ingest/env_steps":400}"#,
            r#"{"wall_secs":5,"learner/ingest/env_steps":500}"#,
        ];
        let text = jsonl.join("\n") + "\n";
        std::fs::write(dir.join("metrics.jsonl"), &text).unwrap();
        let csv = "wall_secs,env_steps_per_sec,actor_restarts,learner/ingest/env_steps\n\
                   1,0,0,100\n2,0,0,300\n3,0,0,301\n4,0,0,500\n";
        std::fs::write(dir.join("metrics.csv"), csv).unwrap();
        let eval = "{\"index\":1,\"train_episodes\":50}\n{\"index\":2,\"train_episodes\":100}\n\
                    {\"index\":3,\"train_episodes\":150}\n{\"index\":3,\"train";
        std::fs::write(dir.join("eval.jsonl"), eval).unwrap();

        let point = ResumePoint {
            sequence: Some(7),
            env_steps: 300,
            episodes: Some(100),
        };
        let moved = move_lines_past(&dir, point).unwrap();
        let summary: Vec<(String, u64)> = moved
            .iter()
            .map(|m| {
                (
                    m.file.file_name().unwrap().to_string_lossy().into_owned(),
                    m.lines,
                )
            })
            .collect();
        assert_eq!(
            summary,
            [
                ("metrics.jsonl".to_owned(), 2),
                ("metrics.csv".to_owned(), 2),
                ("eval.jsonl".to_owned(), 1)
            ]
        );
        assert_eq!(
            std::fs::read_to_string(dir.join("metrics.jsonl")).unwrap(),
            jsonl[..4].join("\n") + "\n"
        );
        assert_eq!(
            std::fs::read_to_string(dir.join("metrics.csv")).unwrap(),
            "wall_secs,env_steps_per_sec,actor_restarts,learner/ingest/env_steps\n1,0,0,100\n2,0,0,300\n"
        );
        assert_eq!(
            std::fs::read_to_string(dir.join("eval.jsonl")).unwrap(),
            "{\"index\":1,\"train_episodes\":50}\n{\"index\":2,\"train_episodes\":100}\n"
        );
        // Nothing is lost: each side file holds exactly what its record file lost.
        assert_eq!(
            side_files(&dir),
            [
                (
                    "eval.jsonl".to_owned(),
                    "{\"index\":3,\"train_episodes\":150}\n{\"index\":3,\"train".to_owned()
                ),
                (
                    "metrics.csv".to_owned(),
                    "3,0,0,301\n4,0,0,500\n".to_owned()
                ),
                ("metrics.jsonl".to_owned(), jsonl[4..].join("\n") + "\n"),
            ]
        );
        assert!(moved
            .iter()
            .all(|m| m.side_file.to_string_lossy().contains(".past-ckpt-7-")));

        // A second pass at the same point finds nothing more to move.
        assert_eq!(move_lines_past(&dir, point).unwrap(), []);
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn tensorboard_events_past_the_checkpoint_move_to_a_folder_of_their_own() {
        use crate::tensorboard::{read_events, EventWriter};
        let dir = scratch("events");
        let mut writer = EventWriter::create(&dir.join("tensorboard")).unwrap();
        for step in [100, 200, 300, 400] {
            writer
                .add_scalars(step, 1.0, &[("a", step as f32)])
                .unwrap();
        }
        writer.flush().unwrap();
        let path = writer.path().to_path_buf();
        drop(writer);
        // A record half-written at the kill.
        let mut bytes = std::fs::read(&path).unwrap();
        let whole = bytes.len();
        bytes.extend_from_within(whole - 20..whole - 10);
        std::fs::write(&path, &bytes).unwrap();

        let point = ResumePoint {
            sequence: Some(4),
            env_steps: 250,
            episodes: None,
        };
        let moved = move_lines_past(&dir, point).unwrap();
        assert_eq!(moved.len(), 1);
        assert_eq!(
            (moved[0].file.as_path(), moved[0].lines, moved[0].unit),
            (path.as_path(), 2, "events")
        );
        let steps =
            |p: &Path| -> Vec<i64> { read_events(p).unwrap().iter().map(|e| e.step).collect() };
        // The file version record (step 0) and the two events up to the checkpoint stay.
        assert_eq!(steps(&path), [0, 100, 200]);
        let side = &moved[0].side_file;
        assert!(side
            .parent()
            .unwrap()
            .file_name()
            .unwrap()
            .to_string_lossy()
            .starts_with("tensorboard.past-ckpt-4-"));
        assert_eq!(side.file_name(), path.file_name());
        let side_bytes = std::fs::read(side).unwrap();
        assert_eq!(
            side_bytes.len() + std::fs::metadata(&path).unwrap().len() as usize,
            bytes.len()
        );
        assert!(format!("{:#}", read_events(side).unwrap_err()).contains("truncated"));
        let readable = &side_bytes[..side_bytes.len() - 10];
        std::fs::write(dir.join("readable"), readable).unwrap();
        assert_eq!(steps(&dir.join("readable")), [300, 400]);
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn eval_lines_stay_when_the_checkpoint_has_no_episode_count_and_missing_files_are_fine() {
        let dir = scratch("old");
        let eval = "{\"index\":1,\"train_episodes\":50}\n{\"index\":2,\"train_episodes\":100}\n";
        std::fs::write(dir.join("eval.jsonl"), eval).unwrap();
        let point = ResumePoint {
            sequence: Some(2),
            env_steps: 10,
            episodes: None,
        };
        assert_eq!(move_lines_past(&dir, point).unwrap(), []);
        assert_eq!(
            std::fs::read_to_string(dir.join("eval.jsonl")).unwrap(),
            eval
        );
        // A half-written last line goes even when no whole line is past: appending to it
        // would corrupt the resumed run's first line.
        let metrics = "{\"learner/ingest/env_steps\":5}\n";
        std::fs::write(
            dir.join("metrics.jsonl"),
            format!("{metrics}{{\"learner/in"),
        )
        .unwrap();
        let moved = move_lines_past(&dir, point).unwrap();
        assert_eq!(moved.len(), 1);
        assert_eq!(moved[0].lines, 0);
        assert_eq!(
            std::fs::read_to_string(dir.join("metrics.jsonl")).unwrap(),
            metrics
        );
        assert_eq!(
            std::fs::read_to_string(&moved[0].side_file).unwrap(),
            "{\"learner/in"
        );
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn a_taken_side_name_gets_a_number_and_a_cut_at_the_start_leaves_eval_alone() {
        let dir = scratch("names");
        let base = dir.join("metrics.jsonl.past-start-5");
        assert_eq!(unused_name(&base), base);
        std::fs::write(&base, "").unwrap();
        assert_eq!(unused_name(&base), dir.join("metrics.jsonl.past-start-5-2"));
        std::fs::write(dir.join("metrics.jsonl.past-start-5-2"), "").unwrap();
        assert_eq!(unused_name(&base), dir.join("metrics.jsonl.past-start-5-3"));
        std::fs::remove_file(&base).unwrap();
        std::fs::remove_file(dir.join("metrics.jsonl.past-start-5-2")).unwrap();

        // A learner restarted without a checkpoint starts over: every counted line goes, twice
        // in a row (the second cut's side file must not collide with the first's, even
        // within one second); eval.jsonl is not the launcher's and stays.
        let eval = "{\"index\":1,\"train_episodes\":50}\n";
        std::fs::write(dir.join("eval.jsonl"), eval).unwrap();
        let mut side = Vec::new();
        for steps in [[10, 20], [5, 15]] {
            let lines = format!(
                "{{\"wall_secs\":0}}\n{{\"learner/ingest/env_steps\":{}}}\n{{\"learner/ingest/env_steps\":{}}}\n",
                steps[0], steps[1]
            );
            std::fs::write(dir.join("metrics.jsonl"), lines).unwrap();
            let moved = move_metrics_past(&dir, ResumePoint::START).unwrap();
            assert_eq!(moved.len(), 1);
            assert_eq!(moved[0].lines, 2);
            assert!(moved[0]
                .side_file
                .to_string_lossy()
                .contains(".past-start-"));
            side.push(moved[0].side_file.clone());
            assert_eq!(
                std::fs::read_to_string(dir.join("metrics.jsonl")).unwrap(),
                "{\"wall_secs\":0}\n"
            );
        }
        assert_ne!(side[0], side[1]);
        assert!(std::fs::read_to_string(&side[0]).unwrap().contains(":20}"));
        assert!(std::fs::read_to_string(&side[1]).unwrap().contains(":15}"));
        assert_eq!(
            std::fs::read_to_string(dir.join("eval.jsonl")).unwrap(),
            eval
        );
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
