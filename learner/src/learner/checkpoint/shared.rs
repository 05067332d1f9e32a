//! Observations the SI buffer shares with the φ store, written once (checkpoint format 3).
//!
//! Both keep the observations of every training episode: the φ store as runs (an episode's
//! states `s_0..s_T`), the SI buffer as one entry per step (`s_0..s_{T−1}`). A checkpoint
//! writes the store's runs whole and, for each SI entry, where the same observation lies in
//! them — its *source*, the index of a state in the store's runs laid end to end — or
//! [`LITERAL`] when the store does not hold it (a run dropped as too short or after a physics
//! failure, evicted, or an open episode), whose observation is then written itself.
//!
//! Finding sources: an episode's entries follow each other in a run (with several actors the
//! episodes' chunks interleave in the buffer), so each entry is first compared with the state
//! after the source of the previous entry *of its episode*; failing that, with the first
//! states of the runs (an episode's first entry, or the first state after a gap, where the
//! store starts a new run). A match is bitwise, so the observations come back exactly; an
//! entry matched by neither is literal (correct, only larger).

use std::collections::HashMap;

/// The source of an entry whose observation is written itself.
pub(super) const LITERAL: i64 = -1;

/// Every SI entry's source, and the observations of the [`LITERAL`] ones in entry order.
#[derive(Debug, Clone, PartialEq)]
pub(super) struct Shared {
    pub sources: Vec<i64>,
    pub literal: Vec<f32>,
}

/// Sources of the entries `obs` (rows of `dim` floats; entry i of episode `episodes[i]`) in
/// `runs` (the φ store's observations, run by run, rows of `dim` floats).
pub(super) fn share(runs: &[&[f32]], obs: &[f32], episodes: &[u64], dim: usize) -> Shared {
    let dim = dim.max(1);
    let mut offsets = Vec::with_capacity(runs.len());
    let mut starts: HashMap<Vec<u32>, usize> = HashMap::with_capacity(runs.len());
    let mut total = 0usize;
    for (index, run) in runs.iter().enumerate() {
        offsets.push(total);
        if let Some(first) = run.get(..dim) {
            starts.entry(bits(first)).or_insert(index);
        }
        total += run.len() / dim;
    }
    let state = |run: usize, t: usize| runs.get(run)?.get(t * dim..(t + 1) * dim);
    let mut shared = Shared {
        sources: Vec::with_capacity(obs.len() / dim),
        literal: Vec::new(),
    };
    // Per episode, the (run, step) its next entry is expected at.
    let mut cursors: HashMap<u64, (usize, usize)> = HashMap::new();
    for (row, episode) in obs.chunks_exact(dim).zip(episodes) {
        let expected = cursors
            .get(episode)
            .copied()
            .filter(|&(run, t)| state(run, t).is_some_and(|s| same(s, row)));
        let found = expected.or_else(|| starts.get(&bits(row)).map(|&run| (run, 0)));
        match found {
            Some((run, t)) => {
                shared.sources.push((offsets[run] + t) as i64);
                cursors.insert(*episode, (run, t + 1));
            }
            None => {
                shared.sources.push(LITERAL);
                shared.literal.extend_from_slice(row);
                cursors.remove(episode);
            }
        }
    }
    shared
}

/// The entries' observations back from their `sources` in `runs` and the `literal` rows;
/// an error when a source is outside the runs or the literal rows do not match the count.
pub(super) fn unshare(
    runs: &[&[f32]],
    sources: &[i64],
    literal: &[f32],
    dim: usize,
) -> Result<Vec<f32>, String> {
    let dim = dim.max(1);
    let mut ends = Vec::with_capacity(runs.len());
    let mut total = 0usize;
    for run in runs {
        total += run.len() / dim;
        ends.push(total);
    }
    let n_literal = sources.iter().filter(|&&s| s == LITERAL).count();
    if literal.len() != n_literal * dim {
        return Err(format!(
            "{} literal observation floats for {n_literal} literal entries (dim {dim})",
            literal.len()
        ));
    }
    let mut literal_rows = literal.chunks_exact(dim);
    let mut obs = Vec::with_capacity(sources.len() * dim);
    for (entry, &source) in sources.iter().enumerate() {
        let row = match source {
            // Invariant: `literal` holds one row per LITERAL source (checked above).
            LITERAL => literal_rows.next().unwrap_or(&[]),
            s => {
                let flat = usize::try_from(s)
                    .ok()
                    .filter(|&f| f < total)
                    .ok_or_else(|| {
                        format!("entry {entry}: source {s} is not a state of the φ store ({total})")
                    })?;
                let run = ends.partition_point(|&end| end <= flat);
                let t = flat - (ends[run] - runs[run].len() / dim);
                &runs[run][t * dim..(t + 1) * dim]
            }
        };
        obs.extend_from_slice(row);
    }
    Ok(obs)
}

