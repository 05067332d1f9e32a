//! The progress line of `asi train` (serial and process mode): where the run stands against
//! its budget, how fast it goes and when it should end. On a terminal it is one line redrawn in
//! place; otherwise (a log file, `nohup`) an info line at most once per interval. It reads the
//! clock for display only: nothing a run computes depends on it.

use std::collections::VecDeque;
use std::io::IsTerminal;
use std::time::{Duration, Instant};

use indicatif::{ProgressBar, ProgressStyle};

/// The line's rates are taken over this much of the recent past: the first episodes of a run
/// (no updates before the replay holds enough) are much faster than the rest.
const RATE_SPAN: Duration = Duration::from_secs(300);

/// What the line shows, read from the run after an episode ended.
#[derive(Debug, Clone, PartialEq)]
pub struct Figures {
    pub episodes: u64,
    pub max_episodes: u64,
    pub env_steps: u64,
    pub max_env_steps: Option<u64>,
    /// `charts/coverage`, for tasks with a maze.
    pub coverage: Option<f64>,
    /// The latest evaluation's success rate and the training episode it was taken at.
    pub eval: Option<(f64, u64)>,
}

/// Episodes and env steps per second over the last `span` (the progress line's five minutes,
/// the launcher's `launcher/env_steps_per_sec` ten seconds).
#[derive(Debug)]
pub struct Rates {
    span: Duration,
    /// (when, episodes, env steps), oldest first.
    samples: VecDeque<(Instant, u64, u64)>,
}

impl Rates {
    /// No samples yet; rates over `span` once there are.
    pub fn over(span: Duration) -> Self {
        Self {
            span,
            samples: VecDeque::new(),
        }
    }

    /// Records where the run stands at `now`. A run that has not moved since the last two
    /// samples only moves the newest one's time on, so frequent calls keep the window short
    /// and a stalled run's rates fall toward 0 instead of keeping their last value.
    pub fn observe(&mut self, now: Instant, episodes: u64, env_steps: u64) {
        let n = self.samples.len();
        let unmoved = |i: usize| {
            let (_, e, s) = self.samples[i];
            (e, s) == (episodes, env_steps)
        };
        if n >= 2 && unmoved(n - 1) && unmoved(n - 2) {
            self.samples[n - 1].0 = now;
        } else {
            self.samples.push_back((now, episodes, env_steps));
        }
        // Keep one sample older than the span, so that the rate always covers the whole span.
        while self.samples.len() > 2 && now.duration_since(self.samples[1].0) >= self.span {
            self.samples.pop_front();
        }
    }

    /// (episodes per second, env steps per second), once time has passed between two samples.
    pub fn per_sec(&self) -> Option<(f64, f64)> {
        let (&(t0, e0, s0), &(t1, e1, s1)) = (self.samples.front()?, self.samples.back()?);
        let secs = t1.duration_since(t0).as_secs_f64();
        (secs > 0.0).then(|| {
            (
                e1.saturating_sub(e0) as f64 / secs,
                s1.saturating_sub(s0) as f64 / secs,
            )
        })
    }
}

/// Time to the first budget reached, at the given rates; `None` when no rate is known yet.
fn eta(figures: &Figures, episodes_per_sec: f64, steps_per_sec: f64) -> Option<Duration> {
    let by_episodes = (episodes_per_sec > 0.0)
        .then(|| figures.max_episodes.saturating_sub(figures.episodes) as f64 / episodes_per_sec);
    let by_steps = figures
        .max_env_steps
        .filter(|_| steps_per_sec > 0.0)
        .map(|max| max.saturating_sub(figures.env_steps) as f64 / steps_per_sec);
    let secs = match (by_episodes, by_steps) {
        (Some(a), Some(b)) => a.min(b),
        (a, b) => a.or(b)?,
    };
    Some(Duration::from_secs_f64(secs))
}

/// `2 h 05 min`, `7 min`, `40 s`.
fn human(d: Duration) -> String {
    let secs = d.as_secs();
    match secs {
        0..60 => format!("{secs} s"),
        60..3600 => format!("{} min", secs / 60),
        _ => format!("{} h {:02} min", secs / 3600, secs % 3600 / 60),
    }
}

