//! The progress of a long loop (the stylization, the 2D fit) on stderr: a bar on a terminal;
//! where stderr is not one (a log file, `nohup`, CI), one plain line every
//! [`LINE_EVERY_PERCENT`] % of the steps, and at least every [`LINE_EVERY`] while steps come,
//! with the step, the percentage, the time elapsed, the estimated time left and the last loss,
//! so that a redirected run still says how far it is.
//! The bar is cleared when the loop ends and its last state printed as such a line, so that
//! whatever is printed next starts on a line of its own.
//!
//! A loop whose stages run at different speeds (a 4D fit: a static warm-up, then the
//! deformation network, then sub-Gaussians) names the steps where its stages begin
//! ([`Progress::with_stages`]): the time left is then estimated from the current stage's
//! speed, measured from its first step, not from the whole loop's average.

use std::cell::{Cell, RefCell};
use std::io::IsTerminal;
use std::ops::ControlFlow;
use std::sync::atomic::Ordering;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use gs_core::dataset::ImageProgress;
use gs_core::train::StepReport;

use indicatif::{ProgressBar, ProgressStyle};

use crate::{RunOptions, StylizeError};

/// The plain lines come every this many percent of the steps (and at the last step).
pub const LINE_EVERY_PERCENT: u64 = 5;

/// A plain line comes at least this often (at the next step after it), whatever the percentage.
pub const LINE_EVERY: Duration = Duration::from_secs(30);

/// How the progress is shown.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ProgressMode {
    /// Not at all (`--quiet`).
    Hidden,
    /// A bar redrawn in place (stderr is a terminal).
    Bar,
    /// A plain line every [`LINE_EVERY_PERCENT`] % (stderr is a file or a pipe).
    Lines,
}

impl ProgressMode {
    /// [`ProgressMode::Hidden`] unless `show`, else a bar when stderr is a terminal and plain
    /// lines when it is not.
    pub fn for_stderr(show: bool) -> Self {
        match (show, std::io::stderr().is_terminal()) {
            (false, _) => Self::Hidden,
            (true, true) => Self::Bar,
            (true, false) => Self::Lines,
        }
    }
}

/// The progress of one loop of `total` steps (see the module documentation).
#[derive(Debug)]
pub struct Progress {
    label: String,
    total: u64,
    /// Steps already taken when this process started the loop (a resumed run).
    first: u64,
    started: Instant,
    bar: Option<ProgressBar>,
    mode: ProgressMode,
    /// The step and message of the last update.
    last: RefCell<(u64, String)>,
    /// The last step a line was printed for.
    printed: Cell<u64>,
    /// When the last line was printed (or the loop started).
    printed_at: Cell<Instant>,
    /// Step counts after which a new stage begins, ascending.
    stages: Vec<u64>,
    /// The current stage: the steps taken when it began and the time since the start then.
    stage: Cell<(u64, Duration)>,
}

impl Progress {
    /// The progress of a loop of `total` steps of which `done` are already taken, labelled
    /// `label` (e.g. `fit`), shown as [`ProgressMode::for_stderr`] chooses.
    pub fn new(show: bool, label: &str, total: u64, done: u64) -> Self {
        Self::with_mode(ProgressMode::for_stderr(show), label, total, done)
    }

    /// As [`Progress::new`] with the mode given.
    pub fn with_mode(mode: ProgressMode, label: &str, total: u64, done: u64) -> Self {
        let bar = (mode == ProgressMode::Bar).then(|| {
            let bar = ProgressBar::new(total);
            bar.set_style(
                ProgressStyle::with_template(
                    "{prefix}{bar:30} {pos}/{len} [{elapsed_precise} < {eta_precise}] {msg}",
                )
                .expect("a valid template"),
            );
            bar.set_prefix(format!("{label} "));
            bar.set_position(done);
            bar.reset_eta();
            bar
        });
        Self {
            label: label.to_string(),
            total,
            first: done,
            started: Instant::now(),
            bar,
            mode,
            last: RefCell::new((done, String::new())),
            printed: Cell::new(done),
            printed_at: Cell::new(Instant::now()),
            stages: Vec::new(),
            stage: Cell::new((done, Duration::ZERO)),
        }
    }

