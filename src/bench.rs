//! `asi bench …`: throughput measurements printed as `name: value` lines, the last one the
//! headline figure, so scripts can `tail -n 1`.
//!
//! - `env`: control steps per second of one environment (here).
//! - `ipc`: iceoryx2 against a Unix domain socket between real processes ([`ipc`]).
//! - `system`: end-to-end `asi train` runs for several actor counts ([`system`]).
//!
//! The pure helpers shared by the measurements (percentiles, aligned tables) live here too.

#[path = "bench_ipc.rs"]
pub mod ipc;
#[path = "bench_learner.rs"]
pub mod learner;
#[path = "bench_system.rs"]
pub mod system;

use anyhow::Context;

use crate::cli::{BenchCommand, BenchEnvArgs};

pub fn run(command: BenchCommand) -> anyhow::Result<()> {
    match command {
        BenchCommand::Env(args) => bench_env(&args),
        BenchCommand::Ipc(args) => ipc::run(&args),
        BenchCommand::IpcWorker(args) => ipc::run_worker(&args.spec),
        BenchCommand::System(args) => system::run(&args),
        BenchCommand::Learner(args) => learner::run(&args),
        BenchCommand::Graph(args) => crate::bench_graph::run(&args),
    }
}

fn bench_env(args: &BenchEnvArgs) -> anyhow::Result<()> {
    anyhow::ensure!(
        args.steps > 0 && args.repeats > 0,
        "--steps and --repeats must be positive"
    );
    let report = envs::bench::run(&args.task, args.steps, args.repeats, args.seed)
        .with_context(|| format!("benchmarking task `{}`", args.task))?;
    println!("task: {}", report.task);
    println!("steps_per_repeat: {}", report.steps);
    for (i, rate) in report.per_repeat.iter().enumerate() {
        println!("repeat_{i}_steps_per_sec: {rate:.0}");
    }
    println!("physics_failures: {}", report.n_physics_failures);
    println!("env_steps_per_sec: {:.0}", report.median);
    Ok(())
}

/// The `p`-th percentile (0–100) of `sorted` by the nearest-rank rule: the smallest value such
/// that at least `p` % of the values are at most it. `None` for an empty sample or a `p`
/// outside 0–100. `sorted` must be in ascending order.
pub fn percentile(sorted: &[u64], p: f64) -> Option<u64> {
    if sorted.is_empty() || !(0.0..=100.0).contains(&p) {
        return None;
    }
    let rank = (p / 100.0 * sorted.len() as f64).ceil() as usize;
    Some(sorted[rank.clamp(1, sorted.len()) - 1])
}

/// Names of the iceoryx2 services on this machine that contain `fragment` (a run id): after a
/// clean stop of that run there must be none. A listing failure is logged and gives none.
pub fn services_containing(fragment: &str) -> Vec<String> {
    use iceoryx2::prelude::*;
    let mut found = Vec::new();
    let listed = ipc::Service::list(iceoryx2::config::Config::global_config(), |service| {
        let name = service.static_details.name().to_string();
        if name.contains(fragment) {
            found.push(name);
        }
        CallbackProgression::Continue
    });
    if let Err(err) = listed {
        tracing::warn!("could not list iceoryx2 services: {err:?}");
    }
    found
}

/// A text table: the first column left-aligned (labels), the others right-aligned (numbers),
/// a dashed rule under the header. Short rows are padded with empty cells.
#[derive(Debug, Clone, Default)]
pub struct Table {
    header: Vec<String>,
    rows: Vec<Vec<String>>,
}

impl Table {
    /// A table with these column titles.
    pub fn new<S: ToString>(header: &[S]) -> Self {
        Self {
            header: header.iter().map(ToString::to_string).collect(),
            rows: Vec::new(),
        }
    }

    /// Appends a row; cells beyond the header's width are kept and widen the table.
    pub fn push<S: ToString>(&mut self, cells: &[S]) {
        self.rows
            .push(cells.iter().map(ToString::to_string).collect());
    }