/// The text of the progress line.
fn line(figures: &Figures, rates: Option<(f64, f64)>, tail: &[String]) -> String {
    let mut parts = vec![format!(
        "episode {}/{}",
        figures.episodes, figures.max_episodes
    )];
    parts.push(match figures.max_env_steps {
        Some(max) => format!("env steps {}/{max}", figures.env_steps),
        None => format!("env steps {}", figures.env_steps),
    });
    if let Some((episodes_per_sec, steps_per_sec)) = rates {
        parts.push(format!(
            "{:.1} episodes/min, {steps_per_sec:.0} steps/s",
            episodes_per_sec * 60.0
        ));
        let left = eta(figures, episodes_per_sec, steps_per_sec).filter(|d| !d.is_zero());
        if let Some(left) = left {
            parts.push(format!("about {} left", human(left)));
        }
    }
    if let Some(coverage) = figures.coverage {
        parts.push(format!("coverage {coverage:.3}"));
    }
    parts.push(match figures.eval {
        Some((success, at)) => format!("eval success {:.0}% at episode {at}", success * 100.0),
        None => "eval success -".to_owned(),
    });
    parts.extend(tail.iter().cloned());
    parts.join(" | ")
}

/// The progress line of one launch.
pub struct Progress {
    bar: ProgressBar,
    rates: Rates,
    /// How often a line is logged when stderr is not a terminal.
    plain_interval: Duration,
    last_plain: Option<Instant>,
}

impl Progress {
    pub fn new(plain_interval: Duration) -> Self {
        let bar = if std::io::stderr().is_terminal() {
            let bar = ProgressBar::new_spinner();
            bar.set_style(
                ProgressStyle::with_template("{spinner} [{elapsed_precise}] {msg}")
                    .unwrap_or_else(|_| ProgressStyle::default_spinner()),
            );
            bar.enable_steady_tick(Duration::from_millis(200));
            bar
        } else {
            ProgressBar::hidden()
        };
        Self {
            bar,
            rates: Rates::over(RATE_SPAN),
            plain_interval,
            last_plain: None,
        }
    }

    /// Shows where the run stands, with `tail` (more ` | `-separated parts) at the end.
    pub fn show(&mut self, figures: &Figures, tail: &[String]) {
        let now = Instant::now();
        self.rates.observe(now, figures.episodes, figures.env_steps);
        let text = line(figures, self.rates.per_sec(), tail);
        if !self.bar.is_hidden() {
            self.bar.set_message(text);
        } else if self
            .last_plain
            .is_none_or(|t| now.duration_since(t) >= self.plain_interval)
        {
            tracing::info!("{text}");
            self.last_plain = Some(now);
        }
    }

    /// Forgets the rates (the run went back to a checkpoint).
    pub fn reset_rates(&mut self) {
        self.rates = Rates::over(RATE_SPAN);
    }