    /// The same progress for a loop whose stages begin after the step counts `stages` (see
    /// the module documentation).
    pub fn with_stages(mut self, stages: &[u64]) -> Self {
        self.stages = stages.to_vec();
        self.stages.sort_unstable();
        self
    }

    /// Starts the stage that begins after `step` steps when it has not begun yet, at
    /// `elapsed` since the loop started.
    fn enter_stage(&self, step: u64, elapsed: Duration) {
        let (first, _) = self.stage.get();
        if self.stages.iter().any(|&b| first < b && b <= step) {
            self.stage.set((step, elapsed));
            if let Some(bar) = &self.bar {
                bar.reset_eta();
            }
        }
    }

    /// Records that `step` steps are taken, the last with `message` (e.g. `loss 0.1234`);
    /// prints a line when the step crosses the next [`LINE_EVERY_PERCENT`] % or is the last.
    pub fn update(&self, step: u64, message: &str) {
        self.enter_stage(step, self.started.elapsed());
        *self.last.borrow_mut() = (step, message.to_string());
        if let Some(bar) = &self.bar {
            bar.set_position(step);
            bar.set_message(message.to_string());
        } else if self.mode == ProgressMode::Lines
            && self.line_due(step, self.printed_at.get().elapsed())
        {
            self.print_line();
        }
    }

    /// Whether a plain line is due at `step`, `since_last` after the last one: at the last
    /// step, when the step crosses the next [`LINE_EVERY_PERCENT`] %, or [`LINE_EVERY`] after
    /// the last line.
    fn line_due(&self, step: u64, since_last: Duration) -> bool {
        step >= self.total
            || bucket(step, self.total) > bucket(self.printed.get(), self.total)
            || (step > self.printed.get() && since_last >= LINE_EVERY)
    }

    /// Ends the progress display: clears the bar and prints its last state as a line (in line
    /// mode, the last state when it was not printed yet). Call it before printing anything
    /// else, when the loop ends or stops.
    pub fn finish(&self) {
        if let Some(bar) = &self.bar {
            bar.finish_and_clear();
        }
        if self.mode != ProgressMode::Hidden && self.printed.get() != self.last.borrow().0 {
            self.print_line();
        }
    }

    /// Prints the line of the last update.
    fn print_line(&self) {
        let (step, message) = &*self.last.borrow();
        eprintln!("{}", self.line(*step, message, self.started.elapsed()));
        self.printed.set(*step);
        self.printed_at.set(Instant::now());
    }

    /// `fit: step 40/800 (5%), 0:01:02 elapsed, about 0:19:38 left, loss 0.1234`, where
    /// `elapsed` is the time since this process started the loop; the time left is at the
    /// current stage's speed once it has taken a step, else at the loop's.
    pub fn line(&self, step: u64, message: &str, elapsed: Duration) -> String {
        let percent = step
            .saturating_mul(100)
            .checked_div(self.total)
            .unwrap_or(100);
        let done_here = step.saturating_sub(self.first);
        let (stage_first, stage_began) = self.stage.get();
        let done_in_stage = step.saturating_sub(stage_first);
        let per_step = if done_in_stage > 0 {
            Some(elapsed.saturating_sub(stage_began).as_secs_f64() / done_in_stage as f64)
        } else {
            (done_here > 0).then(|| elapsed.as_secs_f64() / done_here as f64)
        };
        let left = match per_step {
            _ if step >= self.total => "done".to_string(),
            None => "time left unknown".to_string(),
            Some(per_step) => {
                let left = Duration::from_secs_f64(per_step * (self.total - step) as f64);
                format!("about {} left", clock(left))
            }
        };
        let mut line = format!(
            "{}: step {step}/{} ({percent}%), {} elapsed, {left}",
            self.label,
            self.total,
            clock(elapsed)
        );
        if !message.is_empty() {
            line.push_str(", ");
            line.push_str(message);
        }
        line
    }
}

