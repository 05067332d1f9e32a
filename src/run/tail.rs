//! A resumed run's record files end where its checkpoint was written. A run killed between
//! checkpoints (SIGKILL, power loss, a crash-looping launcher) wrote metrics and evaluations
//! past its newest checkpoint; the resumed run trains that stretch again and writes those lines
//! anew, so appending to the old files would repeat a stretch of every curve (`metrics.jsonl`,
//! `metrics.csv`, `eval.jsonl`, and the plots drawn from them). Before a resume the launch
//! moves each file's lines past the checkpoint — and a last line left half-written — into a
//! side file next to it (`<file>.past-ckpt-<N>-<unix seconds>`): nothing is deleted.
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
    /// N of `ckpt-N` (names the side files).
    pub sequence: u64,
    /// Env steps the learner had ingested.
    pub env_steps: u64,
    /// Episodes it had completed, when the checkpoint records them.
    pub episodes: Option<u64>,
}

/// One file's lines moved aside.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct MovedTail {
    /// The record file.
    pub file: PathBuf,
    /// Whole lines moved (a half-written last line is moved too, not counted here).
    pub lines: u64,
    /// The side file that holds them.
    pub side_file: PathBuf,
}

/// Moves the lines past `point` of the run's `metrics.jsonl`, `metrics.csv` and `eval.jsonl`
/// into side files; returns what was moved (nothing for files that end at the checkpoint).
pub fn move_lines_past(run_dir: &Path, point: ResumePoint) -> anyhow::Result<Vec<MovedTail>> {
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
    if let Some(episodes) = point.episodes {
        let eval = run_dir.join("eval.jsonl");
        moved.extend(move_tail(&eval, point, |line, _| {
            Ok(json_number(line, "train_episodes").is_some_and(|e| e > episodes as f64))
        })?);
    }
    Ok(moved)
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
    let unix = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_secs());
    let side_file = path.with_file_name(format!("{name}.past-ckpt-{}-{unix}", point.sequence));
    // The side file is complete on disk before the record file is cut: a crash in between
    // leaves the lines in both places, never in neither.
    let mut source = reader.into_inner();
    source.seek(SeekFrom::Start(at))?;
    let mut side = File::create_new(&side_file)
        .with_context(|| format!("creating {}", side_file.display()))?;
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
    record.sync_all()?;
    Ok(Some(MovedTail {
        file: path.to_path_buf(),
        lines: index - first,
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
            sequence: 7,
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
    fn eval_lines_stay_when_the_checkpoint_has_no_episode_count_and_missing_files_are_fine() {
        let dir = scratch("old");
        let eval = "{\"index\":1,\"train_episodes\":50}\n{\"index\":2,\"train_episodes\":100}\n";
        std::fs::write(dir.join("eval.jsonl"), eval).unwrap();
        let point = ResumePoint {
            sequence: 2,
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
}