    /// Removes the line from the terminal and logs where the run ended.
    pub fn finish(&mut self, figures: &Figures, tail: &[String]) {
        self.bar.finish_and_clear();
        self.rates
            .observe(Instant::now(), figures.episodes, figures.env_steps);
        tracing::info!("{}", line(figures, self.rates.per_sec(), tail));
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn figures() -> Figures {
        Figures {
            episodes: 500,
            max_episodes: 2000,
            env_steps: 250_000,
            max_env_steps: None,
            coverage: Some(0.41234),
            eval: Some((0.3, 450)),
        }
    }

    #[test]
    fn the_rates_cover_the_recent_span_only() {
        let t0 = Instant::now();
        let mut rates = Rates::over(RATE_SPAN);
        assert_eq!(rates.per_sec(), None);
        rates.observe(t0, 0, 0);
        assert_eq!(rates.per_sec(), None, "one sample has no rate");
        rates.observe(t0 + Duration::from_secs(30), 0, 0);
        assert_eq!(
            rates.per_sec(),
            Some((0.0, 0.0)),
            "not moving is a rate of 0"
        );
        rates.observe(t0 + Duration::from_secs(40), 0, 0);
        assert_eq!(
            rates.samples.len(),
            2,
            "a run that has not moved only moves the newest sample on"
        );
        // A fast start (100 episodes in the first minute), then 10 episodes a minute.
        rates.observe(t0 + Duration::from_secs(60), 100, 50_000);
        for minute in 2..=11 {
            let episodes = 100 + 10 * (minute - 1);
            rates.observe(
                t0 + Duration::from_secs(60 * minute),
                episodes,
                500 * episodes,
            );
        }
        // The oldest sample kept is the last at least 300 s before the newest (minute 11):
        // minute 6, 150 episodes; 200 at minute 11.
        let (episodes, steps) = rates.per_sec().unwrap();
        assert!((episodes * 60.0 - 10.0).abs() < 1e-9, "{episodes}");
        assert!((steps - 500.0 * 10.0 / 60.0).abs() < 1e-9, "{steps}");
        // Then it stalls: two minutes later the window holds 170 at minute 8 to 200 at 13
        // (6 a minute); five minutes later nothing moved in the whole span.
        rates.observe(t0 + Duration::from_secs(60 * 13), 200, 100_000);
        let (episodes, _) = rates.per_sec().unwrap();
        assert!((episodes * 60.0 - 6.0).abs() < 1e-9, "{episodes}");
        rates.observe(t0 + Duration::from_secs(60 * 16), 200, 100_000);
        assert_eq!(rates.per_sec(), Some((0.0, 0.0)));
    }

    #[test]
    fn the_eta_is_that_of_the_budget_reached_first() {
        let mut f = figures();
        // 1,500 episodes left at 10 a minute: 150 min.
        assert_eq!(eta(&f, 10.0 / 60.0, 100.0), Some(Duration::from_secs(9000)));
        // An env-step budget reached sooner: 50,000 steps left at 100 steps/s.
        f.max_env_steps = Some(300_000);
        assert_eq!(eta(&f, 10.0 / 60.0, 100.0), Some(Duration::from_secs(500)));
        // ... or later: the episode budget is reached first.
        f.max_env_steps = Some(10_000_000);
        assert_eq!(eta(&f, 10.0 / 60.0, 100.0), Some(Duration::from_secs(9000)));
        // No rate yet for episodes: the env-step budget alone.
        assert_eq!(eta(&f, 0.0, 100.0), Some(Duration::from_secs(97_500)));
        f.max_env_steps = None;
        assert_eq!(eta(&f, 0.0, 100.0), None);
        // A budget already passed (the budget was lowered on a resume).
        f.episodes = 2100;
        assert_eq!(eta(&f, 1.0, 100.0), Some(Duration::ZERO));
    }

    #[test]
    fn durations_read_in_hours_minutes_or_seconds() {
        assert_eq!(human(Duration::from_secs(40)), "40 s");
        assert_eq!(human(Duration::from_secs(7 * 60 + 59)), "7 min");
        assert_eq!(
            human(Duration::from_secs(2 * 3600 + 5 * 60 + 30)),
            "2 h 05 min"
        );
    }

    #[test]
    fn the_line_names_budget_rates_eta_coverage_and_evaluation() {
        let f = figures();
        assert_eq!(
            line(&f, Some((10.0 / 60.0, 83.3)), &[]),
            "episode 500/2000 | env steps 250000 | 10.0 episodes/min, 83 steps/s \
             | about 2 h 30 min left | coverage 0.412 | eval success 30% at episode 450"
        );
        let f = Figures {
            max_env_steps: Some(1_000_000),
            coverage: None,
            eval: None,
            ..figures()
        };
        assert_eq!(
            line(&f, None, &["restarts 2".to_owned()]),
            "episode 500/2000 | env steps 250000/1000000 | eval success - | restarts 2"
        );
        // At the end: no time left to show.
        let f = Figures {
            episodes: 2000,
            ..f
        };
        assert_eq!(
            line(&f, Some((0.2, 100.0)), &[]),
            "episode 2000/2000 | env steps 250000/1000000 | 12.0 episodes/min, 100 steps/s \
             | eval success -"
        );
    }
}