/// Which [`LINE_EVERY_PERCENT`] % slice of `total` steps `step` is in.
fn bucket(step: u64, total: u64) -> u64 {
    step.saturating_mul(100 / LINE_EVERY_PERCENT) / total.max(1)
}

/// `h:mm:ss`.
pub(crate) fn clock(d: Duration) -> String {
    let s = d.as_secs();
    format!("{}:{:02}:{:02}", s / 3600, s / 60 % 60, s % 60)
}

/// Runs `work`, the fit of a base model (`what`: `the picture`, `the video`, `the scene`) in
/// `steps` steps whose later stages begin after the step counts `stages`
/// ([`Progress::with_stages`]; none for a fit of one stage), with its progress shown as `fit`
/// when `options.progress`: `work` gets the per-step callback, which shows the step's loss and
/// asks the loop to stop once `options.stop` is set (Ctrl-C). Returns `work`'s result, or
/// [`StylizeError::InterruptedFit`] when it was stopped.
pub fn fit_with_progress<T, E: From<StylizeError>>(
    what: &str,
    steps: u64,
    stages: &[u64],
    options: &RunOptions,
    work: impl FnOnce(&mut dyn FnMut(&StepReport) -> ControlFlow<()>) -> Result<T, E>,
) -> Result<T, E> {
    let progress = Progress::new(options.progress, "fit", steps, 0).with_stages(stages);
    let result = work(&mut |report: &StepReport| {
        progress.update(report.step, &format!("loss {:.4}", report.value.loss));
        if options.stop.load(Ordering::SeqCst) {
            ControlFlow::Break(())
        } else {
            ControlFlow::Continue(())
        }
    });
    progress.finish();
    let fitted = result?;
    if options.stop.load(Ordering::SeqCst) {
        return Err(StylizeError::InterruptedFit { what: what.into() }.into());
    }
    Ok(fitted)
}

/// Runs `load` with the progress of its pictures shown as a [`LoadingProgress`] labelled
/// `label` (when `show`), and ends the display once `load` returns, whatever it returns.
pub fn with_loading_progress<T>(
    show: bool,
    label: &str,
    load: impl FnOnce(&ImageProgress) -> T,
) -> T {
    let loading = LoadingProgress::new(show, label);
    let loaded = load(&loading.reporter());
    loading.finish();
    loaded
}

/// The progress of loading pictures (a dataset's, a video's frames), shown as [`Progress`]
/// lines or a bar labelled `label` as the loaders report each picture decoded
/// ([`gs_core::dataset::ImageProgress`]); a loading of several parts (a scene's splits) shows
/// each part as it comes.
pub struct LoadingProgress {
    show: bool,
    label: String,
    current: Arc<Mutex<Option<(usize, Progress)>>>,
}

impl LoadingProgress {
    /// A loading's progress, shown when `show`.
    pub fn new(show: bool, label: &str) -> Self {
        Self {
            show,
            label: label.to_string(),
            current: Arc::new(Mutex::new(None)),
        }
    }

    /// What the loaders report to (`LoadOptions::progress`).
    pub fn reporter(&self) -> ImageProgress {
        let (show, label, current) = (self.show, self.label.clone(), self.current.clone());
        ImageProgress::new(move |done, total| {
            let mut current = current.lock().unwrap_or_else(|e| e.into_inner());
            // A new part when none is shown, the total changed, or the part shown is complete
            // (parallel loaders may report their counts out of order within a part).
            let new_part = current.as_ref().is_none_or(|(part_total, part)| {
                *part_total != total || part.last.borrow().0 >= *part_total as u64
            });
            if new_part {
                if let Some((_, part)) = current.take() {
                    part.finish();
                }
                *current = Some((total, Progress::new(show, &label, total as u64, 0)));
            }
            if let Some((_, part)) = current.as_ref() {
                part.update(done as u64, &format!("picture {done} of {total}"));
            }
        })
    }