    /// The table as lines joined by `\n`, with a trailing newline.
    pub fn render(&self) -> String {
        let n_cols = std::iter::once(&self.header)
            .chain(&self.rows)
            .map(Vec::len)
            .max()
            .unwrap_or(0);
        let cell = |row: &[String], col: usize| row.get(col).cloned().unwrap_or_default();
        let widths: Vec<usize> = (0..n_cols)
            .map(|col| {
                std::iter::once(&self.header)
                    .chain(&self.rows)
                    .map(|r| cell(r, col).chars().count())
                    .max()
                    .unwrap_or(0)
            })
            .collect();
        let line = |row: &[String]| {
            let cells: Vec<String> = widths
                .iter()
                .enumerate()
                .map(|(col, &w)| {
                    if col == 0 {
                        format!("{:<w$}", cell(row, col))
                    } else {
                        format!("{:>w$}", cell(row, col))
                    }
                })
                .collect();
            cells.join("  ").trim_end().to_owned()
        };
        let rule = "-".repeat(widths.iter().sum::<usize>() + 2 * n_cols.saturating_sub(1));
        let mut out = format!("{}\n{rule}\n", line(&self.header));
        for row in &self.rows {
            out.push_str(&line(row));
            out.push('\n');
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};

    /// Reference: the smallest sample value with at least `p` % of the sample at or below it,
    /// found by counting for every candidate.
    fn brute_force_percentile(values: &[u64], p: f64) -> u64 {
        let n = values.len() as f64;
        let mut candidates = values.to_vec();
        candidates.sort_unstable();
        candidates
            .into_iter()
            .find(|&v| values.iter().filter(|&&x| x <= v).count() as f64 >= p / 100.0 * n)
            .expect("the maximum always qualifies")
    }

    #[test]
    fn percentiles_agree_with_a_brute_force_count_on_random_samples() {
        let mut rng = rand::rngs::StdRng::seed_from_u64(7);
        for _ in 0..300 {
            let len = rng.random_range(1..60);
            let values: Vec<u64> = (0..len).map(|_| rng.random_range(0..20)).collect();
            let mut sorted = values.clone();
            sorted.sort_unstable();
            for p in [
                0.0,
                1.0,
                25.0,
                50.0,
                90.0,
                99.0,
                99.9,
                100.0,
                rng.random_range(0.0..100.0),
            ] {
                assert_eq!(
                    percentile(&sorted, p),
                    Some(brute_force_percentile(&values, p)),
                    "p{p} of {values:?}"
                );
            }
        }
    }

    #[test]
    fn percentiles_of_one_to_a_hundred_are_the_rank() {
        let sorted: Vec<u64> = (1..=100).collect();
        assert_eq!(percentile(&sorted, 50.0), Some(50));
        assert_eq!(percentile(&sorted, 99.0), Some(99));
        assert_eq!(percentile(&sorted, 0.0), Some(1));
        assert_eq!(percentile(&sorted, 100.0), Some(100));
    }

    #[test]
    fn an_empty_sample_or_a_bad_p_has_no_percentile() {
        assert_eq!(percentile(&[], 50.0), None);
        assert_eq!(percentile(&[1, 2], -1.0), None);
        assert_eq!(percentile(&[1, 2], 100.5), None);
        assert_eq!(percentile(&[1, 2], f64::NAN), None);
    }

    #[test]
    fn a_table_aligns_labels_left_and_numbers_right() {
        let mut table = Table::new(&["measure", "iceoryx2", "UDS"]);
        table.push(&["chunks/s", "12345", "678"]);
        table.push(&["p99 µs", "7", "1234.5"]);
        let expected = "\
measure   iceoryx2     UDS
--------------------------
chunks/s     12345     678
p99 µs           7  1234.5
";
        assert_eq!(table.render(), expected);
    }

    #[test]
    fn a_short_row_is_padded_and_a_long_one_widens_the_table() {
        let mut table = Table::new(&["a", "b"]);
        table.push(&["x"]);
        table.push(&["y", "1", "22"]);
        assert_eq!(table.render(), "a  b\n--------\nx\ny  1  22\n");
    }
}