fn bits(row: &[f32]) -> Vec<u32> {
    row.iter().map(|x| x.to_bits()).collect()
}

fn same(a: &[f32], b: &[f32]) -> bool {
    a.len() == b.len() && a.iter().zip(b).all(|(x, y)| x.to_bits() == y.to_bits())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Run `r` of `n` states: state t is `[r, t, r·t]` (dim 3).
    fn run(r: usize, n: usize) -> Vec<f32> {
        (0..n)
            .flat_map(|t| [r as f32, t as f32, (r * t) as f32])
            .collect()
    }

    fn round_trip(runs: &[Vec<f32>], obs: &[f32], episodes: &[u64]) -> Shared {
        let views: Vec<&[f32]> = runs.iter().map(Vec::as_slice).collect();
        let shared = share(&views, obs, episodes, 3);
        let back = unshare(&views, &shared.sources, &shared.literal, 3).unwrap();
        let as_bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
        assert_eq!(as_bits(&back), as_bits(obs));
        shared
    }

    #[test]
    fn episodes_in_the_store_are_referenced_wherever_they_begin_and_the_rest_is_literal() {
        let runs = vec![run(0, 5), run(1, 4), run(2, 6)];
        // SI entries: episode 1's first three steps (its last state is s_T, not an entry),
        // then episode 0's four, episode 2 from its start to step 2, an episode the store does
        // not hold (two states of "run 7"), then episode 2 resumed at step 4 (not a start).
        let mut obs = Vec::new();
        obs.extend_from_slice(&runs[1][..9]);
        obs.extend_from_slice(&runs[0][..12]);
        obs.extend_from_slice(&runs[2][..9]);
        obs.extend_from_slice(&run(7, 2));
        obs.extend_from_slice(&runs[2][12..15]);
        let episodes = [1, 1, 1, 0, 0, 0, 0, 2, 2, 2, 7, 7, 2];
        let shared = round_trip(&runs, &obs, &episodes);
        // Runs laid end to end: run 0 at 0..5, run 1 at 5..9, run 2 at 9..15.
        assert_eq!(
            shared.sources,
            [5, 6, 7, 0, 1, 2, 3, 9, 10, 11, LITERAL, LITERAL, LITERAL]
        );
        assert_eq!(shared.literal.len(), 3 * 3);
        // Run 7's first state equals no run's (7 ≠ 0, 1, 2); step 4 of run 2 follows a literal.
        assert_eq!(&shared.literal[6..], &runs[2][12..15]);
    }

    #[test]
    fn interleaved_chunks_of_several_episodes_follow_each_their_own_run() {
        let runs = vec![run(0, 6), run(1, 6)];
        // Two actors' chunks of two steps, alternating: 0:0-1, 1:0-1, 0:2-3, 1:2-3, 0:4.
        let mut obs = Vec::new();
        let mut episodes = Vec::new();
        for (e, from) in [(0, 0), (1, 0), (0, 2), (1, 2), (0, 4)] {
            let steps = if from == 4 { 1 } else { 2 };
            obs.extend_from_slice(&runs[e][from * 3..(from + steps) * 3]);
            episodes.extend(std::iter::repeat_n(e as u64, steps));
        }
        let shared = round_trip(&runs, &obs, &episodes);
        assert_eq!(shared.sources, [0, 1, 6, 7, 2, 3, 8, 9, 4]);
        assert!(shared.literal.is_empty());
    }

    #[test]
    fn matches_are_bit_for_bit() {
        // −0.0 equals 0.0 as a float but is another observation; NaN is equal to itself here.
        let nan = f32::from_bits(0x7fc0_0001);
        let runs = vec![vec![0.0, 1.0, 2.0, nan, 1.0, 2.0, 5.0, 5.0, 5.0]];
        let obs = [0.0, 1.0, 2.0, nan, 1.0, 2.0, -0.0, 1.0, 2.0, nan, 1.0, 2.0];
        let shared = round_trip(&runs, &obs, &[0, 0, 1, 1]);
        // −0.0 is not run 0's start, so it and the state after it are literal.
        assert_eq!(shared.sources, [0, 1, LITERAL, LITERAL]);
    }

    #[test]
    fn sources_outside_the_store_or_a_wrong_literal_count_are_refused() {
        let runs = [run(0, 3)];
        let views: Vec<&[f32]> = runs.iter().map(Vec::as_slice).collect();
        let err = unshare(&views, &[0, 3], &[], 3).unwrap_err();
        assert!(err.contains("source 3"), "{err}");
        let err = unshare(&views, &[-2], &[], 3).unwrap_err();
        assert!(err.contains("source -2"), "{err}");
        let err = unshare(&views, &[LITERAL, 0], &[1.0, 2.0], 3).unwrap_err();
        assert!(err.contains("2 literal observation floats for 1"), "{err}");
        assert_eq!(unshare(&views, &[], &[], 3).unwrap(), Vec::<f32>::new());
    }
}