    /// Ends the display (call it once the loading is done, before printing anything else).
    pub fn finish(&self) {
        let mut current = self.current.lock().unwrap_or_else(|e| e.into_inner());
        if let Some((_, part)) = current.take() {
            part.finish();
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A loop of a fast stage then a slow one: once the slow one has taken a step, the time
    /// left is at its speed, not at the average of both.
    #[test]
    fn the_time_left_is_at_the_current_stages_speed() {
        let p = Progress::with_mode(ProgressMode::Hidden, "fit", 1000, 0).with_stages(&[500, 100]);
        p.enter_stage(50, Duration::from_secs(5));
        assert_eq!(p.stage.get(), (0, Duration::ZERO), "no stage begins at 50");
        // 100 steps in 10 s: 0.1 s a step for the 900 left.
        let line = p.line(100, "", Duration::from_secs(10));
        assert!(line.contains("about 0:01:30 left"), "{line}");
        p.enter_stage(100, Duration::from_secs(10));
        // The second stage: 10 steps in 10 s, 1 s a step for the 890 left (the average of
        // both stages would say 2:42).
        let line = p.line(110, "", Duration::from_secs(20));
        assert!(line.contains("about 0:14:50 left"), "{line}");
        p.enter_stage(600, Duration::from_secs(410));
        assert_eq!(p.stage.get(), (600, Duration::from_secs(410)));
        // No step of the third stage yet: the whole loop's speed, 410 s for 600 steps.
        let line = p.line(600, "", Duration::from_secs(410));
        assert!(line.contains("about 0:04:33 left"), "{line}");
    }

    /// A loading of two parts (a scene's splits) shows each part as it comes, and the display
    /// ends with `finish`.
    #[test]
    fn a_loading_starts_a_new_part_when_the_count_starts_again() {
        let loading = LoadingProgress::new(false, "loading pictures");
        let report = loading.reporter();
        let part = |loading: &LoadingProgress| {
            let current = loading.current.lock().unwrap();
            current
                .as_ref()
                .map(|(total, p)| (*total, p.last.borrow().0))
        };
        report.report(2, 3);
        report.report(1, 3);
        assert_eq!(
            part(&loading),
            Some((3, 1)),
            "counts out of order stay in their part"
        );
        report.report(3, 3);
        assert_eq!(part(&loading), Some((3, 3)));
        report.report(1, 3);
        assert_eq!(
            part(&loading),
            Some((3, 1)),
            "a split of the same size is a new part"
        );
        report.report(1, 2);
        assert_eq!(part(&loading), Some((2, 1)), "so is one of another size");
        loading.finish();
        assert_eq!(part(&loading), None);
    }

    #[test]
    fn lines_come_every_five_percent_and_estimate_the_time_left() {
        let p = Progress::with_mode(ProgressMode::Lines, "stylize", 1000, 200);
        let printed: Vec<u64> = (201..=1000)
            .filter(|&s| bucket(s, 1000) > bucket(s - 1, 1000) || s == 1000)
            .collect();
        assert_eq!(printed.len(), 16);
        assert_eq!((printed[0], printed[15]), (250, 1000));
        let line = p.line(250, "loss 0.5000", Duration::from_secs(100));
        assert_eq!(
            line,
            "stylize: step 250/1000 (25%), 0:01:40 elapsed, about 0:25:00 left, loss 0.5000"
        );
        assert!(p
            .line(200, "", Duration::ZERO)
            .ends_with("time left unknown"));
        assert!(p
            .line(1000, "", Duration::from_secs(3725))
            .contains("1:02:05 elapsed, done"));
    }

    /// Between two 5 % marks a slow loop still prints a line every 30 s, at a new step only.
    #[test]
    fn a_slow_loop_prints_a_line_at_least_every_thirty_seconds() {
        let p = Progress::with_mode(ProgressMode::Lines, "caching views", 1000, 0);
        let soon = Duration::from_secs(29);
        assert!(!p.line_due(1, soon));
        assert!(p.line_due(1, LINE_EVERY));
        assert!(p.line_due(50, soon), "the 5 % mark");
        assert!(p.line_due(1000, Duration::ZERO), "the last step");
        assert!(!p.line_due(0, Duration::from_secs(300)), "no new step");
    }
}
